"""A machine's workspace: the project as one of its machines sees it (atc.project says why it exists).

build/machines/NAME/ is made of links to the project's hand-owned files and of the files generated for NAME; it is
rebuilt (about a second) by a command given `--machine NAME` whenever a file it is made from changed (name, size or
modification time), under a lock, and swapped in whole, so it is never half-written and never stale.
"""
from __future__ import annotations

import contextlib
import fcntl
import hashlib
import io
import os
import shutil
from pathlib import Path

from .generation import check_and_generate
from .project import DESCRIPTION, MACHINES, PROJECT_FILE, MachineError, default_name, description, names, source_root

WORKSPACES = Path("build") / "machines"
# the project's directories a workspace shows (as links to their files; a machine may name another's sequences)
VIEWED = ("st_src", "configs", "modbus_map", "hmi_tags", "docs", "iec_tests", "machines")
SKIPPED = ("var", "__pycache__")
STAMP = ".stamp"


def view(root: Path, name: str) -> Path:
    """The project as machine NAME sees it: root itself for the default machine, else NAME's workspace, built."""
    known = names(root)
    if name not in known:
        raise MachineError(f"no machine {name!r} in {source_root(root) / MACHINES}/ (known: "
                           f"{', '.join(known) or 'none'}); a machine is a folder machines/NAME/ holding "
                           f"{DESCRIPTION}")
    src = source_root(root)
    if name == default_name(src):
        return src
    return build_workspace(src, name)


def build_workspace(root: Path, name: str) -> Path:
    """Build build/machines/NAME/ from the project at root (see the module's text); MachineError when the
    machine's files do not check (nothing is swapped in then)."""
    base = root / WORKSPACES
    base.mkdir(parents=True, exist_ok=True)
    target, fresh, old = base / name, base / f".{name}.new", base / f".{name}.old"
    with open(base / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        stamp = _stamp(root)
        try:
            if (target / STAMP).read_text() == stamp:
                return target
        except OSError:
            pass
        for stale in (fresh, old):
            shutil.rmtree(stale, ignore_errors=True)
        fresh.mkdir()
        (fresh / ".git").mkdir()        # generated headers name files relative to the workspace, as in the project
        cache = base / ".cache" / name      # build/ of the view (compiled programs, test binaries): kept across builds
        cache.mkdir(parents=True, exist_ok=True)
        (fresh / "build").symlink_to(cache)
        _link_files(root, fresh)
        (fresh / PROJECT_FILE).write_text(
            f"# The workspace of machine {name}, built by plc from {root}: do not edit (rebuilt by every command "
            f"given --machine {name}).\n[project]\nmachine = \"{name}\"\n\n[workspace]\nsource = "
            f"\"{_toml_escape(str(root))}\"\n", encoding="utf-8")
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            status = check_and_generate(fresh / description(fresh, name), None, write=True, root=fresh)
        if status != 0:
            shutil.rmtree(fresh, ignore_errors=True)
            text = err.getvalue().replace(str(fresh) + os.sep, "")
            raise MachineError(f"machine {name}: its files do not check, no workspace built:\n{text.rstrip()}")
        (fresh / STAMP).write_text(stamp)
        if target.exists():
            target.rename(old)
        fresh.rename(target)
        shutil.rmtree(old, ignore_errors=True)
    return target


def _sources(root: Path):
    """The hand-owned files a workspace shows: every file of VIEWED but state and caches."""
    for top in VIEWED:
        for dirpath, dirnames, filenames in os.walk(root / top):
            dirnames[:] = sorted(d for d in dirnames if d not in SKIPPED)
            for f in sorted(filenames):
                if not f.endswith((".retain", ".tmp", ".pyc")):
                    yield Path(dirpath) / f


def _stamp(root: Path) -> str:
    """What the workspace is made of: every source file's path, size and modification time, and this package."""
    h = hashlib.sha256(str(Path(__file__).parent).encode())
    for path in (*_sources(root), *Path(__file__).parent.rglob("*.py")):
        st = path.stat()
        h.update(f"{path}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def _link_files(root: Path, dst: Path) -> None:
    """dst mirrors root's hand-owned files: real directories, each file a link to its original (edits go to the
    project's file)."""
    for path in _sources(root):
        out = dst / path.relative_to(root)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.symlink_to(path)


def _toml_escape(text: str) -> str:
    return text.replace("\\", "\\\\").replace("\"", "\\\"")
