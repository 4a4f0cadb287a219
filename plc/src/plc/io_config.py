"""Remote I/O devices of `plc run --io modbus`: the `[[io.device]]` tables of the run configuration.

Each device is a Modbus TCP or Modbus RTU slave (an I/O coupler, an RS-485 board) that the runtime polls from
its own thread (plc/src/plc/native/runtime/io_modbus.c).  Its ranges map the device's tables onto the program's
image::

    [io]
    layer = "modbus"

    [[io.device]]
    name = "carousel"                 # for log lines (letters, digits, - and _)
    tcp = "192.168.1.20"              # IPv4 address; or rtu = "/dev/ttyUSB0" (several units may share a line)
    port = 502                        # tcp only
    # baud = 19200, parity = "none" | "even" | "odd", data_bits = 8, stop_bits = 1   (rtu only)
    unit = 1                          # Modbus unit (slave) id
    poll_ms = 5                       # poll period
    timeout_ms = 20                   # response timeout of one transaction
    max_age_ms = 15                   # inputs older than this: the device is lost (default 2 polls + timeout)
    backoff_ms = [100, 2000]          # reconnect back-off: first wait, doubling up to the second
    status_input = "%IX5.0"           # TRUE while the device is lost (or not yet heard from)
    discrete_inputs = [{ address = 0, count = 32, to = "%IX0.0" }]           # FC2
    coils = [{ address = 0, count = 8, from = "%QX2.0", safe = false }]       # FC15; safe: one value or a list
    input_registers = [{ address = 0, count = 2, to = "%IW0" }]              # FC4
    holding_registers_read = [{ address = 0, count = 2, to = "%IW2" }]       # FC3
    holding_registers_write = [{ address = 8, count = 2, from = "%QW0", safe = 0 }]   # FC16

Every problem is reported with `file:line:col` before anything starts, all of them in one run: unknown keys,
ranges that overlap (in the image, or on one device's table), a range outside the image, a missing serial device,
a baud rate the serial driver cannot set, an age limit a serial line shared by several units cannot meet
(`_check_lines`).  `device_specs()` turns the checked devices into the runtime's `--io-device` arguments.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from typing import Any

from .tomlconf import Check, Document, Field, Int, Invalid, OneOf, Table, ipv4

# The machine's I/O module, as laid out for both runtimes: its discrete inputs 0..31 are the map's discrete
# inputs 0..31 (%IX0.0..%IX3.7 on our runtime), its coils 0..7 the map's coils 16..23 (%QX2.0..%QX2.7).  OpenPLC's
# slave devices put the same module at %IX100.0.. and %QX100.0.. (`plc deploy openplc --slave-devices`).
MAX_RANGES = 32                    # ranges per device (io_modbus.c MAX_RANGES)
MODULE_INPUTS = (0, 32)            # first map discrete input, count
MODULE_OUTPUTS = (16, 8)           # first map coil, count
OPENPLC_SLAVE_FIRST_BYTE = 100     # OpenPLC v3: slave devices from %IX100.0 / %QX100.0 / %IW100 / %QW100

MAX_DEVICES = 16
BITS = 800            # %IX0.0..%IX99.7, %QX0.0..%QX99.7
WORDS = 1024          # %IW0..%IW1023, %QW0..%QW1023
# The baud rates libmodbus 3.1 can set on Linux (others silently become 9600).
BAUD_RATES = (110, 300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000,
              576000, 921600, 1000000, 1152000, 1500000, 2000000, 2500000, 3000000, 3500000, 4000000)
PARITY = {"none": "N", "even": "E", "odd": "O"}


@dataclass(frozen=True)
class RangeKind:
    key: str          # key in [[io.device]]
    spec: str         # key in the runtime's --io-device
    output: bool
    bits: bool
    max_count: int    # libmodbus' limit for one request
    table: str        # the device's table, for overlap messages


KINDS = (
    RangeKind("discrete_inputs", "di", False, True, 2000, "discrete inputs"),
    RangeKind("coils", "co", True, True, 1968, "coils"),
    RangeKind("input_registers", "ir", False, False, 125, "input registers"),
    RangeKind("holding_registers_read", "hr", False, False, 125, "holding registers"),
    RangeKind("holding_registers_write", "hw", True, False, 123, "holding registers"),
)
KIND_BY_KEY = {k.key: k for k in KINDS}

DEVICE_KEYS = {"name", "tcp", "port", "rtu", "baud", "parity", "data_bits", "stop_bits", "unit", "poll_ms",
               "timeout_ms", "max_age_ms", "backoff_ms", "status_input", *KIND_BY_KEY}
RANGE_KEYS = {"address", "count", "to", "from", "safe"}


Path_ = tuple  # a key path: ("io", "device", 0, "coils", 1, "safe")


# ---------------------------------------------------------------------- model

@dataclass
class IoRange:
    kind: RangeKind
    address: int
    count: int
    image: int                       # first bit index (8*byte + bit) or word
    safe: list[int] = field(default_factory=list)
    nth: int = 0                     # its place in the device's list of this kind (for its position)

    def spec(self) -> str:
        text = f"{self.kind.spec}={self.address}:{self.count}:{self.image}"
        if self.kind.output and any(self.safe):
            text += ":" + ",".join(str(v) for v in self.safe)
        return text


@dataclass
class IoDevice:
    index: int                       # 1-based, as the log and the diagnostics say
    name: str
    tcp: str | None = None
    port: int = 502
    rtu: str | None = None
    baud: int = 19200
    parity: str = "none"
    data_bits: int = 8
    stop_bits: int = 1
    unit: int = 1
    poll_ms: int = 10
    timeout_ms: int = 50
    max_age_ms: int | None = None
    backoff_ms: tuple[int, int] = (100, 2000)
    status_input: int | None = None  # bit index
    ranges: list[IoRange] = field(default_factory=list)
    bad: set[str] = field(default_factory=set)   # keys found wrong (later checks leave them out)

    def spec(self) -> str:
        """The runtime's --io-device argument."""
        parts = [f"name={self.name}"]
        if self.tcp is not None:
            parts.append(f"tcp={self.tcp}:{self.port}")
        else:
            parts += [f"rtu={self.rtu}", f"baud={self.baud}", f"parity={PARITY[self.parity]}",
                      f"data={self.data_bits}", f"stop={self.stop_bits}"]
        parts += [f"unit={self.unit}", f"poll={self.poll_ms}", f"timeout={self.timeout_ms}",
                  f"age={self.age_ms}", f"backoff={self.backoff_ms[0]}-{self.backoff_ms[1]}"]
        if self.status_input is not None:
            parts.append(f"status={self.status_input}")
        parts += [r.spec() for r in self.ranges]
        return " ".join(parts)

    @property
    def age_ms(self) -> int:
        return self.max_age_ms if self.max_age_ms is not None else 2 * self.poll_ms + self.timeout_ms


def parse_location(text: Any, prefix: str, bits: bool) -> int | None:
    """'%IX3.2' -> 26, '%IW7' -> 7 (prefix '%IX'/'%QX' for bits, '%IW'/'%QW' for words); None if malformed."""
    if not isinstance(text, str):
        return None
    t = text.strip().upper()
    if not t.startswith(prefix):
        return None
    rest = t[len(prefix):]
    if bits:
        m = re.fullmatch(r"(\d+)\.([0-7])", rest)
        return int(m.group(1)) * 8 + int(m.group(2)) if m else None
    return int(rest) if rest.isdigit() else None


def bit_name(prefix: str, bit: int) -> str:
    return f"{prefix}{bit // 8}.{bit % 8}"


# ------------------------------------------------------------------------ schema

def _device_name(value: Any) -> str:
    if not isinstance(value, str) or not re.fullmatch(r"[A-Za-z0-9_\-]{1,31}", value):
        raise Invalid(f"expected 1-31 letters, digits, '-' or '_', got {value!r}")
    return value


def _serial_device(value: Any) -> str:
    if not isinstance(value, str) or not value or " " in value:
        raise Invalid(f"expected the serial device's path, got {value!r}")
    if not os.path.exists(value):
        raise Invalid(f"serial device {value} does not exist")
    return value


def _baud(value: Any) -> int:
    if value not in BAUD_RATES or isinstance(value, bool):
        raise Invalid(f"{value!r} is not a rate the serial driver can set ({', '.join(map(str, BAUD_RATES[3:12]))}, "
                      "...)")
    return value


def _backoff(value: Any) -> tuple[int, int]:
    if (not isinstance(value, list) or len(value) != 2 or not all(isinstance(v, int) and not isinstance(v, bool)
                                                                   for v in value)
            or not 1 <= value[0] <= value[1] <= 600000):
        raise Invalid(f"expected [FIRST, MAX] in ms, 1 <= FIRST <= MAX <= 600000, got {value!r}")
    return value[0], value[1]


def _status_input(value: Any) -> int:
    bit = parse_location(value, "%IX", True)
    if bit is None or bit >= BITS:
        raise Invalid(f"expected %IXa.b inside %IX0.0..%IX99.7, got {value!r}")
    return bit


def _location(prefix: str, bits: bool) -> Check:
    example = f"{prefix}0.0" if bits else f"{prefix}0"

    def check(value: Any) -> int:
        image = parse_location(value, prefix, bits)
        if image is None:
            raise Invalid(f"expected a location like {example}, got {value!r}")
        return image
    return Check(check, f"a location like {example}")


_ANY = Check(lambda v: v)       # checked by the code that reads it (the ranges: _check_ranges)
TCP_ONLY = ("port",)
RTU_ONLY = ("baud", "parity", "data_bits", "stop_bits")

DEVICE = Table((
    Field("name", Check(_device_name), "for log lines"),
    Field("tcp", Check(ipv4), "the IPv4 address of a Modbus TCP device"),
    Field("port", Int(1, 65535), "TCP port", default=502),
    Field("rtu", Check(_serial_device), "the serial device of a Modbus RTU line"),
    Field("baud", Check(_baud), default=19200),
    Field("parity", OneOf(tuple(PARITY)), default="none"),
    Field("data_bits", Int(7, 8), default=8),
    Field("stop_bits", Int(1, 2), default=1),
    Field("unit", Int(0, 255), "Modbus unit (slave) id", default=1),
    Field("poll_ms", Int(1, 60000), "poll period", default=10),
    Field("timeout_ms", Int(1, 60000), "response timeout of one transaction", default=50),
    Field("max_age_ms", Int(1, 600000), "inputs older than this: the device is lost"),
    Field("backoff_ms", Check(_backoff), "reconnect back-off: first wait, doubling up to the second",
          default=(100, 2000)),
    Field("status_input", Check(_status_input), "TRUE while the device is lost"),
    *(Field(k.key, _ANY, f"FC{k.spec} ranges") for k in KINDS),
))
# a unit on a serial line: 0 is the broadcast address, 248..255 are reserved
RTU_DEVICE = DEVICE.replace(Field("unit", Int(1, 247), "Modbus unit (slave) id", default=1))
DEVICE_KEYS = set(DEVICE.names)


def range_table(kind: RangeKind) -> Table:
    """The keys of one range of `kind`: { address, count, to } or { address, count, from, safe }."""
    prefix = ("%QX" if kind.bits else "%QW") if kind.output else ("%IX" if kind.bits else "%IW")
    fields = [Field("address", Int(0, 65535), "first address on the device", required=True),
              Field("count", Int(1, kind.max_count), "values", required=True),
              Field("from" if kind.output else "to", _location(prefix, kind.bits), "first location of the image",
                    required=True)]
    if kind.output:
        fields.append(Field("safe", _ANY, "the values the device gets when the runtime stops"))
    return Table(tuple(fields))


RANGES = {k.key: range_table(k) for k in KINDS}


# ---------------------------------------------------------------------- checks

def check_devices(doc: Document, entries: Any) -> list[IoDevice]:
    """Check the `[[io.device]]` entries of a run configuration `doc` (every problem into doc.diagnostics);
    the devices as far as their values are right."""
    devices: list[IoDevice] = []
    base: Path_ = ("io", "device")
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        doc.error(base, "io.device: write each device as a [[io.device]] table")
        return []
    if len(entries) > MAX_DEVICES:
        doc.error(base + (MAX_DEVICES,), f"at most {MAX_DEVICES} I/O devices")
    for n, entry in enumerate(entries[:MAX_DEVICES]):
        devices.append(_check_device(doc, base + (n,), n + 1, entry))
    # the checks across devices run whatever else was found: every mistake is reported in one run (a value found
    # wrong is left out of them, so it is reported once, where it is written)
    _check_overlaps(doc, devices)
    _check_lines(doc, devices)
    return devices


def _check_device(doc: Document, key: Path_, index: int, e: dict) -> IoDevice:
    """The device as far as its values are right (the keys found wrong in `bad`)."""
    where = f"[[io.device]] {index}"
    checked = (RTU_DEVICE if "rtu" in e and "tcp" not in e else DEVICE).check(doc, key, e, where + ":")
    bad = set(checked.bad)

    def error(k: str | None, message: str) -> None:
        doc.error(key + ((k,) if k else ()), f"{where}: {message}")
        if k:
            bad.add(k)

    dev = IoDevice(index=index, name=checked.get("name", f"device{index}"))
    if ("tcp" in e) == ("rtu" in e):
        error(None, "give exactly one of tcp = \"ADDRESS\" and rtu = \"/dev/SERIAL\"")
    for k in RTU_ONLY if "tcp" in e else ():
        if k in e:
            error(k, f"{k} belongs to an rtu device")
    for k in TCP_ONLY if "rtu" in e else ():
        if k in e:
            error(k, f"{k} belongs to a tcp device")
    if "tcp" in e:
        dev.tcp, dev.port = checked.get("tcp"), checked["port"]
    if "rtu" in e:
        dev.rtu = checked.get("rtu")
        dev.baud, dev.parity = checked["baud"], checked["parity"]
        dev.data_bits, dev.stop_bits = checked["data_bits"], checked["stop_bits"]
    dev.unit, dev.poll_ms, dev.timeout_ms = checked["unit"], checked["poll_ms"], checked["timeout_ms"]
    dev.max_age_ms, dev.backoff_ms = checked.get("max_age_ms"), checked["backoff_ms"]
    dev.status_input = checked.get("status_input")
    if dev.age_ms < dev.poll_ms:
        error("max_age_ms", f"max_age_ms ({dev.age_ms}) is shorter than poll_ms ({dev.poll_ms}): the device would "
                            "always count as lost")
    for kind in KINDS:
        if kind.key in e:
            _check_ranges(doc, key + (kind.key,), where, kind, e[kind.key], dev)
    if not any(kind.key in e for kind in KINDS):
        error(None, f"no ranges: give at least one of {', '.join(k.key for k in KINDS)}")
    if len(dev.ranges) > MAX_RANGES:
        error(None, f"{len(dev.ranges)} ranges: a device has at most {MAX_RANGES} (the runtime's table per device); "
                    "split the device's tables into fewer, longer ranges")
    dev.bad = bad
    return dev


def _check_ranges(doc: Document, key: Path_, where: str, kind: RangeKind, value: Any, dev: IoDevice) -> None:
    if isinstance(value, dict):
        value = [value]
    if not isinstance(value, list):
        doc.error(key, f"{where}: {kind.key}: expected a list of {{ address, count, "
                       f"{'from' if kind.output else 'to'} }} tables")
        dev.bad.add(kind.key)
        return
    prefix = ("%QX" if kind.bits else "%QW") if kind.output else ("%IX" if kind.bits else "%IW")
    image_key = "from" if kind.output else "to"
    limit = BITS if kind.bits else WORDS
    for i, r in enumerate(value):
        rk = key + (i,)
        w = f"{where}: {kind.key}[{i + 1}]"
        if not isinstance(r, dict):
            doc.error(rk, f"{w}: expected {{ address = N, count = N, {image_key} = \"{prefix}...\" }}")
            continue
        checked = RANGES[kind.key].check(doc, rk, r, w + ":")
        if not checked.ok:
            continue
        address, count, image = checked["address"], checked["count"], checked[image_key]
        if address + count > 65536:
            doc.error(rk, f"{w}: addresses {address}..{address + count - 1} run past the device's 65535")
            continue
        if image + count > limit:
            last = bit_name(prefix, image + count - 1) if kind.bits else f"{prefix}{image + count - 1}"
            end = bit_name(prefix, limit - 1) if kind.bits else f"{prefix}{limit - 1}"
            doc.error(rk, f"{w}: {count} values from {r[image_key]} end at {last}, outside the image (last {end})")
            continue
        safe = [0] * count
        if "safe" in r:
            s = r["safe"]
            items = s if isinstance(s, list) else [s]
            ok_type = (lambda v: isinstance(v, bool)) if kind.bits else \
                (lambda v: isinstance(v, int) and not isinstance(v, bool) and -32768 <= v <= 65535)
            if len(items) not in (1, count) or not all(ok_type(v) for v in items):
                what = "true/false" if kind.bits else "integers -32768..65535"
                doc.error(rk + ("safe",), f"{w}: safe: one value or {count} values ({what})")
                continue
            safe = [int(v) & 0xFFFF for v in (items * count if len(items) == 1 else items)]
        dev.ranges.append(IoRange(kind, address, count, image, safe, nth=i))


# Discrete inputs the runtime itself sets (runtime.h, io_sim.c): no device may write them.
RUNTIME_INPUTS = {398: "ForcesActive (set while a variable is forced)", 399: "SimulatedPlant (the simulated plant)"}


def _check_overlaps(doc: Document, devices: list[IoDevice]) -> None:
    """Two ranges writing one part of the image, two ranges on one table of one device, a status input inside
    an input range; devices sharing a serial line with different line settings or the same unit."""
    def area(r: IoRange) -> str:
        return ("%QX" if r.kind.bits else "%QW") if r.kind.output else ("%IX" if r.kind.bits else "%IW")

    def show(r: IoRange, first: int, last: int) -> str:
        a = area(r)
        return f"{bit_name(a, first)}..{bit_name(a, last)}" if r.kind.bits else f"{a}{first}..{a}{last}"

    placed: list[tuple[IoDevice, int, IoRange]] = []
    for d in devices:
        for i, r in enumerate(d.ranges):
            for od, _oi, o in placed:
                if area(o) == area(r) and r.image < o.image + o.count and o.image < r.image + r.count:
                    doc.error(("io", "device", d.index - 1, r.kind.key, r.nth),
                             f"[[io.device]] {d.index}: {r.kind.key} {show(r, r.image, r.image + r.count - 1)} "
                             f"overlaps {o.kind.key} of device {od.index} "
                             f"({show(o, o.image, o.image + o.count - 1)})")
                if (od is d and o.kind.table == r.kind.table and o.kind.output == r.kind.output
                        and r.address < o.address + o.count and o.address < r.address + r.count):
                    doc.error(("io", "device", d.index - 1, r.kind.key, r.nth),
                             f"[[io.device]] {d.index}: {r.kind.key} addresses {r.address}..{r.address + r.count - 1}"
                             f" overlap {o.kind.key} {o.address}..{o.address + o.count - 1} on the same device")
            if area(r) == "%IX":
                for bit, what in RUNTIME_INPUTS.items():
                    if r.image <= bit < r.image + r.count:
                        doc.error(("io", "device", d.index - 1, r.kind.key, r.nth),
                                 f"[[io.device]] {d.index}: {r.kind.key} {show(r, r.image, r.image + r.count - 1)} "
                                 f"covers {bit_name('%IX', bit)}, the runtime's {what}")
            placed.append((d, i, r))
    status = {}
    for d in devices:
        if d.status_input is None:
            continue
        for od, _, o in placed:
            if area(o) == "%IX" and o.image <= d.status_input < o.image + o.count:
                doc.error(("io", "device", d.index - 1, "status_input"),
                         f"[[io.device]] {d.index}: status_input {bit_name('%IX', d.status_input)} lies in "
                         f"discrete_inputs of device {od.index}")
        if d.status_input in RUNTIME_INPUTS:
            doc.error(("io", "device", d.index - 1, "status_input"),
                     f"[[io.device]] {d.index}: status_input {bit_name('%IX', d.status_input)} is the runtime's "
                     f"{RUNTIME_INPUTS[d.status_input]}")
        if d.status_input in status:
            doc.error(("io", "device", d.index - 1, "status_input"),
                     f"[[io.device]] {d.index}: status_input {bit_name('%IX', d.status_input)} is already the "
                     f"status input of device {status[d.status_input]}")
        status[d.status_input] = d.index


# On a line shared by several units the runtime (io_modbus.c) declares a unit lost once its inputs are older than
# max_age_ms less this margin in time-outs: a failed transaction in flight (2), then the reacting scan and the
# write to a neighbour (1: a task period and a frame time).  Between two polls of a unit at worst every other
# unit fails once (2 time-outs each) and its own read and write take 2: the unit's worst gap.
LINE_MARGIN_TIMEOUTS = 3


def line_worst_gap_ms(poll_ms: int, timeout_ms: int, units: int) -> int:
    """The longest time between two polls of one unit of a serial line of `units` units."""
    return poll_ms + 2 * timeout_ms * units


def _check_lines(doc: Document, devices: list[IoDevice]) -> None:
    """Devices sharing a serial line: the same line settings, distinct units, and an age limit the line's worst
    case can meet (comm loss -> the program's reaction at every answering unit of the line <= max_age_ms)."""
    line_keys = {"rtu", "baud", "parity", "data_bits", "stop_bits", "timeout_ms", "unit", "poll_ms", "max_age_ms"}
    lines: dict[str, list[IoDevice]] = {}
    for d in devices:
        if d.rtu is not None and not d.bad & line_keys:
            lines.setdefault(os.path.realpath(d.rtu), []).append(d)
    for members in lines.values():
        first = members[0]
        for n, d in enumerate(members[1:], 1):
            if (d.baud, d.parity, d.data_bits, d.stop_bits, d.timeout_ms) != \
                    (first.baud, first.parity, first.data_bits, first.stop_bits, first.timeout_ms):
                doc.error(("io", "device", d.index - 1, "rtu"),
                         f"[[io.device]] {d.index}: serial line {d.rtu} is device {first.index}'s: give it the same "
                         "baud, parity, data_bits, stop_bits and timeout_ms")
            same_unit = [o.index for o in members[:n] if o.unit == d.unit]
            if same_unit:
                doc.error(("io", "device", d.index - 1, "unit"),
                         f"[[io.device]] {d.index}: unit {d.unit} is already device {same_unit[0]} on serial line "
                         f"{d.rtu}")
        if len(members) < 2:
            continue
        poll = min(d.poll_ms for d in members)
        for d in members:
            gap = line_worst_gap_ms(poll, d.timeout_ms, len(members))
            need = gap + LINE_MARGIN_TIMEOUTS * d.timeout_ms
            if d.max_age_ms is None:
                d.max_age_ms = need
            elif d.max_age_ms < need:
                doc.error(("io", "device", d.index - 1, "max_age_ms"),
                         f"[[io.device]] {d.index}: max_age_ms {d.max_age_ms} cannot hold on serial line {d.rtu} "
                         f"shared by {len(members)} units: between two polls of a unit up to {gap} ms can pass "
                         f"(poll {poll} ms, 2 time-outs of {d.timeout_ms} ms per unit), and after a loss "
                         f"{LINE_MARGIN_TIMEOUTS} time-outs until the other units have the program's reaction; give "
                         f"max_age_ms >= {need}, or a shorter timeout_ms")


def device_specs(devices: list[IoDevice]) -> list[str]:
    return [d.spec() for d in devices]
