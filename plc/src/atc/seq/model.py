"""Syntax tree of a sequence file: one command per line, every node with its source position.

The parser builds these from text; the checker resolves them against a machine's sequence set; the encoder turns
the resolved commands into steps. Nothing here knows about files on disk or about ST.
"""

from __future__ import annotations

from dataclasses import dataclass
from decimal import Decimal


@dataclass(frozen=True)
class Span:
    """Where a token sits: 1-based line and column, and its width in characters."""

    line: int
    col: int
    width: int = 1


# --- values -----------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Number:
    """A literal such as 10, -5 or 50.25."""

    value: Decimal
    text: str
    span: Span


@dataclass(frozen=True)
class PVar:
    """P variable (P1..): a machine-wide value from the index's [values] table."""

    index: int
    text: str
    span: Span


@dataclass(frozen=True)
class QVar:
    """Q variable (Q1..): the value of the tool the Put/Get Tool sequence is running for."""

    index: int
    text: str
    span: Span


@dataclass(frozen=True)
class ToolQVar:
    """Q variable of a named tool (T2Q4): the same value whichever sequence uses it."""

    tool: int
    index: int
    text: str
    span: Span


Value = Number | PVar | QVar | ToolQVar


@dataclass(frozen=True)
class AxisTarget:
    """One `axis value` pair of MOVEABS or MOVETOEDGE (`Z-10.0`, `Z -10.0`, `X P7`)."""

    axis: str  # upper case letter as written; the checker rejects letters the machine lacks
    axis_span: Span
    value: Value


# --- commands ---------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Command:
    """Fields shared by every command: its keyword's position and the whole source line (for the HMI comment)."""

    span: Span
    source: str

    @property
    def line(self) -> int:
        return self.span.line


@dataclass(frozen=True)
class Out(Command):
    channel: Number
    level: Number


@dataclass(frozen=True)
class WaitIn(Command):
    channel: Number
    level: Number
    timeout: Value  # milliseconds


@dataclass(frozen=True)
class Delay(Command):
    duration: Value  # milliseconds


@dataclass(frozen=True)
class PositionRotary(Command):
    pass


@dataclass(frozen=True)
class HomeRotary(Command):
    pass


@dataclass(frozen=True)
class Message(Command):
    text: str
    text_span: Span
    dialog: bool  # DIALOG waits even when the sequence runs from an M6; MESSAGE is skipped then


@dataclass(frozen=True)
class MoveAbs(Command):
    targets: tuple[AxisTarget, ...]


@dataclass(frozen=True)
class MoveToEdge(Command):
    channel: Number
    level: Number
    target: AxisTarget  # relative distance


@dataclass(frozen=True)
class Feedrate(Command):
    rate: Value  # thousandths of a user unit per second (docs/logosol.md)


@dataclass(frozen=True)
class Spindle(Command):
    mode: str  # "CW", "CCW" or "STOP" (OFF is read as STOP)
    speed: Value | None  # rpm for CW/CCW, None for STOP


@dataclass(frozen=True)
class IfIn(Command):
    """`IFIN n v command`: the command runs only if input n reads v when its step begins (else it is skipped)."""

    channel: Number
    level: Number
    body: Command  # never an IfIn itself


@dataclass(frozen=True)
class SequenceFile:
    """A parsed sequence file: its name as shown in diagnostics, its lines and its commands in order."""

    name: str
    lines: tuple[str, ...]
    commands: tuple[Command, ...]

    def source_line(self, line: int) -> str:
        return self.lines[line - 1] if 1 <= line <= len(self.lines) else ""
