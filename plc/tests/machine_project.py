"""A copy of the project switched to one example machine (`plc machine use NAME`), for the example tests and
scripts/bench-examples. Only what the machine, the map, the sequences and the application need is copied; an
empty .git marks the copy as a repository so generated headers name files as in the real one."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
COPIED = ["st_src", "configs", "modbus_map", "hmi_tags", "docs"]
EXAMPLES = sorted(p.stem for p in (REPO / "configs" / "examples").glob("*.toml"))
# the scan tests every example machine runs (one compiled program per machine)
SCAN_TESTS = ["iec_tests/machine", "iec_tests/app/FB_AppRig.st"]


def plc(*args: str, cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO / "plc" / "src"))
    return subprocess.run([sys.executable, "-m", "plc.cli", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=env)


def project_for(name: str, where: Path) -> Path:
    """A project copy under `where` whose machine is configs/examples/NAME.toml, everything regenerated."""
    root = copy_project(where / name)
    result = plc("machine", "use", name, cwd=root)
    if result.returncode != 0:
        raise RuntimeError(f"plc machine use {name} failed:\n{result.stderr}")
    return root


def copy_project(root: Path) -> Path:
    """A copy of the project (as it is, default machine) at `root`."""
    if root.exists():
        shutil.rmtree(root)
    root.mkdir(parents=True)
    (root / ".git").mkdir()
    for rel in COPIED:
        shutil.copytree(REPO / rel, root / rel, ignore=shutil.ignore_patterns("var", "*.retain"))
    for rel in SCAN_TESTS:
        src, dst = REPO / rel, root / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        (shutil.copytree if src.is_dir() else shutil.copy2)(src, dst)
    return root
