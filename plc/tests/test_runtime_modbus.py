"""The runtime's Modbus/TCP server: OpenPLC address map, write protection, load, bad frames.

Runs against the plain build, or the ASan/UBSan build with PLC_RUNTIME_SANITIZE=1.
The program is tests/runtime_fixtures/fixture_basic.c (its header comment lists its
variables); the sim I/O layer loops every output back to the input of the same address.
"""

from __future__ import annotations

import json
import random
import socket
import struct
import subprocess
from pathlib import Path

import pytest

import rt_harness as h


@pytest.fixture(scope="module")
def binary() -> Path:
    return h.runtime_binary()


@pytest.fixture()
def rt(binary):
    with h.Runtime(binary, "--no-rt") as runtime:
        yield runtime


def alive(port: int) -> None:
    """The server still answers a well-behaved client."""
    with h.Client(port) as c:
        assert c.read_input(h.DIAG_BASE, 1) == [1]


# ------------------------------------------------------------------- address map

def test_coils_round_trip_through_the_loopback_and_the_program(rt):
    with h.Client(rt.port) as c:
        c.write_coil(400, True)                                  # %QX50.0, host-writable
        assert c.read_coils(400) == [True]                       # read back at once
        h.wait_until(lambda: c.read_discrete(400) == [True], 2, "%IX50.0 to follow %QX50.0")
        h.wait_until(lambda: c.read_coils(1) == [True], 2, "the program to copy %IX50.0 to %QX0.1")
        pattern = [(i * 7) % 3 == 0 for i in range(100)]
        c.write_coils(700, pattern)                              # %QX87.4 .. %QX99.7
        assert c.read_coils(700, 100) == pattern
        h.wait_until(lambda: c.read_discrete(700, 100) == pattern, 2, "discrete inputs to follow")
        c.write_coil(400, False)
        h.wait_until(lambda: c.read_coils(1) == [False], 2, "%QX0.1 to drop")
        assert c.read_coils(0) == [True]                         # ALIVE, set by the program
        assert len(c.read_coils(0, 800)) == 800 and len(c.read_discrete(0, 800)) == 800


def test_qw_round_trips_to_iw_and_the_program_sees_it(rt):
    with h.Client(rt.port) as c:
        c.write_register(512, 1234)                              # %QW512
        assert c.read_holding(512) == [1234]
        h.wait_until(lambda: c.read_input(512) == [1234], 2, "%IW512 to follow %QW512")
        h.wait_until(lambda: c.read_holding(1) == [1235], 2, "%QW1 := %IW512 + 1")
        c.write_registers(1000, [1, 2, 3, 65535])
        h.wait_until(lambda: c.read_input(1000, 4) == [1, 2, 3, 65535], 2, "%IW1000..1003")
        c.write_register(512, -3)
        h.wait_until(lambda: c.read_holding(1) == [0xFFFE], 2, "%QW1 = -2 (two's complement)")


def test_mw_md_ml_are_memory_with_high_word_first(rt):
    with h.Client(rt.port) as c:
        assert c.read_holding(1024 + 30) == [4242]               # %MW30's initial value survives binding
        c.write_registers(1024 + 300, [7, 8, 9])                 # unused %MW300..302: plain memory
        h.wait_scans(c)                                          # a whole scan after the write
        assert c.read_holding(1024 + 300, 3) == [7, 8, 9]
        c.write_registers(2048, [0x0000, 0xFFFF])                # %MD0 = 65535
        h.wait_until(lambda: c.read_holding(2050, 2) == [0x0001, 0x0000], 2, "%MD1 := %MD0 + 1 with carry")
        c.write_registers(2048, h.md_words(-5))
        h.wait_until(lambda: h.md(c.read_holding(2050, 2)) == -4, 2, "%MD1 = -4")
        c.write_registers(4096, [0x0001, 0x0002, 0xFFFF, 0xFFFF])  # %ML0
        h.wait_until(lambda: c.read_holding(4100, 4) == [0x0001, 0x0003, 0x0000, 0x0000], 2,
                     "%ML1 := %ML0 + 1 carrying across three words")
        c.write_registers(8188, [1, 2, 3, 4])                    # %ML1023, the last register
        h.wait_scans(c)
        assert c.read_holding(8188, 4) == [1, 2, 3, 4]


def test_a_half_written_md_keeps_its_other_word(rt):
    with h.Client(rt.port) as c:
        c.write_registers(2048 + 2 * 40, [0x1111, 0x2222])      # %MD40
        c.write_register(2048 + 2 * 40 + 1, 0x3333)              # low word only
        h.wait_scans(c)                                          # the queued word applied in a scan
        assert c.read_holding(2048 + 80, 2) == [0x1111, 0x3333]


def test_table_ends_and_the_diagnostic_block(rt):
    with h.Client(rt.port) as c:
        assert c.read_coils(799) == [False]
        assert len(c.read_input(1023, 65)) == 65                 # %IW1023 + the diagnostic block
        assert c.read_input(1088, 125)[:8] == [0] * 8             # I/O device block (--io modbus): unused here
        for fc, addr, count in ((1, 800, 1), (2, 799, 2), (3, 8192, 1), (3, 8191, 2), (4, 1216, 1), (4, 1215, 2)):
            with pytest.raises(h.ModbusError) as e:
                c.request(struct.pack(">BHH", fc, addr, count))
            assert e.value.code == 2, (fc, addr)
        d = h.read_diag(c)
        assert d["version"] == 1 and d["state"] == h.STATE_RUNNING and d["base_tick_us"] == 4000
        assert d["clients"] == 1 and d["requests"] >= 5 and d["exceptions"] >= 5


def test_any_unit_id_is_answered_with_the_same_unit(rt):
    with h.Client(rt.port) as c:
        for unit in (0, 1, 247, 255):
            assert c.request(struct.pack(">BHH", 3, 1024 + 30, 1), unit=unit)[2:] == struct.pack(">H", 4242)


# ------------------------------------------------------------------ write protection

def test_program_owned_outputs_are_write_protected_by_default(rt):
    with h.Client(rt.port) as c:
        for pdu in (struct.pack(">BHH", 5, 0, 0), struct.pack(">BHH", 5, 399, 0xFF00),
                    struct.pack(">BHH", 6, 1, 5), struct.pack(">BHH", 6, 511, 5)):
            with pytest.raises(h.ModbusError) as e:
                c.request(pdu)
            assert e.value.code == 2
        # a request reaching one protected address is refused as a whole
        with pytest.raises(h.ModbusError) as e:
            c.write_coils(398, [True] * 4)                       # 398..401
        assert e.value.code == 2
        with pytest.raises(h.ModbusError) as e:
            c.write_registers(510, [9, 9, 9, 9])                 # 510..513
        assert e.value.code == 2
        h.wait_scans(c)                                          # a refused write queued, a scan would show it
        assert c.read_coils(400, 2) == [False, False]
        assert c.read_holding(512, 2) == [0, 0]
        assert c.read_coils(0) == [True]                         # the program's own value


def test_writable_ranges_are_configurable(binary):
    with h.Runtime(binary, "--no-rt", "--writable-coils", "5,10-11", "--writable-registers", "none") as rt:
        with h.Client(rt.port) as c:
            c.write_coils(10, [True, True])
            c.write_coil(5, True)
            for pdu in (struct.pack(">BHH", 5, 400, 0xFF00), struct.pack(">BHH", 6, 1024, 1),
                        struct.pack(">BHH", 6, 8191, 1)):
                with pytest.raises(h.ModbusError) as e:
                    c.request(pdu)
                assert e.value.code == 2


# ------------------------------------------------------------------------ load

def test_16_clients_10000_requests_each_get_their_own_answers(rt):
    """Every response goes to the client that asked, with its own values and whole scans."""
    result = subprocess.run([str(h.mbload_binary()), "--port", str(rt.port), "--clients", "16",
                             "--requests", "10000"], capture_output=True, text=True, timeout=120 * h.SLOW)
    report = json.loads(result.stdout)
    assert report["errors"] == 0, report
    assert report["requests"] == 160000
    assert result.returncode == 0
    with h.Client(rt.port) as c:
        assert h.read_diag(c)["requests"] >= 160000


# ----------------------------------------------------------------- bad requests

def raw_exchange(port: int, frame: bytes, wait: float = 2.0) -> bytes | None:
    """Send raw bytes on a new connection; return the response, or None if it closed (the
    server resets the connections it drops).  Neither within the wait is a failure: silence
    is not taken for a close."""
    with socket.create_connection(("127.0.0.1", port), timeout=wait * h.SLOW) as s:
        s.sendall(frame)
        data = b""
        while True:
            try:
                chunk = s.recv(512)
            except socket.timeout:
                raise AssertionError(f"neither a whole answer nor a close within {wait * h.SLOW:.0f} s "
                                     f"after {frame[:16].hex()}: received {data.hex() or 'nothing'}") from None
            except ConnectionResetError:
                return None
            if not chunk:
                return data or None
            data += chunk
            if len(data) >= 7 and len(data) >= 6 + struct.unpack(">H", data[4:6])[0]:
                return data


def mbap(pdu: bytes, tid: int = 0x4242, unit: int = 1, length: int | None = None, proto: int = 0) -> bytes:
    return struct.pack(">HHHB", tid, proto, len(pdu) + 1 if length is None else length, unit) + pdu


def expect_exception(port: int, pdu: bytes, code: int) -> None:
    rsp = raw_exchange(port, mbap(pdu))
    assert rsp is not None, f"no answer to {pdu.hex()}"
    assert rsp[:2] == b"\x42\x42", "transaction id echoed"
    assert rsp[7] == (pdu[0] | 0x80) & 0xFF and rsp[8] == code, f"{pdu.hex()} -> {rsp.hex()}"


@pytest.mark.parametrize("fc", [0x00, 0x07, 0x08, 0x11, 0x14, 0x16, 0x17, 0x2B, 0x41, 0x7F])
def test_function_codes_other_than_1_to_6_15_16_get_exception_01(rt, fc):
    body = {0x16: struct.pack(">HHH", 1024, 0xFFFF, 0), 0x17: struct.pack(">HHHHBH", 1024, 1, 1024, 1, 2, 5)}
    expect_exception(rt.port, bytes([fc]) + body.get(fc, b"\x00\x00\x00\x01"), 1)
    alive(rt.port)


@pytest.mark.parametrize("pdu", [
    struct.pack(">BHH", 1, 0, 0), struct.pack(">BHH", 1, 0, 2001),
    struct.pack(">BHH", 2, 0, 0), struct.pack(">BHH", 2, 0, 2001),
    struct.pack(">BHH", 3, 0, 0), struct.pack(">BHH", 3, 0, 126),
    struct.pack(">BHH", 4, 0, 0), struct.pack(">BHH", 4, 0, 126),
    struct.pack(">BHH", 5, 400, 0x1234),                         # coil value neither 0 nor FF00
    struct.pack(">BHHB", 15, 400, 0, 0),                         # quantity 0
    struct.pack(">BHHB", 15, 400, 1969, 247) + bytes(247),       # > 1968 coils
    struct.pack(">BHHB", 15, 400, 10, 1) + b"\x01",              # byte count 1 for 10 coils
    struct.pack(">BHHB", 16, 1024, 0, 0),                        # quantity 0
    struct.pack(">BHHB", 16, 1024, 124, 248) + bytes(246),       # > 123 registers (frame cut to fit)
    struct.pack(">BHHB", 16, 1024, 2, 3) + b"\x00\x01\x02",      # odd byte count
    struct.pack(">BHHB", 16, 1024, 2, 4) + b"\x00\x01",          # byte count says 4, two bytes follow
    struct.pack(">BH", 3, 0),                                    # short PDU
    b"\x03",                                                     # function code only
    struct.pack(">BHH", 3, 0, 1) + b"\xde\xad",                  # long PDU
    struct.pack(">BHH", 6, 1024, 1) + b"\x00",                   # long write
], ids=lambda p: p[:8].hex())
def test_bad_quantities_counts_and_lengths_get_exception_03(rt, pdu):
    expect_exception(rt.port, pdu, 3)
    alive(rt.port)


@pytest.mark.parametrize("frame", [
    mbap(struct.pack(">BHH", 3, 0, 1), proto=1),                 # not Modbus
    mbap(b"", length=0),                                         # MBAP length 0
    mbap(b"", length=1),                                         # unit id only
    mbap(struct.pack(">BHH", 3, 0, 1), length=300),              # longer than any ADU
    b"GET / HTTP/1.1\r\nHost: plc\r\n\r\n",
], ids=["protocol-1", "length-0", "length-1", "length-300", "http"])
def test_unparseable_headers_close_the_connection(rt, frame):
    assert raw_exchange(rt.port, frame) is None
    alive(rt.port)


def test_a_lying_mbap_length_is_waited_for_without_stalling_others(rt):
    with socket.create_connection(("127.0.0.1", rt.port), timeout=2 * h.SLOW) as liar:
        liar.sendall(mbap(struct.pack(">BHH", 3, 0, 1), length=20))  # announces 19 PDU bytes, sends 5
        for _ in range(20):
            alive(rt.port)                                       # the others are served meanwhile
        # the liar's bytes were in before the first of those clients connected: the server read them, and would
        # have answered them, no later than the round that served that client; any answer is in the liar's socket
        liar.setblocking(False)
        with pytest.raises(BlockingIOError):
            liar.recv(64)
        liar.settimeout(2 * h.SLOW)
        liar.sendall(bytes(14))                                  # the announced frame is now complete
        rsp = liar.recv(64)
        assert rsp[7] == 0x83 and rsp[8] == 3                    # PDU length 19 is wrong for FC3
        liar.sendall(mbap(struct.pack(">BHH", 3, 1024 + 30, 1)))  # and the stream is still in step
        rsp = liar.recv(64)
        assert rsp[7:] == bytes([3, 2]) + struct.pack(">H", 4242)


def test_an_mbap_length_shorter_than_the_request_gives_an_exception_or_a_close(rt):
    frame = mbap(struct.pack(">BHHB", 16, 1024, 2, 4) + b"\x00\x01\x00\x02", length=6)
    with socket.create_connection(("127.0.0.1", rt.port), timeout=2 * h.SLOW) as s:
        s.sendall(frame)
        rsp = s.recv(64)
        assert rsp[7] == 0x90 and rsp[8] == 3
        s.sendall(mbap(struct.pack(">BHH", 3, 0, 1)))            # leftover bytes now garble the stream
        try:
            tail = s.recv(64)
        except (ConnectionResetError, socket.timeout):
            tail = b""
        assert tail == b"" or tail[7] in (0x03, 0x83, 0x90)
    alive(rt.port)


def test_random_garbage_from_several_clients_never_stops_the_server(rt):
    rng = random.Random(4)
    for round_ in range(150):                                # every socket operation is bounded on its own
        kind = rng.randrange(3)
        if kind == 0:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40)))
        else:
            pdu = bytes([rng.choice([1, 2, 3, 4, 5, 6, 15, 16, rng.randrange(256)])])
            pdu += bytes(rng.randrange(256) for _ in range(rng.randrange(0, 12)))
            data = mbap(pdu, length=len(pdu) + 1 if kind == 1 else rng.randrange(0, 20))
        try:
            with socket.create_connection(("127.0.0.1", rt.port), timeout=0.05) as s:
                s.sendall(data)
                try:
                    s.recv(300)
                except OSError:
                    pass
        except OSError:
            pass
        if round_ % 25 == 0:
            alive(rt.port)
    alive(rt.port)
    assert rt.proc.poll() is None


# --------------------------------------------------------------- connections

def test_idle_clients_are_never_disconnected(rt):
    with h.Client(rt.port) as c:
        c.read_holding(0)
        h.wait_timeout_check(rt.port)                            # a frame time-out later, checked by the server
        assert c.read_holding(1024 + 30) == [4242]


def test_connection_limit_refuses_with_a_log_line_and_keeps_existing_clients(binary):
    with h.Runtime(binary, "--no-rt", "--max-clients", "2") as rt:
        a, b = h.Client(rt.port), h.Client(rt.port)
        a.read_holding(0)
        b.read_holding(0)
        with socket.create_connection(("127.0.0.1", rt.port), timeout=2 * h.SLOW) as third:
            assert third.recv(16) == b""                         # closed by the server
        rt.wait_for(r"refused: every slot holds a served client \[limit of 2 clients")
        assert a.read_holding(1024 + 30) == [4242] and b.read_holding(1024 + 30) == [4242]
        b.close()
        h.wait_until(lambda: h.read_diag(a)["clients"] == 1, 2, "the slot to be freed")
        with h.Client(rt.port) as c:
            assert c.read_holding(1024 + 30) == [4242]
            assert h.read_diag(c)["refused"] == 1
        a.close()


def test_allowlist_admits_listed_addresses_only(binary):
    with h.Runtime(binary, "--no-rt", "--allow", "127.0.0.2,127.0.1.0/24") as rt:
        with h.Client(rt.port, source="127.0.0.2") as ok, h.Client(rt.port, source="127.0.1.9") as ok2:
            assert ok.read_holding(1024 + 30) == [4242]
            assert ok2.read_holding(1024 + 30) == [4242]
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            s.settimeout(2 * h.SLOW)
            s.connect(("127.0.0.1", rt.port))
            assert s.recv(16) == b""
        rt.wait_for(r"client 127\.0\.0\.1:\d+ refused: address not in the allowlist")
        rt.wait_for(r"clients allowed from 127\.0\.0\.2/32, 127\.0\.1\.0/24")
