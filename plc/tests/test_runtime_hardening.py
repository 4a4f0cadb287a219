"""The Modbus front end under hostile clients: frame timeout, slot reclaim, slow readers,
rate-limited log lines, read-only mode.

Runs against the plain build, or the ASan/UBSan build with PLC_RUNTIME_SANITIZE=1.
Verdicts never depend on the machine's speed: a timeout only bounds a hang, and where a
test needs a drop to happen it uses a small --frame-timeout and waits for it.
"""

from __future__ import annotations

import re
import socket
import struct
import time
from itertools import pairwise
from pathlib import Path

import pytest

import rt_harness as h
from rt_harness import (MODBUS_EXCEPTION_ILLEGAL_FUNCTION, MODBUS_FC_READ_HOLDING_REGISTERS,
                        MODBUS_FC_WRITE_MULTIPLE_COILS, MODBUS_FC_WRITE_MULTIPLE_REGISTERS,
                        MODBUS_FC_WRITE_SINGLE_COIL, MODBUS_FC_WRITE_SINGLE_REGISTER)

MW30 = 1024 + 30                  # %MW30 = 4242, set by the fixture program


@pytest.fixture(scope="module")
def binary() -> Path:
    return h.runtime_binary()


def served(client: h.Client) -> bool:
    return client.read_holding(MW30) == [4242]


def closed_by_server(s: socket.socket, timeout: float = 10.0) -> bool:
    """Block until the server closes s (True), bounded by a hang timeout."""
    s.settimeout(timeout * h.SLOW)
    try:
        while True:
            if not s.recv(4096):
                return True
    except ConnectionResetError:
        return True


def half_frame(port: int, source: str | None = None) -> socket.socket:
    """A connection that sent the first 4 bytes of an MBAP header, then nothing."""
    s = socket.socket()
    if source:
        s.bind((source, 0))
    s.connect(("127.0.0.1", port))
    s.sendall(b"\x00\x01\x00\x00")
    return s


def silent(port: int, source: str | None = None) -> socket.socket:
    s = socket.socket()
    if source:
        s.bind((source, 0))
    s.connect(("127.0.0.1", port))
    return s


# ------------------------------------------------------------------- frame timeout

def test_a_half_received_request_is_dropped_after_the_frame_timeout(binary):
    with h.Runtime(binary, "--no-rt", "--frame-timeout", "200") as rt:
        started = time.monotonic()
        with half_frame(rt.port) as s:
            assert closed_by_server(s)
        assert time.monotonic() - started >= 0.2                # never before the timeout
        rt.wait_for(r"client 127\.0\.0\.1:\d+ dropped: request incomplete after the frame timeout "
                    r"\[4 bytes of a request after 200 ms\]")
        with h.Client(rt.port) as c:
            assert served(c)
            assert h.read_diag(c)["dropped"] == 1


def test_a_request_trickling_in_byte_by_byte_is_dropped_too(binary):
    frame = struct.pack(">HHHBBHH", 1, 0, 6, 1, MODBUS_FC_READ_HOLDING_REGISTERS, MW30, 1)
    with h.Runtime(binary, "--no-rt", "--frame-timeout", "300") as rt, silent(rt.port) as s:
        dropped = False
        for byte in frame[:-1]:                                 # one byte every 100 ms never completes
            try:
                s.sendall(bytes([byte]))
            except (BrokenPipeError, ConnectionResetError):
                dropped = True
                break
            time.sleep(0.1)
        assert dropped or closed_by_server(s)
        rt.wait_for(r"dropped: request incomplete after the frame timeout")


def test_an_idle_connection_without_a_partial_frame_is_kept(binary):
    with h.Runtime(binary, "--no-rt", "--frame-timeout", "50") as rt:
        with h.Client(rt.port) as used, silent(rt.port) as never_asked:
            assert served(used)
            for _ in range(3):                                  # 3 frame timeouts of silence, each checked
                h.wait_timeout_check(rt.port)
            assert served(used)
            never_asked.sendall(struct.pack(">HHHBBHH", 7, 0, 6, 1, MODBUS_FC_READ_HOLDING_REGISTERS, MW30, 1))
            never_asked.settimeout(5 * h.SLOW)
            assert never_asked.recv(64)[7:] == bytes([3, 2]) + struct.pack(">H", 4242)
            d = h.read_diag(used)
            assert d["dropped"] == 3 and d["clients"] == 2           # the three half requests, only they


# ---------------------------------------------------------------- slot reclaim

@pytest.mark.parametrize("allow", [None, "127.0.0.2"], ids=["no-allowlist", "allowlist"])
def test_full_slots_are_reclaimed_from_suspect_clients_never_from_served_ones(binary, allow):
    """Silent and half-frame connections give their slots to newcomers; served idle clients keep theirs."""
    args = ["--no-rt", "--max-clients", "4"] + (["--allow", allow] if allow else [])
    src = allow
    with h.Runtime(binary, *args) as rt:
        strangers = []
        if allow:                                               # not listed: refused, never take a slot
            for _ in range(5):
                with silent(rt.port) as s:
                    assert closed_by_server(s)
        a, b = h.Client(rt.port, source=src), h.Client(rt.port, source=src)
        assert served(a) and served(b)
        strangers = [silent(rt.port, src), half_frame(rt.port, src)]
        h.wait_until(lambda: h.read_diag(a)["clients"] == 4, 5, "four clients")
        newcomers = []
        for _ in range(2):                                      # each takes a suspect's slot
            c = h.Client(rt.port, source=src)
            assert served(c)
            newcomers.append(c)
        for s in strangers:
            assert closed_by_server(s)
        assert served(a) and served(b)                          # idle but served: kept
        with silent(rt.port, src) as late:                      # all four slots hold served clients now
            assert closed_by_server(late)
        rt.wait_for(r"dropped to make room: no request served, one half-received or answers unread")
        rt.wait_for(r"refused: every slot holds a served client \[limit of 4 clients")
        d = h.read_diag(a)
        assert d["clients"] == 4 and d["dropped"] == 2
        for c in (a, b, *newcomers):
            assert served(c)
            c.close()


# ----------------------------------------------------------------- slow readers

def test_a_client_that_stops_reading_is_dropped_and_others_are_served(binary):
    request = struct.pack(">HHHBBHH", 1, 0, 6, 1, MODBUS_FC_READ_HOLDING_REGISTERS, 0, 125)   # 259-byte answer
    with h.Runtime(binary, "--no-rt", "--frame-timeout", "200") as rt, h.Client(rt.port) as other:
        reader = socket.socket()
        reader.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        reader.connect(("127.0.0.1", rt.port))
        reader.settimeout(10 * h.SLOW)
        try:
            for _ in range(200):                                # 200 x 50 answers = 2.6 MB, never read
                reader.sendall(request * 50)
        except (BrokenPipeError, ConnectionResetError):
            pass                                                # dropped while still sending
        rt.wait_for(r"client 127\.0\.0\.1:\d+ dropped: stopped reading its responses", timeout=10)
        reader.close()
        assert served(other)
        assert h.read_diag(other)["dropped"] == 1


# ------------------------------------------------------------------ log flooding

LINE = re.compile(r"^(\d\d):(\d\d):(\d\d)\.(\d{3}) plc-runtime: (?:warning: )?modbus: (.*)$")


def events(log: str, *kinds: str) -> list[tuple[float, str, int]]:
    """(time of day in s, kind, number of events) of each log line about one of `kinds`."""
    out = []
    for line in log.splitlines():
        m = LINE.match(line)
        if not m:
            continue
        t = int(m[1]) * 3600 + int(m[2]) * 60 + int(m[3]) + int(m[4]) / 1000
        for kind in kinds:
            if re.match(r"client \S+ " + re.escape(kind), m[5]):
                out.append((t, kind, 1))
            elif (more := re.match(r"(\d+) more clients " + re.escape(kind) + r".* in the last", m[5])):
                out.append((t, kind, int(more[1])))
    return out


CONNECTED = "connected"
CLOSED = "disconnected (closed by the client)"
RECLAIMED = "dropped to make room"


def test_a_connection_storm_logs_one_line_per_kind_per_second_with_counts(binary):
    """300 connect/close cycles: every one counted (a slot whose client has closed but was not read
    yet may be reclaimed first), at most one line a second for each kind."""
    storm = 300
    with h.Runtime(binary, "--no-rt") as rt:
        for _ in range(storm):
            with silent(rt.port):
                pass
        for kinds in ((CONNECTED,), (CLOSED, RECLAIMED)):
            h.wait_until(lambda kinds=kinds: sum(n for _, _, n in events(rt.log, *kinds)) >= storm, 10,
                         f"the counts of {kinds} to add up to {storm}")
            assert sum(n for _, _, n in events(rt.log, *kinds)) == storm, rt.log
        for kind in (CONNECTED, CLOSED, RECLAIMED):
            times = [t for t, _, _ in events(rt.log, kind)]
            gaps = [(b - a) % 86400 for a, b in pairwise(times)]
            # the gate holds a kind for 1 s of CLOCK_MONOTONIC; a line's stamp is the wall clock in ms, read when
            # the line is formatted, after the gate's decision: a busy machine delays one stamp by a few ms (a CI
            # run saw 0.998 s). 300 events in about a second without the gate would be lines milliseconds apart.
            assert all(g >= 0.9 for g in gaps), f"two '{kind}' lines less than a second apart:\n{rt.log}"
        assert len(events(rt.log, CONNECTED, CLOSED, RECLAIMED)) < storm / 10, rt.log


# ---------------------------------------------------------------------- read-only

@pytest.mark.parametrize("pdu", [
    struct.pack(">BHH", MODBUS_FC_WRITE_SINGLE_COIL, 400, 0xFF00),
    struct.pack(">BHH", MODBUS_FC_WRITE_SINGLE_REGISTER, 1024 + 300, 7),
    struct.pack(">BHHBB", MODBUS_FC_WRITE_MULTIPLE_COILS, 400, 3, 1, 0x07),
    struct.pack(">BHHBHH", MODBUS_FC_WRITE_MULTIPLE_REGISTERS, 1024 + 300, 2, 4, 7, 8),
    struct.pack(">BHH", MODBUS_FC_WRITE_SINGLE_REGISTER, 1, 7),          # not host-writable either
], ids=["coil", "register", "coils", "registers", "protected-register"])
def test_read_only_answers_every_write_with_illegal_function_and_serves_reads(binary, pdu):
    with h.Runtime(binary, "--no-rt", "--read-only") as rt, h.Client(rt.port) as c:
        rt.wait_for(r"READ-ONLY: every write refused")
        with pytest.raises(h.ModbusError) as e:
            c.request(pdu)
        assert e.value.code == MODBUS_EXCEPTION_ILLEGAL_FUNCTION
        h.wait_scans(c)                                         # a whole scan after it: nothing was queued
        assert c.read_coils(400, 3) == [False] * 3
        assert c.read_holding(1024 + 300, 2) == [0, 0]
        assert served(c) and c.read_input(h.DIAG_BASE, 1) == [1]
