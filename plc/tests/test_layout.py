"""The package layout: `plc` is importable from the repository root (the folder plc/ does not shadow the
package in plc/src/plc), and the files the toolchain ships are found through plc.resources as package data."""
import subprocess
import sys
from pathlib import Path

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
    src = REPO / "plc" / "src" / "plc"
    offenders = [str(p.relative_to(src)) for p in src.rglob("*.py")
                 if "parents[" in p.read_text(encoding="utf-8") and p.name != "resources.py"]
    assert offenders == []


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
