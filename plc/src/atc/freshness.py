"""Are the generated files of the project up to date with their sources?

`plc run` and `plc test` refuse to run a program built from stale generated files: the machine description
(machines/default/machine.toml -> FB_MachineConfig, tool table, the sequence set's tool count), the register map
(modbus_map/ -> AtcMain's declarations and wiring, HMI tags, LinuxCNC files, docs) and the sequences
(the machine's [sequences] index, default configs/sequences/ -> SequenceTables.st). Each problem names the command
that regenerates the files.
"""
from __future__ import annotations

import sys
from pathlib import Path

from plc.diagnostics import Diagnostics

from . import generation, machine, project
from .map.generate import drift as map_drift
from .map.generate import load_and_check
from .seq.assemble import check_set
from .seq.diagnostics import Diagnostics as SeqDiagnostics
from .seq.stgen import generate, stable_name

SEQ_TABLES = "st_src/sequence/generated/SequenceTables.st"


def problems(root: Path) -> list[str]:
    """One line per stale or broken source, each with the command that fixes it; [] when all is fresh. A machine
    description that does not check is the one problem named: the map reads its lines from it, so the map's
    own complaint would only repeat it."""
    machine_problems = _machine(root)
    if machine_problems and any("fix the machine description" in line for line in machine_problems):
        return machine_problems
    return machine_problems + _map(root) + _sequences(root)


def _machine(root: Path) -> list[str]:
    rel = project.description(root).as_posix()
    config = root / rel
    if not config.is_file():
        return []
    data, ck = machine.load(config, rel)
    if not ck.problems:
        machine.check_sequences(ck, data, root, rel)
    if ck.problems:
        return [d.render() for d in ck.problems] + ["  fix the machine description (plc machine check), then run "
                                                    "`plc machine generate`"]
    files, errors = generation.outputs(root, data, rel)
    if errors:
        return errors
    return [f"{out}: out of date with {rel}: run `plc machine generate`" for out in generation.drift(root, files)]


def _map(root: Path) -> list[str]:
    path = root / "modbus_map" / "map.toml"
    if not path.is_file():
        return []
    diags = Diagnostics()
    loaded = load_and_check(path, diags)
    if loaded is None or diags.has_errors():
        return [d.render() for d in diags.sorted() if d.severity == "error"][:10] + \
            ["  fix the register map (plc map check), then run `plc map generate`"]
    return [f"{rel}: out of date with modbus_map/map.toml: run `plc map generate`"
            for rel in map_drift(loaded, Diagnostics(), show_diff=False)]


def _sequences(root: Path) -> list[str]:
    rel = project.sequence_index(root)
    index, tables = root / rel, root / SEQ_TABLES
    if not index.is_file():
        return []
    fix = f"plc seq compile {rel} --out {SEQ_TABLES}"
    diags = SeqDiagnostics()
    assembly = check_set(index, diags)
    if assembly is None or diags.errors:
        return [d.render() for d in diags.errors][:10] + [f"  fix the sequences (plc seq check {rel}), "
                                                          f"then run `{fix}`"]
    text = generate(assembly, stable_name(index), stable_name(tables))
    if not tables.is_file() or tables.read_text(encoding="utf-8") != text:
        return [f"{SEQ_TABLES}: out of date with the sequences of {rel}: run `{fix}`"]
    return []


def refuse_if_stale(root: Path, command: str) -> bool:
    """Print the problems and return True when `command` (e.g. 'plc run') must not go on."""
    found = problems(root)
    if not found:
        return False
    for line in found:
        print(line, file=sys.stderr)
    print(f"{command}: the generated files are not up to date with their sources: nothing was run", file=sys.stderr)
    return True
