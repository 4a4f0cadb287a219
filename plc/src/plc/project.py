"""What a project is, for the toolchain: a directory holding st_src/ (the program) and iec_tests/ (its scan
tests) or one of the marks an installed extension names (plc.extensions).  Commands run inside a project take
their defaults from it (`plc test` its iec_tests/, `plc run` its st_src/)."""
from __future__ import annotations

from pathlib import Path

from . import extensions

SOURCES = "st_src"
TESTS = "iec_tests"


def project_root(start: Path | None = None) -> Path | None:
    """The nearest directory at or above `start` (default: here) holding st_src/ and iec_tests/ or a mark of an
    extension: a project copy without scan tests is its own project, not part of the repository around it."""
    marks = (TESTS, *extensions.load().project_marks)
    p = (start or Path.cwd()).resolve()
    for q in (p, *p.parents):
        if (q / SOURCES).is_dir() and any((q / mark).exists() for mark in marks):
            return q
    return None


def refused_by_preflight(root: Path, command: str) -> bool:
    """Run every extension's check before `command` in the project at root; True when one refuses."""
    return any(check(root, command) for check in extensions.load().preflight)
