"""Validate the register map and the reason codes; every problem becomes a Diagnostic at file:line.

What is checked (docs/openplc-addressing.md and the portability rules of docs/matiec.md):
- names: ST identifiers MATIEC takes, unique (case-insensitive) across signals and generated constants;
- tables, types and addresses: BOOL only in coils/discrete inputs; INT/UINT/WORD one register; 32-bit types two
  registers, high word first, only in %MD (holding 2048..4095, even offset); everything inside OpenPLC's map;
  no two signals on the same bit or register;
- directions: physical inputs read-only, host_writable exactly for host_to_plc, retained only in %MW/%MD;
- enums and states, units, descriptions (they become ST comments: no comment delimiters);
- LinuxCNC wiring: iov2 pin names, types and directions, the mb2hal transaction plan (see gen_linuxcnc);
- [link] heartbeats and [linuxcnc] settings;
- reason codes: unique, severity agrees with the sign, INT range, rotary errors all covered and numbered by
  the documented rule against st_src/rotary.
"""
from __future__ import annotations

import ipaddress
import re

from plc.diagnostics import Diagnostics
from plc.lexer import KEYWORDS
from plc.portability import MATIEC_RESERVED, library_identifiers
from plc.stdfuncs import STD_FUNCS, conversion
from plc.types import ELEMENTARY, GENERIC

from . import iov2pins
from .enums import EnumType, StFacts
from .gen_linuxcnc import plan
from .model import DIRECTIONS, SEVERITIES, TABLES, TYPES_16, TYPES_32, TYPES_BIT, RegisterMap, Signal, iec_address

IDENT = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
HAL_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
MAX_TEXT = 80                # reason texts: one operator message line
LIMITS = {"coil": 800, "discrete_input": 800, "input_register": 1024, "holding_register": 4096}


def check(rmap: RegisterMap, facts: StFacts, diags: Diagnostics) -> None:
    """Check everything; the caller decides what to do with the diagnostics."""
    enums = facts.enums
    _check_signals(rmap, enums, diags)
    _check_overlaps(rmap, diags)
    _check_coil_bytes(rmap, diags)
    _check_link(rmap, diags)
    _check_linuxcnc(rmap, diags)
    _check_reasons(rmap, diags)
    _check_rotary(rmap, facts, diags)
    _check_st_agreement(rmap, facts, diags)
    _check_unique_st_names(rmap, diags)


# ------------------------------------------------------------- coil bytes --
def _check_coil_bytes(rmap: RegisterMap, diags: Diagnostics) -> None:
    """OpenPLC v3 applies FC15 by whole bytes (8 coils per data byte, from the start address), so a host writing
    its coils with FC15 (mb2hal) rewrites every coil of their bytes: a byte holding a host coil holds host coils
    only, and the coils LinuxCNC's mb2hal writes (those with hal) never share a byte with coils other hosts
    write."""
    by_byte: dict[int, list[Signal]] = {}
    for sig in rmap.signals:
        if sig.table == "coil":
            by_byte.setdefault(sig.address // 8, []).append(sig)
    for byte, sigs in sorted(by_byte.items()):
        host = [s for s in sigs if s.host_writable]
        if not host:
            continue
        others = [s for s in sigs if not s.host_writable]
        if others:
            diags.error(rmap.pos(others[0], "address"), f"{others[0].name}: coil {others[0].address} shares byte "
                        f"{byte} (coils {8 * byte}..{8 * byte + 7}) with the host command {host[0].name}; OpenPLC "
                        "writes coils by whole bytes", hint="give host commands bytes of their own")
        groups = {bool(s.hal) for s in host}
        if len(groups) > 1:
            first = next(s for s in host if not s.hal)
            diags.error(rmap.pos(first, "address"), f"{first.name}: coil {first.address} shares byte {byte} with "
                        "coils mb2hal writes (hal); mb2hal would clear it on OpenPLC (whole-byte FC15)",
                        hint="put coils without hal in another byte")


# ------------------------------------------------------------------ names --
def st_name_problem(name: str) -> str | None:
    """Why `name` cannot name a variable or constant MATIEC accepts, or None."""
    if not IDENT.match(name):
        return "is not an ST identifier (letter, then letters, digits, '_')"
    if "__" in name or name.endswith("_"):
        return "contains '__' or ends with '_' (rejected by MATIEC)"
    upper = name.upper()
    if upper in KEYWORDS or upper in MATIEC_RESERVED or upper in GENERIC:
        return "is a keyword to MATIEC"
    if upper in ELEMENTARY:
        return "is a type name"
    if upper in STD_FUNCS or conversion(upper) is not None:
        return "is the name of a standard function"
    if upper in {"RAMP", "PID", "HYSTERESIS", "INTEGRAL", "DERIVATIVE", "SEMA", "RTC", "BLINK"} \
            and upper in library_identifiers():
        return "is the name of an OpenPLC library function block"
    return None


def _check_unique_st_names(rmap: RegisterMap, diags: Diagnostics) -> None:
    seen: dict[str, str] = {}
    for sig in rmap.signals:
        key = sig.name.upper()
        if key in seen:
            diags.error(rmap.pos(sig, "name"), f"signal name '{sig.name}' is used twice (names are "
                        f"case-insensitive in ST)", f"first used by {seen[key]}")
        else:
            seen[key] = f"the signal at {rmap.pos(sig, 'name')}"
    for reason in rmap.reasons:
        const = rmap.reason_prefix + reason.name
        if const.upper() in seen:
            diags.error(rmap.reason_pos(reason, "name"), f"constant {const} clashes with a signal name")
    for const in link_constant_names():
        if const.upper() in seen:
            diags.error(rmap.section_pos("link"), f"generated constant {const} clashes with a signal name")


def link_constant_names() -> list[str]:
    return ["LINK_PLC_ALIVE_TOGGLE", "LINK_PLC_TIMEOUT", "LINK_HOST_HEARTBEAT_PERIOD", "LINK_HOST_TIMEOUT"]


# ---------------------------------------------------------------- signals --
def _check_signals(rmap: RegisterMap, enums: dict[str, EnumType], diags: Diagnostics) -> None:
    for sig in rmap.signals:
        problem = st_name_problem(sig.name)
        if problem:
            diags.error(rmap.pos(sig, "name"), f"signal name '{sig.name}' {problem}")
        if not _check_kind(rmap, sig, diags):
            continue
        _check_address(rmap, sig, diags)
        _check_direction(rmap, sig, diags)
        _check_enum(rmap, sig, enums, diags)
        _check_text(rmap, sig, diags)
        if sig.hal:
            _check_hal(rmap, sig, diags)


def _check_kind(rmap: RegisterMap, sig: Signal, diags: Diagnostics) -> bool:
    ok = True
    if sig.table not in TABLES:
        diags.error(rmap.pos(sig, "table"), f"{sig.name}: unknown table '{sig.table}'",
                    "one of: " + ", ".join(TABLES))
        ok = False
    if sig.direction not in DIRECTIONS:
        diags.error(rmap.pos(sig, "direction"), f"{sig.name}: unknown direction '{sig.direction}'",
                    "one of: " + ", ".join(DIRECTIONS))
        ok = False
    if sig.type not in TYPES_BIT + TYPES_16 + TYPES_32:
        diags.error(rmap.pos(sig, "type"), f"{sig.name}: type {sig.type} cannot be exchanged",
                    "BOOL, INT, UINT, WORD, DINT, UDINT, DWORD or REAL")
        ok = False
    if not ok:
        return False
    bit_table = sig.table in ("coil", "discrete_input")
    if bit_table and sig.type != "BOOL":
        diags.error(rmap.pos(sig, "type"), f"{sig.name}: a {sig.table} holds one bit, not {sig.type}",
                    "use BOOL, or a register table")
        return False
    if not bit_table and sig.type == "BOOL":
        diags.error(rmap.pos(sig, "type"), f"{sig.name}: BOOL belongs in a coil or discrete input, "
                    f"not in a {sig.table}")
        return False
    return True


def _check_address(rmap: RegisterMap, sig: Signal, diags: Diagnostics) -> None:
    a, limit = sig.address, LIMITS[sig.table]
    where = rmap.pos(sig, "address")
    if a < 0 or sig.last >= limit:
        diags.error(where, f"{sig.name}: {sig.table} {a} is outside OpenPLC's map (0..{limit - 1})")
        return
    if sig.type in TYPES_32:
        if not 2048 <= a <= 4094 or (a - 2048) % 2:
            diags.error(where, f"{sig.name}: {sig.type} takes two registers and lives in %MD only: holding "
                        f"2048..4095 at an even offset from 2048 (got {sig.table} {a})",
                        "%MDn = holding registers 2048 + 2n (high word) and 2049 + 2n (low word)")
    elif sig.table == "holding_register" and a >= 2048:
        diags.error(where, f"{sig.name}: {sig.type} is one register; holding {a} is in %MD (32-bit)",
                    "one-register values go in %QW (0..1023) or %MW (1024..2047)")
    elif iec_address(sig) is None:
        diags.error(where, f"{sig.name}: no IEC location for {sig.table} {a}")


def _check_direction(rmap: RegisterMap, sig: Signal, diags: Diagnostics) -> None:
    d = sig.direction
    if sig.table in ("discrete_input", "input_register") and d != "input":
        diags.error(rmap.pos(sig, "direction"), f"{sig.name}: {sig.table}s are physical inputs (read-only for "
                    f"host and program), direction must be input, not {d}")
    if d == "input" and sig.table not in ("discrete_input", "input_register"):
        diags.error(rmap.pos(sig, "table"), f"{sig.name}: a physical input lives in discrete_input (%IX) or "
                    f"input_register (%IW), not in {sig.table}")
    if d == "output" and not (sig.table == "coil" or (sig.table == "holding_register" and sig.address < 1024)):
        diags.error(rmap.pos(sig, "table"), f"{sig.name}: a physical output lives in a coil (%QX) or "
                    f"holding register 0..1023 (%QW)")
    if sig.host_writable and d != "host_to_plc":
        diags.error(rmap.pos(sig, "host_writable"), f"{sig.name}: host_writable is only for host_to_plc "
                    f"signals (this one is {d}): the host must not write what the PLC or the I/O drives")
    if d == "host_to_plc" and not sig.host_writable:
        diags.error(rmap.pos(sig, "direction"), f"{sig.name}: a host_to_plc signal must be host_writable = true",
                    "`plc run` refuses host writes outside the host-writable ranges")
    if sig.retained and not (sig.table == "holding_register" and sig.address >= 1024):
        diags.error(rmap.pos(sig, "retained"), f"{sig.name}: retained signals must be holding registers in "
                    f"%MW/%MD (1024..4095)", "the memory both runtimes keep: ours through [retain] registers, "
                    "OpenPLC through its persistent storage")


def _check_enum(rmap: RegisterMap, sig: Signal, enums: dict[str, EnumType], diags: Diagnostics) -> None:
    if sig.enum and sig.states:
        diags.error(rmap.pos(sig, "states"), f"{sig.name}: give either enum or states, not both")
    if sig.enum or sig.states:
        if sig.type not in ("INT", "UINT", "DINT"):
            diags.error(rmap.pos(sig, "enum" if sig.enum else "states"),
                        f"{sig.name}: an enumerated code must be an integer type, not {sig.type}")
    if sig.enum and sig.enum != "reason_codes" and sig.enum.upper() not in enums:
        diags.warning(rmap.pos(sig, "enum"), f"{sig.name}: enumeration type {sig.enum} is not declared in "
                      f"st_src/: its state names are left out of the HMI tags",
                      "declare the TYPE, or list the names with states = [...]")
    seen = set()
    for name in sig.states:
        if not IDENT.match(name):
            diags.error(rmap.pos(sig, "states"), f"{sig.name}: state name '{name}' is not an identifier")
        if name.upper() in seen:
            diags.error(rmap.pos(sig, "states"), f"{sig.name}: state name '{name}' given twice")
        seen.add(name.upper())
    if sig.scale is not None and sig.scale == 0:
        diags.error(rmap.pos(sig, "scale"), f"{sig.name}: scale 0 would hide every value")
    if sig.scale is not None and sig.type == "BOOL":
        diags.error(rmap.pos(sig, "scale"), f"{sig.name}: a BOOL has no scale")


def comment_problem(text: str) -> str | None:
    if "(*" in text or "*)" in text:
        return "contains '(*' or '*)' (it becomes an ST comment)"
    if any(not (32 <= ord(c) < 127) for c in text):
        return "contains characters outside printable ASCII"
    return None


def _check_text(rmap: RegisterMap, sig: Signal, diags: Diagnostics) -> None:
    if not sig.description.strip():
        diags.error(rmap.pos(sig, "description"), f"{sig.name}: empty description")
    problem = comment_problem(sig.description) or comment_problem(sig.unit)
    if problem:
        diags.error(rmap.pos(sig, "description"), f"{sig.name}: description or unit {problem}")
    if "," in sig.hal or any(c.isspace() for c in sig.hal):
        diags.error(rmap.pos(sig, "hal"), f"{sig.name}: hal must be one pin or signal name")


def _check_hal(rmap: RegisterMap, sig: Signal, diags: Diagnostics) -> None:
    where = rmap.pos(sig, "hal")
    if sig.direction not in ("host_to_plc", "plc_to_host"):
        diags.error(where, f"{sig.name}: only signals exchanged with the host can be wired to LinuxCNC "
                    f"(this one is {sig.direction})")
        return
    if sig.type == "DINT" and sig.direction == "plc_to_host" and "." not in sig.hal:
        pass            # two registers joined in HAL into a float signal (gen_linuxcnc)
    elif sig.type not in ("BOOL", "INT", "UINT"):
        diags.error(where, f"{sig.name}: mb2hal pins carry BOOL, INT or UINT here (and DINT read by the host into "
                    f"a bare HAL signal), not {sig.type}")
        return
    if not HAL_NAME.match(sig.hal):
        diags.error(where, f"{sig.name}: '{sig.hal}' is not a HAL pin or signal name")
        return
    if "." not in sig.hal:
        return
    pin = iov2pins.lookup(sig.hal)
    if pin is None:
        diags.error(where, f"{sig.name}: iov2 has no pin '{sig.hal}'",
                    "pins: " + ", ".join(iov2pins.PREFIX + p for p in sorted(iov2pins.PINS)))
        return
    hal_type, direction = pin
    want = "bit" if sig.type == "BOOL" else "s32"
    if hal_type != want:
        diags.error(where, f"{sig.name}: {sig.hal} is {hal_type}, the signal is {sig.type}")
    short = sig.hal[len(iov2pins.PREFIX):]
    if sig.direction == "host_to_plc" and direction != "OUT" and short not in iov2pins.OPERATOR_INPUTS:
        diags.error(where, f"{sig.name}: {sig.hal} is an iov2 input; a host_to_plc signal reads an iov2 output")
    if sig.direction == "plc_to_host" and direction != "IN":
        diags.error(where, f"{sig.name}: {sig.hal} is an iov2 output; the PLC cannot drive it")


def _check_overlaps(rmap: RegisterMap, diags: Diagnostics) -> None:
    used: dict[tuple[str, int], Signal] = {}
    for sig in rmap.signals:
        if sig.table not in TABLES:
            continue
        for a in range(sig.address, sig.last + 1):
            other = used.get((sig.table, a))
            if other is not None:
                line = sig.origin or other.origin
                fix = f"move one of them (the carousel lines: {line.file} [channels], then `plc machine generate`)" \
                    if line else None
                diags.error(rmap.pos(sig, "address"), f"{sig.name}: {sig.table} {a} is already taken by "
                            f"{other.name} at {rmap.pos(other, 'address')}", fix)
                break
            used[(sig.table, a)] = sig
    hal_users: dict[str, Signal] = {}
    for sig in rmap.signals:
        if not sig.hal:
            continue
        other = hal_users.get(sig.hal)
        if other is not None:
            diags.error(rmap.pos(sig, "hal"), f"{sig.name}: {sig.hal} is already wired to {other.name}")
        hal_users[sig.hal] = sig


# ------------------------------------------------------------ link, linuxcnc --
def _check_link(rmap: RegisterMap, diags: Diagnostics) -> None:
    link = rmap.link
    alive = rmap.signal(link.plc_alive)
    if alive is None:
        diags.error(rmap.section_pos("link", "plc_alive"), f"[link] plc_alive: no signal named {link.plc_alive}")
    elif not (alive.type == "BOOL" and alive.table == "coil" and alive.direction == "plc_to_host"):
        diags.error(rmap.section_pos("link", "plc_alive"), f"[link] plc_alive: {alive.name} must be a "
                    f"plc_to_host BOOL coil (the PLC toggles it)")
    beat = rmap.signal(link.host_heartbeat)
    if beat is None:
        diags.error(rmap.section_pos("link", "host_heartbeat"),
                    f"[link] host_heartbeat: no signal named {link.host_heartbeat}")
    elif not (beat.type in ("INT", "UINT") and beat.table == "holding_register"
              and beat.direction == "host_to_plc"):
        diags.error(rmap.section_pos("link", "host_heartbeat"), f"[link] host_heartbeat: {beat.name} must be "
                    f"a host_to_plc INT or UINT holding register (the host changes it)")
    for key in ("plc_alive_toggle_ms", "plc_timeout_ms", "host_heartbeat_period_ms", "host_timeout_ms"):
        if getattr(link, key) <= 0:
            diags.error(rmap.section_pos("link", key), f"[link] {key} must be > 0")
    if 0 < link.plc_timeout_ms < 3 * link.plc_alive_toggle_ms:
        diags.error(rmap.section_pos("link", "plc_timeout_ms"), "[link] plc_timeout_ms must be at least three "
                    "toggle periods (plc_alive_toggle_ms), or a single late scan looks like a lost link")
    if 0 < link.host_timeout_ms < 3 * link.host_heartbeat_period_ms:
        diags.error(rmap.section_pos("link", "host_timeout_ms"), "[link] host_timeout_ms must be at least three "
                    "heartbeat periods (host_heartbeat_period_ms)")


def _check_linuxcnc(rmap: RegisterMap, diags: Diagnostics) -> None:
    lc = rmap.linuxcnc
    try:
        ipaddress.IPv4Address(lc.host)
    except ValueError:
        diags.error(rmap.section_pos("linuxcnc", "host"), f"[linuxcnc] host {lc.host!r} is not an IPv4 address")
    if not 1 <= lc.port <= 65535:
        diags.error(rmap.section_pos("linuxcnc", "port"), "[linuxcnc] port must be 1..65535")
    if not 0 <= lc.slave_id <= 247:
        diags.error(rmap.section_pos("linuxcnc", "slave_id"), "[linuxcnc] slave_id must be 0..247")
    if lc.update_rate_hz <= 0:
        diags.error(rmap.section_pos("linuxcnc", "update_rate_hz"), "[linuxcnc] update_rate_hz must be > 0 "
                    "(0 would make mb2hal poll as fast as it can and settle_s meaningless)")
    elif lc.settle_s < 1.0 / lc.update_rate_hz:
        diags.error(rmap.section_pos("linuxcnc", "settle_s"), f"[linuxcnc] settle_s ({lc.settle_s} s) must be "
                    f"at least one mb2hal pass (1 / update_rate_hz = {1.0 / lc.update_rate_hz:.3f} s)",
                    "otherwise a request bit can reach the PLC before the numbers that go with it")
    if lc.response_timeout_ms <= 0:
        diags.error(rmap.section_pos("linuxcnc", "response_timeout_ms"), "[linuxcnc] response_timeout_ms "
                    "must be > 0")
    if not HAL_NAME.match(lc.component) or not HAL_NAME.match(lc.thread):
        diags.error(rmap.section_pos("linuxcnc"), "[linuxcnc] component and thread must be HAL names")
    if lc.estop_chain and (not HAL_NAME.match(lc.estop_chain) or "." in lc.estop_chain):
        diags.error(rmap.section_pos("linuxcnc", "estop_chain"), "[linuxcnc] estop_chain must be a HAL signal "
                    "name (the machine HAL's E-stop chain), or \"\" to use iocontrol.0.user-enable-out")
    for key in ("settle", "settle_fall"):
        for name in getattr(lc, key):
            sig = rmap.signal(name) if isinstance(name, str) else None
            if sig is None:
                diags.error(rmap.section_pos("linuxcnc", key), f"[linuxcnc] {key}: no signal named {name!r}")
            elif sig.type != "BOOL" or not sig.hal:
                diags.error(rmap.section_pos("linuxcnc", key), f"[linuxcnc] {key}: {name} must be a BOOL "
                            f"signal wired to LinuxCNC (hal = ...)")
    both = {n.upper() for n in lc.settle if isinstance(n, str)} & {n.upper() for n in lc.settle_fall
                                                                    if isinstance(n, str)}
    if both:
        diags.error(rmap.section_pos("linuxcnc", "settle_fall"), f"[linuxcnc] {', '.join(sorted(both))} in both "
                    "settle and settle_fall")
    plan(rmap, diags)


# ----------------------------------------------------------------- reasons --
def _check_reasons(rmap: RegisterMap, diags: Diagnostics) -> None:
    codes: dict[int, str] = {}
    names: dict[str, str] = {}
    for r in rmap.reasons:
        where = rmap.reason_pos(r, "code")
        if not -32768 <= r.code <= 32767:
            diags.error(where, f"reason {r.name}: code {r.code} does not fit an INT register (-32768..32767)")
        if r.code in codes:
            diags.error(where, f"reason {r.name}: code {r.code} is already used by {codes[r.code]}")
        codes.setdefault(r.code, r.name)
        if not re.match(r"^[A-Z][A-Z0-9]*(_[A-Z0-9]+)*$", r.name):
            diags.error(rmap.reason_pos(r, "name"), f"reason name '{r.name}' must be UPPER_SNAKE_CASE")
        elif st_name_problem(rmap.reason_prefix + r.name):
            diags.error(rmap.reason_pos(r, "name"), f"constant {rmap.reason_prefix + r.name} "
                        f"{st_name_problem(rmap.reason_prefix + r.name)}")
        if r.name in names:
            diags.error(rmap.reason_pos(r, "name"), f"reason name {r.name} is already used by code {names[r.name]}")
        names.setdefault(r.name, str(r.code))
        want = "none" if r.code == 0 else "hard" if r.code < 0 else "soft"
        if r.severity not in SEVERITIES:
            diags.error(rmap.reason_pos(r, "severity"), f"reason {r.name}: severity must be none, hard or soft")
        elif r.severity != want:
            diags.error(rmap.reason_pos(r, "severity"), f"reason {r.name}: code {r.code} is {want} "
                        f"(< 0 hard: program aborts; > 0 soft: program continues; 0 none), not {r.severity}")
        problem = comment_problem(r.text)
        if problem:
            diags.error(rmap.reason_pos(r, "text"), f"reason {r.name}: text {problem}")
        if not r.text.strip() or len(r.text) > MAX_TEXT:
            diags.error(rmap.reason_pos(r, "text"), f"reason {r.name}: text must be 1..{MAX_TEXT} characters "
                        f"(one operator message line), has {len(r.text)}")
        if r.source not in ("", "application", "link", "rotary", "sequence"):
            diags.error(rmap.reason_pos(r, "source"), f"reason {r.name}: unknown source '{r.source}'",
                        "application, link, rotary or sequence")
    if 0 not in codes:
        diags.error(rmap.reasons_file_pos(), "reason codes: code 0 (no fault, severity none) must be listed")


def rotary_reason_code(error_id: int) -> int:
    """The documented rule: ErrorID 16#0GII of FB_RotaryPositioner -> reason -(300 + 10*(G-1) + II)."""
    group, index = error_id >> 8, error_id & 0xFF
    return -(300 + 10 * (group - 1) + index)


def _check_st_agreement(rmap: RegisterMap, facts: StFacts, diags: Diagnostics) -> None:
    """The ST copies of the numbers (constants, CASE tables) agree with the table, and nothing is missing."""
    named = set()
    for r in rmap.reasons:
        if r.st_constant:
            key = r.st_constant.upper()
            named.add(key)
            found = facts.constants.get(key)
            if found is None:
                diags.error(rmap.reason_pos(r, "st_constant"), f"reason {r.name}: no VAR CONSTANT {r.st_constant} "
                            f"in st_src/")
            elif found[0] != r.code:
                diags.error(rmap.reason_pos(r, "st_constant"), f"reason {r.name}: {r.st_constant} is {found[0]} "
                            f"in {found[1]}, the table says {r.code}")
        if r.st_case:
            func, _, label = r.st_case.partition(":")
            table = facts.cases.get(func.upper())
            if table is None or not label:
                diags.error(rmap.reason_pos(r, "st_case"), f"reason {r.name}: no CASE mapping function {func} "
                            f"in st_src/ (st_case = \"F_Function:EnumValue\")")
            elif label.upper() not in table:
                diags.error(rmap.reason_pos(r, "st_case"), f"reason {r.name}: {func} has no branch for {label}")
            elif table[label.upper()] != r.code:
                diags.error(rmap.reason_pos(r, "st_case"), f"reason {r.name}: {func} gives "
                            f"{table[label.upper()]} for {label}, the table says {r.code}")
    generated = {f"{rmap.program}.{rmap.reason_prefix}{r.name}".upper() for r in rmap.reasons}
    for key, (value, pos) in sorted(facts.constants.items()):
        name = key.split(".", 1)[1]
        if name.startswith("REASON") and key not in named and key not in generated and value != 0:
            diags.error(pos, f"reason constant {key.split('.')[0]}.{name} = {value} is not in "
                        f"{rmap.reasons_file_pos().file}", "add a [[reason]] with st_constant = "
                        f"\"{key}\" (one table for every reason code)")
    seq_fault = facts.enums.get("E_SEQFAULT")
    if seq_fault is not None and "F_SEQREASONCODE" in facts.cases:
        covered = {r.st_case.partition(":")[2].upper() for r in rmap.reasons if r.st_case}
        for value in seq_fault.values[1:]:
            if value.upper() not in covered:
                diags.error(rmap.reasons_file_pos(), f"reason codes: E_SeqFault value {value} has no reason code",
                            f"add a [[reason]] with st_case = \"F_SeqReasonCode:{value}\"")


def _check_rotary(rmap: RegisterMap, facts: StFacts, diags: Diagnostics) -> None:
    rotary = facts.enums.get("E_ROTARYERROR")
    ids = facts.cases.get("F_ROTARYERRORID", {})
    covered = set()
    for r in rmap.reasons:
        if r.source != "rotary" and not r.rotary_error:
            continue
        where = rmap.reason_pos(r, "rotary_error")
        if not r.rotary_error or r.error_id is None:
            diags.error(where, f"reason {r.name}: a rotary reason needs rotary_error and error_id")
            continue
        if rotary is not None and r.rotary_error not in rotary.values:
            diags.error(where, f"reason {r.name}: {r.rotary_error} is not a value of E_RotaryError",
                        "values: " + ", ".join(rotary.values))
        covered.add(r.rotary_error)
        if ids.get(r.rotary_error.upper()) not in (None, r.error_id):
            diags.error(rmap.reason_pos(r, "error_id"), f"reason {r.name}: F_RotaryErrorId gives "
                        f"16#{ids[r.rotary_error.upper()]:04X} for {r.rotary_error}, not 16#{r.error_id:04X}")
        if r.code != rotary_reason_code(r.error_id):
            diags.error(rmap.reason_pos(r, "code"), f"reason {r.name}: ErrorID 16#{r.error_id:04X} is reason "
                        f"{rotary_reason_code(r.error_id)} by the documented rule, not {r.code}",
                        "16#0GII -> -(300 + 10*(G-1) + II)")
    if rotary is not None:
        for value in rotary.values[1:]:
            if value not in covered:
                diags.error(rmap.reasons_file_pos(), f"reason codes: E_RotaryError value {value} has no reason code",
                            f"add a [[reason]] with source = \"rotary\", rotary_error = \"{value}\"")
