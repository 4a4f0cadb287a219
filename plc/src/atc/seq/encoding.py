"""The contract between the sequence compiler and the ST interpreter FB_SequenceRunner.

Single source of truth for the sequence kinds, the opcodes, the limits and the step record. The ST generator
writes E_SeqKind, E_SeqOpcode and ST_SeqStep from these tables, so Python and ST cannot disagree.

Fixed point: every value the host receives (positions, distances, feed rate, spindle speed) is a DINT in
thousandths of its unit. Times stay on the PLC and are TIME literals, never converted from DINT (OpenPLC's
DINT_TO_TIME counts seconds).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

from ..machine import MAX_POCKETS

# --- limits (the Logosol manual, docs/logosol.md, and the runner's array bounds) ----------------------------------
MAX_TOOLS = MAX_POCKETS  # one tool per carousel pocket (pocket n holds tool n): the machine's pocket limit
P_COUNT = 230  # P1..P230, the Logosol P table (23 rows of 10)
Q_COUNT = 20  # TnQ1..TnQ20 per tool, the Logosol Q table (2 rows of 10 per tool)
IO_CHANNELS = 64  # channel n is %IX/%QX (n / 8).(n mod 8); the runner's arrays are ARRAY[0..63] OF BOOL
MAX_PROCEDURES = 16  # user procedures of one machine (FB_ProcedureScheduler's slots 1..16)
PROCEDURE_MODES = ("every interval", "at program start", "after a successful program end", "on error or stop")
MAX_STEPS = 500  # steps of one sequence (its End step not counted)
MAX_MESSAGE = 80  # characters of a MESSAGE/DIALOG text (the IEC default STRING length)
DINT_MAX = 2**31 - 1
INT_MAX = 2**15 - 1  # source line numbers are INT in ST_SeqStep
SCALE = 1000  # fixed point: thousandths
AXES = "XYZABC"  # bit i of axisMask is AXES[i]: X=1, Y=2, Z=4, A=8, B=16, C=32


class Kind(enum.Enum):
    """The kinds of sequence a machine has, in E_SeqKind order."""

    HOME = ("home", "KindHome", "Toolchanger Home")
    LENGTH = ("length", "KindLengthMeasurement", "Length Measurement")
    PUT = ("put", "KindPutTool", "Put Tool")
    GET = ("get", "KindGetTool", "Get Tool")
    PROCEDURE = ("procedure", "KindProcedure", "Procedure")  # a user procedure (docs/procedures.md): tool = its slot

    def __init__(self, key: str, st_name: str, title: str):
        self.key = key  # name in the index's [sequences] table
        self.st_name = st_name
        self.title = title

    @property
    def per_tool(self) -> bool:
        return self in (Kind.PUT, Kind.GET)

    @property
    def changer(self) -> bool:
        """A tool-change sequence named in [sequences] (not a user procedure)."""
        return self is not Kind.PROCEDURE

    @classmethod
    def from_key(cls, key: str) -> "Kind":
        for kind in cls:
            if kind.key == key:
                return kind
        raise KeyError(key)


class Opcode(enum.Enum):
    """What a step does, in E_SeqOpcode order (OpEnd first: the default value of a step is the end)."""

    END = ("OpEnd", "end of the sequence: Done")
    OUT = ("OpOut", "write `level` to output `channel`")
    WAIT_IN = ("OpWaitIn", "wait until input `channel` = `level`; fail after `duration`")
    DELAY = ("OpDelay", "wait `duration`")
    POSITION_ROTARY = ("OpPositionRotary", "FB_RotaryPositioner to the pocket of the sequence's tool")
    HOME_ROTARY = ("OpHomeRotary", "FB_RotaryPositioner homing (pocket of tool 1)")
    MESSAGE = ("OpMessage", "host shows text `message`, waits for OK; skipped when run from an M6")
    DIALOG = ("OpDialog", "host shows text `message`, waits for OK, even from an M6")
    MOVE_ABS = ("OpMoveAbs", "host moves the axes of `axisMask` to x..c (absolute, machine coordinates)")
    MOVE_TO_EDGE = ("OpMoveToEdge", "host moves one axis by x..c (relative), stops at input `channel` = `level`")
    FEEDRATE = ("OpFeedrate", "host feed rate for the next moves = `value` (1/1000 user unit per second)")
    SPINDLE_CW = ("OpSpindleCw", "host spindle clockwise at `value` (1/1000 rpm)")
    SPINDLE_CCW = ("OpSpindleCcw", "host spindle counter-clockwise at `value` (1/1000 rpm)")
    SPINDLE_STOP = ("OpSpindleStop", "host spindle stop and disable")

    def __init__(self, st_name: str, meaning: str):
        self.st_name = st_name
        self.meaning = meaning


# Fields of ST_SeqStep: (name, ST type, comment). The order is the declaration order.
STEP_FIELDS = (
    ("opcode", "E_SeqOpcode", "what the step does; OpEnd (the default) ends the sequence"),
    ("line", "INT", "line of the command in its sequence file, for the HMI; 0 for the End step"),
    ("channel", "INT", "OUT output / WAITIN and MOVETOEDGE input channel n = %QX or %IX (n / 8).(n mod 8)"),
    ("level", "BOOL", "OUT value written; WAITIN and MOVETOEDGE input level awaited"),
    ("duration", "TIME", "DELAY time; WAITIN timeout"),
    ("value", "DINT", "FEEDRATE in 1/1000 user unit per second; SPINDLE speed in 1/1000 rpm"),
    ("axisMask", "INT", "MOVEABS / MOVETOEDGE axes: X 1, Y 2, Z 4, A 8, B 16, C 32"),
    ("x", "DINT", "X target (MOVEABS, absolute) or distance (MOVETOEDGE, relative), 1/1000 user unit"),
    ("y", "DINT", "Y, as x"),
    ("z", "DINT", "Z, as x"),
    ("a", "DINT", "A, as x"),
    ("b", "DINT", "B, as x"),
    ("c", "DINT", "C, as x"),
    ("message", "INT", "MESSAGE / DIALOG text number for F_SequenceMessage; 0 = none"),
    ("expectEdge", "BOOL", "MOVETOEDGE: TRUE = no edge fails (Length Measurement), FALSE = an edge fails (Put Tool)"),
    ("guarded", "BOOL", "IFIN: the step runs only if input guardChannel reads guardLevel when it begins"),
    ("guardChannel", "INT", "IFIN input channel n = %IX(n / 8).(n mod 8)"),
    ("guardLevel", "BOOL", "IFIN level that lets the step run"),
)


# Fields of ST_ProcedureDef (F_ProcedureDef): one user procedure of [[procedures]] (docs/procedures.md).
PROCEDURE_FIELDS = (
    ("defined", "BOOL", "the slot holds a procedure (FALSE past the last one)"),
    ("id", "INT", "the procedure's ID"),
    ("mode", "INT", "0 every interval, 1 at program start, 2 after a successful program end, 3 on error or stop"),
    ("enabled", "BOOL", "FALSE: never started"),
    ("interval", "TIME", "mode 0: from one start to the next"),
    ("stopOnError", "BOOL", "TRUE: a failed step ends the procedure; FALSE: the failure is recorded, it goes on"),
    ("canStopGCode", "BOOL", "TRUE: a failure raises the procedure fault (the G-code program stops)"),
    ("errMsg", "INT", "F_SequenceMessage number of the ErrMsg text; 0 = none"),
    ("sequence", "INT", "its sequence number (F_SequenceSelect(KindProcedure, slot))"),
)


@dataclass(frozen=True)
class Step:
    """One resolved step with integer fields, ready for the table. `source` only feeds a comment."""

    opcode: Opcode
    line: int
    source: str = ""
    channel: int = 0
    level: bool = False
    duration_ms: int = 0
    value: int = 0
    axis_mask: int = 0
    axes: tuple[int, int, int, int, int, int] = (0, 0, 0, 0, 0, 0)
    text: str = ""  # MESSAGE / DIALOG text; the generator numbers the texts
    expect_edge: bool = False
    guarded: bool = False  # IFIN: skipped unless input guard_channel reads guard_level when the step begins
    guard_channel: int = 0
    guard_level: bool = False


@dataclass(frozen=True)
class Sequence:
    """The steps of one sequence for one tool (tool 0 for Home and Length Measurement)."""

    kind: Kind
    tool: int
    file: str  # sequence file name as written in the index
    steps: tuple[Step, ...] = field(default_factory=tuple)

    def body_key(self) -> tuple:
        """What makes two sequences share one table: the same file resolved to the same steps."""
        return (self.file, self.steps)


def channel_address(prefix: str, channel: int) -> str:
    """`%IX2.3` for input channel 19."""
    return f"%{prefix}{channel // 8}.{channel % 8}"
