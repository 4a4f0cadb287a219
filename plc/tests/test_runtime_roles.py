"""Roles of Modbus/TCP clients (read, host, engineer) and the audit of Modbus writes, with pymodbus as the
independent client over plain TCP (issue 35 points 1 and 3).

The runtime is started with one allowlist entry per role (127.0.0.2 read, 127.0.0.3 host, 127.0.0.4 engineer),
a host range narrower than the writable one, and an audit file. Runs against the plain build, or the ASan/UBSan
build with PLC_RUNTIME_SANITIZE=1. No verdict depends on the machine's speed: what must not have happened is
checked after whole scans (h.wait_scans), and the audit's rate bound is counted in lines, not timed.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import rt_harness as h

pytest.importorskip("pymodbus", reason="pymodbus is a test dependency (pip install -e 'plc[test]')")
from pymodbus.client import ModbusTcpClient

READ, HOST, ENGINEER = "127.0.0.2", "127.0.0.3", "127.0.0.4"
COMMAND_COIL = 400                    # %QX50.0: in the host range
COMMAND_REGISTER = 520                # %QW520: in the host range
ENGINEERING_REGISTER = 1024 + 300     # %MW300: writable, outside the host range
ENGINEERING_COIL = 700                # %QX87.4: writable, outside the host range
ROLE_ARGS = ["--no-rt", "--allow", f"{READ}=read,{HOST}=host,{ENGINEER}",
             "--host-coils", "400-407", "--host-registers", "512-527"]


@pytest.fixture(scope="module")
def binary() -> Path:
    return h.runtime_binary()


def client(port: int, source: str) -> ModbusTcpClient:
    c = ModbusTcpClient("127.0.0.1", port=port, source_address=(source, 0), timeout=3 * h.SLOW, retries=0)
    assert c.connect(), f"pymodbus could not connect from {source}"
    return c


def exception_code(response) -> int | None:
    """The Modbus exception code of a pymodbus response, None when it was served."""
    return response.exception_code if response.isError() else None


WRITES = {        # every write function code, each as a pymodbus call on one address of each kind
    "fc5": lambda c, a: c.write_coil(a, True),
    "fc6": lambda c, a: c.write_register(a, 77),
    "fc15": lambda c, a: c.write_coils(a, [True, False, True]),
    "fc16": lambda c, a: c.write_registers(a, [77, 78]),
    "fc22": lambda c, a: c.mask_write_register(address=a, and_mask=0, or_mask=77),
    "fc23": lambda c, a: c.readwrite_registers(read_address=a, read_count=1, write_address=a, values=[77]),
}


def test_a_read_client_reads_and_every_write_function_code_is_refused_with_exception_01(binary, tmp_path):
    audit = tmp_path / "audit.log"
    with h.Runtime(binary, *ROLE_ARGS, "--audit", str(audit)) as rt, h.Client(rt.port, source=ENGINEER) as eng:
        rt.wait_for(r"clients allowed from 127\.0\.0\.2/32 as read, 127\.0\.0\.3/32 as host, 127\.0\.0\.4/32")
        c = client(rt.port, READ)
        try:
            assert c.read_holding_registers(1024 + 30).registers == [4242]      # %MW30, set by the program
            assert len(c.read_coils(0, count=8).bits) >= 8
            assert len(c.read_input_registers(h.DIAG_BASE, count=4).registers) == 4
            for name, write in WRITES.items():
                coil = name in ("fc5", "fc15")
                for addr in ([COMMAND_COIL, ENGINEERING_COIL] if coil else [COMMAND_REGISTER, ENGINEERING_REGISTER]):
                    assert exception_code(write(c, addr)) == h.MODBUS_EXCEPTION_ILLEGAL_FUNCTION, (name, addr)
            h.wait_scans(eng)                        # whole scans after the refusals: nothing was queued
            assert eng.read_coils(COMMAND_COIL, 3) == [False] * 3
            assert eng.read_coils(ENGINEERING_COIL, 3) == [False] * 3
            assert eng.read_holding(COMMAND_REGISTER, 2) == [0, 0]
            assert eng.read_holding(ENGINEERING_REGISTER, 2) == [0, 0]
            diag = h.read_diag(eng)
            assert diag["writes_refused"] == 12 and diag["writes"] == 0, diag
        finally:
            c.close()
        # its own line, or the second's summary line
        rt.wait_for(r"connected.*127\.0\.0\.2:\d+, \d+ of \d+, role read\]"
                    r"|client 127\.0\.0\.2:\d+ connected \[\d+ of \d+, role read\]")
        rt.wait_for(r"modbus: client 127\.0\.0\.2:\d+ write refused \[role read, fc=5 coil 400 count=1: exception 01, "
                    r"role read writes nothing\]")
    text = audit.read_text()
    lines = [ln for ln in text.splitlines() if " modbus peer=127.0.0.2:" in ln]
    assert len(lines) == 12, text
    assert all(" role=read " in ln and "-> refused: exception 01 ILLEGAL FUNCTION" in ln for ln in lines), text
    assert re.search(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z modbus peer=127\.0\.0\.2:\d+ role=read fc=16 "
                     r"registers 520-521 count=2 -> refused: exception 01 ILLEGAL FUNCTION \(role read writes "
                     r"nothing\)$", text, re.M), text


def test_a_host_writes_command_signals_and_is_refused_an_engineering_register_an_engineer_writes_both(binary,
                                                                                                   tmp_path):
    audit = tmp_path / "audit.log"
    with h.Runtime(binary, *ROLE_ARGS, "--audit", str(audit)) as rt, h.Client(rt.port, source=ENGINEER) as eng:
        host = client(rt.port, HOST)
        engineer = client(rt.port, ENGINEER)
        try:
            assert exception_code(host.write_coil(COMMAND_COIL, True)) is None
            assert exception_code(host.write_registers(COMMAND_REGISTER, [11, 12])) is None
            assert exception_code(host.write_register(ENGINEERING_REGISTER, 5)) == \
                h.MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS
            assert exception_code(host.write_coil(ENGINEERING_COIL, True)) == h.MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS
            # a multiple write reaching out of the host range is refused whole: nothing of it is applied
            assert exception_code(host.write_registers(526, [21, 22, 23])) == h.MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS
            assert exception_code(host.write_coils(406, [True, True, True])) == h.MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS
            h.wait_scans(eng)
            assert eng.read_coils(COMMAND_COIL) == [True]
            assert eng.read_holding(COMMAND_REGISTER, 2) == [11, 12]
            assert eng.read_holding(ENGINEERING_REGISTER) == [0] and eng.read_coils(ENGINEERING_COIL) == [False]
            assert eng.read_holding(526, 3) == [0, 0, 0] and eng.read_coils(406, 3) == [False] * 3

            assert exception_code(engineer.write_register(COMMAND_REGISTER, 31)) is None
            assert exception_code(engineer.write_register(ENGINEERING_REGISTER, 32)) is None
            assert exception_code(engineer.write_coils(ENGINEERING_COIL, [True, True])) is None
            assert exception_code(engineer.write_registers(526, [21, 22, 23])) is None
            h.wait_scans(eng)
            assert eng.read_holding(COMMAND_REGISTER) == [31] and eng.read_holding(ENGINEERING_REGISTER) == [32]
            assert eng.read_coils(ENGINEERING_COIL, 2) == [True, True] and eng.read_holding(526, 3) == [21, 22, 23]
            diag = h.read_diag(eng)
            assert (diag["writes"], diag["writes_refused"]) == (6, 4), diag
        finally:
            host.close()
            engineer.close()
        rt.wait_for(r"client 127\.0\.0\.3:\d+ write refused \[role host, fc=6 register 1324 count=1: exception 02, "
                    r"outside the host ranges: an engineer's\]")
    text = audit.read_text()
    for pattern in (r"peer=127\.0\.0\.3:\d+ role=host fc=5 coil 400 count=1 -> ok$",
                    r"peer=127\.0\.0\.3:\d+ role=host fc=16 registers 520-521 count=2 -> ok$",
                    r"peer=127\.0\.0\.3:\d+ role=host fc=6 register 1324 count=1 -> refused: exception 02 ILLEGAL "
                    r"DATA ADDRESS \(outside the host ranges: an engineer's\)$",
                    r"peer=127\.0\.0\.3:\d+ role=host fc=16 registers 526-528 count=3 -> refused: exception 02",
                    r"peer=127\.0\.0\.4:\d+ role=engineer fc=6 register 1324 count=1 -> ok$",
                    r"peer=127\.0\.0\.4:\d+ role=engineer fc=15 coils 700-701 count=2 -> ok$"):
        assert re.search(pattern, text, re.M), f"{pattern!r} not in the audit file:\n{text}"


def test_a_client_no_entry_holds_is_refused_and_the_longest_prefix_decides(binary):
    with h.Runtime(binary, "--no-rt", "--allow", "127.0.0.0/24=read,127.0.0.5=host") as rt:
        narrow, wide = client(rt.port, "127.0.0.5"), client(rt.port, "127.0.0.6")
        try:
            assert exception_code(narrow.write_coil(COMMAND_COIL, True)) is None
            assert exception_code(wide.write_coil(COMMAND_COIL, True)) == h.MODBUS_EXCEPTION_ILLEGAL_FUNCTION
        finally:
            narrow.close()
            wide.close()
        with pytest.raises(ConnectionError):
            with h.Client(rt.port, source="127.0.1.1") as c:
                c.read_holding(1024 + 30)
        rt.wait_for(r"client 127\.0\.1\.1:\d+ refused: address not in the allowlist")


def test_without_an_allowlist_every_client_is_an_engineer_as_before(binary):
    with h.Runtime(binary, "--no-rt") as rt:
        c = client(rt.port, "127.0.0.1")
        try:
            assert exception_code(c.write_register(ENGINEERING_REGISTER, 9)) is None
            assert exception_code(c.write_coil(COMMAND_COIL, True)) is None
        finally:
            c.close()
        rt.wait_for(r"client 127\.0\.0\.1:\d+ connected \[\d+ of \d+, role engineer\]")


def test_a_write_burst_is_itemised_up_to_the_bound_and_summed_up_beyond_it(binary, tmp_path):
    """MODBUS_AUDIT_PER_S (50) itemised lines a second at most: 400 writes give at most 50 lines per second of the
    burst plus one summary line per second, and the summaries count every write that was not itemised."""
    audit = tmp_path / "audit.log"
    n = 400
    with h.Runtime(binary, *ROLE_ARGS, "--audit", str(audit)) as rt:
        c = client(rt.port, HOST)
        try:
            for i in range(n):
                addr = COMMAND_REGISTER if i % 4 else ENGINEERING_REGISTER       # a quarter refused
                c.write_register(addr, i)
        finally:
            c.close()
    text = audit.read_text()
    items = [ln for ln in text.splitlines() if " modbus peer=" in ln]
    summaries = [re.search(r"modbus (\d+) more write requests in [\d.]+ s not itemised \(at most 50 lines a second\):"
                           r" (\d+) served, (\d+) refused; the last: peer=127\.0\.0\.3", ln)
                 for ln in text.splitlines() if " more write requests " in ln]
    assert summaries and all(summaries), text
    held = sum(int(m.group(1)) for m in summaries)
    assert held == sum(int(m.group(2)) + int(m.group(3)) for m in summaries)
    assert len(items) + held == n, text                       # every write itemised or counted, none lost
    refused = sum(1 for ln in items if "-> refused" in ln) + sum(int(m.group(3)) for m in summaries)
    assert refused == n // 4
    # the bound: no window of itemised lines holds more than 50 (each summary closes one window)
    run = 0
    for ln in text.splitlines():
        if " more write requests " in ln:
            run = 0
        elif " modbus peer=" in ln:
            run += 1
            assert run <= 50, text


def test_a_bad_role_on_the_command_line_is_a_usage_error(binary):
    cases = {"127.0.0.1=admin": "--allow: 'admin' is not a role (read, host or engineer)",
             "127.0.0.1=read,127.0.0.1=host": "--allow: 127.0.0.1/32 is given two roles (read and host)",
             "10.0.0.0/33=read": "--allow: '33' is not a prefix length 0..32"}
    for allow, message in cases.items():
        result = h.subprocess.run([str(binary), "--allow", allow], capture_output=True, text=True, timeout=30 * h.SLOW)
        assert result.returncode == 2, result.stderr
        assert message in result.stderr and "(expected ADDR[/BITS][=read|host|engineer], ...)" in result.stderr


# ------------------------------------------------------------------- the run configuration

def test_the_run_configuration_gives_roles_and_reports_a_bad_one_at_its_key(tmp_path):
    from plc import runtime
    from plc.extensions import RunSetup
    good = tmp_path / "good.toml"
    good.write_text('[modbus]\nallow = ["127.0.0.1"]\n\n[[modbus.client]]\naddress = "192.168.1.0/24"\nrole = "read"\n'
                    '\n[[modbus.client]]\naddress = "192.168.1.20"\nrole = "host"\n')
    cfg = runtime.load_config(good)
    runtime.apply_application(cfg, RunSetup(writable_coils=["400-423"], writable_registers=["512-534"]), good)
    argv = runtime.runtime_argv(Path("plc-runtime"), cfg)
    assert argv[argv.index("--allow") + 1] == "127.0.0.1/32,192.168.1.0/24=read,192.168.1.20/32=host"
    assert argv[argv.index("--host-coils") + 1] == "400-423"            # the application's command signals
    assert argv[argv.index("--host-registers") + 1] == "512-534"

    bad = tmp_path / "bad.toml"
    bad.write_text('[modbus]\nallow = ["127.0.0.1"]\n\n[[modbus.client]]\naddress = "10.0.0.0/8"\nrole = "admin"\n'
                   '\n[[modbus.client]]\naddress = "127.0.0.1"\nrole = "read"\n\n[[modbus.client]]\nrole = "host"\n')
    with pytest.raises(runtime.ConfigError) as e:
        runtime.load_config(bad)
    assert e.value.problems == [
        f'{bad}:6:1: error: [[modbus.client]] 1: role: expected one of "read", "host", "engineer", got \'admin\'',
        f"{bad}:9:1: error: [[modbus.client]] 2: 127.0.0.1/32 has the role engineer already ([modbus] allow): "
        "one role per address",
        f"{bad}:12:1: error: [[modbus.client]] 3: address is required (an IPv4 address or ADDR/BITS)"]


def test_an_old_configuration_keeps_its_meaning(tmp_path):
    """allow entries without a role are engineers; without allow and clients any client is one (the shipped
    configuration: mb2hal on loopback writes as before)."""
    from plc import runtime
    old = tmp_path / "old.toml"
    old.write_text('[modbus]\nbind = "127.0.0.1"\nport = 5020\nallow = ["127.0.0.1", "192.168.1.0/24"]\n')
    argv = runtime.runtime_argv(Path("plc-runtime"), runtime.load_config(old))
    assert argv[argv.index("--allow") + 1] == "127.0.0.1/32,192.168.1.0/24"
    shipped = runtime.load_config(Path(__file__).resolve().parents[2] / "machines" / "default" / "runtime.toml")
    assert shipped.allow == [] and "--allow" not in runtime.runtime_argv(Path("plc-runtime"), shipped)
