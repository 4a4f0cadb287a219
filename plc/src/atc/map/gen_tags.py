"""hmi_tags/atc_tags.csv and atc_tags.json: the tag list for HMI/SCADA tools.

One row per signal: name, Modbus table and address, IEC address, type, access from the host's side (R or RW),
unit and scale, retained, description, and for enumerated codes the state names (from the ST TYPE
declarations, the map's `states`, or the reason code table).
"""
from __future__ import annotations

import csv
import io
import json

from .enums import EnumType
from .model import RegisterMap, Signal, display, iec_address, reason_order

COLUMNS = ["name", "table", "address", "iec_address", "type", "access", "direction", "unit", "scale",
           "retained", "description", "states"]


def states_of(rmap: RegisterMap, sig: Signal, enums: dict[str, EnumType]) -> list[tuple[int, str]]:
    """(value, name) pairs of an enumerated signal, in value order for ST enums and state lists."""
    if sig.enum == "reason_codes":
        return [(r.code, r.name) for r in sorted(rmap.reasons, key=reason_order)]
    if sig.enum:
        found = enums.get(sig.enum.upper())
        return list(enumerate(found.values)) if found else []
    return list(enumerate(sig.states))


def _scale(sig: Signal) -> str:
    return "" if sig.scale is None else format(sig.scale, "g")


def rows(rmap: RegisterMap, enums: dict[str, EnumType]) -> list[dict]:
    out = []
    for sig in rmap.signals:
        out.append({
            "name": sig.name,
            "table": sig.table,
            "address": sig.address,
            "iec_address": iec_address(sig) or "",
            "type": sig.type,
            "access": "RW" if sig.host_writable else "R",
            "direction": sig.direction,
            "unit": sig.unit,
            "scale": _scale(sig),
            "retained": sig.retained,
            "description": sig.description,
            "states": states_of(rmap, sig, enums),
        })
    return out


def tags_csv(rmap: RegisterMap, enums: dict[str, EnumType]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(COLUMNS)
    for row in rows(rmap, enums):
        cells = dict(row)
        cells["retained"] = "yes" if row["retained"] else ""
        cells["states"] = ";".join(f"{v}={n}" for v, n in row["states"])
        writer.writerow([cells[c] for c in COLUMNS])
    return buf.getvalue()


def tags_json(rmap: RegisterMap, enums: dict[str, EnumType]) -> str:
    tags = []
    for row in rows(rmap, enums):
        tag = {k: row[k] for k in COLUMNS if k != "states"}
        tag["scale"] = None if row["scale"] == "" else float(row["scale"])
        if row["states"]:
            tag["states"] = [{"value": v, "name": n} for v, n in row["states"]]
        tags.append(tag)
    doc = {
        "generated_from": [display(rmap.path, rmap.root),
                           display(rmap.reasons_path, rmap.root) if rmap.reasons_path else ""],
        "modbus": {
            "default_port": rmap.linuxcnc.port,
            "unit_id": rmap.linuxcnc.slave_id,
            "addressing": "0-based; coils FC1/5/15, discrete inputs FC2, input registers FC4, "
                          "holding registers FC3/6/16",
            "word_order": "32-bit values: two holding registers, high word first",
            "signed": "INT registers are two's complement 16-bit",
        },
        "heartbeats": {
            "plc_alive": rmap.link.plc_alive, "plc_alive_toggle_ms": rmap.link.plc_alive_toggle_ms,
            "plc_timeout_ms": rmap.link.plc_timeout_ms, "host_heartbeat": rmap.link.host_heartbeat,
            "host_heartbeat_period_ms": rmap.link.host_heartbeat_period_ms,
            "host_timeout_ms": rmap.link.host_timeout_ms,
        },
        "tags": tags,
        "reason_codes": [{"code": r.code, "name": r.name, "severity": r.severity, "text": r.text}
                         for r in sorted(rmap.reasons, key=reason_order)],
    }
    return json.dumps(doc, indent=2, ensure_ascii=True) + "\n"
