"""What the tool-changer application adds to its runtime, for `plc run` (atc.plugin) and for a service release
(atc.service): the application's events (native/events.c, linked in place of the runtime's events_none.c) with
the register map's description, the map's SimulatedPlant input as the simulation flag of `--io sim`, what the map
implies for the run (host-writable ranges, retained registers)."""
from __future__ import annotations

import sys
from pathlib import Path

from plc.extensions import RunSetup

from . import machine, project
from .hmi import mapinfo
from .host.tags import MapError
from .map import run_ranges

EVENTS_C = Path(__file__).resolve().parent / "native" / "events.c"
SIM_FLAG_SIGNAL = "SimulatedPlant"


def runtime_setup(map_path: Path, build_dir: Path) -> RunSetup:
    """The events description written under build_dir from the map at map_path, the events' C source and the
    map's SimulatedPlant input; a map with errors gives the runtime no events and no flag (said on stderr)."""
    try:
        info = mapinfo.load(map_path)
    except MapError as e:
        print(f"plc run: no application events and no simulation flag (the register map has errors):\n{e}",
              file=sys.stderr)
        return RunSetup()
    text = mapinfo.events_description(info)
    out = build_dir / "events.txt"
    out.parent.mkdir(parents=True, exist_ok=True)
    if not out.exists() or out.read_text() != text:
        out.write_text(text)
    root = map_path.parents[1]
    levels = stop_levels(root / project.description(root))
    flag = info.rmap.signal(SIM_FLAG_SIGNAL)
    sim_flag = f"%IX{flag.address // 8}.{flag.address % 8}" if flag is not None and flag.table == "discrete_input" \
        else None
    rmap = info.rmap
    return RunSetup(events_file=out, observer=EVENTS_C, sim_flag=sim_flag, stop_levels=levels,
                    writable_coils=run_ranges.writable_coils(rmap),
                    writable_registers=run_ranges.writable_registers(rmap),
                    retain_registers=run_ranges.retained_registers(rmap))


STOP_LINES = {"on": "invert_on", "plus_dir": "invert_plus_dir", "minus_dir": "invert_minus_dir"}


def stop_levels(machine_path: Path) -> dict[int, tuple[bool, str]]:
    """The carousel's output lines at their Stop-row level on the wire (the line's invert flag: an inverted line
    stops with TRUE), by coil; {} without a carousel or a readable description (its own check reports that)."""
    if not machine_path.is_file():
        return {}
    data, ck = machine.load(machine_path)
    if data is None or ck.problems or "carousel" not in data:
        return {}
    car = data["carousel"]
    out = {}
    for key, channel in machine.line_channels(data).items():
        if key in STOP_LINES:
            invert = bool(car.get(STOP_LINES[key], False))
            name = machine.LINES[key][0]
            why = f"{name} is {'inverted' if invert else 'not inverted'} ({STOP_LINES[key]} = " \
                  f"{'true' if invert else 'false'} in {machine_path.name})"
            out[channel] = (invert, why)
    return out
