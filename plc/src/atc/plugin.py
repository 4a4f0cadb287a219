"""What the tool-changer application adds to the `plc` command, through the toolchain's hook (plc.extensions):
its subcommands, the freshness check before `plc run` and `plc test`, and what `plc run` adds to the runtime:
the application's events (native/events.c) with the register map's description, and the register map's
SimulatedPlant input as the simulation flag."""
from __future__ import annotations

from pathlib import Path

from plc.extensions import Extensions, RunSetup, ViewError, ViewOption

from . import freshness, generation, project, workspace
from .runsetup import runtime_setup


def register(ext: Extensions) -> None:
    ext.command("seq", "check and compile tool-change sequences (plc seq --help)", "atc.seq.cli:main")
    ext.command("map", "check the register map and generate from it (plc map --help)", "atc.map.cli:main")
    ext.command("host", "CNC host client: plc host \"T5 M6\" (plc host --help)", "atc.host.cli:main")
    ext.command("tools", "the PLC's tool table: list, set, reset, clear, load/export .tbl (plc tools --help)",
                "atc.tools:main")
    ext.command("deploy", "bundle for OpenPLC (plc deploy openplc), install and upgrade our soft-PLC as a "
                "systemd service (plc deploy service|upgrade|rollback)", "atc.deploy:main")
    ext.command("hmi", "the live toolchanger page in a browser (plc hmi --help)", "atc.hmi.server:main")
    ext.parsers.append(generation.add_parser)
    ext.preflight.append(freshness.refuse_if_stale)
    ext.run_setup.append(run_setup)
    ext.project_marks.extend(["modbus_map", project.PROJECT_FILE])
    ext.run_config.append(run_config)
    ext.views.append(ViewOption("--machine", "NAME", "the machine (machines/NAME/; default: the one project.toml "
                                "names); another than the default runs in its workspace build/machines/NAME/",
                                machine_view))


def run_config(root: Path) -> tuple[Path | None, Path | None] | None:
    """The machine's own run configuration and state directory (atc.project), for a project with machines."""
    if not (project.source_root(root) / project.MACHINES).is_dir():
        return None
    return project.run_config(root), project.state_dir(root)


def machine_view(root: Path, name: str) -> Path:
    try:
        return workspace.view(root, name)
    except project.MachineError as e:
        raise ViewError(str(e)) from None


def run_setup(root: Path, build_dir: Path) -> RunSetup | None:
    """The runtime of this project: the application's events over the register map, its simulation flag."""
    map_path = root / "modbus_map" / "map.toml"
    if not map_path.is_file():
        return None
    return runtime_setup(map_path, build_dir)
