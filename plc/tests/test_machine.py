"""plc machine: machines/default/machine.toml is checked with file:line errors and generates FB_MachineConfig
reproducibly."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "machines" / "default" / "machine.toml"
GENERATED = ROOT / "st_src" / "app" / "generated" / "FB_MachineConfig.st"


def machine(*args, cwd=ROOT):
    # PYTHONPATH: from the project root `plc` would otherwise be the folder plc/, not the package plc/plc
    env = dict(os.environ, PYTHONPATH=str(ROOT / "plc" / "src"))
    return subprocess.run([sys.executable, "-m", "plc.cli", "machine", *args], capture_output=True, text=True,
                          cwd=cwd, timeout=60, env=env)


def test_the_shipped_configuration_checks_clean_and_matches_the_generated_st():
    proc = machine("check")
    assert proc.returncode == 0, proc.stderr
    # a one-line summary on success (issue 27: it printed nothing)
    assert proc.stderr.splitlines() == ["plc machine check: machines/default/machine.toml: ok (6 pockets; the "
                                        "register map and the sequences agree; its 3 generated files are up to "
                                        "date)"], proc.stderr


def test_generation_is_reproducible(tmp_path):
    out = tmp_path / "FB_MachineConfig.st"
    assert machine("generate", "--out", str(out)).returncode == 0
    assert out.read_text() == GENERATED.read_text()


def test_drift_is_an_error(tmp_path):
    out = tmp_path / "FB_MachineConfig.st"
    out.write_text(GENERATED.read_text().replace("Rotary.pockets := 6;", "Rotary.pockets := 7;"))
    proc = machine("check", "--out", str(out))
    assert proc.returncode == 1
    assert "out of date" in proc.stderr and ": ok (" not in proc.stderr


def line_of(text: str, needle: str) -> int:
    return next(n for n, line in enumerate(text.splitlines(), 1) if line.startswith(needle))


@pytest.mark.parametrize("edit,needle,message", [
    ("pockets = 6 ", "pockets =", "[carousel] pockets: expected an integer 2..50, got 60"),
    ("inputs = \"home+pocket\"", "inputs =", "[carousel] inputs: expected one of \"home+pocket\", "),
    ("homing = \"positive\"", "homing =", "counting pockets (inputs = home+pocket) needs homing"),
    ("auto_home = true", "auto_home =", "[changer] auto_home: expected true or false"),
    ("worn_out = \"soft\"", "worn_out =", "[changer] worn_out: expected one of \"soft\", \"hard\""),
    ("brake_ms = 50", "brake_ms", "[simulation] brake_ms: expected an integer 0..60000, got -5"),
    ("stop_delay_ms = 0", "stop_delay_ms", "[carousel] unknown key 'stop_delay'\n    hint: did you mean "
                                           "'stop_delay_ms'?"),
])
def test_each_bad_setting_is_reported_with_its_line(tmp_path, edit, needle, message):
    text = CONFIG.read_text()
    replacement = {
        "pockets = 6 ": "pockets = 60 ",
        "inputs = \"home+pocket\"": "inputs = \"home+optical\"",
        "homing = \"positive\"": "homing = \"none\"",
        "auto_home = true": "auto_home = 1",
        "worn_out = \"soft\"": "worn_out = \"never\"",
        "brake_ms = 50": "brake_ms = -5",
        "stop_delay_ms = 0": "stop_delay = 0",
    }[edit]
    bad = text.replace(edit, replacement, 1)
    assert bad != text
    cfg = tmp_path / "machine.toml"
    cfg.write_text(bad)
    proc = machine("check", "--config", str(cfg), "--out", str(tmp_path / "x.st"))
    assert proc.returncode == 1
    line = line_of(bad, needle.replace("stop_delay_ms", "stop_delay"))
    assert f"{cfg}:{line}: error:" in proc.stderr, proc.stderr
    assert message in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr


def test_mistakes_of_several_sections_are_reported_together_each_at_its_line(tmp_path):
    """The description is read by the one TOML reader and checked by its schema (atc.machine.SCHEMA): a misspelt
    [changer] key, a wrong [simulation] value and a misspelt section are three errors of one check."""
    from atc import machine as machine_config
    text = CONFIG.read_text().replace("auto_home = true", "auto_hmoe = true", 1).replace(
        "brake_ms = 50", "brake_ms = -5", 1) + "\n[simulaton]\ncoast_ms = 1\n"
    cfg = tmp_path / "machine.toml"
    cfg.write_text(text)
    _data, ck = machine_config.load(cfg)
    assert [(d.line, d.message, d.hint) for d in ck.problems] == [
        (line_of(text, "auto_hmoe ="), "[changer] unknown key 'auto_hmoe'", "did you mean 'auto_home'?"),
        (line_of(text, "brake_ms ="), "[simulation] brake_ms: expected an integer 0..60000, got -5", None),
        (line_of(text, "[simulaton]"), "unknown section [simulaton]", "did you mean [simulation]?"),
    ]


def test_code_mode_needs_one_distinct_code_per_pocket(tmp_path):
    bad = CONFIG.read_text().replace('inputs = "home+pocket"', 'inputs = "code"').replace(
        "pocket_codes = [6, 7, 3, 1, 5, 4]", "pocket_codes = [6, 7, 3, 1, 5, 5]")
    cfg = tmp_path / "machine.toml"
    cfg.write_text(bad)
    proc = machine("check", "--config", str(cfg), "--out", str(tmp_path / "x.st"))
    assert proc.returncode == 1
    assert "pocket_codes: code 5 is used twice" in proc.stderr


def test_an_invert_code_list_shorter_than_the_code_inputs_is_an_error_naming_both_lengths(tmp_path):
    # issue 27: `invert_code = [false, false]` with 4 code inputs was accepted, inputs 3 and 4 silently not inverted
    bad = CONFIG.read_text().replace('inputs = "home+pocket"', 'inputs = "code"').replace(
        "code_inputs = 3 ", "code_inputs = 4 ").replace(
        "invert_minus_dir = false", "invert_minus_dir = false\ninvert_code = [false, false]")
    cfg = tmp_path / "machine.toml"
    cfg.write_text(bad)
    proc = machine("check", "--config", str(cfg), "--out", str(tmp_path / "x.st"))
    assert proc.returncode == 1, proc.stderr
    line = line_of(bad, "invert_code =")
    assert f"{cfg}:{line}: error: [carousel] invert_code: 2 values for 4 code inputs" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize("edit,key,message", [
    (('stop_delay_ms = 0 ', 'centre_on_code = true\nstop_delay_ms = 0 '), "centre_on_code =",
     ('[carousel] centre_on_code: only for the code modes without a pocket input (home+code, code): with '
      'inputs = "home+pocket"')),
    (('code_between = "nearest"', 'code_between = "nearest"\ncode_window_pct = 10'), "code_window_pct =",
     '[simulation] code_window_pct: applies to code_between = "zero"'),
    (('inputs = "home+pocket" ', 'inputs = "code" '), None, None),
])
def test_centring_and_the_simulated_code_disc_are_checked(tmp_path, edit, key, message):
    text = CONFIG.read_text()
    assert edit[0] in text, edit[0]
    bad = text.replace(edit[0], edit[1], 1)
    if key is None:          # a code-only carousel with a gap disc checked as valid-only: code 0 would fault
        bad = bad.replace('code_check = "not-controlled"', 'code_check = "valid-only"').replace(
            'code_between = "nearest"', 'code_between = "zero"')
        key, message = "code_between =", '[simulation] code_between = "zero": code_check = "valid-only" faults'
    cfg = tmp_path / "machine.toml"
    cfg.write_text(bad)
    proc = machine("check", "--config", str(cfg), "--out", str(tmp_path / "x.st"))
    assert proc.returncode == 1, proc.stderr
    assert f"{cfg}:{line_of(bad, key)}: error: {message}" in proc.stderr, proc.stderr


def test_a_carousel_that_cannot_stop_centred_is_a_warning_with_the_numbers(tmp_path):
    """Code only without centring on a sector disc: it stops when the code settles, 38 ms before the centre at
    100 ms a pitch (50 ms half a pitch, 12 ms debounce), outside the +-20 ms window; the check passes and says so."""
    text = CONFIG.read_text().replace('inputs = "home+pocket" ', 'inputs = "code" ').replace(
        'stop_delay_ms = 0 ', 'centre_on_code = false\nstop_delay_ms = 0 ')
    cfg = tmp_path / "machine.toml"
    cfg.write_text(text)
    proc = machine("check", "--config", str(cfg), "--out", str(tmp_path / "x.st"))
    assert proc.returncode == 0, proc.stderr
    assert (f"{cfg}:{line_of(text, 'pocket_time_ms =')}: warning: [simulation] the simulated carousel stops about "
            "38 ms before the pocket centre") in proc.stderr, proc.stderr
    assert "outside the +-20 ms where the arm meets the holder" in proc.stderr
    assert "set centre_on_code = true" in proc.stderr


def test_another_machine_file_is_checked_with_the_register_map_as_its_run_would(tmp_path):
    """Issue 27: `plc machine check --config FILE` said ok to a machine whose home input sits on the map's
    ArmAtForward channel, which `plc run --machine` then refused. Now the map is checked with FILE's lines, the
    error at FILE's line; a good file (another shipped machine) passes with the same checks."""
    text = CONFIG.read_text()
    assert "home = 17 " in text
    bad = text.replace("home = 17 ", "home = 18 ", 1)
    cfg = tmp_path / "machine.toml"
    cfg.write_text(bad)
    proc = machine("check", "--config", str(cfg))
    assert proc.returncode == 1, proc.stderr
    assert (f"{cfg}:{line_of(bad, 'home = 18')}:1: error: CarouselHome: discrete_input 18 is already taken by "
            "ArmAtForward") in proc.stderr, proc.stderr
    assert f"the carousel lines: {cfg} [channels]" in proc.stderr
    good = machine("check", "--config", str(ROOT / "machines" / "carousel-50" / "machine.toml"))
    assert good.returncode == 0, good.stderr
    assert "the sequences' and the register map's with its lines" in good.stderr


RACK = ROOT / "machines" / "rack8" / "machine.toml"


def test_worn_out_hard_makes_a_worn_tool_without_a_sister_a_hard_refusal(tmp_path):
    assert "ToolsWornHard := FALSE;" in GENERATED.read_text()            # the shipped machine: soft (109)
    cfg = tmp_path / "machine.toml"
    cfg.write_text(CONFIG.read_text().replace('worn_out = "soft"', 'worn_out = "hard"', 1))
    out = tmp_path / "FB_MachineConfig.st"
    proc = machine("generate", "--config", str(cfg), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "ToolsWornHard := TRUE;" in out.read_text()


def test_a_rack_machine_generates_fixed_pockets_and_its_positions(tmp_path):
    from machine_project import project_for
    root = project_for("rack8")                       # its workspace (--machine rack8)
    st = (root / "st_src" / "app" / "generated" / "FB_MachineConfig.st").read_text()
    assert "FixedPockets := TRUE;" in st and "RackPlant.positions := 8;" in st
    assert "RackPlant.x[8] := 105000;" in st and "RackPlant.y[1] := 150000;" in st   # mm -> 1/1000 mm
    assert "RackPlant.gripZ := -50000;" in st and "Rotary.homing := HomingNone;" in st
    # no carousel lines; the tool-present sensor is the register map's ToolPresent channel, not a constant
    assert "Channels.home := -1;" in st and "Channels.pocket := -1;" in st
    tool_present = re.search(r'name = "ToolPresent"\ntable = "discrete_input"\naddress = (\d+)',
                             (ROOT / "modbus_map" / "map.toml").read_text()).group(1)
    assert f"Channels.toolPresent := {tool_present};" in st
    table = (root / "configs" / "linuxcnc" / "atc-sim.tbl").read_text().splitlines()
    assert [int(re.match(r"T(\d+) P(\d+)", row).group(2)) for row in table] == list(range(1, 9)), table
    seqs = (root / "machines" / "rack8" / "sequences" / "sequences.toml").read_text()
    assert re.search(r"(?m)^tools = 8\b", seqs)
    assert "FixedPockets := FALSE;" in GENERATED.read_text()


@pytest.mark.parametrize("change,message", [
    (lambda t: t + '\n[carousel]\npockets = 6\ninputs = "code"\noutputs = "separate"\nhoming = "none"\n',
     '[carousel] belongs to a machine of kind "carousel"'),
    (lambda t: t.replace('kind = "fixed-pockets"', 'kind = "carousel"'),
     '[rack] belongs to a machine of kind "fixed-pockets"'),
    (lambda t: re.sub(r"(?s)\[rack\].*?(?=\n\[changer\])", "", t), "[rack] positions is required"),
    (lambda t: t.replace("x = [-105.0, -75.0,", "x = [-75.0,"), "[rack] x: 7 values for 8 positions"),
    (lambda t: t.replace("grip_z = -50.0", "grip_z = \"low\""), "[rack] grip_z: expected a number"),
    (lambda t: t.replace("grip_z = -50.0", ""), "[rack] grip_z is required"),
])
def test_a_bad_rack_is_reported(tmp_path, change, message):
    cfg = tmp_path / "machine.toml"
    cfg.write_text(change(RACK.read_text()))
    proc = machine("check", "--config", str(cfg), "--out", str(tmp_path / "x.st"))
    assert proc.returncode == 1 and message in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr


def test_a_project_copy_inside_the_repository_is_its_own_project(tmp_path):
    """A copy of the project without scan tests under another project's tree (the LinuxCNC e2e switches one to the
    rack example under build/) is the root for `plc` commands run in it; before, the search for st_src/ with
    iec_tests/ went up to the repository and `plc machine use` rewrote the repository's own machine."""
    from plc.project import project_root
    outer = tmp_path / "repo"
    for rel in ("st_src", "iec_tests", "modbus_map", "configs"):
        (outer / rel).mkdir(parents=True)
    inner = outer / "build" / "run" / "rack-project"
    for rel in ("st_src", "modbus_map", "configs"):
        (inner / rel).mkdir(parents=True)
    assert project_root(inner / "st_src") == inner
    assert project_root(inner) == inner
    assert project_root(outer / "build" / "run") == outer
    bare = tmp_path / "sources-only"
    (bare / "st_src").mkdir(parents=True)
    assert project_root(bare) is None, "st_src/ alone is not a project"
