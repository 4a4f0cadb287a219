"""The package layout: `plc` is importable from the repository root (the folder plc/ does not shadow the
package in plc/src/plc), and the files the toolchain ships are found through plc.resources as package data."""
import subprocess
import sys
from pathlib import Path

from code_rules import parents_subscripts

REPO = Path(__file__).resolve().parents[2]


def test_import_from_repository_root():
    out = subprocess.run([sys.executable, "-c", "import plc.cli, plc.resources as r; print(r.PACKAGE)"],
                         cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert Path(out.stdout.strip()) == REPO / "plc" / "src" / "plc"


def test_shipped_files_are_package_data():
    from plc import resources as r
    assert (r.INCLUDE / "plc_abi.h").is_file()
    assert (r.RUNTIME_SRC / "main.c").is_file()
    assert (r.STDLIB / "standard_fbs.st").is_file()
    assert (r.DATA / "openplc_library_identifiers.txt").is_file()
    for p in (r.INCLUDE, r.RUNTIME_SRC, r.STDLIB, r.DATA):
        assert r.PACKAGE in p.parents                  # nothing outside the package


def test_no_module_reaches_outside_the_package():
    """Parsed code (ast): no module but plc.resources finds a file by counting folders up (`.parents[n]`)."""
    src = REPO / "plc" / "src" / "plc"
    offenders = [f"{p.relative_to(src)}:{line}" for p in sorted(src.rglob("*.py")) if p.name != "resources.py"
                 for line in parents_subscripts(p.read_text(encoding="utf-8"), str(p))]
    assert offenders == []


def test_the_folder_counting_rule_flags_a_parents_index_and_only_that():
    snippet = ('from pathlib import Path\n'
               'ROOT = Path(__file__).resolve().parents[3]\n'
               'HELP = "never write .parents[2]"  # nor parents[1] in a comment\n'
               'UP = Path(__file__).parent.parent\n'
               'def above(p, n):\n'
               '    return p.parents[n]\n')
    assert parents_subscripts(snippet) == [2, 6]


def test_nothing_machine_local_is_tracked():
    """A run's state (var/: retained data, the monitor's token and audit log) belongs to the machine it ran on:
    no var/ folder is tracked anywhere, and git ignores a new one wherever it appears."""
    tracked = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert tracked.returncode == 0, tracked.stderr
    assert [f for f in tracked.stdout.splitlines() if "var" in Path(f).parts[:-1]] == []
    for path in ("var/plc.retain", "machines/rack8/var/plc.retain", "plc/src/var/monitor.token"):
        probe = subprocess.run(["git", "check-ignore", "-q", path], cwd=REPO, capture_output=True, text=True,
                               timeout=60)
        assert probe.returncode == 0, f"{path}: var/ must be ignored wherever it appears {probe.stderr}"
