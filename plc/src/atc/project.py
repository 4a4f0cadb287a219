"""The machines of a project, side by side (the workspace each is built in: atc.workspace).

A project holds several machine descriptions: machines/NAME/machine.toml, each naming its sequence set and with
its own run configuration (machines/NAME/runtime.toml, the user's own file). project.toml names the machine a
command uses when none is given (`--machine NAME` chooses another).

The files generated from a machine (FB_MachineConfig, the sequence tables, AtcMain's declarations and wiring, the
LinuxCNC files and tool table, the HMI tags, docs/register-map.md) are committed for the project's default machine
only, where they are drift-checked. Any other machine is built out of the source tree, in its workspace
build/machines/NAME/: a view of the project made of links to the hand-owned files and of the files generated for
that machine. A command given `--machine NAME` runs in that view, so switching or adding a machine never rewrites
a tracked file, and two machines run at once from one checkout. The view is rebuilt by every command that uses
it (about a second), under a lock, and swapped in whole: it is never half-written and never stale.
"""
from __future__ import annotations

import tomllib
from pathlib import Path


PROJECT_FILE = "project.toml"
MACHINES = "machines"
DESCRIPTION = "machine.toml"
RUN_CONFIG = "runtime.toml"
FALLBACK = "default"
SEQUENCES = "configs/sequences/sequences.toml"   # a machine's sequence set unless its [sequences] index says


class MachineError(Exception):
    """A machine that cannot be used (unknown name, a workspace that cannot be built); the text says why."""


def read_project(root: Path) -> dict:
    try:
        return tomllib.loads((root / PROJECT_FILE).read_text(encoding="utf-8"))
    except FileNotFoundError:
        return {}
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise MachineError(f"{root / PROJECT_FILE}: cannot read: {e}") from None


def default_name(root: Path) -> str:
    """The machine named by project.toml ([project] machine), else "default"."""
    try:
        name = read_project(root).get("project", {}).get("machine", FALLBACK)
    except MachineError:
        return FALLBACK
    return name if isinstance(name, str) else FALLBACK


def source_root(root: Path) -> Path:
    """The project a workspace views (its project.toml says), else root itself."""
    try:
        src = read_project(root).get("workspace", {}).get("source")
    except MachineError:
        return root
    return Path(src) if isinstance(src, str) else root


def names(root: Path) -> list[str]:
    base = source_root(root) / MACHINES
    return sorted(p.parent.name for p in base.glob(f"*/{DESCRIPTION}")) if base.is_dir() else []


def description(root: Path, name: str | None = None) -> Path:
    """The machine description relative to root: machines/NAME/machine.toml (default: the project's machine)."""
    return Path(MACHINES) / (name or default_name(root)) / DESCRIPTION


def run_config(root: Path, name: str | None = None) -> Path | None:
    """The machine's own run configuration (machines/NAME/runtime.toml in the project, not in a workspace), or
    None when the machine has none."""
    name = name or default_name(root)
    path = source_root(root) / MACHINES / name / RUN_CONFIG
    return path if path.is_file() else None


def state_dir(root: Path, name: str | None = None) -> Path:
    """Where a machine keeps its state when its run configuration does not say: var/ for the project's default
    machine (as before machines were side by side), var/NAME/ for the others."""
    src = source_root(root)
    name = name or default_name(root)
    return src / "var" if name == default_name(src) else src / "var" / name


def sequence_index(root: Path) -> str:
    """The sequence set the machine description names ([sequences] index), relative to root; SEQUENCES when the
    description has none or cannot be read (its own check reports that)."""
    try:
        data = tomllib.loads((root / description(root)).read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError):
        return SEQUENCES
    index = data.get("sequences", {}).get("index") if isinstance(data.get("sequences"), dict) else None
    return index if isinstance(index, str) else SEQUENCES
