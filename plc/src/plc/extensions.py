"""How an application built on the toolchain extends the `plc` command.

The toolchain (this package) knows nothing of any application.  An application package declares an entry point
in the group `plc.extensions` (pyproject.toml, `[project.entry-points."plc.extensions"]`); its target is a
function `register(ext: Extensions)` that adds:

    commands      subcommands of `plc`: a name, a one-line help and "module:function" for main(argv) -> int,
                  imported only when the subcommand runs (so `plc --help` stays fast)
    parsers       functions add_parser(subparsers) for subcommands that live in the main argument parser
    preflight     checks run before `plc run` and `plc test` of a project: f(root, command) -> True refuses
                  (the function prints why)
    run_setup     f(root, build_dir) -> RunSetup | None: what `plc run` of the project adds to the runtime (the
                  application's events and their description, the simulation flag of its program)
    project_marks files or directories that, next to st_src/, make a directory a project
    run_config    f(root) -> (run configuration, state directory) | None: where the project's run is configured
                  and keeps its state when the configuration does not say (`plc run`, `plc status`, `plc monitor`)
    views         options choosing a view of the project (ViewOption: e.g. `--machine NAME`): given to any
                  subcommand, the option's function returns the directory that command treats as the project

Without any extension `plc` is the bare IEC 61131-3 toolchain: check, build, test, run, retain, status,
monitor, import, export.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache
from importlib import import_module
from importlib.metadata import entry_points
from pathlib import Path
from typing import Callable

GROUP = "plc.extensions"


@dataclass(frozen=True)
class Command:
    name: str
    help: str
    target: str                 # "package.module:function", the function is main(argv) -> int

    def main(self, argv: list[str]) -> int:
        module, _, function = self.target.partition(":")
        return getattr(import_module(module), function or "main")(argv)


@dataclass(frozen=True)
class RunSetup:
    """What an application adds to `plc run` of its project."""
    events_file: Path | None = None     # --events: the description the application's events read
    observer: Path | None = None        # C source of the application's events (monitor.h), linked into the runtime
    sim_flag: str | None = None         # --sim-flag: the input (%IXa.b) telling the program its plant is simulated
    # coils whose level on the wire when the runtime stops is prescribed (bit index -> (level, why)): a remote I/O
    # device's `safe` values must give them that level (an inverted motor line is stopped by TRUE)
    stop_levels: dict[int, tuple[bool, str]] = field(default_factory=dict)
    # what the program implies for the run configuration, used where the user's file does not say: the Modbus
    # ranges a host may write and the holding registers retained with the RETAIN variables ("first-last" ranges)
    writable_coils: list[str] | None = None
    writable_registers: list[str] | None = None
    retain_registers: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class ViewOption:
    """An option every project-bound subcommand accepts (`flag VALUE`): resolve(root, VALUE) returns the directory
    the command then treats as its project, or raises ViewError saying why it cannot."""
    flag: str
    metavar: str
    help: str
    resolve: Callable[[Path, str], Path]


class ViewError(Exception):
    """A view that cannot be used; the text says why (plc prints it and exits with status 2)."""


@dataclass
class Extensions:
    commands: dict[str, Command] = field(default_factory=dict)
    parsers: list[Callable] = field(default_factory=list)
    preflight: list[Callable[[Path, str], bool]] = field(default_factory=list)
    run_setup: list[Callable[[Path, Path], RunSetup | None]] = field(default_factory=list)
    project_marks: list[str] = field(default_factory=list)
    run_config: list[Callable[[Path], tuple[Path | None, Path | None] | None]] = field(default_factory=list)
    views: list[ViewOption] = field(default_factory=list)
    sources: list[str] = field(default_factory=list)     # the entry points that registered, for messages

    def command(self, name: str, help: str, target: str) -> None:
        if name in self.commands:
            raise ValueError(f"plc extension: the subcommand {name!r} is registered twice")
        self.commands[name] = Command(name, help, target)


@cache
def load() -> Extensions:
    """Every installed extension, registered once per process."""
    ext = Extensions()
    for ep in sorted(entry_points(group=GROUP), key=lambda e: e.name):
        ep.load()(ext)
        ext.sources.append(f"{ep.name} ({ep.value})")
    return ext
