"""What the tool-changer application adds to the `plc` command, through the toolchain's hook (plc.extensions):
its subcommands, the freshness check before `plc run` and `plc test`, and the events description of the
register map for the runtime's log."""
from __future__ import annotations

import sys
from pathlib import Path

from plc.extensions import Extensions

from . import freshness, generation
from .hmi import mapinfo
from .host.tags import MapError


def register(ext: Extensions) -> None:
    ext.command("seq", "check and compile tool-change sequences (plc seq --help)", "atc.seq.cli:main")
    ext.command("map", "check the register map and generate from it (plc map --help)", "atc.map.cli:main")
    ext.command("host", "CNC host client: plc host \"T5 M6\" (plc host --help)", "atc.host.cli:main")
    ext.command("deploy", "bundle for OpenPLC (plc deploy openplc), install and upgrade our soft-PLC as a "
                "systemd service (plc deploy service|upgrade|rollback)", "atc.deploy:main")
    ext.command("hmi", "the live toolchanger page in a browser (plc hmi --help)", "atc.hmi.server:main")
    ext.parsers.append(generation.add_parser)
    ext.preflight.append(freshness.refuse_if_stale)
    ext.run_events.append(events_file)
    ext.project_marks.extend(["modbus_map", "configs/machine.toml"])


def events_file(root: Path, build_dir: Path) -> Path | None:
    """The runtime's --events description, from the project's register map (None when it cannot be read)."""
    map_path = root / "modbus_map" / "map.toml"
    if not map_path.is_file():
        return None
    try:
        text = mapinfo.events_description(mapinfo.load(map_path))
    except MapError as e:
        print(f"plc run: no application events (the register map has errors):\n{e}", file=sys.stderr)
        return None
    out = build_dir / "events.txt"
    out.parent.mkdir(parents=True, exist_ok=True)
    if not out.exists() or out.read_text() != text:
        out.write_text(text)
    return out
