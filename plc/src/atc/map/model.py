"""Load the register map sources into dataclasses, remembering where every key is written.

`modbus_map/map.toml` lists the signals (one `[[signal]]` table each) and the link and LinuxCNC settings;
`modbus_map/reason_codes.toml` lists the toolchanger reason codes (one `[[reason]]` table each).  Both are read
with the toolchain's one TOML reader (plc.tomlconf), which keeps the place of every key: a problem is reported at
file:line:col of the key concerned.  Loading checks the shapes by schema (SIGNAL, REASON, SECTIONS: types of
values, unknown keys, missing keys, all at once); `check` does the meaning.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plc import tomlconf
from plc.diagnostics import Diagnostics, Pos
from plc.project import where
from plc.tomlconf import Bool, Field, Int, ListOf, Number, OneOf, Str, Table

from .. import machine, project

TABLES = ("coil", "discrete_input", "input_register", "holding_register")
DIRECTIONS = ("input", "output", "plc_to_host", "host_to_plc")
SEVERITIES = ("none", "hard", "soft")


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
    doc: tomlconf.Document      # map.toml as read: its values and the place of every key
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
    reason_doc: tomlconf.Document | None = None
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
        return self.doc.pos(("signal", sig.index) + ((key,) if key else ()))

    def reason_pos(self, reason: Reason, key: str | None = None) -> Pos:
        assert self.reason_doc is not None
        return self.reason_doc.pos(("reason", reason.index) + ((key,) if key else ()))

    def reasons_file_pos(self) -> Pos:
        return Pos(self.reason_doc.file if self.reason_doc else "reason_codes.toml", 1, 1)

    def section_pos(self, section: str, key: str | None = None) -> Pos:
        return self.doc.pos((section,) + ((key,) if key else ()))


# -------------------------------------------------------------------- loading --
SIGNAL = Table((
    Field("name", Str(), "the ST variable, HMI tag and mb2hal pin name", required=True),
    Field("table", Str(), " | ".join(TABLES), required=True),
    Field("address", Int(), "Modbus address, 0-based", required=True),
    Field("type", Str(), "BOOL, INT, UINT, WORD, DINT, UDINT, DWORD or REAL", required=True),
    Field("direction", Str(), " | ".join(DIRECTIONS), required=True),
    Field("description", Str(), "one line: meaning, unit, safe value", required=True),
    Field("host_writable", Bool(), default=False),
    Field("retained", Bool(), default=False),
    Field("unit", Str(), default=""),
    Field("scale", Number()),
    Field("enum", Str(), default=""),
    Field("states", ListOf(Str(), "names"), "state names of an INT code, value = position", default=[]),
    Field("hal", Str(), "an iov2 pin or a bare HAL signal name", default=""),
))
REASON = Table((
    Field("code", Int(), required=True), Field("name", Str(), required=True),
    Field("severity", Str(), " | ".join(SEVERITIES), required=True), Field("text", Str(), required=True),
    Field("source", Str(), default=""), Field("rotary_error", Str(), default=""), Field("error_id", Int()),
    Field("st_constant", Str(), default=""), Field("st_case", Str(), default=""), Field("cause", Str(), default=""),
    Field("remedy", Str(), default=""),
))
# [map], [link], [linuxcnc]: each key sets the field of its name of RegisterMap, Link or LinuxCnc
SECTIONS = {
    "map": Table(tuple(Field(k, Str()) for k in ("program", "program_file", "configuration", "resource",
                                                 "reason_codes", "machine", "application", "instance"))),
    "link": Table((Field("plc_alive", Str()), Field("plc_alive_toggle_ms", Int()), Field("plc_timeout_ms", Int()),
                   Field("host_heartbeat", Str()), Field("host_heartbeat_period_ms", Int()),
                   Field("host_timeout_ms", Int()))),
    "linuxcnc": Table((Field("host", Str()), Field("port", Int()), Field("slave_id", Int()), Field("component", Str()),
                       Field("update_rate_hz", Number()), Field("response_timeout_ms", Int()),
                       Field("settle_s", Number()), Field("settle", ListOf(Str(), "signal names")),
                       Field("settle_fall", ListOf(Str(), "signal names")), Field("thread", Str()),
                       Field("estop_chain", Str()))),
    "signal": None, "wiring": None,
}
REASONS_HEAD = Table((Field("st_type", OneOf(("INT", "DINT")), "the ST type of the reason constants"),
                      Field("constant_prefix", Str(), "the ST constants' prefix")))
REASON_SECTIONS = {"reasons": REASONS_HEAD, "reason": None}


def _read_toml(path: Path, label: str, diags: Diagnostics) -> tomlconf.Document | None:
    """The document, None when it cannot be read or is not TOML (said in diags)."""
    try:
        return tomlconf.read(path, label)
    except tomlconf.TomlError as exc:
        diags.items.append(exc.diagnostic)
        return None


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
    doc = _read_toml(path, display(path, root), diags)
    if doc is None:
        return None
    rmap = RegisterMap(path=path, root=root, doc=doc)
    checked = tomlconf.check_sections(doc, SECTIONS)
    for section, target in (("map", rmap), ("link", rmap.link), ("linuxcnc", rmap.linuxcnc)):
        for key, value in checked[section].values.items() if section in checked else ():
            if key != "reason_codes":
                number = isinstance(SECTIONS[section].field(key).kind, Number)
                setattr(target, key, float(value) if number else value)
    _load_wiring(doc.data.get("wiring", {}), rmap, doc)
    signals = doc.data.get("signal", [])
    if isinstance(signals, dict):
        doc.error(("signal",), "signal must be an array of tables: [[signal]]")
    if not isinstance(signals, list):
        signals = []                            # a value: check_sections said so
    for i, table in enumerate(signals):
        sig = _load_signal(i, table, doc)
        if sig is not None:
            rmap.signals.append(sig)
    diags.items.extend(doc.diagnostics)
    if described is None:
        described = path.parent / rmap.machine if rmap.machine else rmap.root / project.description(rmap.root)
    if rmap.machine or described.is_file():
        _load_machine_lines(rmap, described, diags)
    reasons_file = checked["map"].get("reason_codes", "reason_codes.toml") if "map" in checked else \
        "reason_codes.toml"
    _load_reasons(rmap, path.parent / reasons_file, diags)
    return rmap


def _load_wiring(table: Any, rmap: RegisterMap, doc: tomlconf.Document) -> None:
    """[wiring.inputs] pin = "ST expression"; [wiring.series.Base] output = "ArrayPin", restore = "array"."""
    if not isinstance(table, dict):
        return                                  # check_sections said so
    for key, value in table.items():
        if key == "inputs" and isinstance(value, dict) and all(isinstance(v, str) for v in value.values()):
            rmap.wiring_inputs = dict(value)
        elif key == "series" and isinstance(value, dict) and all(
                isinstance(v, dict) and isinstance(v.get("output"), str) for v in value.values()):
            rmap.wiring_series = {b: (v["output"], v.get("restore", "")) for b, v in value.items()}
        else:
            doc.error(("wiring", key), f"[wiring] {key}: not understood",
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
        line = ck.line("channels", section_key)
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


def _load_signal(index: int, table: Any, doc: tomlconf.Document) -> Signal | None:
    checked = SIGNAL.check(doc, ("signal", index), table, "signal:")
    if not checked.ok:
        return None
    return Signal(index=index, name=checked["name"], table=checked["table"], address=checked["address"],
                  type=checked["type"].upper(), direction=checked["direction"], description=checked["description"],
                  host_writable=checked["host_writable"], retained=checked["retained"], unit=checked["unit"],
                  scale=checked.get("scale"), enum=checked["enum"], states=list(checked["states"]),
                  hal=checked["hal"])


def _load_reasons(rmap: RegisterMap, path: Path, diags: Diagnostics) -> None:
    rmap.reasons_path = path
    doc = _read_toml(path, display(path, rmap.root), diags)
    if doc is None:
        rmap.reason_doc = tomlconf.Document(display(path, rmap.root), "", {}, {})
        return
    rmap.reason_doc = doc
    checked = tomlconf.check_sections(doc, REASON_SECTIONS)
    head = checked.get("reasons")
    if head is not None:
        rmap.reason_type = head.get("st_type", rmap.reason_type)
        rmap.reason_prefix = head.get("constant_prefix", rmap.reason_prefix)
    reasons = doc.data.get("reason", [])
    for i, table in enumerate(reasons if isinstance(reasons, list) else []):
        entry = REASON.check(doc, ("reason", i), table, "reason:")
        if entry.ok:
            rmap.reasons.append(Reason(index=i, code=entry["code"], name=entry["name"], severity=entry["severity"],
                                       text=entry["text"], source=entry["source"],
                                       rotary_error=entry["rotary_error"], error_id=entry.get("error_id"),
                                       st_constant=entry["st_constant"], st_case=entry["st_case"],
                                       cause=entry["cause"], remedy=entry["remedy"]))
    diags.items.extend(doc.diagnostics)


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
