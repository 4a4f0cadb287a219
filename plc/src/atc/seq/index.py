"""Load a machine's sequence set from its TOML index (configs/sequences/sequences.toml).

The index names the machine's tools and axes, the I/O channels sequences may touch, the sequence files of each
kind and the P/Q values. Its format is described in docs/sequences.md; a short example:

    [machine]
    tools = 6
    axes = "XYZ"
    always_use_tool1 = true

    [io]
    inputs = ["16-21"]
    outputs = ["17-19"]

    [sequences]
    home = "home.seq"
    put = "put.seq"          # a string is tool 1's file; a table [sequences.put] maps tool numbers to files
    get = "get.seq"

    [values]
    P1 = -5.0
    T2Q1 = 60

    [[procedures]]           # user procedures, run by the PLC in this order (docs/procedures.md)
    id = 0
    name = "lube"
    mode = 0                 # 0 every interval ms, 1 program start, 2 program ended OK, 3 error or stop
    interval = 240000
    file = "lube.seq"

The index is read with the toolchain's one TOML reader (plc.tomlconf): every problem is reported at once, at the
line and column of its key, the fixed tables checked by their schema (unknown keys with a did-you-mean).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from decimal import Decimal
from pathlib import Path

from plc import tomlconf
from plc.diagnostics import SEQ
from plc.tomlconf import Bool, Check, Field, Int, Invalid, Str, Table

from .diagnostics import Diagnostics, format_ranges
from .encoding import (
    AXES,
    DINT_MAX,
    IO_CHANNELS,
    MAX_MESSAGE,
    MAX_PROCEDURES,
    MAX_TOOLS,
    P_COUNT,
    Q_COUNT,
    SCALE,
    Kind,
)

def _axes(value: object) -> str:
    """Distinct letters of AXES (either case), in AXES order."""
    if not isinstance(value, str) or not value or any(a not in AXES for a in value.upper()) \
            or len(set(value.upper())) != len(value):
        raise Invalid(f"expected distinct letters of {AXES}, got {value!r}")
    return "".join(a for a in AXES if a in value.upper())


_LISTED = Check(lambda v: v)     # checked item by item by the reader (channel lists, sequence entries)
_CHANNELS_HINT = 'e.g. {key} = ["16-23"]; channel n is %{prefix}(n/8).(n mod 8)'

MACHINE = Table((
    Field("name", Str(), "the machine's name", default=""),
    Field("tools", Int(1, MAX_TOOLS), f"the number of tools, 1..{MAX_TOOLS}", required=True),
    Field("axes", Check(_axes), "the axes sequences may move", default="XYZ"),
    Field("always_use_tool1", Bool(), "every tool runs tool 1's Put and Get sequences", default=False),
))
IO = Table((
    Field("inputs", _LISTED, "the inputs sequences may use", required=True,
          hint=_CHANNELS_HINT.format(key="inputs", prefix="IX")),
    Field("outputs", _LISTED, "the outputs sequences may use", required=True,
          hint=_CHANNELS_HINT.format(key="outputs", prefix="QX")),
    Field("procedure_inputs", _LISTED, "the inputs user procedures may read",
          hint=_CHANNELS_HINT.format(key="procedure_inputs", prefix="IX")),
    Field("procedure_outputs", _LISTED, "the outputs user procedures own (never the tool change's)",
          hint=_CHANNELS_HINT.format(key="procedure_outputs", prefix="QX")),
))
SEQUENCES = Table(tuple(Field(kind.key, _LISTED, f"the {kind.title} sequence") for kind in Kind if kind.changer))
SECTIONS = {"machine": MACHINE, "io": IO, "sequences": SEQUENCES, "values": None, "procedures": None}
MAX_INTERVAL_MS = 86_400_000  # a day: FB_ProcedureScheduler's clock restarts daily


def _text(value: object) -> str:
    """An ErrMsg: 0..MAX_MESSAGE printable ASCII characters (F_SequenceMessage's texts)."""
    if not isinstance(value, str):
        raise Invalid(f"expected a text, got {value!r}")
    if any(not " " <= ch <= "~" for ch in value) or "/" in value:
        raise Invalid("may hold printable ASCII only, without '/'")
    if len(value) > MAX_MESSAGE:
        raise Invalid(f"is {len(value)} characters long; at most {MAX_MESSAGE} fit")
    return value


PROCEDURE = Table((
    Field("id", Int(0, 32767), "the procedure's ID (the Logosol manual's Proc_ID), unique in the set", required=True),
    Field("name", Str(), "the procedure's name", required=True),
    Field("enabled", Bool(), "FALSE: checked and compiled, never run", default=True),
    Field("mode", Int(0, 3), "0 every interval ms, 1 at program start, 2 after a successful end, 3 on error or stop",
          required=True),
    Field("interval", Int(0, MAX_INTERVAL_MS), "mode 0: ms from one start to the next", default=0),
    Field("stop_on_error", Bool(), "TRUE: a failed step ends the procedure; FALSE: it goes on", default=True),
    Field("can_stop_gcode", Bool(), "TRUE: a failure stops the G-code program (fault -150)", default=False),
    Field("err_msg", Check(_text), "the operator message of a failure", default=""),
    Field("file", Str(), "the procedure's body, a sequence file", required=True),
))

_PKEY = re.compile(r"P(\d+)")
_QKEY = re.compile(r"T(\d+)Q(\d+)")
_RANGE = re.compile(r"\s*(\d+)\s*-\s*(\d+)\s*")


@dataclass(frozen=True)
class IoMap:
    """Channels a sequence may read (WAITIN, MOVETOEDGE INP) and write (OUT).

    None means the index failed to declare them: that error is reported once, at the index, and channel checks
    against the missing list are skipped rather than repeated at every OUT or WAITIN.
    """

    inputs: frozenset[int] | None
    outputs: frozenset[int] | None
    input_key: str = "inputs"    # the [io] keys that declared them (hints)
    output_key: str = "outputs"


@dataclass(frozen=True)
class Values:
    """P values by index, Q values by (tool, index); exact decimals as written."""

    p: dict[int, Decimal] = field(default_factory=dict)
    q: dict[tuple[int, int], Decimal] = field(default_factory=dict)


@dataclass(frozen=True)
class SequenceRef:
    """One `kind [tool] = file` entry of the index and where it was written."""

    kind: Kind
    tool: int  # 0 for Home and Length Measurement
    file: str  # as written in the index
    path: Path
    line: int
    col: int


@dataclass(frozen=True)
class ProcedureDef:
    """One [[procedures]] entry: the manual's fields, its body file and where it was written. slot = file order, 1.."""

    slot: int
    id: int
    name: str
    enabled: bool
    mode: int
    interval_ms: int
    stop_on_error: bool
    can_stop_gcode: bool
    err_msg: str
    file: str
    path: Path
    line: int
    col: int


@dataclass
class SequenceSet:
    index_path: Path
    index_name: str  # the index as shown in diagnostics
    name: str
    tools: int  # 0 when the index failed to give a valid number
    axes: str | None  # None when the index failed to give valid axes
    always_use_tool1: bool
    io: IoMap
    values: Values
    refs: list[SequenceRef]
    procedures: list[ProcedureDef] = field(default_factory=list)
    procedure_io: IoMap = IoMap(frozenset(), frozenset(), "procedure_inputs", "procedure_outputs")

    def ref_for(self, kind: Kind, tool: int = 0) -> SequenceRef | None:
        """The entry that runs for this kind and tool, honouring always_use_tool1."""
        if kind.per_tool and self.always_use_tool1:
            tool = 1
        for ref in self.refs:
            if ref.kind is kind and ref.tool == tool:
                return ref
        return None

    def tools_of(self, ref: SequenceRef) -> tuple[int, ...]:
        """The tools a Put/Get entry runs for; () for Home and Length Measurement."""
        if not ref.kind.per_tool:
            return ()
        return tuple(t for t in range(1, self.tools + 1) if self.ref_for(ref.kind, t) == ref)


class _IndexReader:
    """Validates the parsed TOML table by table, reporting at the key of each problem."""

    def __init__(self, path: Path, doc: tomlconf.Document, diags: Diagnostics):
        self.path = path
        self.doc = doc
        self.diags = diags

    def error(self, key: tuple[str, ...], message: str, hint: str = "") -> None:
        self.doc.error(key, message, hint)

    def warning(self, key: tuple[str, ...], message: str, hint: str = "") -> None:
        self.doc.warning(key, message, hint)

    def machine(self, checked: tomlconf.Checked | None) -> tuple[str, int, str | None, bool]:
        if checked is None:
            return "", 0, None, False
        # a wrong axes value leaves them unknown: the axis checks are skipped rather than repeated at every MOVEABS
        axes = None if "axes" in checked.bad else checked["axes"]
        return checked["name"], checked.get("tools", 0), axes, checked["always_use_tool1"]

    def io(self, table: dict | None) -> tuple[IoMap, IoMap]:
        """The tool change's channels and the procedures' (absent procedure lists: none)."""
        if table is None:
            return IoMap(None, None), IoMap(None, None, "procedure_inputs", "procedure_outputs")
        channels: dict[str, frozenset[int] | None] = {}
        for key in ("inputs", "outputs", "procedure_inputs", "procedure_outputs"):
            channels[key] = frozenset(self.channel_list(table[key], ("io", key))) if key in table else None
        shared = (channels["outputs"] or frozenset()) & (channels["procedure_outputs"] or frozenset())
        if shared:
            self.error(("io", "procedure_outputs"), f"[io] procedure_outputs: {format_ranges(sorted(shared))} "
                       "also in [io] outputs: an output belongs to the tool change or to the procedures",
                       hint="a procedure never drives what a tool-change sequence drives (docs/procedures.md)")
        return (IoMap(channels["inputs"], channels["outputs"]),
                IoMap(channels["procedure_inputs"] or frozenset(), channels["procedure_outputs"] or frozenset(),
                      "procedure_inputs", "procedure_outputs"))

    def channel_list(self, items: object, key: tuple[str, ...]) -> set[int]:
        channels: set[int] = set()
        if not isinstance(items, list):
            self.error(key, f"[io] {key[-1]} must be a list of channels and ranges, e.g. [16, \"18-21\"]")
            return channels
        for item in items:
            if isinstance(item, int) and not isinstance(item, bool):
                low = high = item
            elif isinstance(item, str) and _RANGE.fullmatch(item):
                match = _RANGE.fullmatch(item)
                low, high = int(match[1]), int(match[2])
            else:
                self.error(key, f"[io] {key[-1]}: {item!r} is neither a channel number nor a range \"a-b\"")
                continue
            if not 0 <= low <= high < IO_CHANNELS:
                self.error(key, f"[io] {key[-1]}: {item!r} is outside channels 0..{IO_CHANNELS - 1}",
                           hint="the sequence runner reaches %IX0.0..%IX7.7 and %QX0.0..%QX7.7")
                continue
            channels.update(range(low, high + 1))
        return channels

    def sequences(self, table: dict, tools: int, always: bool) -> list[SequenceRef]:
        refs: list[SequenceRef] = []
        for kind in (k for k in Kind if k.changer):
            entry = table.get(kind.key)
            if entry is None:
                continue
            if isinstance(entry, str):
                entries = {"1" if kind.per_tool else "": entry}
            elif isinstance(entry, dict) and kind.per_tool:
                entries = entry
            else:
                shape = "a file name or a table of tool = file" if kind.per_tool else "a file name"
                self.error(("sequences", kind.key), f"[sequences] {kind.key} must be {shape}")
                continue
            for tool_key, file in sorted(entries.items(), key=lambda kv: _tool_sort_key(kv[0])):
                ref = self.sequence_ref(kind, tool_key, file, tools, always, in_table=isinstance(entry, dict))
                if ref is not None:
                    refs.append(ref)
        return refs

    def sequence_ref(self, kind: Kind, tool_key: str, file: object, tools: int, always: bool,
                     in_table: bool) -> SequenceRef | None:
        key = ("sequences", kind.key) + ((tool_key,) if in_table else ())
        if not isinstance(file, str) or not file:
            self.error(key, f"the {kind.title} sequence must be a file name")
            return None
        tool = 0
        if kind.per_tool:
            if not tool_key.isdigit() or not 1 <= int(tool_key) <= MAX_TOOLS:
                self.error(key, f"'{tool_key}' is not a tool number 1..{MAX_TOOLS}")
                return None
            tool = int(tool_key)
            if tools and tool > tools:
                self.error(key, f"tool {tool} has a {kind.title} sequence but the machine has tools 1..{tools}",
                           hint="raise [machine] tools or remove the entry")
                return None
            if always and tool != 1:
                self.warning(key, f"always_use_tool1 = true: the {kind.title} sequence of tool {tool} is never used")
        path = self.path.parent / file
        place = self.doc.places.get(key)
        line, col = (place.key.line, place.key.col) if place else (0, 0)
        return SequenceRef(kind, tool, file, path, line, col)

    def procedures(self, items: object) -> list[ProcedureDef]:
        """[[procedures]] in file order: each checked by its schema, IDs unique, mode 0 with an interval."""
        if not isinstance(items, list):
            if items is not None:
                self.error(("procedures",), "procedures must be written as [[procedures]] tables, one per procedure")
            return []
        out: list[ProcedureDef] = []
        ids: dict[int, int] = {}
        for n, item in enumerate(items):
            key = ("procedures", n)
            checked = PROCEDURE.check(self.doc, key, item, f"[[procedures]] {n + 1}:")
            if not checked.ok:
                continue
            if n >= MAX_PROCEDURES:
                self.error(key, f"at most {MAX_PROCEDURES} procedures; this is procedure {n + 1}")
                continue
            if checked["id"] in ids:
                self.error(key + ("id",), f"procedure id {checked['id']} is already procedure {ids[checked['id']]}'s",
                           hint="each procedure has its own id")
                continue
            ids[checked["id"]] = n + 1
            if checked["mode"] == 0 and checked["interval"] <= 0:
                self.error(key + ("mode",), "mode 0 runs every interval ms: give interval > 0",
                           hint="e.g. interval = 240000 (4 minutes)")
                continue
            place = self.doc.places.get(key + ("file",))
            line, col = (place.key.line, place.key.col) if place else (0, 0)
            out.append(ProcedureDef(n + 1, checked["id"], checked["name"], checked["enabled"], checked["mode"],
                                    checked["interval"], checked["stop_on_error"], checked["can_stop_gcode"],
                                    checked["err_msg"], checked["file"], self.path.parent / checked["file"],
                                    line, col))
        return out

    def values(self, table: dict, tools: int) -> Values:
        values = Values()
        for key, raw in table.items():
            where = ("values", key)
            number = self.number(raw, where, key)
            p_match, q_match = _PKEY.fullmatch(key), _QKEY.fullmatch(key)
            if p_match:
                index = int(p_match[1])
                if not 1 <= index <= P_COUNT:
                    self.error(where, f"{key} is out of range: P variables are P1..P{P_COUNT}")
                elif number is not None:
                    values.p[index] = number
            elif q_match:
                tool, index = int(q_match[1]), int(q_match[2])
                if not 1 <= index <= Q_COUNT:
                    self.error(where, f"{key} is out of range: Q variables are Q1..Q{Q_COUNT} of each tool")
                elif not 1 <= tool <= (tools or MAX_TOOLS):
                    self.error(where, f"{key} names tool {tool} but the machine has tools 1..{tools or MAX_TOOLS}")
                elif number is not None:
                    values.q[(tool, index)] = number
            else:
                self.error(where, f"'{key}' is not a P or Q variable name",
                           hint=f"write P1..P{P_COUNT} or T1Q1..T{MAX_TOOLS}Q{Q_COUNT}")
        return values

    def number(self, raw: object, where: tuple[str, ...], key: str) -> Decimal | None:
        if isinstance(raw, bool) or not isinstance(raw, (int, float)):
            self.error(where, f"{key} must be a number, got {raw!r}")
            return None
        value = Decimal(repr(raw)) if isinstance(raw, float) else Decimal(raw)
        if not value.is_finite():
            self.error(where, f"{key} must be a finite number")
            return None
        if (value * SCALE) % 1 != 0:
            self.error(where, f"{key} = {raw!r} has more than 3 decimals", hint="values are stored in thousandths")
            return None
        if abs(value * SCALE) > DINT_MAX:
            self.error(where, f"{key} = {raw!r} does not fit in thousandths (|value| <= {DINT_MAX / SCALE:.3f})")
            return None
        return value


def _tool_sort_key(key: str) -> tuple[int, str]:
    return (int(key), "") if key.isdigit() else (MAX_TOOLS + 1, key)


def load_index(path: Path, name: str, diags: Diagnostics) -> SequenceSet | None:
    """Read and validate an index; None when it cannot be read or parsed at all (the reason is in diags)."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        diags.error(name, 0, 0, f"cannot read the index: {getattr(exc, 'strerror', None) or exc}")
        return None
    try:
        doc = tomlconf.parse(text, name, layout=SEQ, show_source=True, unplaced=(0, 0), anchor="key")
    except tomlconf.TomlError as exc:
        diags.add(exc.diagnostic)
        return None
    reader = _IndexReader(path, doc, diags)
    data = doc.data
    checked = tomlconf.check_sections(doc, SECTIONS)
    for table in ("machine", "io", "sequences"):
        if table not in data:
            reader.error((), f"the index needs a [{table}] table")
    io_table = data["io"] if isinstance(data.get("io"), dict) else None
    seq_table = data.get("sequences") if isinstance(data.get("sequences"), dict) else {}
    values_table = data.get("values", {})
    if not isinstance(values_table, dict):
        values_table = {}                   # check_sections: 'values' must be a section [values]
    set_name, tools, axes, always = reader.machine(checked.get("machine"))
    io, procedure_io = reader.io(io_table)
    refs = reader.sequences(seq_table, tools, always)
    values = reader.values(values_table, tools)
    procedures = reader.procedures(data.get("procedures"))
    seqset = SequenceSet(path, name, set_name, tools, axes, always, io, values, refs, procedures, procedure_io)
    _check_coverage(seqset, reader, seq_table)
    for d in doc.diagnostics:
        diags.add(d)
    return seqset


def _check_coverage(seqset: SequenceSet, reader: _IndexReader, seq_table: dict) -> None:
    """Toolchanger Home is mandatory; every tool needs a Put Tool and a Get Tool sequence."""
    if "home" not in seq_table:
        reader.error(("sequences",), "the set has no Toolchanger Home sequence",
                     hint='add home = "home.seq" to [sequences]; it runs after power-up')
    if not seqset.tools:
        return
    for kind in (Kind.PUT, Kind.GET):
        missing = [t for t in range(1, seqset.tools + 1) if seqset.ref_for(kind, t) is None]
        if not missing:
            continue
        hint = (f"add [sequences.{kind.key}] entries for them, or set [machine] always_use_tool1 = true"
                if not seqset.always_use_tool1 else f'add {kind.key} = "{kind.key}.seq" to [sequences]')
        subject = f"tool {missing[0]} has" if len(missing) == 1 else f"tools {format_ranges(missing)} have"
        reader.error(("sequences", kind.key) if kind.key in seq_table else ("sequences",),
                     f"{subject} no {kind.title} sequence", hint=hint)
