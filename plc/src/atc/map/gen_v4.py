"""OpenPLC v4's Modbus slave for our register map: its conf/modbus_slave.json, and the check that it serves every
signal at the address the map gives it (docs/openplc-v4.md).

The v4 runtime's Modbus slave is a plugin, off unless the uploaded program carries its configuration.  It lays
each Modbus table out from segment counts: holding registers are %QW, then %MW, then %MD (two registers each),
then %ML (four), packed end to end; coils are %QX then %MX; discrete inputs %IX; input registers %IW.  With the
counts of v3's map (below) every address is where v3 and our runtime put it; a smaller count moves every later
segment down, which is why the counts are fixed here and checked against the map.  It answers unit id 1 only.
"""
from __future__ import annotations

import json

from plc.diagnostics import Diagnostics

from .model import RegisterMap, Signal, iec_address

SLAVE_JSON = "configs/openplc-v4/modbus_slave.json"

# v3's layout, as the v4 slave's segment counts (registers or bits per segment)
HOLDING = {"qw_count": 1024, "mw_count": 1024, "md_count": 1024, "ml_count": 1024}
COILS = {"qx_bits": 8192, "mx_bits": 0}
DISCRETE_INPUTS = {"ix_bits": 8192}
INPUT_REGISTERS = {"iw_count": 1024}
PORT = 502
UNIT_ID = 1


def slave_config() -> dict:
    """The settings the map needs: v3's segments, high word first (as v3 and our runtime), every interface."""
    return {
        "network_configuration": {"host": "0.0.0.0", "port": PORT},
        "buffer_mapping": {
            "holding_registers": dict(HOLDING),
            "coils": dict(COILS),
            "discrete_inputs": dict(DISCRETE_INPUTS),
            "input_registers": dict(INPUT_REGISTERS),
        },
        "word_order": "high_word_first",
    }


def modbus_slave_json(_rmap: RegisterMap) -> str:
    return json.dumps(slave_config(), indent=2) + "\n"


def served_as(table: str, address: int, config: dict) -> str | None:
    """The location the v4 slave configured by `config` serves at a Modbus address (%QW5, %MD0 for the first of
    its two registers, %QX1.2), None where it serves nothing or the second word of a %MD/%ML."""
    mapping = config["buffer_mapping"]
    if table == "holding_register":
        counts = mapping["holding_registers"]
        for area, count, width in (("QW", counts["qw_count"], 1), ("MW", counts["mw_count"], 1),
                                   ("MD", counts["md_count"], 2), ("ML", counts["ml_count"], 4)):
            if address < count * width:
                return f"%{area}{address // width}" if address % width == 0 else None
            address -= count * width
        return None
    if table == "input_register":
        return f"%IW{address}" if address < mapping["input_registers"]["iw_count"] else None
    bits = mapping["coils"]["qx_bits"] if table == "coil" else mapping["discrete_inputs"]["ix_bits"]
    area = "QX" if table == "coil" else "IX"
    return f"%{area}{address // 8}.{address % 8}" if address < bits else None


def check(rmap: RegisterMap, diags: Diagnostics, config: dict | None = None) -> None:
    """Every located signal is served by the v4 slave at its map address as the same location; the host's unit id
    is the one the slave answers (a warning: our runtime and v3 answer any)."""
    config = config or slave_config()
    for sig in rmap.signals:
        want = iec_address(sig)
        if want is None or sig.address < 0:
            continue
        got = served_as(sig.table, sig.address, config)
        if got != want:
            diags.error(rmap.pos(sig, "address"), f"{sig.name}: OpenPLC v4's Modbus slave ({SLAVE_JSON}) serves "
                        f"{describe(sig)} as {got or 'nothing'}, the map has {want}")
    if rmap.linuxcnc.slave_id != UNIT_ID:
        diags.warning(rmap.section_pos("linuxcnc", "slave_id"), f"[linuxcnc] slave_id {rmap.linuxcnc.slave_id}: "
                      f"OpenPLC v4's Modbus slave answers unit id {UNIT_ID} only")


def describe(sig: Signal) -> str:
    return f"{sig.table.replace('_', ' ')} {sig.address}"
