"""One Diagnostic type for every tool: the compiler, the map, the sequence tools and the machine check all report
plc.diagnostics.Diagnostic, each written the way that tool always wrote it."""
from __future__ import annotations

from pathlib import Path

from harness import compile_st
from atc import machine
from plc.diagnostics import Diagnostic, Pos, Severity
from atc.seq.parser import parse_text


def test_the_compiler_reports_the_shared_type_gcc_style():
    res = compile_st("PROGRAM Main\nVAR x : INT; END_VAR\nx := y;\nEND_PROGRAM\n", name="t.st", generate=False)
    (d,) = res.diags.errors
    assert type(d) is Diagnostic and d.severity == Severity.ERROR
    assert d.render(res.sources).splitlines()[0] == "t.st:3:6: error: undeclared variable 'y'"


def test_the_sequence_tools_report_the_shared_type_and_leave_out_a_zero_line():
    from atc.seq.diagnostics import Diagnostics
    diags = Diagnostics()
    parse_text("t.seq", "DELAY 10\nOUT 40x 1\n", diags)
    (d,) = diags.errors
    assert type(d) is Diagnostic and (d.file, d.line, d.col) == ("t.seq", 2, 5)
    diags.error("x.seq", 0, 0, "the Put Tool sequence has no commands")
    assert diags.items[-1].render() == "x.seq: error: the Put Tool sequence has no commands"


def test_the_machine_check_reports_the_shared_type_as_file_and_line(tmp_path: Path):
    cfg = tmp_path / "machine.toml"
    cfg.write_text("[carousel]\npockets = 99\n")
    _data, ck = machine.load(cfg)
    assert ck.problems and all(type(d) is Diagnostic for d in ck.problems)
    pockets = next(d for d in ck.problems if "pockets:" in d.message)
    assert pockets.pos == Pos(str(cfg), 2, 1)           # the column is known; the layout leaves it out
    assert pockets.render().startswith(f"{cfg}:2: error: ")
