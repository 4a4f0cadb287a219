"""One diagnostic type for every stage: severity, position, message, hint.

Stages collect diagnostics into a `Diagnostics` bag instead of raising, so one run
reports every problem.  `render()` prints the gcc-style line, the source line and
a caret under the column.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Pos:
    """A position in a source file; line and col are 1-based."""
    file: str
    line: int
    col: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.col}"


NOWHERE = Pos("<builtin>", 0, 0)


class InternalError(Exception):
    """A compiler bug: a pass met something it does not handle.  Raised, never turned into output."""

    def __init__(self, pos: Pos, message: str) -> None:
        super().__init__(f"{pos}: internal compiler error: {message}")
        self.pos = pos
        self.message = message


class Severity(str, enum.Enum):
    """A diagnostic's severity; equal to its name as a string ("error" == Severity.ERROR)."""
    ERROR = "error"
    WARNING = "warning"
    NOTE = "note"

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class Layout:
    """How a tool writes a diagnostic's position and hint.  Each tool keeps the output it always had:
    the compiler (and map, deploy, PLCopen) as gcc does, `file:line:col` even for line 0; the sequence tools
    leave out a zero line or column; `plc machine` writes `file:line`."""
    zero_position: bool = True     # write line and column even when 0
    column: bool = True            # write the column at all
    hint_indent: str = "    "


GCC = Layout()
SEQ = Layout(zero_position=False, hint_indent="  ")
FILE_LINE = Layout(column=False)


@dataclass
class Diagnostic:
    """One problem found by any tool: the compiler's stages, the map, the sequence tools, the machine check."""
    severity: str          # "error" | "warning" | "note" (a Severity or its string)
    pos: Pos
    message: str
    hint: str | None = None
    code: str | None = None   # stable identifier, e.g. "portability.comment-line"
    source_line: str = ""     # the offending line, for tools that keep it instead of a SourceSet
    width: int = 1            # how many characters the caret underlines
    layout: Layout = GCC

    @property
    def file(self) -> str:
        return self.pos.file

    @property
    def line(self) -> int:
        return self.pos.line

    @property
    def col(self) -> int:
        return self.pos.col

    def where(self) -> str:
        p, lay = self.pos, self.layout
        if lay.zero_position:
            return f"{p.file}:{p.line}:{p.col}" if lay.column else f"{p.file}:{p.line}"
        out = p.file
        if p.line > 0:
            out += f":{p.line}"
            if lay.column and p.col > 0:
                out += f":{p.col}"
        return out

    def render(self, sources: "SourceSet | None" = None) -> str:
        out = [f"{self.where()}: {Severity(self.severity).value}: {self.message}"]
        text = self.source_line or None
        if text is None and sources is not None and self.pos.line > 0:
            text = sources.line(self.pos.file, self.pos.line)
        if text is not None and (self.layout.zero_position or self.pos.col > 0):
            shown = text.rstrip("\n").replace("\t", " ")
            out.append("    " + shown)
            out.append("    " + " " * max(0, self.pos.col - 1) + "^" + "~" * max(0, self.width - 1))
        if self.hint:
            out.append(f"{self.layout.hint_indent}hint: {self.hint}")
        return "\n".join(out)


class SourceSet:
    """The text of every file read, for rendering source lines under diagnostics."""

    def __init__(self) -> None:
        self._lines: dict[str, list[str]] = {}

    def add(self, name: str, text: str) -> None:
        self._lines[name] = text.splitlines()

    def line(self, name: str, line: int) -> str | None:
        lines = self._lines.get(name)
        if lines is None or not (1 <= line <= len(lines)):
            return None
        return lines[line - 1]


@dataclass
class Diagnostics:
    items: list[Diagnostic] = field(default_factory=list)
    portability: bool = True      # report portability warnings

    def error(self, pos: Pos, message: str, hint: str | None = None, code: str | None = None) -> None:
        self.items.append(Diagnostic("error", pos, message, hint, code))

    def warning(self, pos: Pos, message: str, hint: str | None = None, code: str | None = None) -> None:
        self.items.append(Diagnostic("warning", pos, message, hint, code))

    def portable(self, pos: Pos, message: str, hint: str | None, code: str) -> None:
        """A portability warning: what our compiler accepts but MATIEC/OpenPLC does not (written by
        portability.warn only, `code` naming the rule of portability.RULES)."""
        if self.portability:
            self.items.append(Diagnostic("warning", pos, f"portability: {message}", hint, code))

    @property
    def errors(self) -> list[Diagnostic]:
        return [d for d in self.items if d.severity == "error"]

    @property
    def warnings(self) -> list[Diagnostic]:
        return [d for d in self.items if d.severity == "warning"]

    def has_errors(self) -> bool:
        return any(d.severity == "error" for d in self.items)

    def sorted(self) -> list[Diagnostic]:
        """By position; at one position errors first (whichever stage found them), duplicates once."""
        seen = set()
        out = []
        for d in sorted(self.items, key=lambda d: (d.pos.file, d.pos.line, d.pos.col, d.severity != "error")):
            key = (d.severity, d.pos, d.message)
            if key not in seen:
                seen.add(key)
                out.append(d)
        return out
