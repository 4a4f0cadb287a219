"""Check a parsed sequence against its machine and resolve it into integer steps.

The checker knows the context a file runs in: its kind (Home, Length Measurement, Put Tool, Get Tool), the tools
it runs for, the I/O map, the axes and the P/Q values. It reports every problem, once, at the offending token,
and returns the steps of each tool. P and Q variables are compile-time constants: a Put/Get Tool file that uses
per-tool Q variables resolves into one step list per tool; the generator shares identical lists.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from decimal import Decimal
from typing import Callable

from .diagnostics import Diagnostics, format_ranges
from .encoding import (
    AXES,
    DINT_MAX,
    INT_MAX,
    MAX_MESSAGE,
    MAX_STEPS,
    MAX_TOOLS,
    P_COUNT,
    Q_COUNT,
    SCALE,
    Kind,
    Opcode,
    Step,
    channel_address,
)
from .index import IoMap, Values
from .model import (
    AxisTarget,
    Command,
    Delay,
    Feedrate,
    HomeRotary,
    IfIn,
    Message,
    MoveAbs,
    MoveToEdge,
    Number,
    Out,
    PositionRotary,
    PVar,
    QVar,
    SequenceFile,
    Span,
    Spindle,
    ToolQVar,
    Value,
    WaitIn,
)


@dataclass(frozen=True)
class Context:
    kind: Kind
    tools: tuple[int, ...]  # the tools a Put/Get Tool file runs for; ignored for Home and Length Measurement
    io: IoMap
    axes: str | None  # the machine's axes, a subset of XYZABC; None = unknown (the index reports why)
    tool_count: int  # tools 1..tool_count exist
    values: Values
    index_name: str = ""  # where I/O map, axes and values come from, for hints; "" = built-in defaults
    tools_note: str = ""  # why the file runs for these tools, e.g. "always_use_tool1 = true"


# A rule turns a resolved decimal into the integer stored in the step, or returns an error message.
Rule = Callable[[Decimal], "int | str"]


def _whole_ms(what: str, minimum: int) -> Rule:
    def rule(v: Decimal) -> int | str:
        if v != v.to_integral_value():
            return f"the {what} must be a whole number of milliseconds, got {v}"
        if v < minimum:
            return f"the {what} must be {'greater than 0' if minimum == 1 else 'at least 0'} ms, got {v}"
        if v > DINT_MAX:
            return f"the {what} must be at most {DINT_MAX} ms, got {v}"
        return int(v)
    return rule


def _thousandths(what: str, positive: bool = False, nonzero: bool = False) -> Rule:
    def rule(v: Decimal) -> int | str:
        scaled = v * SCALE
        if scaled != scaled.to_integral_value():
            return f"the {what} has more than 3 decimals: {v}"
        if abs(scaled) > DINT_MAX:
            return f"the {what} is too large for 1/1000 units in a DINT: {v}"
        if positive and v <= 0:
            return f"the {what} must be greater than 0, got {v}"
        if nonzero and v == 0:
            return f"the {what} must not be 0"
        return int(scaled)
    return rule


def _feedrate(v: Decimal) -> int | str:
    if v != v.to_integral_value() or v <= 0 or v > DINT_MAX:
        return f"FEEDRATE must be a whole number greater than 0 (1/1000 user unit per second), got {v}"
    return int(v)


_WORDS = {Message: "MESSAGE", MoveAbs: "MOVEABS", MoveToEdge: "MOVETOEDGE", Feedrate: "FEEDRATE",
          Spindle: "SPINDLE", PositionRotary: "POSITION ROTARY", HomeRotary: "HOME ROTARY"}


class _Checker:
    def __init__(self, seq: SequenceFile, ctx: Context, diags: Diagnostics):
        self.seq = seq
        self.ctx = ctx
        self.diags = diags
        per_tool = ctx.kind.per_tool
        self.tools: tuple[int, ...] = (ctx.tools or (1,)) if per_tool else (0,)
        self.ok = True

    # --- reporting ---
    def error(self, span: Span, message: str, hint: str = "") -> None:
        self.ok = False
        self.diags.error(self.seq.name, span.line, span.col, message, hint=hint,
                         source_line=self.seq.source_line(span.line), width=span.width)

    def warning(self, span: Span, message: str, hint: str = "") -> None:
        self.diags.warning(self.seq.name, span.line, span.col, message, hint=hint,
                           source_line=self.seq.source_line(span.line), width=span.width)

    def where_values(self) -> str:
        return f"[values] of {self.ctx.index_name}" if self.ctx.index_name else "[values] of the index (see --index)"

    def for_tools(self, tools: list[int]) -> str:
        if tools == [0] or not self.ctx.kind.per_tool:
            return ""
        return f" for tool{'s' if len(tools) > 1 else ''} {format_ranges(tools)}"

    # --- values ---
    def resolve(self, value: Value) -> dict[int, Decimal] | None:
        """The value for each tool the file runs for; None (reported) when a variable is unknown."""
        if isinstance(value, Number):
            return {t: value.value for t in self.tools}
        if isinstance(value, PVar):
            if not 1 <= value.index <= P_COUNT:
                self.error(value.span, f"{value.text} is out of range: P variables are P1..P{P_COUNT}")
                return None
            if value.index not in self.ctx.values.p:
                self.error(value.span, f"{value.text} is not defined",
                           hint=f"define P{value.index} in {self.where_values()}")
                return None
            return {t: self.ctx.values.p[value.index] for t in self.tools}
        if isinstance(value, QVar):
            return self.resolve_q(value)
        return self.resolve_tool_q(value)

    def resolve_q(self, value: QVar) -> dict[int, Decimal] | None:
        if not self.ctx.kind.per_tool:
            self.error(value.span, f"{value.text} is a value of the tool being changed, and a {self.ctx.kind.title} "
                                   "sequence has no tool", hint=f"name the tool: T1Q{value.index}")
            return None
        if not 1 <= value.index <= Q_COUNT:
            self.error(value.span, f"{value.text} is out of range: Q variables are Q1..Q{Q_COUNT}")
            return None
        missing = [t for t in self.tools if (t, value.index) not in self.ctx.values.q]
        if missing:
            note = f" ({self.ctx.tools_note})" if self.ctx.tools_note else ""
            example = f"T{missing[0]}Q{value.index}"
            self.error(value.span, f"{value.text} is not defined{self.for_tools(missing)}{note}",
                       hint=f"define {example}{' and the others' if len(missing) > 1 else ''} in {self.where_values()}")
            return None
        return {t: self.ctx.values.q[(t, value.index)] for t in self.tools}

    def resolve_tool_q(self, value: ToolQVar) -> dict[int, Decimal] | None:
        count = self.ctx.tool_count or MAX_TOOLS
        if not 1 <= value.tool <= count:
            self.error(value.span, f"{value.text} names tool {value.tool} but the machine has tools 1..{count}")
            return None
        if not 1 <= value.index <= Q_COUNT:
            self.error(value.span, f"{value.text} is out of range: Q variables are Q1..Q{Q_COUNT}")
            return None
        if (value.tool, value.index) not in self.ctx.values.q:
            self.error(value.span, f"{value.text} is not defined",
                       hint=f"define {value.text.upper()} in {self.where_values()}")
            return None
        return {t: self.ctx.values.q[(value.tool, value.index)] for t in self.tools}

    def number(self, value: Value, rule: Rule) -> dict[int, int] | None:
        """Resolve, then apply the rule; one error per distinct bad value, naming the tools that get it."""
        resolved = self.resolve(value)
        if resolved is None:
            return None
        encoded: dict[int, int] = {}
        failures: dict[str, list[int]] = {}
        for tool, v in resolved.items():
            outcome = rule(v)
            if isinstance(outcome, str):
                failures.setdefault(outcome, []).append(tool)
            else:
                encoded[tool] = outcome
        for message, tools in failures.items():
            if isinstance(value, Number):
                source = ""
            elif isinstance(value, QVar):
                source = f" (from {value.text}{self.for_tools(tools)})"
            else:
                source = f" (from {value.text})"
            self.error(value.span, message + source)
        return None if failures else encoded

    # --- channels, axes, texts ---
    def channel(self, number: Number, output: bool) -> int | None:
        channel = int(number.value)
        allowed = self.ctx.io.outputs if output else self.ctx.io.inputs
        if allowed is None or channel in allowed:
            return channel  # None: the index lacks the list, which it reports itself
        what, verb, key, prefix = ("output", "OUT may write", self.ctx.io.output_key, "QX") if output else \
                                  ("input", "sequences may read" if self.ctx.kind.changer else "procedures may read",
                                   self.ctx.io.input_key, "IX")
        where = f"[io] {key} of {self.ctx.index_name}" if self.ctx.index_name else f"the I/O map ([io] {key})"
        address = f", here {channel_address(prefix, channel)}" if channel < 64 else ""
        listed = format_ranges(allowed) if allowed else "(none)"
        self.error(number.span, f"{what} {channel} is outside the I/O map: {verb} {key} {listed}",
                   hint=f"{where}; channel n is %{prefix}(n/8).(n mod 8){address}")
        return None

    def axis(self, target: AxisTarget) -> bool:
        if self.ctx.axes is None or target.axis in self.ctx.axes:
            return True
        source = f"[machine] axes of {self.ctx.index_name}" if self.ctx.index_name else "[machine] axes"
        self.error(target.axis_span, f"axis {target.axis} is not on this machine (axes: {self.ctx.axes or 'none'})",
                   hint=f"the machine's axes are {source}")
        return False

    def text(self, command: Message) -> bool:
        for offset, ch in enumerate(command.text):
            if not " " <= ch <= "~":
                span = Span(command.text_span.line, command.text_span.col + offset, 1)
                self.error(span, f"the {'DIALOG' if command.dialog else 'MESSAGE'} text may hold printable ASCII "
                                 f"only, found {ch!r}")
                return False
        if len(command.text) > MAX_MESSAGE:
            span = Span(command.text_span.line, command.text_span.col + MAX_MESSAGE, len(command.text) - MAX_MESSAGE)
            self.error(span, f"the text is {len(command.text)} characters long; at most {MAX_MESSAGE} fit")
            return False
        return True

    # --- commands ---
    def steps(self, command: Command) -> dict[int, Step] | None:
        """The command's step for each tool, or None when it has an error (already reported)."""
        if self.ctx.kind is Kind.PROCEDURE and not isinstance(command, (Out, WaitIn, Delay, IfIn)):
            word = "DIALOG" if isinstance(command, Message) and command.dialog else _WORDS[type(command)]
            self.error(command.span, f"{word} is not allowed in a procedure",
                       hint="a procedure may use OUT, WAITIN, DELAY and IFIN: the host mailbox, the carousel and "
                            "the operator belong to the tool change (docs/procedures.md)")
            return None
        if isinstance(command, IfIn):
            return self.guarded(command)
        base = {"line": command.line, "source": command.source.strip()}
        kind = self.ctx.kind
        if isinstance(command, Out):
            channel = self.channel(command.channel, output=True)
            return None if channel is None else self.same(
                Step(Opcode.OUT, channel=channel, level=command.level.value == 1, **base))
        if isinstance(command, WaitIn):
            channel = self.channel(command.channel, output=False)
            timeout = self.number(command.timeout, _whole_ms("WAITIN timeout", 1))
            if channel is None or timeout is None:
                return None
            return {t: Step(Opcode.WAIT_IN, channel=channel, level=command.level.value == 1, duration_ms=timeout[t],
                            **base) for t in self.tools}
        if isinstance(command, Delay):
            duration = self.number(command.duration, _whole_ms("DELAY time", 0))
            if duration is None:
                return None
            if 0 in duration.values():
                self.warning(command.duration.span, "DELAY 0 does nothing")
            return {t: Step(Opcode.DELAY, duration_ms=duration[t], **base) for t in self.tools}
        if isinstance(command, PositionRotary):
            if not kind.per_tool:
                self.error(command.span, f"POSITION ROTARY has no target pocket in a {kind.title} sequence",
                           hint="POSITION ROTARY belongs to the Put Tool and Get Tool sequences; "
                                "HOME ROTARY goes to the pocket of tool 1")
                return None
            return self.same(Step(Opcode.POSITION_ROTARY, **base))
        if isinstance(command, HomeRotary):
            if kind is Kind.LENGTH:
                self.error(command.span, "HOME ROTARY is not allowed in a Length Measurement sequence",
                           hint="HOME ROTARY belongs to the Toolchanger Home, Put Tool and Get Tool sequences")
                return None
            return self.same(Step(Opcode.HOME_ROTARY, **base))
        if isinstance(command, Message):
            if not self.text(command):
                return None
            return self.same(Step(Opcode.DIALOG if command.dialog else Opcode.MESSAGE, text=command.text, **base))
        if isinstance(command, MoveAbs):
            return self.move_abs(command, base)
        if isinstance(command, MoveToEdge):
            return self.move_to_edge(command, base)
        if isinstance(command, Feedrate):
            rate = self.number(command.rate, _feedrate)
            return None if rate is None else {t: Step(Opcode.FEEDRATE, value=rate[t], **base) for t in self.tools}
        if isinstance(command, Spindle):
            if command.mode == "STOP":
                return self.same(Step(Opcode.SPINDLE_STOP, **base))
            speed = self.number(command.speed, _thousandths("spindle speed", positive=True))
            opcode = Opcode.SPINDLE_CW if command.mode == "CW" else Opcode.SPINDLE_CCW
            return None if speed is None else {t: Step(opcode, value=speed[t], **base) for t in self.tools}
        raise AssertionError(f"no checker for {type(command).__name__}")

    def guarded(self, command: IfIn) -> dict[int, Step] | None:
        """The guarded command's steps, each skipped at run time unless the input reads the level."""
        channel = self.channel(command.channel, output=False)
        steps = self.steps(command.body)
        if channel is None or steps is None:
            return None
        level = command.level.value == 1
        return {t: replace(step, guarded=True, guard_channel=channel, guard_level=level) for t, step in steps.items()}

    def same(self, step: Step) -> dict[int, Step]:
        return {t: step for t in self.tools}

    def axes(self, targets: tuple[AxisTarget, ...], rule: Rule) -> dict[int, tuple[int, tuple[int, ...]]] | None:
        """(axisMask, x..c) per tool."""
        per_axis: dict[str, dict[int, int]] = {}
        ok = True
        for target in targets:
            encoded = self.number(target.value, rule) if self.axis(target) else None
            if encoded is None:
                ok = False
            else:
                per_axis[target.axis] = encoded
        if not ok:
            return None
        mask = sum(1 << AXES.index(a) for a in per_axis)
        return {t: (mask, tuple(per_axis[a][t] if a in per_axis else 0 for a in AXES)) for t in self.tools}

    def move_abs(self, command: MoveAbs, base: dict) -> dict[int, Step] | None:
        moves = self.axes(command.targets, _thousandths("target position"))
        if moves is None:
            return None
        return {t: Step(Opcode.MOVE_ABS, axis_mask=moves[t][0], axes=moves[t][1], **base) for t in self.tools}

    def move_to_edge(self, command: MoveToEdge, base: dict) -> dict[int, Step] | None:
        kind = self.ctx.kind
        if kind not in (Kind.LENGTH, Kind.PUT):
            self.error(command.span, f"MOVETOEDGE is not defined in a {kind.title} sequence",
                       hint="the Logosol manual defines it for Length Measurement (the input must change) and Put Tool "
                            "(a change fails the sequence)")
            return None
        channel = self.channel(command.channel, output=False)
        moves = self.axes((command.target,), _thousandths("MOVETOEDGE distance", nonzero=True))
        if channel is None or moves is None:
            return None
        return {t: Step(Opcode.MOVE_TO_EDGE, channel=channel, level=command.level.value == 1,
                        axis_mask=moves[t][0], axes=moves[t][1], expect_edge=kind is Kind.LENGTH, **base)
                for t in self.tools}

    # --- the whole file ---
    def run(self) -> dict[int, tuple[Step, ...]]:
        per_tool: dict[int, list[Step]] = {t: [] for t in self.tools}
        for command in self.seq.commands:
            steps = self.steps(command)
            if steps is not None:
                for t in self.tools:
                    per_tool[t].append(steps[t])
        self.whole_file_rules()
        return {t: tuple(steps) for t, steps in per_tool.items()}

    def whole_file_rules(self) -> None:
        if not self.seq.lines or not any(line.strip() and not line.strip().startswith("/") for line in self.seq.lines):
            self.ok = False
            self.diags.error(self.seq.name, 0, 0, f"the {self.ctx.kind.title} sequence has no commands")
            return
        for command in self.seq.commands:
            if command.line > INT_MAX:
                self.error(command.span, f"line {command.line} is past line {INT_MAX}: the HMI's line number is an INT")
                break
        if len(self.seq.commands) > MAX_STEPS:
            command = self.seq.commands[MAX_STEPS]
            self.error(command.span, f"a sequence may have at most {MAX_STEPS} commands; this is command "
                                     f"{MAX_STEPS + 1}")
        if self.diags.has_errors_in(self.seq.name):
            return  # a command dropped for an error would make the warnings below wrong
        first = self.seq.commands[0].span if self.seq.commands else Span(1, 1)
        if self.ctx.kind is Kind.HOME and not any(isinstance(c, HomeRotary) for c in self.seq.commands):
            self.warning(first, "the Toolchanger Home sequence never runs HOME ROTARY",
                         hint="the carousel position stays unknown after power-up")
        if self.ctx.kind.per_tool and not any(isinstance(c, (PositionRotary, HomeRotary)) for c in self.seq.commands):
            self.warning(first, f"the {self.ctx.kind.title} sequence never runs POSITION ROTARY",
                         hint="the carousel stays at whatever pocket it is at")


def check_sequence(seq: SequenceFile, ctx: Context, diags: Diagnostics) -> dict[int, tuple[Step, ...]] | None:
    """Steps per tool (tool 0 for Home and Length Measurement), or None if the file has errors."""
    checker = _Checker(seq, ctx, diags)
    steps = checker.run()
    return steps if checker.ok else None
