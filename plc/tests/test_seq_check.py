"""`plc seq check`: the broken corpus gives exactly the recorded error, valid sets and the default configs pass."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from atc.seq.assemble import check_files
from atc.seq.checker import Context, check_sequence
from atc.seq.diagnostics import Diagnostics
from atc.seq.encoding import Kind, Opcode
from atc.seq.index import load_index
from atc.seq.parser import parse_text
from seq_testlib import CONFIG_INDEX, CORPUS, VALID_INDEX, assemble, load_manifest, run_cli

BROKEN = CORPUS / "broken"
BROKEN_SETS = CORPUS / "broken_sets"
BROKEN_CASES = load_manifest(BROKEN / "manifest.toml")
SET_CASES = load_manifest(BROKEN_SETS / "manifest.toml")


def test_manifest_and_broken_files_match_one_to_one():
    on_disk = {p.stem for p in BROKEN.glob("*.seq")}
    assert on_disk == set(BROKEN_CASES["cases"])
    assert len(on_disk) >= 50


@pytest.mark.parametrize("name", sorted(BROKEN_CASES["cases"]))
def test_broken_file_gives_its_one_line_numbered_error(name):
    case = BROKEN_CASES["cases"][name]
    index = BROKEN / BROKEN_CASES["index"]
    run = run_cli("check", "--index", index, "--kind", case["kind"], BROKEN / f"{name}.seq")
    assert run.status == 1
    assert run.out == ""
    errors = run.diagnostics()
    assert len(errors) == 1, run.err
    (error,) = errors
    assert Path(error["file"]).name == f"{name}.seq"
    assert int(error["line"] or 0) == case["line"], run.err
    assert int(error["col"] or 0) == case["col"], run.err
    assert case["message"] in error["msg"], run.err
    if case["line"]:
        source = (BROKEN / f"{name}.seq").read_text(encoding="utf-8").splitlines()[case["line"] - 1]
        assert f"\n    {source}\n    {' ' * (case['col'] - 1)}^" in run.err  # the line and the caret under it


def test_whole_broken_corpus_in_one_run_reports_every_file():
    files = sorted(BROKEN.glob("*.seq"))
    run = run_cli("check", "--index", VALID_INDEX, *files)
    assert run.status == 1
    reported = {Path(m["file"]).name for m in run.diagnostics()}
    put_kind = {f"{n}.seq" for n, c in BROKEN_CASES["cases"].items() if c["kind"] == "put"}
    assert put_kind <= reported  # checked as Put Tool (the default kind), every put-kind file fails


def test_manifest_and_broken_sets_match_one_to_one():
    on_disk = {p.name for p in BROKEN_SETS.iterdir() if p.is_dir()}
    assert on_disk == set(SET_CASES["cases"])


@pytest.mark.parametrize("name", sorted(SET_CASES["cases"]))
def test_broken_set_gives_its_one_error(name):
    case = SET_CASES["cases"][name]
    run = run_cli("check", BROKEN_SETS / name / "sequences.toml")
    assert run.status == 1
    errors = run.diagnostics()
    assert len(errors) == 1, run.err
    (error,) = errors
    assert Path(error["file"]).resolve() == (BROKEN_SETS / name / case["file"]).resolve(), run.err
    assert (int(error["line"]), int(error["col"])) == (case["line"], case["col"]), run.err
    assert case["message"] in error["msg"], run.err


def test_default_configs_check_clean_without_warnings():
    run = run_cli("check", "--werror", CONFIG_INDEX)
    assert run.status == 0, run.err
    assert run.err == ""


def test_each_default_sequence_file_checks_clean_on_its_own():
    files = sorted(CONFIG_INDEX.parent.glob("*.seq"))
    assert {f.name for f in files} == {"home.seq", "put.seq", "get.seq", "length.seq", "lube.seq", "alarm.seq"}
    run = run_cli("check", "--werror", *files)
    assert run.status == 0, run.err


def test_valid_corpus_checks_clean_with_only_the_expected_warnings():
    run = run_cli("check", VALID_INDEX)
    assert run.status == 0, run.err
    warnings = sorted((Path(m["file"]).name, int(m["line"]), m["msg"]) for m in run.diagnostics("warning"))
    assert warnings == [("get.seq", 13, "DELAY 0 does nothing"),
                        ("seed_put_p.seq", 1, "the Put Tool sequence never runs POSITION ROTARY")]


def _steps_of(path: Path, kind: Kind = Kind.PUT, tool: int = 1):
    diags = Diagnostics()
    seqset = load_index(VALID_INDEX, "valid", diags)
    seq = parse_text(path.name, path.read_text(encoding="utf-8"), diags)
    ctx = Context(kind, (tool,), seqset.io, seqset.axes, seqset.tools, seqset.values, "valid")
    steps = check_sequence(seq, ctx, diags)
    assert not diags.errors, [d.render() for d in diags.errors]
    return steps[tool]


def test_seed_p_coordinates_program_equals_the_literal_one():
    # The Logosol manual rewrites its Put Tool example with P4, P7, P2, P11: both must compile to the same steps.
    literal = _steps_of(CORPUS / "valid" / "seed_put_literal.seq")
    with_p = _steps_of(CORPUS / "valid" / "seed_put_p.seq")

    def strip(steps):
        return [(s.opcode, s.channel, s.level, s.duration_ms, s.value, s.axis_mask, s.axes, s.text) for s in steps]

    assert strip(literal) == strip(with_p)
    assert literal[3].axes == (50000, 20000, 0, 0, 0, 0) and literal[3].axis_mask == 1 | 2


def test_q_variables_resolve_per_tool():
    # The Logosol manual: "For T1: MOVEABS X Q1 => MOVEABS X 10.0; for T2: MOVEABS X Q1 => MOVEABS X 60.0".
    assembly, diags = assemble(VALID_INDEX)
    assert assembly is not None, [d.render() for d in diags.errors]
    put1 = assembly.sequences[assembly.select[(Kind.PUT, 1)] - 1]
    put2 = assembly.sequences[assembly.select[(Kind.PUT, 2)] - 1]
    holder1 = next(s for s in put1.steps if s.line == 6)
    holder2 = next(s for s in put2.steps if s.line == 6)
    assert holder1.axes[:2] == (10000, 20000)
    assert holder2.axes[:2] == (60000, 70000)
    z1 = next(s for s in put1.steps if s.line == 8)
    assert (z1.axis_mask, z1.axes[2]) == (4, -10000)


def test_movetoedge_expects_the_edge_in_length_measurement_and_forbids_it_in_put_tool():
    assembly, _ = assemble(VALID_INDEX)
    length = assembly.sequences[assembly.select[(Kind.LENGTH, 0)] - 1]
    put = assembly.sequences[assembly.select[(Kind.PUT, 1)] - 1]
    (edge_length,) = [s for s in length.steps if s.opcode is Opcode.MOVE_TO_EDGE]
    (edge_put,) = [s for s in put.steps if s.opcode is Opcode.MOVE_TO_EDGE]
    assert edge_length.expect_edge is True and edge_put.expect_edge is False
    assert (edge_length.channel, edge_length.level, edge_length.axis_mask, edge_length.axes[2]) == (5, True, 4, -10000)


def test_a_lone_file_gets_its_kind_from_the_index_beside_it(tmp_path):
    shutil.copytree(CONFIG_INDEX.parent, tmp_path / "set")
    home = tmp_path / "set" / "home.seq"
    home.write_text(home.read_text() + "POSITION ROTARY\n")
    run = run_cli("check", home)  # default --kind is put, but the index says home.seq is Toolchanger Home
    assert run.status == 1
    (error,) = run.diagnostics()
    assert "no target pocket in a Toolchanger Home sequence" in error["msg"]
    assert int(error["line"]) == len(home.read_text().splitlines())


def test_a_file_without_any_index_is_checked_against_the_defaults(tmp_path):
    lone = tmp_path / "lone.seq"
    lone.write_text("POSITION ROTARY\nOUT 63 1\nMOVEABS C 1\nOUT 64 1\nMOVEABS Z P1\n")
    diags = Diagnostics()
    check_files([lone], diags)
    assert [(d.line, d.col) for d in diags.errors] == [(4, 5), (5, 11)]
    assert "outside the I/O map" in diags.errors[0].message
    assert diags.errors[1].message == "P1 is not defined"


def test_a_broken_file_shared_by_two_kinds_reports_each_error_once(tmp_path):
    (tmp_path / "both.seq").write_text("POSITION ROTARY\nOUT 99 1\n")
    (tmp_path / "home.seq").write_text("HOME ROTARY\n")
    (tmp_path / "sequences.toml").write_text(
        '[machine]\ntools = 2\nalways_use_tool1 = true\n[io]\ninputs = [0]\noutputs = [0]\n'
        '[sequences]\nhome = "home.seq"\nput = "both.seq"\nget = "both.seq"\n')
    run = run_cli("check", tmp_path / "sequences.toml")
    assert run.status == 1
    assert [(Path(m["file"]).name, int(m["line"])) for m in run.diagnostics()] == [("both.seq", 2)]


def test_q_undefined_for_some_tools_names_them_in_one_error(tmp_path):
    (tmp_path / "put.seq").write_text("POSITION ROTARY\nMOVEABS X Q2\n")
    (tmp_path / "home.seq").write_text("HOME ROTARY\n")
    (tmp_path / "sequences.toml").write_text(
        '[machine]\ntools = 6\nalways_use_tool1 = true\n[io]\ninputs = [0]\noutputs = [0]\n'
        '[sequences]\nhome = "home.seq"\nput = "put.seq"\nget = "put.seq"\n'
        '[values]\nT1Q2 = 1\nT2Q2 = 2\nT5Q2 = 5\n')
    run = run_cli("check", tmp_path / "sequences.toml")
    (error,) = run.diagnostics()
    assert error["msg"].startswith("Q2 is not defined for tools 3-4, 6 (always_use_tool1 = true")


def test_a_bad_q_value_for_one_tool_is_reported_with_that_tool(tmp_path):
    (tmp_path / "put.seq").write_text("POSITION ROTARY\nWAITIN 0 1 Q1\n")
    (tmp_path / "home.seq").write_text("HOME ROTARY\n")
    (tmp_path / "sequences.toml").write_text(
        '[machine]\ntools = 3\nalways_use_tool1 = true\n[io]\ninputs = [0]\noutputs = [0]\n'
        '[sequences]\nhome = "home.seq"\nput = "put.seq"\nget = "put.seq"\n'
        '[values]\nT1Q1 = 100\nT2Q1 = 0\nT3Q1 = 250\n')
    run = run_cli("check", tmp_path / "sequences.toml")
    (error,) = run.diagnostics()
    assert error["msg"] == "the WAITIN timeout must be greater than 0 ms, got 0 (from Q1 for tool 2)"


def test_every_mistake_of_an_index_is_reported_in_one_run_each_at_its_key(tmp_path):
    """The index is read by the toolchain's one TOML reader and checked by its schema (atc.seq.index.SECTIONS):
    a misspelt key, a tool count out of range and an unknown section are three errors of one run."""
    (tmp_path / "home.seq").write_text("HOME ROTARY\n")
    (tmp_path / "sequences.toml").write_text(
        '[machine]\ntools = 99\nalways_use_tol1 = true\n[io]\ninputs = [0]\noutputs = [0]\n'
        '[sequences]\nhome = "home.seq"\n[vaules]\nP1 = 1\n')
    diags = Diagnostics()
    load_index(tmp_path / "sequences.toml", "sequences.toml", diags)
    assert [(d.line, d.col, d.message, d.hint) for d in diags.sorted()] == [
        (2, 1, "[machine] tools: expected an integer 1..50, got 99", None),
        (3, 1, "[machine] unknown key 'always_use_tol1'", "did you mean 'always_use_tool1'?"),
        (9, 2, "unknown section [vaules]", "did you mean [values]?"),
    ]
