"""The project as one of its machines sees it (its workspace, `--machine NAME`), for the example tests and
scripts/bench-examples; and a copy of the project for the tests that edit its files (only what the machine, the
map, the sequences and the application need is copied; an empty .git marks the copy as a repository so generated
headers name files as in the real one)."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
COPIED = ["st_src", "configs", "modbus_map", "hmi_tags", "docs", "machines", "project.toml"]
EXAMPLES = sorted(p.parent.name for p in (REPO / "machines").glob("*/machine.toml"))
# the scan tests every example machine runs (one compiled program per machine)
SCAN_TESTS = ["iec_tests/machine", "iec_tests/app/FB_AppRig.st"]


def plc(*args: str, cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO / "plc" / "src"))
    return subprocess.run([sys.executable, "-m", "plc.cli", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=env)


def project_for(name: str) -> Path:
    """The workspace of machine NAME (build/machines/NAME/), built by `plc machine check --machine NAME`; the
    project itself for its default machine."""
    result = plc("machine", "check", "--machine", name, cwd=REPO)
    if result.returncode != 0:
        raise RuntimeError(f"plc machine check --machine {name} failed:\n{result.stderr}")
    workspace = REPO / "build" / "machines" / name
    return workspace if workspace.is_dir() and name != "default" else REPO


def copy_project(root: Path) -> Path:
    """A copy of the project (as it is, default machine) at `root`."""
    if root.exists():
        shutil.rmtree(root)
    root.mkdir(parents=True)
    (root / ".git").mkdir()
    for rel in COPIED:
        if (REPO / rel).is_file():
            shutil.copy2(REPO / rel, root / rel)
        else:
            shutil.copytree(REPO / rel, root / rel, ignore=shutil.ignore_patterns("var", "*.retain"))
    for rel in SCAN_TESTS:
        src, dst = REPO / rel, root / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        (shutil.copytree if src.is_dir() else shutil.copy2)(src, dst)
    return root
