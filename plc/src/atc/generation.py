"""Everything generated from the machine description, and `plc machine check|generate|use`.

The machine description (machine.py) is read and checked on its own; this module puts it together with the
register map and the sequence set: the channels the map places (map_channels), the files the description
generates (FB_MachineConfig, the LinuxCNC tool table, the sequence set's tool count), then the map's files and
the sequence tables, written together or not at all.
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from plc.diagnostics import Diagnostics
from plc.project import add_view_options, where
from plc.project import project_root as find_project

from . import project
from .machine import (
    DEFAULT_OUT,
    DEFAULT_SEQUENCES,
    MAP_CHANNELS,
    MAP_FILE,
    SEQ_TABLES,
    TOOL_TABLE,
    _rel,
    check_sequences,
    generate,
    load,
    pockets,
    report,
    sequences_index,
    tool_table,
    tools_line,
)
from .map import generate as mapgen
from .map.model import load as load_map
from .seq.assemble import check_set
from .seq.diagnostics import Diagnostics as SeqDiagnostics
from .seq.stgen import generate as seqgen
from .seq.stgen import stable_name


def map_channels(root: Path) -> tuple[dict[str, int], list[str]]:
    """Channels of the changer lines placed by the register map (MAP_CHANNELS); problems as text."""
    diags = Diagnostics()
    rmap = load_map(root / MAP_FILE, diags)
    if rmap is None or diags.has_errors():
        return {}, [d.render() for d in diags.sorted()] or [f"{MAP_FILE}: cannot be read"]
    found = {}
    for field_, name in MAP_CHANNELS.items():
        sig = rmap.signal(name)
        if sig is not None:
            found[field_] = sig.address
    return found, []


def project_root(start: Path | None = None) -> Path:
    return find_project(start) or Path.cwd()


def outputs(root: Path, data: dict, config_label: str) -> tuple[dict[str, str], list[str]]:
    """{path relative to root: text} of the files the machine description generates itself (the FB, the tool
    table and the sequence set's tool count); problems as text."""
    chans, problems = map_channels(root)
    if problems:
        return {}, problems
    files = {DEFAULT_OUT.as_posix(): generate(data, config_label, chans), TOOL_TABLE: tool_table(data)}
    index = sequences_index(data, root)
    rel = _rel(index, root)
    try:
        text = index.read_text()
    except OSError as e:
        return {}, [f"{rel}: cannot read: {e.strerror}"]
    line, tools = tools_line(text)
    if tools is not None:
        lines = text.splitlines(keepends=True)
        lines[line - 1] = re.sub(r"tools(\s*)=(\s*)\d+", lambda m: f"tools{m.group(1)}={m.group(2)}"
                                 f"{pockets(data)}", lines[line - 1], count=1)
        files[rel] = "".join(lines)
    return files, []


def drift(root: Path, files: dict[str, str]) -> list[str]:
    stale = []
    for rel, text in files.items():
        path = root / rel
        if not path.exists() or path.read_text() != text:
            stale.append(rel)
    return stale


def check_and_generate(config: Path, out: Path | None, write: bool, label: str | None = None,
                       root: Path | None = None) -> int:
    """Check `config` against the project at `root`; write every file it generates (write=True, then also the
    register map's files and the sequence tables) or fail when one differs (drift)."""
    root = root or project_root()
    data, ck = load(config, _rel(config, root))
    if not write and where(config) != where(root / project.description(root)):
        # another file (e.g. a candidate machine): its own checks, the sequences' and the register map's with its
        # lines, as a run of it would check them; its generated files are its workspace's (--machine NAME)
        if not ck.problems:
            check_sequences(ck, data, root, label or config.as_posix())
            # the set's tool count is written for the machine that runs (its workspace), not checked against it
            ck.problems = [d for d in ck.problems if "tools =" not in d.message]
        report(ck)
        if ck.problems:
            return 1
        diags = Diagnostics()
        mapgen.check_with_machine(root / MAP_FILE, config, diags)
        for d in diags.sorted():
            print(d.render(), file=sys.stderr)
        if diags.has_errors():
            return 1
        print(f"plc machine check: {_rel(config, root)}: ok (its own checks, the sequences' and the register map's "
              "with its lines; not the project's machine: its generated files are built by --machine NAME)",
              file=sys.stderr)
        return 0
    if not ck.problems:
        check_sequences(ck, data, root, label or config.as_posix())
    for d in ck.warnings if not ck.problems else []:
        print(d.render(), file=sys.stderr)
    if ck.problems:
        if not write or any("tools =" not in d.message for d in ck.problems):
            report(ck)
            return 1
    label = label or _rel(config, root)
    files, problems = outputs(root, data, label)
    if problems:
        for line in problems:
            print(line, file=sys.stderr)
        return 1
    if out is not None:
        files[_rel(out, root)] = files.pop(DEFAULT_OUT.as_posix())
    if not write:
        stale = drift(root, files)
        for rel in stale:
            print(f"{rel}: error: out of date with {label}: run `plc machine generate`", file=sys.stderr)
        if not stale:
            places = "positions" if "rack" in data else "pockets"
            warned = f"; {len(ck.warnings)} warning(s) above" if ck.warnings else ""
            print(f"plc machine check: {label}: ok ({pockets(data)} {places}; the register map and the sequences "
                  f"agree; its {len(files)} generated files are up to date{warned})", file=sys.stderr)
        return 1 if stale else 0
    return write_all(root, files)


def write_all(root: Path, files: dict[str, str]) -> int:
    """Write the machine's files, then regenerate the register map and the sequence tables; nothing is written
    when the map or the sequences would not check with the new machine."""
    saved = {rel: (root / rel).read_text() if (root / rel).exists() else None for rel in files}
    for rel, text in files.items():
        _write(root / rel, text)
    diags = Diagnostics()
    loaded = mapgen.load_and_check(root / MAP_FILE, diags)
    index = root / [rel for rel in files if rel.endswith(".toml")][0] if any(r.endswith(".toml") for r in files) \
        else root / DEFAULT_SEQUENCES
    seq_diags = SeqDiagnostics()
    assembly = check_set(index, seq_diags)
    if loaded is None or diags.has_errors() or assembly is None or seq_diags.errors:
        for d in list(diags.sorted()) + list(seq_diags.errors):
            if d.severity == "error":
                print(d.render(), file=sys.stderr)
        for rel, text in saved.items():         # nothing half-applied
            if text is None:
                (root / rel).unlink(missing_ok=True)
            else:
                _write(root / rel, text)
        print("plc machine: nothing written", file=sys.stderr)
        return 1
    written = [rel for rel in files if saved[rel] != files[rel]]
    written += mapgen.write(loaded)
    tables = root / SEQ_TABLES
    text = seqgen(assembly, stable_name(index), stable_name(tables))
    if not tables.exists() or tables.read_text() != text:
        _write(tables, text)
        written.append(SEQ_TABLES)
    for rel in written:
        print(f"wrote {rel}", file=sys.stderr)
    return 0


def _write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8", newline="\n")
    tmp.replace(path)


def add_parser(sub) -> None:
    p = sub.add_parser("machine", help="check a machine description / generate everything from it / list machines",
                       description="A machine description (machines/NAME/machine.toml) is the one place a changer "
                                   "is configured. check: file:line errors, cross-checks with the register map and "
                                   "the sequence set, and drift of every file generated from it. generate: write "
                                   "FB_MachineConfig, the sequence set's tool count, the LinuxCNC tool table, then "
                                   "the register map's files and the sequence tables (the project's default machine: "
                                   "in the tree; another machine: in its workspace build/machines/NAME/). list: the "
                                   "project's machines, the default marked. Exit status: 0 ok, 1 errors or drift "
                                   "(nothing written), 2 usage.")
    p.add_argument("action", choices=["check", "generate", "list", "use"], help="check, generate or list")
    p.add_argument("name", nargs="?", help=argparse.SUPPRESS)
    p.add_argument("--config", type=Path, default=None,
                   help="`check` of another description file checks that file alone")
    p.add_argument("--out", type=Path, default=None, help=f"the generated FB (default {DEFAULT_OUT})")
    add_view_options(p)
    p.set_defaults(func=_main)


def _main(a) -> int:
    root = project_root()
    if a.action == "use":
        print("plc machine use: error: machines now live side by side and nothing is switched: give any command "
              f"--machine {a.name or 'NAME'} (machines/NAME/machine.toml), or name the default machine in "
              f"{project.PROJECT_FILE} ([project] machine = \"NAME\")", file=sys.stderr)
        return 2
    if a.action == "list":
        default = project.default_name(root)
        for name in project.names(root):
            print(f"{name}{'  (default)' if name == default else ''}")
        return 0
    config = a.config or root / project.description(root)
    return check_and_generate(config, a.out, a.action == "generate", root=root)
