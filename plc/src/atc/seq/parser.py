"""Parse the text of a sequence file into a `SequenceFile`, collecting every syntax error on the way.

Context-free checks live here: the command word, the number of arguments, the form of numbers and variables,
0/1 levels, whole-number channels. Everything that needs the machine (I/O map, axes, P/Q values, which kind of
sequence the file is) is the checker's job.
"""

from __future__ import annotations

import difflib
import re
from decimal import Decimal
from typing import Callable

from .diagnostics import Diagnostics
from .lexer import Word, rest_of_line, split_words
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

AXIS_LETTERS = "XYZABC"

# What each command looks like, for arity messages and hints.
USAGE = {
    "OUT": "OUT output level",
    "WAITIN": "WAITIN input level timeout_ms",
    "DELAY": "DELAY ms",
    "POSITION": "POSITION ROTARY",
    "HOME": "HOME ROTARY",
    "MESSAGE": "MESSAGE text",
    "DIALOG": "DIALOG text",
    "MOVEABS": "MOVEABS axis value [axis value ...]",
    "MOVETOEDGE": "MOVETOEDGE INP input level axis distance",
    "FEEDRATE": "FEEDRATE rate",
    "SPINDLE": "SPINDLE CW rpm | SPINDLE CCW rpm | SPINDLE STOP | SPINDLE OFF",
    "IFIN": "IFIN input level command",
}

VALUE_HINT = ("a value is a number (10, -5.25), a P variable (P4), a Q variable of this tool (Q2) "
              "or of a named tool (T3Q2)")

_NUMBER = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)")
_PVAR = re.compile(r"P(\d+)", re.IGNORECASE)
_QVAR = re.compile(r"Q(\d+)", re.IGNORECASE)
_TQVAR = re.compile(r"T(\d+)Q(\d+)", re.IGNORECASE)


class _LineParser:
    """Parses one line; reports problems into the shared diagnostics with the file name and line."""

    def __init__(self, name: str, line_no: int, text: str, diags: Diagnostics):
        self.name = name
        self.line_no = line_no
        self.text = text
        self.diags = diags
        self.ok = True

    # --- reporting ---
    def error(self, col: int, width: int, message: str, hint: str = "") -> None:
        self.ok = False
        self.diags.error(self.name, self.line_no, col, message, hint=hint, source_line=self.text, width=width)

    def span(self, word: Word) -> Span:
        return Span(self.line_no, word.col, word.width)

    def arity(self, keyword: Word, words: list[Word], expected: int, what: str) -> bool:
        """True when exactly `expected` arguments follow the keyword; otherwise one error for the line."""
        args = words[1:]
        if len(args) == expected:
            return True
        usage = USAGE[keyword.text.upper()]
        if len(args) > expected:
            extra = args[expected]
            self.error(extra.col, words[-1].end_col - extra.col,
                       f"{keyword.text.upper()} takes {what}, got {len(args)}", hint=f"usage: {usage}")
        else:
            end = words[-1].end_col
            self.error(end, 1, f"{keyword.text.upper()} takes {what}, got {len(args)}", hint=f"usage: {usage}")
        return False

    # --- values ---
    def value(self, text: str, col: int) -> Value | None:
        """A number or a P/Q variable; None (and an error) if the text is neither."""
        span = Span(self.line_no, col, max(1, len(text)))
        if _NUMBER.fullmatch(text):
            return Number(Decimal(text), text, span)
        for pattern, build in ((_PVAR, lambda m: PVar(int(m[1]), text, span)),
                               (_QVAR, lambda m: QVar(int(m[1]), text, span)),
                               (_TQVAR, lambda m: ToolQVar(int(m[1]), int(m[2]), text, span))):
            match = pattern.fullmatch(text)
            if match:
                return build(match)
        if text[:1] in "+-" and (_PVAR.fullmatch(text[1:]) or _QVAR.fullmatch(text[1:]) or _TQVAR.fullmatch(text[1:])):
            self.error(col, len(text), f"a variable cannot carry a sign: '{text}'",
                       hint="store the negative value in the variable itself")
            return None
        self.error(col, max(1, len(text)), f"bad number '{text}'", hint=VALUE_HINT)
        return None

    def literal(self, word: Word, what: str) -> Number | None:
        """A whole, non-negative literal number (channels and levels cannot come from variables)."""
        value = self.value(word.text, word.col)
        if value is None:
            return None
        if not isinstance(value, Number):
            self.error(word.col, word.width, f"the {what} must be a literal number, not the variable '{word.text}'")
            return None
        if value.value != value.value.to_integral_value() or value.value < 0 or word.text[:1] in "+-":
            self.error(word.col, word.width, f"the {what} must be a whole number, got '{word.text}'")
            return None
        return value

    def level(self, word: Word) -> Number | None:
        value = self.literal(word, "level")
        if value is not None and value.value not in (0, 1):
            self.error(word.col, word.width, f"the level must be 0 or 1, got '{word.text}'")
            return None
        return value

    def axis_targets(self, words: list[Word]) -> list[AxisTarget] | None:
        """`axis value` pairs, the value either glued to the letter (`Z-5`) or the next word (`Z -5`, `X P7`)."""
        targets: list[AxisTarget] = []
        i = 0
        while i < len(words):
            word = words[i]
            letter = word.text[0].upper()
            if not letter.isalpha() or letter in "PQT" and len(word.text) > 1 and word.text[1:2].isdigit():
                self.error(word.col, word.width, f"expected an axis letter before '{word.text}'",
                           hint="write the axis before its value, e.g. 'Z-10.0' or 'X P7'")
                return None
            if letter not in AXIS_LETTERS:
                self.error(word.col, 1, f"unknown axis '{word.text[0]}'",
                           hint=f"axes are {', '.join(AXIS_LETTERS)}")
                return None
            axis_span = Span(self.line_no, word.col, 1)
            if len(word.text) > 1:
                value = self.value(word.text[1:], word.col + 1)
                i += 1
            elif i + 1 < len(words):
                value = self.value(words[i + 1].text, words[i + 1].col)
                i += 2
            else:
                self.error(word.end_col, 1, f"axis {letter} has no value", hint=VALUE_HINT)
                return None
            if value is None:
                return None
            targets.append(AxisTarget(letter, axis_span, value))
        return targets


# --- one function per command ------------------------------------------------------------------------------------

def _out(p: _LineParser, kw: Word, words: list[Word]) -> Command | None:
    if not p.arity(kw, words, 2, "2 arguments (output level)"):
        return None
    channel, level = p.literal(words[1], "output number"), p.level(words[2])
    if channel is None or level is None:
        return None
    return Out(p.span(kw), p.text, channel, level)


def _waitin(p: _LineParser, kw: Word, words: list[Word]) -> Command | None:
    if not p.arity(kw, words, 3, "3 arguments (input level timeout_ms)"):
        return None
    channel, level = p.literal(words[1], "input number"), p.level(words[2])
    timeout = p.value(words[3].text, words[3].col)
    if channel is None or level is None or timeout is None:
        return None
    return WaitIn(p.span(kw), p.text, channel, level, timeout)


def _delay(p: _LineParser, kw: Word, words: list[Word]) -> Command | None:
    if not p.arity(kw, words, 1, "1 argument (ms)"):
        return None
    duration = p.value(words[1].text, words[1].col)
    return None if duration is None else Delay(p.span(kw), p.text, duration)


def _rotary(p: _LineParser, kw: Word, words: list[Word]) -> Command | None:
    keyword = kw.text.upper()
    if len(words) < 2 or words[1].text.upper() != "ROTARY":
        col = words[1].col if len(words) > 1 else kw.end_col
        width = words[1].width if len(words) > 1 else 1
        p.error(col, width, f"expected ROTARY after {keyword}", hint=f"usage: {USAGE[keyword]}")
        return None
    if len(words) > 2:
        p.error(words[2].col, words[-1].end_col - words[2].col, f"{keyword} ROTARY takes no arguments",
                hint=f"usage: {USAGE[keyword]}")
        return None
    return (PositionRotary if keyword == "POSITION" else HomeRotary)(p.span(kw), p.text)


def _message(p: _LineParser, kw: Word, words: list[Word]) -> Command | None:
    text, col = rest_of_line(p.text, kw.end_col)
    if not text:
        p.error(kw.end_col, 1, f"{kw.text.upper()} needs a text to show", hint=f"usage: {USAGE[kw.text.upper()]}")
        return None
    return Message(p.span(kw), p.text, text, Span(p.line_no, col, len(text)), kw.text.upper() == "DIALOG")


def _moveabs(p: _LineParser, kw: Word, words: list[Word]) -> Command | None:
    if len(words) < 2:
        p.error(kw.end_col, 1, "MOVEABS takes at least one axis and its value", hint=f"usage: {USAGE['MOVEABS']}")
        return None
    targets = p.axis_targets(words[1:])
    if targets is None:
        return None
    seen: dict[str, AxisTarget] = {}
    for target in targets:
        if target.axis in seen:
            p.error(target.axis_span.col, 1, f"axis {target.axis} appears twice in one MOVEABS",
                    hint="each axis takes one target; use two MOVEABS lines for two moves")
            return None
        seen[target.axis] = target
    return MoveAbs(p.span(kw), p.text, tuple(targets))


def _movetoedge(p: _LineParser, kw: Word, words: list[Word]) -> Command | None:
    usage = f"usage: {USAGE['MOVETOEDGE']}, e.g. MOVETOEDGE INP 5 1 Z-10.0"
    if len(words) < 2 or words[1].text.upper() != "INP":
        col = words[1].col if len(words) > 1 else kw.end_col
        p.error(col, words[1].width if len(words) > 1 else 1, "expected INP after MOVETOEDGE", hint=usage)
        return None
    if len(words) < 5:
        p.error(words[-1].end_col, 1, "MOVETOEDGE INP takes an input, a level, an axis and a distance", hint=usage)
        return None
    channel, level = p.literal(words[2], "input number"), p.level(words[3])
    targets = p.axis_targets(words[4:])
    if targets is None or channel is None or level is None:
        return None
    if len(targets) != 1:
        extra = targets[1].axis_span
        p.error(extra.col, words[-1].end_col - extra.col, "MOVETOEDGE moves exactly one axis", hint=usage)
        return None
    return MoveToEdge(p.span(kw), p.text, channel, level, targets[0])


def _feedrate(p: _LineParser, kw: Word, words: list[Word]) -> Command | None:
    if not p.arity(kw, words, 1, "1 argument (rate in 1/1000 user units per second)"):
        return None
    rate = p.value(words[1].text, words[1].col)
    return None if rate is None else Feedrate(p.span(kw), p.text, rate)


def _spindle(p: _LineParser, kw: Word, words: list[Word]) -> Command | None:
    if len(words) < 2:
        p.error(kw.end_col, 1, "SPINDLE needs a mode: CW, CCW, STOP or OFF", hint=f"usage: {USAGE['SPINDLE']}")
        return None
    mode = words[1].text.upper()
    if mode in ("STOP", "OFF"):
        if len(words) > 2:
            p.error(words[2].col, words[-1].end_col - words[2].col, f"SPINDLE {mode} takes no speed",
                    hint=f"usage: {USAGE['SPINDLE']}")
            return None
        return Spindle(p.span(kw), p.text, "STOP", None)
    if mode not in ("CW", "CCW"):
        p.error(words[1].col, words[1].width, f"unknown spindle mode '{words[1].text}'",
                hint=f"usage: {USAGE['SPINDLE']}")
        return None
    if len(words) != 3:
        col = words[3].col if len(words) > 3 else words[1].end_col
        p.error(col, 1, f"SPINDLE {mode} takes 1 speed in rpm, got {len(words) - 2}", hint=f"usage: {USAGE['SPINDLE']}")
        return None
    speed = p.value(words[2].text, words[2].col)
    return None if speed is None else Spindle(p.span(kw), p.text, mode, speed)


def _ifin(p: _LineParser, kw: Word, words: list[Word]) -> Command | None:
    usage = f"usage: {USAGE['IFIN']}, e.g. IFIN 20 1 MOVEABS Z P1"
    if len(words) < 4:
        p.error(words[-1].end_col, 1, "IFIN takes an input, a level and the command it guards", hint=usage)
        return None
    channel, level = p.literal(words[1], "input number"), p.level(words[2])
    keyword = words[3]
    if keyword.text.upper() == "IFIN":
        p.error(keyword.col, keyword.width, "IFIN guards one command, not another IFIN",
                hint="one condition per line: two conditions need two inputs wired into one")
        return None
    handler = _COMMANDS.get(keyword.text.upper())
    if handler is None:
        _unknown_command(p, keyword)
        return None
    body = handler(p, keyword, words[3:])
    if channel is None or level is None or body is None:
        return None
    return IfIn(p.span(kw), p.text, channel, level, body)


_COMMANDS: dict[str, Callable[[_LineParser, Word, list[Word]], Command | None]] = {
    "OUT": _out,
    "WAITIN": _waitin,
    "DELAY": _delay,
    "POSITION": _rotary,
    "HOME": _rotary,
    "MESSAGE": _message,
    "DIALOG": _message,
    "MOVEABS": _moveabs,
    "MOVETOEDGE": _movetoedge,
    "FEEDRATE": _feedrate,
    "SPINDLE": _spindle,
    "IFIN": _ifin,
}


def _unknown_command(p: _LineParser, kw: Word) -> None:
    close = difflib.get_close_matches(kw.text.upper(), list(_COMMANDS), n=1, cutoff=0.6)
    if close:
        hint = f"did you mean {close[0]}?"
    elif p.line_no > 1 and kw.text[:1].islower():
        hint = "a comment that continues on a new line needs its own '/'"
    else:
        hint = "commands are " + ", ".join(sorted(_COMMANDS))
    p.error(kw.col, kw.width, f"unknown command '{kw.text}'", hint=hint)


def parse_text(name: str, text: str, diags: Diagnostics) -> SequenceFile:
    """Parse a whole file; lines with errors are left out of the commands, and every error is reported."""
    lines = tuple(text.splitlines())
    commands: list[Command] = []
    for line_no, line in enumerate(lines, start=1):
        words = split_words(line)
        if not words:
            continue
        parser = _LineParser(name, line_no, line, diags)
        handler = _COMMANDS.get(words[0].text.upper())
        if handler is None:
            _unknown_command(parser, words[0])
            continue
        command = handler(parser, words[0], words)
        if command is not None and parser.ok:
            commands.append(command)
    return SequenceFile(name, lines, tuple(commands))
