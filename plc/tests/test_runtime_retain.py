"""RETAIN data: saved atomically, restored at start, never half-applied, safe against kill -9.

The fixture program retains `keep` (INT, set from %MW20 when non-zero, shown in %MW21)
and `scans` (UDINT, +1 every scan, shown in %MD5 = holding registers 2058-2059).
Runs against the plain build, or the ASan/UBSan build with PLC_RUNTIME_SANITIZE=1.
"""

from __future__ import annotations

import random
import signal
import struct
import sys
import time
import zlib
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "runtime_fixtures"))
import rt_harness as h  # noqa: E402

HEADER = 28
PAYLOAD = 6                                   # keep (2 bytes) + scans (4 bytes), native little-endian


@pytest.fixture(scope="module")
def binary() -> Path:
    return h.runtime_binary()


def parse(path: Path, payload: int = PAYLOAD) -> dict:
    """Check a retain file the way the runtime must (magic, size, CRC) and decode it."""
    data = path.read_bytes()
    assert len(data) == HEADER + payload + 4, f"size {len(data)}"
    assert data[:8] == b"ATCPLCR1"
    version, layout, gen_lo, gen_hi, length = struct.unpack("<IIIII", data[8:28])
    assert version == 1 and length == payload
    (crc,) = struct.unpack("<I", data[-4:])
    assert zlib.crc32(data[:-4]) == crc, "CRC"
    out = {"layout": layout, "generation": gen_hi << 32 | gen_lo}
    if payload == PAYLOAD:
        out["keep"], out["scans"] = struct.unpack("<hI", data[HEADER:HEADER + payload])
    return out


def keep_and_scans(c: h.Client) -> tuple[int, int]:
    keep = c.read_holding(1024 + 21)[0]
    return keep - 65536 if keep & 0x8000 else keep, (lambda w: w[0] << 16 | w[1])(c.read_holding(2058, 2))


def test_retained_values_survive_a_restart(binary, tmp_path):
    f = tmp_path / "plc.retain"
    with h.Runtime(binary, "--no-rt", "--retain", str(f)) as rt, h.Client(rt.port) as c:
        rt.wait_for(r"retain: .* does not exist yet")
        c.write_register(1024 + 20, 1234)
        h.wait_until(lambda: keep_and_scans(c)[0] == 1234, 2, "keep = 1234")
        h.wait_until(lambda: f.exists() and parse(f)["keep"] == 1234, 3, "a save with keep = 1234")
        h.wait_until(lambda: h.read_diag(c)["retain_saves"] >= 1, 2, "the save counter")
        _, scans_before = keep_and_scans(c)
    with h.Runtime(binary, "--no-rt", "--retain", str(f)) as rt, h.Client(rt.port) as c:
        rt.wait_for(r"retain: restored 6 bytes from ")
        h.wait_until(lambda: h.read_diag(c)["scans"] >= 1, 2, "the first scan")
        keep, scans = keep_and_scans(c)
        assert keep == 1234                                  # %MW20 is 0 now: only the retained value
        assert scans > scans_before
        assert h.read_diag(c)["flags"] & h.FLAG_RETAIN_RESTORED


def test_shutdown_saves_what_the_rate_limit_held_back(binary, tmp_path):
    f = tmp_path / "plc.retain"
    with h.Runtime(binary, "--no-rt", "--retain", str(f), "--retain-interval", "3600000") as rt, \
            h.Client(rt.port) as c:
        h.wait_until(f.exists, 3, "the first save")
        first = parse(f)
        c.write_register(1024 + 20, -77)
        h.wait_until(lambda: keep_and_scans(c)[0] == -77, 2, "keep = -77")
        time.sleep(0.1)
        assert parse(f) == first                             # held back by the one-hour interval
    after = parse(f)
    assert after["keep"] == -77 and after["generation"] == first["generation"] + 1


def test_retained_holding_registers(binary, tmp_path):
    f = tmp_path / "plc.retain"
    args = ("--no-rt", "--retain", str(f), "--retain-registers", "1100-1103,2100-2101")
    with h.Runtime(binary, *args) as rt, h.Client(rt.port) as c:
        c.write_registers(1100, [11, 12, 13, 14, 15])        # 1104 is not retained
        c.write_registers(2100, [0xABCD, 0x1234])            # %MD26
    assert f.stat().st_size == HEADER + PAYLOAD + 12 + 4
    with h.Runtime(binary, *args) as rt, h.Client(rt.port) as c:
        assert c.read_holding(1100, 5) == [11, 12, 13, 14, 0]
        assert c.read_holding(2100, 2) == [0xABCD, 0x1234]
    with h.Runtime(binary, "--no-rt", "--retain", str(f)) as rt:    # other registers: other layout
        rt.wait_for(r"rejected \(size 50 bytes, expected 38\)")


def make_saved_file(binary: Path, f: Path, keep: int) -> None:
    with h.Runtime(binary, "--no-rt", "--retain", str(f)) as rt, h.Client(rt.port) as c:
        c.write_register(1024 + 20, keep)
        h.wait_until(lambda: keep_and_scans(c)[0] == keep, 2, "keep")
    assert parse(f)["keep"] == keep


@pytest.mark.parametrize("damage, why", [
    (lambda d: d[:HEADER] + bytes([d[HEADER] ^ 0x40]) + d[HEADER + 1:], r"CRC mismatch: the file is corrupt"),
    (lambda d: d[:-1], r"size 37 bytes, expected 38"),
    (lambda d: b"", r"size 0 bytes, expected 38"),
    (lambda d: b"XXXXXXXX" + d[8:], r"not a retain file"),
    (lambda d: d[:8] + b"\x02" + d[9:], r"unknown format version"),
], ids=["flipped-bit", "truncated", "empty", "magic", "version"])
def test_a_damaged_file_is_reported_and_ignored(binary, tmp_path, damage, why):
    f = tmp_path / "plc.retain"
    make_saved_file(binary, f, 555)
    damaged = damage(f.read_bytes())
    f.write_bytes(damaged)
    with h.Runtime(binary, "--no-rt", "--retain", str(f)) as rt, h.Client(rt.port) as c:
        rt.wait_for(r"warning: retain: .*plc\.retain rejected \(" + why + r"\); kept as .*plc\.retain\.rejected")
        h.wait_until(lambda: h.read_diag(c)["scans"] >= 1, 2, "the first scan")
        keep, scans = keep_and_scans(c)
        assert keep == 0                                     # initial value, nothing half-applied
        assert scans < 1000
        assert h.read_diag(c)["flags"] & h.FLAG_RETAIN_REJECTED
    assert (tmp_path / "plc.retain.rejected").read_bytes() == damaged
    assert parse(f)["keep"] == 0                             # a fresh, valid file replaced it


def test_a_file_from_another_program_is_rejected(binary, tmp_path):
    f = tmp_path / "plc.retain"
    make_saved_file(binary, f, 321)
    other_hash = h.runtime_binary(FIXTURE_LAYOUT_HASH="0x0badcafeu")
    with h.Runtime(other_hash, "--no-rt", "--retain", str(f)) as rt, h.Client(rt.port) as c:
        rt.wait_for(r"rejected \(layout hash differs: saved by a different program\)")
        h.wait_until(lambda: h.read_diag(c)["scans"] >= 1, 2, "the first scan")
        assert keep_and_scans(c)[0] == 0
    make_saved_file(binary, f, 321)
    more = h.runtime_binary(FIXTURE_EXTRA_RETAIN=1)
    with h.Runtime(more, "--no-rt", "--retain", str(f)) as rt, h.Client(rt.port) as c:
        rt.wait_for(r"rejected \(size 38 bytes, expected 42\)")
        h.wait_until(lambda: h.read_diag(c)["scans"] >= 1, 2, "the first scan")
        assert keep_and_scans(c)[0] == 0


def test_kill_9_during_retained_writes_never_loses_or_corrupts_the_last_save(tmp_path):
    """200 runs killed at random instants while the writer saves after every 1 ms scan."""
    binary = h.runtime_binary(FIXTURE_BASE_TICK_NS="1000000u")
    f = tmp_path / "plc.retain"
    tmp = tmp_path / "plc.retain.tmp"
    rng = random.Random(9)
    trials, mid_write, last_completed = 200, 0, -1
    for trial in range(trials):                              # each start, wait and stop is bounded on its own
        saved_before = f.exists()
        rt = h.Runtime(binary, "--no-rt", "--retain", str(f), "--retain-interval", "0",
                       "--status", "off")
        try:
            rt.start()
            if saved_before:
                assert "retain: restored 6 bytes" in rt.log, rt.log
                assert "rejected" not in rt.log, rt.log
            if saved_before and trial % 20 == 1:             # the runtime applied exactly that file
                with h.Client(rt.port) as c:
                    h.wait_until(lambda: h.read_diag(c)["scans"] >= 1, 2, "the first scan")
                    s1 = h.read_diag(c)["scans"]
                    scans = keep_and_scans(c)[1]
                    s2 = h.read_diag(c)["scans"]
                assert last_completed + s1 <= scans <= last_completed + s2
            time.sleep(rng.uniform(0.0, 0.03))
            seen = parse(f)["scans"] if f.exists() else -1   # a completed save, whatever happens next
            time.sleep(rng.uniform(0.0, 0.004))
        finally:
            rt.proc.send_signal(signal.SIGKILL)
            rt.kill()
        mid_write += tmp.exists()
        if not f.exists():
            assert not saved_before
            continue                                         # killed before the very first save
        after = parse(f)                                     # complete and consistent
        assert after["scans"] >= seen >= last_completed, (trial, after, seen, last_completed)
        last_completed = after["scans"]
    print(f"{trials} kills, {mid_write} left a half-written temporary file behind")
    assert mid_write >= trials // 10, f"only {mid_write} of {trials} kills hit a write in progress"
