"""configs/linuxcnc/atc_mb2hal.ini and atc_iov2.hal: LinuxCNC 2.9 (iov2 + mb2hal) on the register map.

mb2hal (docs/mb2hal.md) runs the transactions of a link strictly in INI order, round-robin, and re-sends
writes every pass.  The plan: the host's numbers are written before its bits, the PLC's numbers are read
after its bits (so a number is never older than the bit read with it; the PLC sets both in one scan):

    atc-words-out   FC16  host_to_plc registers wired to LinuxCNC (one transaction per contiguous run)
    atc-bits-out    FC15  host_to_plc coils wired to LinuxCNC: all in ONE transaction, so one request
                          carries every request bit and the runtime applies it between two scans
    atc-bits-in     FC01  plc_to_host coils
    atc-words-in    FC03  plc_to_host registers (unused registers in a run are read as spare pins)

Ordering alone cannot keep a number and its request bit together: iov2 may change both between the FC16 and
the FC15 of one pass.  So the HAL file delays the rising edge of each [linuxcnc] settle bit by settle_s (at
least one pass): tool-prepare and tool-change reach the PLC only after tool-prep-number/pocket have, and
toolchanger-fault reaches iov2 only after toolchanger-reason has.  FC03 values arrive unsigned (0..65535):
every INT register wired to HAL goes through a lincurve that maps 32768..65535 to -32768..-1 and a
conv_float_s32.  The PLC toggles [link] plc_alive; a retriggerable oneshot of plc_timeout_ms turns a missing
edge (PLC stopped, link lost, mb2hal gone) into E-stop through iocontrol.0.emc-enable-in.  A siggen sawtooth
is the host heartbeat written to [link] host_heartbeat.  A DINT register pair read by LinuxCNC (the mailbox
arguments) arrives as two unsigned words, pins <name>-hi and <name>-lo: a sum2 joins them (hi * 65536 + lo), a
lincurve restores the sign and applies the signal's scale, so its HAL signal is a float in engineering units.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from plc.diagnostics import Diagnostics

from . import iov2pins
from .model import RegisterMap, Signal, display

HAL_NAME_LEN = 47            # the longest HAL pin name of LinuxCNC 2.9 (HAL_NAME_LEN in hal.h)

MAX_READ_REGISTERS = 125
MAX_READ_BITS = 2000
READ_GAP = 16               # unused addresses a read transaction may span rather than split
# LinuxCNC 2.9's INI reader keeps 255 characters of a line: mb2hal silently drops the pins of a longer PIN_NAMES
# line's tail (seen: the record's last register, MbxArgsId, had no pin). Spare registers are named u<address>.
MAX_INI_LINE = 254
SPARE = "u"


@dataclass
class Tx:
    name: str                                   # HAL_TX_NAME
    code: str                                   # MB_TX_CODE
    first: int                                  # FIRST_ELEMENT
    pins: list[tuple[str, Signal | None]] = field(default_factory=list)   # PIN_NAMES, in address order

    @property
    def writes(self) -> bool:
        return "write" in self.code

    @property
    def bits(self) -> bool:
        return "coils" in self.code

    def pin(self, rmap: RegisterMap, sig: Signal, part: str = "") -> str:
        """Full HAL name of the mb2hal pin that carries `sig` (mb2hal VERSION 1.1 pin names); a DINT has two,
        part "-hi" and "-lo"."""
        suffix = "bit" if self.bits else ("int" if self.writes else "float")
        if sig.type == "DINT" and not part:
            part = "-hi"
        return f"{rmap.linuxcnc.component}.{self.name}.{sig.name}{part}.{suffix}"


def plan(rmap: RegisterMap, diags: Diagnostics | None = None) -> list[Tx]:
    """The mb2hal transactions for the signals with `hal`, in INI order; problems go to diags."""
    diags = diags if diags is not None else Diagnostics()
    wired = [s for s in rmap.signals if s.hal and s.direction in ("host_to_plc", "plc_to_host")
             and (s.type in ("BOOL", "INT", "UINT") or (s.type == "DINT" and s.direction == "plc_to_host"))]
    txs: list[Tx] = []
    words_out = sorted((s for s in wired if s.direction == "host_to_plc" and s.type != "BOOL"),
                       key=lambda s: s.address)
    for i, run in enumerate(_runs(words_out, gap=0, limit=123)):
        txs.append(_tx(_numbered("atc-words-out", i), "fnct_16_write_multiple_registers", run, False))
    bits_out = sorted((s for s in wired if s.direction == "host_to_plc" and s.type == "BOOL"),
                      key=lambda s: s.address)
    if bits_out:
        _check_bit_block(rmap, bits_out, diags)
        txs.append(_tx("atc-bits-out", "fnct_15_write_multiple_coils", bits_out, False))
    bits_in = sorted((s for s in wired if s.direction == "plc_to_host" and s.type == "BOOL"),
                     key=lambda s: s.address)
    for i, run in enumerate(_runs(bits_in, gap=READ_GAP, limit=MAX_READ_BITS)):
        txs.append(_tx(_numbered("atc-bits-in", i), "fnct_01_read_coils", run, True))
    words_in = sorted((s for s in wired if s.direction == "plc_to_host" and s.type != "BOOL"),
                      key=lambda s: s.address)
    for i, run in enumerate(_runs(words_in, gap=READ_GAP, limit=MAX_READ_REGISTERS)):
        txs.append(_tx(_numbered("atc-words-in", i), "fnct_03_read_holding_registers", run, True))
    for tx in txs:
        line = "PIN_NAMES=" + ",".join(n for n, _s in tx.pins)
        if len(line) > MAX_INI_LINE:
            first = next(s for _n, s in tx.pins if s is not None)
            diags.error(rmap.pos(first, "address"), f"the mb2hal transaction {tx.name} from {first.name} needs a "
                        f"PIN_NAMES line of {len(line)} characters; LinuxCNC 2.9 reads {MAX_INI_LINE}",
                        "fewer or closer registers in one read, or shorter signal names")
        for _name, sig in tx.pins:
            if sig is not None and len(tx.pin(rmap, sig, "-lo" if sig.type == "DINT" else "")) > HAL_NAME_LEN:
                diags.error(rmap.pos(sig, "name"), f"{sig.name}: HAL pin {tx.pin(rmap, sig)} is longer than "
                            f"{HAL_NAME_LEN} characters", "shorten the signal name")
    return txs


def _numbered(base: str, i: int) -> str:
    return base if i == 0 else f"{base}-{i + 1}"


def _runs(signals: list[Signal], gap: int, limit: int) -> list[list[Signal]]:
    runs: list[list[Signal]] = []
    for sig in signals:
        if runs and sig.address - runs[-1][-1].last - 1 <= gap and sig.last - runs[-1][0].address < limit:
            runs[-1].append(sig)
        else:
            runs.append([sig])
    return runs


def _tx(name: str, code: str, run: list[Signal], spares: bool) -> Tx:
    tx = Tx(name, code, run[0].address)
    by_address = {s.address: s for s in run}
    for s in run:
        if s.type == "DINT":
            by_address[s.address + 1] = s
    for a in range(run[0].address, run[-1].last + 1):
        sig = by_address.get(a)
        if sig is not None and sig.type == "DINT":
            tx.pins.append((sig.name + ("-hi" if a == sig.address else "-lo"), sig))
        else:
            tx.pins.append((sig.name, sig) if sig is not None else (f"{SPARE}{a}", None))
    return tx


def _check_bit_block(rmap: RegisterMap, bits: list[Signal], diags: Diagnostics) -> None:
    """All host bits travel in one FC15: every coil between the first and the last must be one of them."""
    wired = {s.address for s in bits}
    for a in range(bits[0].address, bits[-1].address + 1):
        if a in wired:
            continue
        other = next((s for s in rmap.signals if s.table == "coil" and s.address == a), None)
        what = f"{other.name} ({other.direction}, not wired to LinuxCNC)" if other else "no signal"
        diags.error(rmap.pos(other or bits[0], "address"), f"coil {a} lies inside the host bits that mb2hal "
                    f"writes in one FC15 transaction ({bits[0].address}..{bits[-1].address}) but is {what}",
                    "host bits wired to LinuxCNC must be contiguous: mb2hal would write 0 there every pass "
                    "(or the runtime would refuse the whole request)")


# ------------------------------------------------------------------- INI --
def mb2hal_ini(rmap: RegisterMap) -> str:
    lc = rmap.linuxcnc
    txs = plan(rmap)
    src = display(rmap.path, rmap.root)
    out = [
        f"# Generated by `plc map generate` from {src}: do not edit (CI fails on drift).",
        "# mb2hal (LinuxCNC 2.9) configuration of the atc-plc register map; loaded by atc_iov2.hal:",
        f"#     loadusr -W {lc.component} config=atc_mb2hal.ini",
        "# Transactions run in this order every pass: host numbers (FC16), host bits (FC15, all in one),",
        "# PLC bits (FC01), PLC numbers (FC03: never older than the bits). Pins:",
        "# <component>.<HAL_TX_NAME>.<signal>.int|float|bit",
        "# (VERSION 1.1 pin names). The runtime refuses writes outside the map's host-writable ranges.",
        "",
        "[MB2HAL_INIT]",
        "INIT_DEBUG=1",
        "VERSION=1.1",
        f"HAL_MODULE_NAME={lc.component}",
        "SLOWDOWN=0.0",
        f"TOTAL_TRANSACTIONS={len(txs)}",
    ]
    for i, tx in enumerate(txs):
        names = [n for n, _s in tx.pins]
        out += ["", f"[TRANSACTION_{i:02d}]"]
        described = [f"{sig.name} {sig.table} {sig.address}" for n, sig in tx.pins
                     if sig is not None and not (sig.type == "DINT" and n.endswith("-lo"))]
        out.append("# " + "; ".join(described) if len(described) <= 4 else
                   f"# {tx.pins[0][0]} .. {tx.pins[-1][0]}: {len(described)} signals from {tx.first}")
        if i == 0:
            out += ["LINK_TYPE=tcp", f"TCP_IP={lc.host}", f"TCP_PORT={lc.port}"]
        out += [
            f"MB_SLAVE_ID={lc.slave_id}",
            f"MB_TX_CODE={tx.code}",
            f"FIRST_ELEMENT={tx.first}",
            f"PIN_NAMES={','.join(names)}",
            f"HAL_TX_NAME={tx.name}",
            f"MAX_UPDATE_RATE={_num(lc.update_rate_hz)}",
            f"MB_RESPONSE_TIMEOUT_MS={lc.response_timeout_ms}",
            f"MB_BYTE_TIMEOUT_MS={lc.response_timeout_ms}",
            "DEBUG=1",
        ]
    return "\n".join(out) + "\n"


def _num(value: float) -> str:
    text = f"{value:.6f}".rstrip("0")
    return text + "0" if text.endswith(".") else text


# ------------------------------------------------------------------- HAL --
def _net(name: str) -> str:
    return "atc-" + "".join("-" + c.lower() if c.isupper() else c for c in name).lstrip("-")


VARIANTS = {
    "iov2": ("atc_iov2.hal", "iov2 -support-start-change", None),
    "io": ("atc_io.hal", "io", iov2pins.V1_PINS),
}


def _endpoint(sig: Signal, pins: frozenset[str] | None) -> str | None:
    """The LinuxCNC end of a wired signal in this variant: a pin, '' for a bare signal, None to leave it out."""
    if "." not in sig.hal:
        return ""
    if pins is None or sig.hal[len(iov2pins.PREFIX):] in pins:
        return sig.hal
    if sig.hal[len(iov2pins.PREFIX):] in iov2pins.OPERATOR_INPUTS:
        return ""          # the operator line stays (M150, GUI); only iov2's end is missing
    return None


def hal_file(rmap: RegisterMap, variant: str = "iov2") -> str:
    """atc_iov2.hal (iov2, protocol 2) or atc_io.hal (EMCIO = io: only the prepare and change pairs)."""
    lc, link = rmap.linuxcnc, rmap.link
    filename, emcio, pins = VARIANTS[variant]
    txs = plan(rmap)
    where: dict[str, tuple[Tx, Signal]] = {}
    for tx in txs:
        for _n, sig in tx.pins:
            if sig is not None and _endpoint(sig, pins) is not None:
                where[sig.name] = (tx, sig)
    settle = [rmap.signal(n) for n in lc.settle + lc.settle_fall
              if rmap.signal(n) is not None and rmap.signal(n).name in where]
    falling = {rmap.signal(n).name for n in lc.settle_fall if rmap.signal(n) is not None}
    signed = [sig for tx, sig in where.values() if not tx.writes and sig.type == "INT"]
    alive = rmap.signal(link.plc_alive)
    beat = rmap.signal(link.host_heartbeat)
    thread = lc.thread
    src = display(rmap.path, rmap.root)
    chain = lc.estop_chain or "iocontrol.0.user-enable-out"
    out = [
        f"# Generated by `plc map generate` from {src}: do not edit (CI fails on drift).",
        f"# LinuxCNC 2.9 [EMCIO] EMCIO = {emcio} <-> atc-plc over Modbus/TCP (mb2hal, atc_mb2hal.ini in the same",
        f"# directory). Load it after the HAL file that creates {thread}: [HAL] HALFILE = {filename}",
        f"# It drives iocontrol.0.emc-enable-in = {chain} AND the PLC link (no {link.plc_alive} edge for "
        f"{link.plc_timeout_ms} ms",
        "# = E-stop): the machine HAL must not connect emc-enable-in itself.",
        "# Realtime helpers are loaded with names=atc-...: if the machine HAL loads one of these components too",
        "# (timedelay, lincurve, conv_float_s32, oneshot, and2, siggen), merge the names= lists into one loadrt.",
        "# Signals without a writer (atc-clear-fault, atc-home-request, atc-confirm-tool...) are set by the M-codes",
        "# of configs/linuxcnc/mcodes (M150 clear, M151 P<tool> confirm, M152 home), a GUI or `halcmd sets`.",
    ]
    if pins is not None:
        out.append("# Protocol 1 (EMCIO = io): only the prepare and change pairs exist; the PLC's other iov2 lines "
                   "stay unwired (mb2hal writes 0 for them).")
    out += ["", "# ---- Modbus master", f"loadusr -W {lc.component} config=atc_mb2hal.ini", ""]
    comps: list[tuple[str, list[str], str]] = []     # (module, instance names, extra loadrt args)
    settle_names = [f"atc-settle-{_net(s.name)[4:]}" for s in settle]
    if settle_names:
        comps.append(("timedelay", settle_names, ""))
    joined = [sig for tx, sig in where.values() if not tx.writes and sig.type == "DINT"]
    sign_names = [f"atc-sign-{_net(s.name)[4:]}" for s in signed + joined]
    if sign_names:
        comps.append(("lincurve", sign_names, "personality=" + ",".join("4" for _ in sign_names)))
        comps.append(("conv_float_s32", [f"atc-s32-{_net(s.name)[4:]}" for s in signed], ""))
    if joined:
        comps.append(("sum2", [f"atc-join-{_net(s.name)[4:]}" for s in joined], ""))
    watch = alive is not None and alive.name in where
    if watch:
        comps.append(("oneshot", ["atc-link-watch"], ""))
        comps.append(("and2", ["atc-estop-and"], ""))
    if beat is not None and beat.name in where:
        comps.append(("siggen", ["atc-host-beat"], ""))
    out.append("# ---- realtime helpers (all in " + thread + ")")
    for module, names, extra in comps:
        out.append(f"loadrt {module} names={','.join(names)}" + (f" {extra}" if extra else ""))
    # The conversions of the PLC's registers run in descending address order within each component: mb2hal sets
    # a transaction's pins in ascending order, so a register's conversion never runs before that of a register
    # mb2hal set earlier in the same pass. Motion then never sees the last register of a read (the mailbox
    # record's MbxArgsId) new while an earlier one is still old (docs/linuxcnc.md, the mailbox record).
    helper_address = {f"atc-{kind}-{_net(s.name)[4:]}": s.address
                      for s in signed + joined for kind in ("sign", "s32", "join")}
    for module, names, _extra in comps:
        for name in sorted(names, key=lambda n: -helper_address.get(n, -1)):
            out.append(f"addf {name}{'.update' if module == 'siggen' else ''} {thread}")
    out.append("")

    out.append("# ---- CNC -> PLC (host_to_plc): numbers, then request bits")
    for tx in txs:
        if tx.writes:
            for _n, sig in tx.pins:
                if sig is not None and sig.name in where and not (beat is not None and sig.name == beat.name):
                    out += _wire_out(rmap, tx, sig, settle, _endpoint(sig, pins))
    out += ["", "# ---- PLC -> CNC (plc_to_host)"]
    for tx in txs:
        if not tx.writes:
            for pin_name, sig in tx.pins:
                if pin_name.endswith("-lo") and sig is not None and sig.type == "DINT":
                    continue            # wired with its -hi pin
                if sig is not None and sig.name in where and not (alive is not None and sig.name == alive.name):
                    out += _wire_in(rmap, tx, sig, settle, signed, _endpoint(sig, pins))
    out.append("")
    if settle:
        out.append(f"# ---- settle: these edges wait {_num(lc.settle_s)} s (one mb2hal pass is "
                   f"{_num(1.0 / lc.update_rate_hz)} s), the other edge passes at once")
        for sig, name in zip(settle, settle_names, strict=True):
            on, off = (0, lc.settle_s) if sig.name in falling else (lc.settle_s, 0)
            edge = "falling" if sig.name in falling else "rising"
            out += [f"# {sig.name}: {edge} edge delayed", f"setp {name}.on-delay {_num(on)}",
                    f"setp {name}.off-delay {_num(off)}"]
        out.append("")
    if signed:
        out.append("# ---- INT registers arrive unsigned (0..65535): 32768..65535 -> -32768..-1")
        for name in sign_names[:len(signed)]:
            for k, (x, y) in enumerate([(0, 0), (32767, 32767), (32768, -32768), (65535, -1)]):
                out += [f"setp {name}.x-val-{k:02d} {x}", f"setp {name}.y-val-{k:02d} {y}"]
        out.append("")
    if joined:
        out.append("# ---- DINT register pairs: hi * 65536 + lo (0..4294967295), 2147483648.. -> negative, times "
                   "the signal's scale")
        for sig in joined:
            net = _net(sig.name)
            scale = sig.scale if sig.scale else 1.0
            out += [f"setp atc-join-{net[4:]}.gain0 65536", f"setp atc-join-{net[4:]}.gain1 1"]
            for k, (x, y) in enumerate([(0, 0), (2147483647, 2147483647), (2147483648, -2147483648),
                                        (4294967295, -1)]):
                out += [f"setp atc-sign-{net[4:]}.x-val-{k:02d} {x}",
                        f"setp atc-sign-{net[4:]}.y-val-{k:02d} {_num(y * scale)}"]
        out.append("")
    if watch:
        tx, sig = where[alive.name]
        source = f"net {lc.estop_chain} atc-estop-and.in0" if lc.estop_chain else \
            "net atc-user-enable iocontrol.0.user-enable-out => atc-estop-and.in0"
        out += [
            f"# ---- link watch: {alive.name} toggles every {link.plc_alive_toggle_ms} ms; no edge for "
            f"{link.plc_timeout_ms} ms (PLC stopped or faulted, link or mb2hal lost) = E-stop",
            f"setp atc-link-watch.width {_num(link.plc_timeout_ms / 1000.0)}",
            "setp atc-link-watch.rising 1",
            "setp atc-link-watch.falling 1",
            "setp atc-link-watch.retriggerable 1",
            f"net {_net(alive.name)} {tx.pin(rmap, sig)} => atc-link-watch.in",
            "net atc-link-ok atc-link-watch.out => atc-estop-and.in1",
            source,
            "net atc-estop-ok atc-estop-and.out => iocontrol.0.emc-enable-in",
            "",
        ]
    if beat is not None and beat.name in where:
        tx, sig = where[beat.name]
        top = 1000
        freq = 1000.0 / (4 * link.host_heartbeat_period_ms)
        out += [
            f"# ---- host heartbeat: a sawtooth 0..{top} at {_num(freq)} Hz, written to {beat.name} every pass "
            f"(the PLC wants a change within {link.host_timeout_ms} ms)",
            f"setp atc-host-beat.frequency {_num(freq)}",
            f"setp atc-host-beat.amplitude {top // 2}",
            f"setp atc-host-beat.offset {top // 2}",
            f"net {_net(beat.name)} atc-host-beat.sawtooth => {lc.component}.{tx.name}.{sig.name}.float",
            "",
        ]
    return "\n".join(out).rstrip("\n") + "\n"


def _wire_out(rmap: RegisterMap, tx: Tx, sig: Signal, settle: list[Signal], source: str) -> list[str]:
    pin = tx.pin(rmap, sig)
    net = _net(sig.name)
    if any(s.name == sig.name for s in settle):
        delay = f"atc-settle-{net[4:]}"
        return [f"net {net} {source} => {delay}.in" if source else f"net {net} {delay}.in",
                f"net {net}-settled {delay}.out => {pin}"]
    if not source:
        name = sig.hal if "." not in sig.hal else net
        if sig.type != "BOOL":
            return [f"# {name}: no writer here, set by an M-code (configs/linuxcnc/mcodes), a GUI or "
                    f"`halcmd sets {name} N`", f"net {name} {pin}"]
        return [f"# {name}: no writer here, pulsed by an M-code (configs/linuxcnc/mcodes), a GUI or "
                f"`halcmd sets {name} 1`", f"net {name} {pin}"]
    if iov2pins.lookup(source) and iov2pins.lookup(source)[1] == "IN":
        return [f"# {net}: no writer here, pulsed by an M-code (configs/linuxcnc/mcodes), a GUI or "
                f"`halcmd sets {net} 1`; iov2 reads it too",
                f"net {net} {pin} {source}"]
    return [f"net {net} {source} => {pin}"]


def _wire_in(rmap: RegisterMap, tx: Tx, sig: Signal, settle: list[Signal], signed: list[Signal],
             target: str) -> list[str]:
    pin = tx.pin(rmap, sig)
    net = _net(sig.name)
    name = net if target else (sig.hal if "." not in sig.hal else net)
    arrow = f" => {target}" if target else ""
    if sig.type == "DINT":
        join = f"atc-join-{net[4:]}"
        return [f"net {net}-hi {pin} => {join}.in0", f"net {net}-lo {tx.pin(rmap, sig, '-lo')} => {join}.in1",
                f"net {net}-raw {join}.out => atc-sign-{net[4:]}.in", f"net {name} atc-sign-{net[4:]}.out{arrow}"]
    if any(s.name == sig.name for s in signed):
        conv = f"atc-s32-{net[4:]}"
        return [f"net {net}-raw {pin} => atc-sign-{net[4:]}.in",
                f"net {net}-float atc-sign-{net[4:]}.out => {conv}.in",
                f"net {name} {conv}.out{arrow}"]
    if any(s.name == sig.name for s in settle):
        delay = f"atc-settle-{net[4:]}"
        return [f"net {net}-raw {pin} => {delay}.in", f"net {name} {delay}.out{arrow}"]
    if sig.type == "UINT":
        pin = pin[:-len("float")] + "int"
    return [f"net {name} {pin}{arrow}"]
