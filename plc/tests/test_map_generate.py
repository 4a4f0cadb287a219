"""What `plc map generate` writes: the PROGRAM's located declarations, HMI tags, the LinuxCNC files, the map
document and the runtime configuration, each checked against the map (not against a copy of itself)."""
from __future__ import annotations

import configparser
import csv
import io
import json
import re
from itertools import pairwise
from pathlib import Path

import pytest

from code_rules import parse_st, parse_st_files, st_enum_values
from plc import ast as A
from plc.diagnostics import Diagnostics
from plc.driver import compile_sources
from atc.map import gen_st, iov2pins
from atc.map.gen_linuxcnc import plan
from atc.map.generate import load_and_check, outputs
from atc.map.model import iec_address
from plc.parser import parse
from plc.runtime import RunConfig, apply_application, load_config

from atc.runsetup import runtime_setup

REPO = Path(__file__).resolve().parents[2]
LOADED = load_and_check(REPO / "modbus_map" / "map.toml", Diagnostics())
RMAP = LOADED.rmap
OUT = outputs(LOADED)


def test_region_declares_every_signal_once_at_its_openplc_address():
    tree = parse("PROGRAM X\n" + gen_st.region(RMAP) + "END_PROGRAM\n", "region", Diagnostics())
    located = {d.name: d.location.text for pou in tree.items for d in pou.decls() if d.location is not None}
    assert located == {s.name.upper(): iec_address(s) for s in RMAP.signals}


def test_region_var_blocks_are_all_located_or_all_constant():
    tree = parse("PROGRAM X\n" + gen_st.region(RMAP) + "END_PROGRAM\n", "region", Diagnostics())
    for block in tree.items[0].blocks:
        if block.constant:
            assert all(d.location is None for d in block.decls)
        else:
            assert all(d.location is not None for d in block.decls)
        retained = {d.name for d in block.decls} & {s.name.upper() for s in RMAP.signals if s.retained}
        assert block.retain == bool(retained)
        assert not block.retain or len(retained) == len(block.decls)


def test_region_constants_hold_every_reason_code_and_the_link_timing():
    tree = parse("PROGRAM X\n" + gen_st.region(RMAP) + "END_PROGRAM\n", "region", Diagnostics())
    consts = {d.name: d.init for b in tree.items[0].blocks if b.constant for d in b.decls}
    for r in RMAP.reasons:
        init = consts[f"REASON_{r.name}"]
        value = -init.operand.value if isinstance(init, A.Unary) else init.value
        assert value == r.code
    assert consts["LINK_HOST_TIMEOUT"].text == f"{RMAP.link.host_timeout_ms}ms"


def test_the_program_with_its_region_compiles_for_openplc_without_warnings():
    result = compile_sources([REPO / "st_src"], target="openplc", generate=False)
    assert [d.render() for d in result.diags.items if d.severity in ("error", "warning")] == []


def test_hmi_csv_has_one_row_per_signal_with_access_from_the_host_side():
    rows = list(csv.DictReader(io.StringIO(OUT["hmi_tags/atc_tags.csv"])))
    assert [r["name"] for r in rows] == [s.name for s in RMAP.signals]
    for row, sig in zip(rows, RMAP.signals, strict=True):
        assert row["access"] == ("RW" if sig.direction == "host_to_plc" else "R")
        assert int(row["address"]) == sig.address and row["iec_address"] == iec_address(sig)


def test_hmi_json_names_the_states_of_enumerated_signals():
    doc = json.loads(OUT["hmi_tags/atc_tags.json"])
    tags = {t["name"]: t for t in doc["tags"]}
    assert [s["name"] for s in tags["IovState"]["states"]] == ["IDLE", "PREPARING", "START_CHANGE", "CHANGING",
                                                                "WAITING_FOR_ABORT_ACK"]
    declared = st_enum_values(parse_st_files([REPO / "st_src" / "app" / "E_AtcState.st"], REPO), "E_AtcState")
    assert len(declared) > 5 and [s["name"] for s in tags["ChangerState"]["states"]] == declared
    reasons = {s["value"]: s["name"] for s in tags["ToolchangerReason"]["states"]}
    assert reasons == {r.code: r.name for r in RMAP.reasons}
    assert {r["code"] for r in doc["reason_codes"]} == {r.code for r in RMAP.reasons}
    assert tags["MbxX"]["scale"] == 0.001


def test_the_states_are_read_from_the_enum_declaration_not_its_text():
    tree = parse_st("TYPE\n    E_Run : (Idle (* first (x) *), Busy, (* a comment, Gone *) Done);\nEND_TYPE\n", "e.st")
    assert st_enum_values([tree], "E_Run") == ["Idle", "Busy", "Done"]


def _ini() -> configparser.ConfigParser:
    ini = configparser.ConfigParser(interpolation=None)
    ini.optionxform = str
    ini.read_string(OUT["configs/linuxcnc/atc_mb2hal.ini"])
    return ini


def test_mb2hal_writes_numbers_then_bits_then_reads_bits_then_numbers():
    ini = _ini()
    n = int(ini["MB2HAL_INIT"]["TOTAL_TRANSACTIONS"])
    codes = [ini[f"TRANSACTION_{i:02d}"]["MB_TX_CODE"] for i in range(n)]
    rank = {"fnct_16_write_multiple_registers": 0, "fnct_15_write_multiple_coils": 1,
            "fnct_01_read_coils": 2, "fnct_03_read_holding_registers": 3}
    assert [rank[c] for c in codes] == sorted(rank[c] for c in codes)
    assert codes.count("fnct_15_write_multiple_coils") == 1          # each direction's bits in one transaction
    assert ini["TRANSACTION_00"]["TCP_IP"] == "127.0.0.1" and ini["TRANSACTION_00"]["TCP_PORT"] == "5020"


def test_mb2hal_transactions_cover_exactly_the_wired_signals_at_their_addresses():
    ini = _ini()
    seen = {}
    for i in range(int(ini["MB2HAL_INIT"]["TOTAL_TRANSACTIONS"])):
        tx = ini[f"TRANSACTION_{i:02d}"]
        first = int(tx["FIRST_ELEMENT"])
        for k, name in enumerate(tx["PIN_NAMES"].split(",")):
            if not re.fullmatch(r"u[0-9]+", name):
                seen[name] = first + k
        if "write" in tx["MB_TX_CODE"]:
            assert not any(re.fullmatch(r"u[0-9]+", n) for n in tx["PIN_NAMES"].split(","))
        assert len("PIN_NAMES=" + tx["PIN_NAMES"]) <= 254, "LinuxCNC 2.9 reads 255 characters of a line"
    want = {}
    for s in RMAP.signals:
        if s.hal and s.type == "DINT":          # two registers, high word first: pins <name>-hi, <name>-lo
            want[f"{s.name}-hi"], want[f"{s.name}-lo"] = s.address, s.address + 1
        elif s.hal:
            want[s.name] = s.address
    assert seen == want


def test_a_dint_read_by_linuxcnc_is_joined_signed_and_scaled_in_hal():
    """MbxZ (DINT, thousandths): hi * 65536 + lo in a sum2, then a lincurve to the signed value times 0.001."""
    hal = OUT["configs/linuxcnc/atc_iov2.hal"]
    assert "net atc-mbx-z-hi mb2hal.atc-words-in-3.MbxZ-hi.float => atc-join-mbx-z.in0" in hal
    assert "net atc-mbx-z-lo mb2hal.atc-words-in-3.MbxZ-lo.float => atc-join-mbx-z.in1" in hal
    assert "setp atc-join-mbx-z.gain0 65536" in hal
    points = dict(re.findall(r"setp atc-sign-mbx-z\.x-val-(\d\d) (\S+)", hal))
    values = dict(re.findall(r"setp atc-sign-mbx-z\.y-val-(\d\d) (\S+)", hal))
    curve = sorted((float(points[k]), float(values[k])) for k in points)

    def through(raw: int) -> float:             # lincurve: linear between the points
        for (x0, y0), (x1, y1) in pairwise(curve):
            if x0 <= raw <= x1:
                return y0 + (raw - x0) * (y1 - y0) / (x1 - x0)
        raise AssertionError(raw)
    for value in (-50000, -5000, -1, 0, 1, 20000, 2147483647):
        raw = value & 0xFFFFFFFF
        assert abs(through((raw >> 16) * 65536 + (raw & 0xFFFF)) - value / 1000) < 1e-6, value


def _hal(rel: str) -> list[list[str]]:
    lines = []
    for line in OUT[rel].splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            lines.append(line.split())
    return lines


def _mb2hal_pins() -> dict[str, str]:
    """Every pin mb2hal creates for the INI (name -> direction seen from HAL: 'IN' or 'OUT')."""
    pins = {}
    for tx in plan(RMAP):
        for name, _sig in tx.pins:
            base = f"mb2hal.{tx.name}.{name}"
            if tx.bits:
                pins[f"{base}.bit"] = "IN" if tx.writes else "OUT"
                if not tx.writes:
                    pins[f"{base}.bit-inv"] = "OUT"
            else:
                pins[f"{base}.int"] = pins[f"{base}.float"] = "IN" if tx.writes else "OUT"
    return pins


@pytest.mark.parametrize("rel,pins", [("configs/linuxcnc/atc_iov2.hal", None),
                                      ("configs/linuxcnc/atc_io.hal", iov2pins.V1_PINS)])
def test_hal_nets_use_existing_pins_and_every_iov2_input_has_one_writer(rel, pins):
    mb = _mb2hal_pins()
    loaded = {}
    added = set()
    writers: dict[str, list[str]] = {}
    for words in _hal(rel):
        if words[0] == "loadrt":
            loaded[words[1]] = [n for w in words[2:] if w.startswith("names=") for n in w[6:].split(",")]
        elif words[0] == "addf":
            added.add(words[1].removesuffix(".update"))
        elif words[0] == "net":
            for pin in (w for w in words[2:] if w not in ("=>", "<=")):
                if pin.startswith("mb2hal."):
                    assert pin in mb, f"{rel}: mb2hal has no pin {pin}"
                    if mb[pin] == "OUT":
                        writers.setdefault(words[1], []).append(pin)
                elif pin.startswith(iov2pins.PREFIX):
                    short = pin[len(iov2pins.PREFIX):]
                    assert (pins or iov2pins.PINS).__contains__(short), f"{rel}: no pin {pin} in this variant"
                    if iov2pins.PINS[short][1] == "OUT":
                        writers.setdefault(words[1], []).append(pin)
                else:
                    instance = pin.rsplit(".", 1)[0]
                    assert any(instance in names for names in loaded.values()), f"{rel}: {pin} of nothing loaded"
                    if pin.endswith(".out") or pin.endswith(".sawtooth"):
                        writers.setdefault(words[1], []).append(pin)
    assert all(len(w) == 1 for w in writers.values()), writers
    assert {n for names in loaded.values() for n in names} == added


def _lincurve(rel: str, name: str):
    points = {}
    for words in _hal(rel):
        if words[0] == "setp" and words[1].startswith(f"{name}."):
            kind, k = words[1][len(name) + 1:].split("-val-")
            points.setdefault(int(k), {})[kind] = float(words[2])
    xs = [points[k]["x"] for k in sorted(points)]
    ys = [points[k]["y"] for k in sorted(points)]

    def f(x: float) -> float:               # lincurve: piecewise linear, clamped at both ends
        if x <= xs[0]:
            return ys[0]
        for (x0, y0), (x1, y1) in pairwise(zip(xs, ys, strict=True)):
            if x <= x1:
                return y0 + (x - x0) * (y1 - y0) / (x1 - x0)
        return ys[-1]
    return f


def test_the_sign_chain_turns_every_unsigned_register_value_into_its_int16():
    f = _lincurve("configs/linuxcnc/atc_iov2.hal", "atc-sign-toolchanger-reason")
    for raw in range(65536):
        assert f(float(raw)) == (raw - 65536 if raw >= 32768 else raw)


def test_hal_settles_the_request_bits_and_watches_the_plc_link():
    text = OUT["configs/linuxcnc/atc_iov2.hal"]
    for sig in RMAP.linuxcnc.settle:
        name = "atc-settle-" + re.sub(r"(?<!^)([A-Z])", r"-\1", sig).lower()
        assert f"setp {name}.on-delay {RMAP.linuxcnc.settle_s}" in text
        assert f"setp {name}.off-delay 0" in text
    assert "net atc-tool-prepare-settled atc-settle-tool-prepare.out => mb2hal.atc-bits-out.ToolPrepare.bit" in text
    assert f"setp atc-link-watch.width {RMAP.link.plc_timeout_ms / 1000}" in text
    assert "net atc-estop-ok atc-estop-and.out => iocontrol.0.emc-enable-in" in text
    assert "net atc-plc-alive mb2hal.atc-bits-in.PlcAlive.bit => atc-link-watch.in" in text


def test_a_run_allows_writes_only_to_host_signals_and_keeps_the_retained(tmp_path):
    """Issue 26: the map's ranges reach a run through the application's run setup, never written into the
    user's run configuration; a range the user's file sets is the user's."""
    setup = runtime_setup(REPO / "modbus_map" / "map.toml", tmp_path)
    cfg = RunConfig()
    apply_application(cfg, setup, "test")
    own = tmp_path / "own.toml"
    own.write_text('[modbus]\nwritable_registers = ["512"]\n')
    mine = load_config(own)
    apply_application(mine, setup, own)
    assert mine.writable_registers == ["512-512"] and mine.writable_coils == cfg.writable_coils
    assert not any(key in (REPO / "machines" / "default" / "runtime.toml").read_text()
                   for key in ("writable_coils", "writable_registers", "registers ="))

    def expand(ranges):
        out = set()
        for r in ranges:
            lo, _, hi = r.partition("-")
            out |= set(range(int(lo), int(hi or lo) + 1))
        return out
    host = [s for s in RMAP.signals if s.direction == "host_to_plc"]
    # coils by whole bytes (OpenPLC applies FC15 so); `plc map check` keeps other signals out of those bytes
    assert expand(cfg.writable_coils) == {a for s in host if s.table == "coil"
                                          for a in range(s.address // 8 * 8, s.address // 8 * 8 + 8)}
    coils = {s.address: s for s in RMAP.signals if s.table == "coil"}
    assert all(coils[a].direction == "host_to_plc" for a in expand(cfg.writable_coils) if a in coils)
    assert expand(cfg.writable_registers) == {a for s in host if s.table == "holding_register"
                                              for a in range(s.address, s.last + 1)}
    assert expand(cfg.retain_registers) == {a for s in RMAP.signals if s.retained
                                            for a in range(s.address, s.last + 1)}


def test_the_map_document_lists_every_signal_and_reason_code():
    doc = OUT["docs/register-map.md"]
    for sig in RMAP.signals:
        assert f"| `{sig.name}` |" in doc and f"`{iec_address(sig)}`" in doc
    for r in RMAP.reasons:
        assert f"| {r.code} | `{r.name}` | {r.severity} |" in doc
