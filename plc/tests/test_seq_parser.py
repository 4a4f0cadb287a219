"""The sequence language, line by line: what parses, what each mistake reports and where."""

from __future__ import annotations

from decimal import Decimal

import pytest

from atc.seq.diagnostics import Diagnostics, Severity, seq_diagnostic
from atc.seq.lexer import split_words, strip_comment
from atc.seq.model import (Delay, Feedrate, HomeRotary, Message, MoveAbs, MoveToEdge, Number, Out, PositionRotary,
                           PVar, QVar, Spindle, ToolQVar, WaitIn)
from atc.seq.parser import parse_text


def parse(text: str):
    diags = Diagnostics()
    seq = parse_text("t.seq", text, diags)
    return seq, diags


def only_command(text: str):
    seq, diags = parse(text)
    assert not diags.items, [d.render() for d in diags.items]
    assert len(seq.commands) == 1
    return seq.commands[0]


def test_slash_starts_a_comment_anywhere_on_the_line():
    assert strip_comment("OUT 17 1 / brake is OFF") == "OUT 17 1"
    assert strip_comment("/ whole line") == ""
    assert [w.text for w in split_words("  WAITIN\t18 1 100 / check")] == ["WAITIN", "18", "1", "100"]


def test_blank_and_comment_lines_are_not_commands_but_keep_line_numbers():
    seq, diags = parse("/ header\n\n   \nOUT 3 1\n/ more\nDELAY 20\n")
    assert not diags.items
    assert [type(c) for c in seq.commands] == [Out, Delay]
    assert [c.line for c in seq.commands] == [4, 6]


def test_words_carry_their_columns():
    words = split_words("MOVEABS\tX50.0   Y20.0")
    assert [(w.text, w.col) for w in words] == [("MOVEABS", 1), ("X50.0", 9), ("Y20.0", 17)]


@pytest.mark.parametrize("text", ["MOVEABS Z-10.0", "MOVEABS Z -10.0", "moveabs z-10.0", "MoveAbs  Z   -10.000"])
def test_axis_and_value_may_be_glued_or_apart_in_any_case(text):
    command = only_command(text)
    assert isinstance(command, MoveAbs)
    assert [(t.axis, t.value.value) for t in command.targets] == [("Z", Decimal("-10"))]


def test_moveabs_takes_several_axes_and_variables():
    command = only_command("MOVEABS X P7 Y P2 ZQ4 AT2Q3")
    assert [t.axis for t in command.targets] == ["X", "Y", "Z", "A"]
    kinds = [type(t.value) for t in command.targets]
    assert kinds == [PVar, PVar, QVar, ToolQVar]
    assert (command.targets[3].value.tool, command.targets[3].value.index) == (2, 3)


def test_every_command_of_seed_003_parses():
    text = "\n".join([
        "OUT 4 1", "WAITIN 4 1 2000", "DELAY 2000", "POSITION ROTARY", "HOME ROTARY", "MESSAGE Get Tool completed",
        "DIALOG Please place tool 2", "MOVEABS Z 10.5", "MOVETOEDGE INP 5 1 Z-10.0", "FEEDRATE 10000",
        "SPINDLE CW 50", "SPINDLE CCW 50", "SPINDLE STOP", "SPINDLE OFF"])
    seq, diags = parse(text)
    assert not diags.items, [d.render() for d in diags.items]
    assert [type(c) for c in seq.commands] == [Out, WaitIn, Delay, PositionRotary, HomeRotary, Message, Message,
                                               MoveAbs, MoveToEdge, Feedrate, Spindle, Spindle, Spindle, Spindle]
    assert [c.mode for c in seq.commands[-4:]] == ["CW", "CCW", "STOP", "STOP"]
    edge = seq.commands[8]
    assert (int(edge.channel.value), int(edge.level.value), edge.target.axis, edge.target.value.value) == \
        (5, 1, "Z", Decimal("-10.0"))


def test_message_text_is_the_rest_of_the_line_up_to_the_comment():
    command = only_command("MESSAGE   Put tool done!   / shown in manual mode only")
    assert command.text == "Put tool done!"
    assert command.text_span.col == 11
    assert command.dialog is False
    assert only_command("DIALOG Insert tool 2").dialog is True


def test_numbers_keep_their_exact_decimal_value():
    command = only_command("MOVEABS X.5 Y-0.125 Z+3")
    assert [t.value.value for t in command.targets] == [Decimal("0.5"), Decimal("-0.125"), Decimal("3")]
    assert all(isinstance(t.value, Number) for t in command.targets)


def test_all_errors_of_a_file_come_in_one_run_with_their_lines():
    seq, diags = parse("OUT 3 1\nMOVEABZ Z0\nDELAY 100\nWAITIN 4 1\nSPINDLE FWD 5\nOUT 3 0\n")
    assert [(d.line, d.col) for d in diags.errors] == [(2, 1), (4, 11), (5, 9)]
    assert [c.line for c in seq.commands] == [1, 3, 6]


def test_two_mistakes_on_one_line_are_both_reported():
    _, diags = parse("OUT P1 2")
    assert [(d.col, d.message) for d in diags.errors] == [
        (5, "the output number must be a literal number, not the variable 'P1'"),
        (8, "the level must be 0 or 1, got '2'")]


def test_unknown_command_suggests_the_closest_one():
    _, diags = parse("WAITINN 4 1 100")
    (error,) = diags.errors
    assert error.message == "unknown command 'WAITINN'"
    assert error.hint == "did you mean WAITIN?"


def test_a_wrapped_comment_gets_a_hint():
    _, diags = parse("POSITION ROTARY / position carousel at the corresponding\nempty tool pocket\n")
    (error,) = diags.errors
    assert (error.line, error.message) == (2, "unknown command 'empty'")
    assert "its own '/'" in error.hint


def test_rendered_diagnostic_shows_the_line_and_a_caret_under_the_token():
    _, diags = parse("DELAY 10\nOUT 40x 1 / bad\n")
    (error,) = diags.errors
    assert error.render() == (
        "t.seq:2:5: error: bad number '40x'\n"
        "    OUT 40x 1 / bad\n"
        "        ^~~\n"
        "  hint: a value is a number (10, -5.25), a P variable (P4), a Q variable of this tool (Q2) or of a named "
        "tool (T3Q2)")


def test_diagnostic_without_position_renders_file_only():
    d = seq_diagnostic(Severity.ERROR, "x.seq", 0, 0, "the Put Tool sequence has no commands")
    assert d.render() == "x.seq: error: the Put Tool sequence has no commands"


def test_identical_diagnostics_are_kept_once():
    diags = Diagnostics()
    diags.error("a.seq", 3, 1, "same")
    diags.error("a.seq", 3, 1, "same")
    diags.warning("a.seq", 3, 1, "same")
    assert len(diags.items) == 2


def test_ifin_guards_the_command_after_its_input_and_level():
    command = only_command("IFIN 3 1 MOVEABS Z P1 / only with the collet open")
    from atc.seq.model import IfIn
    assert isinstance(command, IfIn)
    assert (command.channel.value, command.level.value) == (3, 1)
    assert isinstance(command.body, MoveAbs)
    assert command.body.targets[0].axis == "Z" and isinstance(command.body.targets[0].value, PVar)
    assert (command.span.col, command.body.span.col) == (1, 10)
    message = only_command("IFIN 2 0 MESSAGE spindle / up").body
    assert isinstance(message, Message) and message.text == "spindle"
