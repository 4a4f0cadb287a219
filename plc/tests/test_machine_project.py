"""The machine description is the one place the changer is configured (issue 13): in a copy of the project,
a wrong machine file gets a positioned error from `plc machine check` and stops `plc run` before anything runs;
stale generated files (machine, map, sequences) are refused by `plc run` and `plc test`, naming the command that
regenerates them; `plc machine generate` carries a new pocket count into the sequences, the tool table and the
register map; another machine of the project is built in its workspace, rewriting no project file."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from machine_project import copy_project, plc

MACHINE = "machines/default/machine.toml"


@pytest.fixture
def project(tmp_path) -> Path:
    return copy_project(tmp_path / "project")


def edit(path: Path, old: str, new: str) -> int:
    """Replace the first occurrence of old; the 1-based line of the replacement."""
    text = path.read_text()
    at = text.index(old)
    path.write_text(text[:at] + new + text[at + len(old):])
    return text[:at].count("\n") + 1


def refused_by_run(root: Path, *needles: str) -> str:
    result = plc("run", "--io", "sim", "--port", "1", "--build-dir", str(root / "build"), cwd=root, timeout=120)
    assert result.returncode == 1, result.stdout + result.stderr
    assert "listening" not in result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    for needle in needles:
        assert needle in result.stderr, result.stderr
    return result.stderr


@pytest.mark.parametrize("old,new,message", [
    ('outputs = "enable+positive-dir"', 'outputs = "enable+plus-dir"',
     "[carousel] outputs: expected one of \"single-positive\", "),
    ('inputs = "home+pocket"', 'inputs = "code"\npocket_codes = [6, 7, 3, 1, 5]\n#',
     "[carousel] pocket_codes: 5 codes for 6 pockets"),
    ("plus_dir = 20 ", "plus_dir = 16 ", "[channels] plus_dir and on are both on output channel 16"),
    ("plus_dir = 20 ", "plus_dir = 18 ", "[channels] plus_dir = 18 is also a sequence output "
                                          "(configs/sequences/sequences.toml:17 [io] outputs)"),
])
def test_a_wrong_machine_file_is_a_positioned_error_before_anything_runs(project, old, new, message):
    path = project / MACHINE
    text = path.read_text()
    if "pocket_codes" in new:                 # keep one pocket_codes key: replace the existing one
        text = re.sub(r"(?m)^pocket_codes = .*\n", "", text)
        path.write_text(text)
    line = edit(path, old, new)
    if "pocket_codes" in new:
        line += 1
    result = plc("machine", "check", cwd=project)
    assert result.returncode == 1
    assert f"{MACHINE}:{line}: error: {message}" in result.stderr, result.stderr
    refused_by_run(project, message)


def test_a_machine_file_that_is_not_toml_is_named_once_not_also_as_a_map_problem(project):
    """Issue 27: invalid TOML in the machine file made `plc run` also say "fix the register map"."""
    path = project / MACHINE
    path.write_text(path.read_text() + "pockets = = 3\n")
    stderr = refused_by_run(project, f"{MACHINE}:", "invalid TOML", "fix the machine description")
    assert "fix the register map" not in stderr, stderr


def test_a_pocket_count_the_sequences_do_not_cover_names_both_files_and_the_fix(project):
    line = edit(project / MACHINE, "pockets = 6 ", "pockets = 8 ")
    seq_line = next(n for n, ln in enumerate((project / "configs/sequences/sequences.toml").read_text()
                                             .splitlines(), 1) if ln.startswith("tools ="))
    result = plc("machine", "check", cwd=project)
    assert result.returncode == 1
    assert (f"{MACHINE}:{line}: error: [carousel] pockets = 8, but configs/sequences/sequences.toml:{seq_line} "
            f"has tools = 6") in result.stderr, result.stderr
    assert "plc machine generate" in result.stderr
    refused_by_run(project, "pockets = 8", "plc machine generate")
    # the fix named: generate carries the count everywhere, then everything is clean
    assert plc("machine", "generate", cwd=project).returncode == 0
    assert re.search(r"(?m)^tools = 8\b", (project / "configs/sequences/sequences.toml").read_text())
    assert (project / "configs/linuxcnc/atc-sim.tbl").read_text().count("\nT") == 7     # T1..T8
    assert "Rotary.pockets := 8;" in (project / "st_src/app/generated/FB_MachineConfig.st").read_text()
    assert "tools 1..8" in (project / "st_src/sequence/generated/SequenceTables.st").read_text()
    for args in (["machine", "check"], ["map", "check"]):
        assert plc(*args, cwd=project).returncode == 0


@pytest.mark.parametrize("what,change,command", [
    ("machine", ("st_src/app/generated/FB_MachineConfig.st", "Rotary.pockets := 6;", "Rotary.pockets := 7;"),
     "plc machine generate"),
    ("map", ("modbus_map/map.toml", 'description = "spindle collet opened"', 'description = "collet open"'),
     "plc map generate"),
    ("sequences", ("configs/sequences/put.seq", "DELAY 500", "DELAY 400"),
     "plc seq compile configs/sequences/sequences.toml --out st_src/sequence/generated/SequenceTables.st"),
    ("broken sequence", ("configs/sequences/put.seq", "DELAY 500", "DELAY half a second"), "plc seq compile"),
    ("duplicate map address", ("modbus_map/map.toml", "address = 20\n", "address = 19\n"), "plc map generate"),
])
def test_stale_or_broken_sources_are_refused_by_run_and_test(project, what, change, command):
    rel, old, new = change
    edit(project / rel, old, new)
    refused_by_run(project, command)
    result = plc("test", "-q", "--build-dir", str(project / "build" / "t"), cwd=project, timeout=300)
    assert result.returncode == 2, result.stdout + result.stderr          # the project, not a test, is wrong
    assert command in result.stderr and "nothing was run" in result.stderr, result.stderr
    assert " passed" not in result.stdout, result.stdout                   # no test count for tests not run


def test_a_machine_beside_the_default_is_built_in_its_workspace_and_rewrites_no_project_file(project):
    """Issue 26: `--machine NAME` builds machines/NAME/ in build/machines/NAME/ (links to the hand-owned files, the
    files generated for NAME); no file of the project changes, the default machine's files stay as they were."""
    before = {p: p.read_bytes() for d in ("st_src", "configs", "modbus_map", "hmi_tags", "docs", "machines")
              for p in (project / d).rglob("*") if p.is_file()}
    result = plc("machine", "check", "--machine", "carousel-24-separate-inverted", cwd=project)
    assert result.returncode == 0, result.stderr
    workspace = project / "build" / "machines" / "carousel-24-separate-inverted"
    program = workspace / "st_src/app/AtcMain.st"
    assert not program.is_symlink() and "CarouselDirNegative AT %QX2.5" in program.read_text()
    assert "CarouselCode5" in (workspace / "hmi_tags/atc_tags.csv").read_text()
    hand_owned = workspace / "st_src/app/FB_AtcMachine.st"
    assert hand_owned.is_symlink() and hand_owned.resolve() == (project / "st_src/app/FB_AtcMachine.st").resolve()
    assert "CarouselDirNegative" not in (project / "st_src/app/AtcMain.st").read_text()
    after = {p: p.read_bytes() for p in before}
    assert [str(p.relative_to(project)) for p in before if before[p] != after[p]] == []
    listed = plc("machine", "list", cwd=project)
    assert "default  (default)" in listed.stdout.splitlines() and "rack8" in listed.stdout.splitlines()
    unknown = plc("machine", "check", "--machine", "no-such-machine", cwd=project)
    assert unknown.returncode == 2 and "known: " in unknown.stderr and "carousel-50" in unknown.stderr
    assert "Traceback" not in unknown.stderr
    old = plc("machine", "use", "rack8", cwd=project)
    assert old.returncode == 2 and "--machine rack8" in old.stderr, old.stderr


def test_a_machine_that_does_not_check_builds_no_workspace(project):
    path = project / "machines" / "carousel-50" / "machine.toml"
    edit(path, "pockets = 50", "pockets = 60")
    result = plc("machine", "check", "--machine", "carousel-50", cwd=project)
    assert result.returncode == 2, result.stderr
    assert "machines/carousel-50/machine.toml:" in result.stderr and "2..50" in result.stderr, result.stderr
    assert not (project / "build" / "machines" / "carousel-50").exists()
