"""What a project is, for the toolchain: a directory holding st_src/ (the program) and iec_tests/ (its scan
tests) or one of the marks an installed extension names (plc.extensions).  Commands run inside a project take
their defaults from it (`plc test` its iec_tests/, `plc run` its st_src/)."""
from __future__ import annotations

import os
from pathlib import Path

from . import extensions

SOURCES = "st_src"
TESTS = "iec_tests"


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
