"""What a project is, for the toolchain: a directory holding st_src/ (the program) and iec_tests/ (its scan
tests) or one of the marks an installed extension names (plc.extensions).  Commands run inside a project take
their defaults from it (`plc test` its iec_tests/, `plc run` its st_src/)."""
from __future__ import annotations

import io
import json
import os
import sys
import threading
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Callable, TypeVar

from . import extensions

SOURCES = "st_src"
TESTS = "iec_tests"


T = TypeVar("T")

_view: Path | None = None       # the project as a view option chose it (choose_view), for this process


def project_root(start: Path | None = None) -> Path | None:
    """The nearest directory at or above `start` (default: here) holding st_src/ and iec_tests/ or a mark of an
    extension: a project copy without scan tests is its own project, not part of the repository around it.
    Without `start`, a view chosen on the command line (choose_view) is the project."""
    if start is None and _view is not None:
        return _view
    marks = (TESTS, *extensions.load().project_marks)
    p = (start or Path.cwd()).resolve()
    for q in (p, *p.parents):
        if (q / SOURCES).is_dir() and any((q / mark).exists() for mark in marks):
            return q
    return None


def refused_by_preflight(root: Path, command: str) -> bool:
    """Run every extension's check before `command` in the project at root; True when one refuses."""
    return any(check(root, command) for check in extensions.load().preflight)


class Preflight:
    """refused_by_preflight run beside the caller's own work, in a child process (fork) on the machine's other
    CPU: `plc test` builds while the extensions check the project.  `refused()` waits for the verdict and prints
    what the checks printed, as they would have.  The caller holds back its own output until then, so a refused
    command prints only why (beside_preflight).  Where a child cannot be forked safely (no fork, other threads
    running, no extension check) or the child dies, the checks run in this process when the verdict is asked."""

    def __init__(self, root: Path, command: str) -> None:
        self.root, self.command = root, command
        self.pid: int | None = None
        self._verdict: bool | None = None
        if not extensions.load().preflight:
            self._verdict = False
        elif hasattr(os, "fork") and threading.active_count() == 1:
            self._start()

    def _start(self) -> None:
        read_end, write_end = os.pipe()
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:                                        # the child: the checks, their output, the verdict
            code = 3
            try:
                os.close(read_end)
                out, err = io.StringIO(), io.StringIO()
                with redirect_stdout(out), redirect_stderr(err):
                    refused = refused_by_preflight(self.root, self.command)
                with os.fdopen(write_end, "w", encoding="utf-8") as pipe:
                    json.dump([out.getvalue(), err.getvalue()], pipe)
                code = 1 if refused else 0
            finally:
                os._exit(code)                              # no atexit hooks, no flush of the parent's buffers
        os.close(write_end)
        self.pid, self._pipe = pid, os.fdopen(read_end, encoding="utf-8")

    def refused(self) -> bool:
        if self._verdict is not None:
            return self._verdict
        if self.pid is not None:
            with self._pipe:
                text = self._pipe.read()
            _pid, status = os.waitpid(self.pid, 0)
            self.pid = None
            code = os.waitstatus_to_exitcode(status)
            if code in (0, 1):
                out, err = json.loads(text)
                sys.stdout.write(out)
                sys.stderr.write(err)
                self._verdict = code == 1
                return self._verdict
        # no child, or it died (the checks raised): run them here, where an error shows as it always did
        self._verdict = refused_by_preflight(self.root, self.command)
        return self._verdict


def beside_preflight(preflight: Preflight | None, work: Callable[[], T]) -> tuple[bool, T | None]:
    """(refused, result): work() run while `preflight` checks the project (None: no check).  What work prints is
    held until the verdict: a refused command prints only why, and work's result is dropped; else work's output
    follows the checks' and an exception work raised is raised now."""
    if preflight is None:
        return False, work()
    out, err = io.StringIO(), io.StringIO()
    result, error = None, None
    with redirect_stdout(out), redirect_stderr(err):
        try:
            result = work()
        except Exception as e:          # the work's own errors come after the verdict (an interrupt does not wait)
            error = e
    if preflight.refused():
        return True, None
    sys.stdout.write(out.getvalue())
    sys.stderr.write(err.getvalue())
    if error is not None:
        raise error
    return False, result


def where(path: Path) -> Path:
    """`path` made absolute and normalised without following links: a project view made of links to another
    project's files (an application's workspace) keeps its own paths."""
    return Path(os.path.normpath(os.path.abspath(path)))


def choose_view(argv: list[str]) -> None:
    """Find an extension's view option (`--machine NAME`, `--machine=NAME`) in argv (before `--`) and make the
    directory it names the project of this process; ViewError when it cannot be used. The option stays in argv:
    every subcommand that accepts it declares it (add_view_options)."""
    global _view
    options = {v.flag: v for v in extensions.load().views}
    for i, arg in enumerate(argv):
        if arg == "--":
            break
        flag, eq, value = arg.partition("=")
        option = options.get(flag)
        if option is None:
            continue
        if not eq:
            if i + 1 >= len(argv) or argv[i + 1].startswith("-"):
                raise extensions.ViewError(f"{flag} needs a value ({option.metavar})")
            value = argv[i + 1]
        root = project_root()
        if root is None:
            raise extensions.ViewError(f"{flag} {value}: no project found from {Path.cwd()}")
        _view = option.resolve(root, value)


def add_view_options(parser) -> None:
    """Declare the extensions' view options on a subcommand's parser (the choice itself is made by choose_view)."""
    for v in extensions.load().views:
        parser.add_argument(v.flag, metavar=v.metavar, help=v.help)


def run_config(root: Path | None) -> tuple[Path | None, Path | None]:
    """The project's run configuration and state directory, as the first extension that knows the project says;
    else its configs/runtime.toml (when there is one) and no state directory."""
    if root is None:
        return None, None
    for hook in extensions.load().run_config:
        found = hook(root)
        if found is not None:
            return found
    own = root / "configs" / "runtime.toml"
    return (own if own.is_file() else None), None
