"""Load the register map sources into dataclasses, remembering the line of every key.

`modbus_map/map.toml` lists the signals (one `[[signal]]` table each) and the link and LinuxCNC settings;
`modbus_map/reason_codes.toml` lists the toolchanger reason codes (one `[[reason]]` table each).  tomllib
gives no positions, so `KeyLines` scans the text once for table headers and `key =` lines: a problem is then
reported as file:line of the key concerned.  Loading checks only shapes (types of values, unknown keys);
`check` does the meaning.
"""
from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plc.diagnostics import Diagnostics, Pos
from plc.project import where

from .. import machine, project

TABLES = ("coil", "discrete_input", "input_register", "holding_register")
DIRECTIONS = ("input", "output", "plc_to_host", "host_to_plc")
SEVERITIES = ("none", "hard", "soft")


# ------------------------------------------------------------------ positions --
class KeyLines:
    """Line numbers of table headers and keys in a flat TOML file (arrays of tables and plain tables)."""

    _header = re.compile(r"^\s*(\[\[?)\s*([A-Za-z0-9_.-]+)\s*\]\]?")
    _key = re.compile(r"^\s*([A-Za-z0-9_-]+)\s*=")

    def __init__(self, path: str, text: str) -> None:
        self.path = path
        self.tables: dict[tuple[str, int], int] = {}      # (table name, index) -> header line
        self.keys: dict[tuple[str, int, str], int] = {}   # (table name, index, key) -> line
        counts: dict[str, int] = {}
        current = ("", 0)
        for number, line in enumerate(text.splitlines(), start=1):
            m = self._header.match(line)
            if m:
                name = m.group(2)
                if m.group(1) == "[[":
                    index = counts.get(name, 0)
                    counts[name] = index + 1
                else:
                    index = 0
                current = (name, index)
                self.tables[current] = number
                continue
            m = self._key.match(line)
            if m:
                self.keys.setdefault((current[0], current[1], m.group(1)), number)

    def pos(self, table: str, index: int = 0, key: str | None = None) -> Pos:
        line = self.keys.get((table, index, key)) if key else None
        if line is None:
            line = self.tables.get((table, index), 1)
        return Pos(self.path, line, 1)


# --------------------------------------------------------------------- model --
@dataclass
class Signal:
    index: int                  # position in map.toml (0-based), for positions and stable order
    name: str
    table: str
    address: int
    type: str
    direction: str
    description: str
    host_writable: bool = False
    retained: bool = False
    unit: str = ""
    scale: float | None = None
    enum: str = ""              # "reason_codes" or an ST enumeration type of st_src/
    states: list[str] = field(default_factory=list)   # explicit state names of an INT code: value = index
    hal: str = ""               # LinuxCNC side: a HAL pin (has a dot) or a bare HAL signal name
    origin: Pos | None = None   # set for the carousel lines, which come from the machine description

    @property
    def words(self) -> int:
        """Registers (or bits) the signal occupies."""
        return 2 if self.type in TYPES_32 else 1

    @property
    def last(self) -> int:
        return self.address + self.words - 1


TYPES_BIT = ("BOOL",)
TYPES_16 = ("INT", "UINT", "WORD")
TYPES_32 = ("DINT", "UDINT", "DWORD", "REAL")


@dataclass
class Reason:
    index: int
    code: int
    name: str
    severity: str
    text: str
    source: str = ""            # "", "rotary", "sequence", "link", "application"
    rotary_error: str = ""      # E_RotaryError value this code reports
    error_id: int | None = None # F_RotaryErrorId of that value
    st_constant: str = ""       # "POU.NAME": a VAR CONSTANT of st_src/ that must equal code
    st_case: str = ""           # "F_Function:EnumValue": a CASE mapping of st_src/ that must give code
    cause: str = ""             # what usually leads to it (the toolchanger page shows it)
    remedy: str = ""            # what the operator does about it


@dataclass
class Link:
    plc_alive: str = "PlcAlive"
    plc_alive_toggle_ms: int = 100
    plc_timeout_ms: int = 1000
    host_heartbeat: str = "HostHeartbeat"
    host_heartbeat_period_ms: int = 100
    host_timeout_ms: int = 1000


@dataclass
class LinuxCnc:
    host: str = "127.0.0.1"
    port: int = 5020
    slave_id: int = 1
    component: str = "mb2hal"
    update_rate_hz: float = 50.0
    response_timeout_ms: int = 500
    settle_s: float = 0.05
    settle: list[str] = field(default_factory=list)          # bits whose rising edge waits settle_s
    settle_fall: list[str] = field(default_factory=list)     # bits whose falling edge waits settle_s
    thread: str = "servo-thread"
    estop_chain: str = ""        # HAL signal of the machine's E-stop chain ("" = iocontrol.0.user-enable-out)


@dataclass
class RegisterMap:
    path: Path
    root: Path                  # the repository (map.toml lives in <root>/modbus_map/)
    lines: KeyLines
    program: str = "AtcMain"
    program_file: str = "st_src/app/AtcMain.st"
    machine: str = ""           # the machine description the carousel lines come from (relative to map.toml;
                                # default: the project's machine, project.toml)
    application: str = ""       # FB type holding the logic: its same-named pins are wired by the generator
    instance: str = ""          # its instance in the PROGRAM
    configuration: str = "Config0"
    resource: str = "Res0"
    link: Link = field(default_factory=Link)
    linuxcnc: LinuxCnc = field(default_factory=LinuxCnc)
    signals: list[Signal] = field(default_factory=list)
    reasons: list[Reason] = field(default_factory=list)
    reasons_path: Path | None = None
    reason_lines: KeyLines | None = None
    reason_type: str = "DINT"
    reason_prefix: str = "REASON_"
    wiring_inputs: dict[str, str] = field(default_factory=dict)   # [wiring.inputs] pin -> ST expression
    wiring_series: dict[str, tuple[str, str]] = field(default_factory=dict)  # base -> (output array, restore array)

    def signal(self, name: str) -> Signal | None:
        key = name.upper()
        return next((s for s in self.signals if s.name.upper() == key), None)

    def pos(self, sig: Signal, key: str | None = None) -> Pos:
        if sig.origin is not None:
            return sig.origin
        return self.lines.pos("signal", sig.index, key)

    def reason_pos(self, reason: Reason, key: str | None = None) -> Pos:
        assert self.reason_lines is not None
        return self.reason_lines.pos("reason", reason.index, key)

    def reasons_file_pos(self) -> Pos:
        return Pos(self.reason_lines.path if self.reason_lines else "reason_codes.toml", 1, 1)

    def section_pos(self, section: str, key: str | None = None) -> Pos:
        return self.lines.pos(section, 0, key)


# -------------------------------------------------------------------- loading --
_SIGNAL_KEYS = {
    "name": str, "table": str, "address": int, "type": str, "direction": str, "description": str,
    "host_writable": bool, "retained": bool, "unit": str, "scale": (int, float), "enum": str, "states": list,
    "hal": str,
}
_REQUIRED = ("name", "table", "address", "type", "direction", "description")
_REASON_KEYS = {"code": int, "name": str, "severity": str, "text": str, "source": str, "rotary_error": str,
                "error_id": int, "st_constant": str, "st_case": str, "cause": str, "remedy": str}
_SECTIONS = {
    "map": {"program": str, "program_file": str, "configuration": str, "resource": str, "reason_codes": str,
            "machine": str, "application": str, "instance": str},
    "link": {"plc_alive": str, "plc_alive_toggle_ms": int, "plc_timeout_ms": int, "host_heartbeat": str,
             "host_heartbeat_period_ms": int, "host_timeout_ms": int},
    "linuxcnc": {"host": str, "port": int, "slave_id": int, "component": str, "update_rate_hz": (int, float),
                 "response_timeout_ms": int, "settle_s": (int, float), "settle": list, "settle_fall": list, "thread": str,
                 "estop_chain": str},
}


def _type_ok(value: Any, want) -> bool:
    if want is int or want == (int, float):
        if isinstance(value, bool):
            return False
    return isinstance(value, want)


def _type_name(want) -> str:
    names = {str: "a string", int: "an integer", bool: "true or false", list: "a list"}
    return names.get(want, "a number")


def _read_toml(path: Path, diags: Diagnostics) -> tuple[dict | None, str]:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        diags.error(Pos(str(path), 0, 0), "no such file")
        return None, ""
    except (OSError, UnicodeDecodeError) as exc:
        diags.error(Pos(str(path), 0, 0), f"cannot read: {exc}")
        return None, ""
    try:
        return tomllib.loads(text), text
    except tomllib.TOMLDecodeError as exc:
        line = getattr(exc, "lineno", None) or _line_of(str(exc))
        diags.error(Pos(str(path), line, 1), f"invalid TOML: {exc}")
        return None, text


def _line_of(message: str) -> int:
    m = re.search(r"line (\d+)", message)
    return int(m.group(1)) if m else 0


def display(path: Path, root: Path) -> str:
    """A path relative to the repository when it lies inside it (stable in messages and generated files)."""
    try:
        return where(path).relative_to(where(root)).as_posix()
    except ValueError:
        return str(path)


def load(path: Path, diags: Diagnostics, root: Path | None = None,
         described: Path | None = None) -> RegisterMap | None:
    """Read map.toml and the reason code file it names; None when a file cannot be read at all. The carousel
    lines come from the project's machine description, or from `described` when given (another machine file)."""
    path = Path(path)
    root = Path(root) if root is not None else where(path).parent.parent
    data, text = _read_toml(path, diags)
    if data is None:
        return None
    lines = KeyLines(display(path, root), text)
    rmap = RegisterMap(path=path, root=root, lines=lines)
    for section in data:
        if section not in _SECTIONS and section not in ("signal", "wiring"):
            diags.error(lines.pos(section), f"unknown section [{section}]",
                        "known: [map], [link], [linuxcnc], [[signal]]")
    _load_section(data, "map", rmap, lines, diags)
    _load_section(data, "link", rmap.link, lines, diags)
    _load_section(data, "linuxcnc", rmap.linuxcnc, lines, diags)
    _load_wiring(data.get("wiring", {}), rmap, lines, diags)
    signals = data.get("signal", [])
    if not isinstance(signals, list):
        diags.error(lines.pos("signal"), "signal must be an array of tables: [[signal]]")
        signals = []
    for i, table in enumerate(signals):
        sig = _load_signal(i, table, lines, diags)
        if sig is not None:
            rmap.signals.append(sig)
    if described is None:
        described = path.parent / rmap.machine if rmap.machine else rmap.root / project.description(rmap.root)
    if rmap.machine or described.is_file():
        _load_machine_lines(rmap, described, diags)
    reasons_file = data.get("map", {}).get("reason_codes", "reason_codes.toml")
    _load_reasons(rmap, path.parent / reasons_file, diags)
    return rmap


def _load_wiring(table: dict, rmap: RegisterMap, lines: KeyLines, diags: Diagnostics) -> None:
    """[wiring.inputs] pin = "ST expression"; [wiring.series.Base] output = "ArrayPin", restore = "array"."""
    for key, value in table.items():
        if key == "inputs" and isinstance(value, dict) and all(isinstance(v, str) for v in value.values()):
            rmap.wiring_inputs = dict(value)
        elif key == "series" and isinstance(value, dict) and all(
                isinstance(v, dict) and isinstance(v.get("output"), str) for v in value.values()):
            rmap.wiring_series = {b: (v["output"], v.get("restore", "")) for b, v in value.items()}
        else:
            diags.error(lines.pos("wiring"), f"[wiring] {key}: not understood",
                        "known: [wiring.inputs] pin = \"ST expression\", "
                        "[wiring.series.Base] output = \"ArrayPin\", restore = \"array\"")


def _load_machine_lines(rmap: RegisterMap, path: Path, diags: Diagnostics) -> None:
    """The carousel lines (home, pocket, code 1..6, Output ON, +DIR, -DIR) as signals, from the machine
    description: their channels live there only, and a problem is reported at its line."""
    name = display(path, rmap.root)
    data, ck = machine.load(path, name)
    if ck.problems or data is None:
        for d in ck.problems:
            diags.error(Pos(name, d.pos.line, 1), d.message, "run: plc machine check")
        return
    first = len(rmap.signals) + 1000
    for i, (key, channel) in enumerate(machine.line_channels(data).items()):
        sig_name, table, description = machine.LINES[key]
        section_key = "code" if key.startswith("code") else key
        line = ck.line_of("channels", section_key)
        sig = Signal(index=first + i, name=sig_name, table=table, address=channel, type="BOOL",
                     direction="input" if table == "discrete_input" else "output",
                     description=description, origin=Pos(name, line, 1))
        # listed among the map's own physical lines in address order (generated files, docs, tags)
        at = next((k for k, s in enumerate(rmap.signals) if s.table == table and s.direction == sig.direction
                   and s.address > channel), None)
        if at is None:
            at = max((k + 1 for k, s in enumerate(rmap.signals) if s.direction == sig.direction),
                     default=len(rmap.signals))
        rmap.signals.insert(at, sig)


def _load_section(data: dict, section: str, target: Any, lines: KeyLines, diags: Diagnostics) -> None:
    table = data.get(section, {})
    if not isinstance(table, dict):
        diags.error(lines.pos(section), f"'{section}' must be a table [{section}]")
        return
    for key, value in table.items():
        want = _SECTIONS[section].get(key)
        if want is None:
            diags.error(lines.pos(section, 0, key), f"[{section}] unknown key '{key}'",
                        "known: " + ", ".join(sorted(_SECTIONS[section])))
        elif not _type_ok(value, want):
            diags.error(lines.pos(section, 0, key), f"[{section}] {key} must be {_type_name(want)}")
        elif key != "reason_codes":
            setattr(target, key, float(value) if want == (int, float) else value)


def _check_entry(kind: str, index: int, table: dict, known: dict, required, lines: KeyLines,
                 diags: Diagnostics) -> bool:
    """The keys of one [[kind]] table: none unknown, each of its type, the required ones there."""
    ok = True
    for key, value in table.items():
        want = known.get(key)
        if want is None:
            diags.error(lines.pos(kind, index, key), f"{kind}: unknown key '{key}'",
                        "known: " + ", ".join(sorted(known)))
            ok = False
        elif not _type_ok(value, want):
            diags.error(lines.pos(kind, index, key), f"{kind}: {key} must be {_type_name(want)}")
            ok = False
    for key in required:
        if key not in table:
            diags.error(lines.pos(kind, index), f"{kind}: missing key '{key}'")
            ok = False
    return ok


def _load_signal(index: int, table: dict, lines: KeyLines, diags: Diagnostics) -> Signal | None:
    ok = _check_entry("signal", index, table, _SIGNAL_KEYS, _REQUIRED, lines, diags)
    states = table.get("states", [])
    if isinstance(states, list) and not all(isinstance(s, str) for s in states):
        diags.error(lines.pos("signal", index, "states"), "signal: states must be a list of names")
        ok = False
    if not ok:
        return None
    return Signal(index=index, name=table["name"], table=table["table"], address=table["address"],
                  type=table["type"].upper(), direction=table["direction"], description=table["description"],
                  host_writable=table.get("host_writable", False), retained=table.get("retained", False),
                  unit=table.get("unit", ""), scale=table.get("scale"), enum=table.get("enum", ""),
                  states=list(states), hal=table.get("hal", ""))


def _load_reasons(rmap: RegisterMap, path: Path, diags: Diagnostics) -> None:
    data, text = _read_toml(path, diags)
    rmap.reasons_path = path
    rmap.reason_lines = KeyLines(display(path, rmap.root), text)
    if data is None:
        return
    lines = rmap.reason_lines
    for section in data:
        if section not in ("reasons", "reason"):
            diags.error(lines.pos(section), f"unknown section [{section}]", "known: [reasons], [[reason]]")
    head = data.get("reasons", {})
    for key, value in head.items() if isinstance(head, dict) else []:
        if key == "st_type" and value in ("INT", "DINT"):
            rmap.reason_type = value
        elif key == "constant_prefix" and isinstance(value, str):
            rmap.reason_prefix = value
        else:
            diags.error(lines.pos("reasons", 0, key), f"[reasons] {key} = {value!r} is not understood",
                        "known: st_type = \"INT\" | \"DINT\", constant_prefix = \"...\"")
    for i, table in enumerate(data.get("reason", [])):
        if _check_entry("reason", i, table, _REASON_KEYS, ("code", "name", "severity", "text"), lines, diags):
            rmap.reasons.append(Reason(index=i, code=table["code"], name=table["name"],
                                       severity=table["severity"], text=table["text"],
                                       source=table.get("source", ""), rotary_error=table.get("rotary_error", ""),
                                       error_id=table.get("error_id"), st_constant=table.get("st_constant", ""),
                                       st_case=table.get("st_case", ""), cause=table.get("cause", ""),
                                       remedy=table.get("remedy", "")))


def reason_order(reason: Reason) -> tuple[int, int]:
    """Listing order of reason codes: 0, then hard faults -1, -2, ..., then soft faults 1, 2, ..."""
    return (0 if reason.code == 0 else 1 if reason.code < 0 else 2, abs(reason.code))


# ------------------------------------------------------------ IEC addresses --
def iec_address(sig: Signal) -> str | None:
    """The OpenPLC location of a signal (%QX10.0, %IW3, %QW512, %MW5, %MD0), None if it has none."""
    a = sig.address
    if a < 0:
        return None
    if sig.table == "coil":
        return f"%QX{a // 8}.{a % 8}" if a < 800 else None
    if sig.table == "discrete_input":
        return f"%IX{a // 8}.{a % 8}" if a < 800 else None
    if sig.table == "input_register":
        return f"%IW{a}" if a < 1024 else None
    if sig.table == "holding_register":
        if a < 1024:
            return f"%QW{a}"
        if a < 2048:
            return f"%MW{a - 1024}"
        if a < 4096 and (a - 2048) % 2 == 0:
            return f"%MD{(a - 2048) // 2}"
    return None


def area(sig: Signal) -> str:
    """OpenPLC area of a signal's address: QX IX IW QW MW MD, or '' outside the map."""
    loc = iec_address(sig)
    return loc[1:3] if loc else ""
