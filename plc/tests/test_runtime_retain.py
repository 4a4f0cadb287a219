"""RETAIN data: saved atomically, restored at start, never half-applied, safe against kill -9.

The fixture program retains `keep` (INT, set from %MW20 when non-zero, shown in %MW21)
and `scans` (UDINT, +1 every scan, shown in %MD5 = holding registers 2058-2059).
Runs against the plain build, or the ASan/UBSan build with PLC_RUNTIME_SANITIZE=1.
"""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "runtime_fixtures"))
import rt_harness as h  # noqa: E402
from retain_trials import HEADER, PAYLOAD, keep_and_scans, kill_trials, parse  # noqa: E402


@pytest.fixture(scope="module")
def binary() -> Path:
    return h.runtime_binary()


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
    """200 runs killed at random instants while the writer saves after every 1 ms scan
    (the benchmark runs 1000: scripts/bench-hardening --kill-trials 1000)."""
    report = kill_trials(tmp_path, 200, hang_limit_s=240)
    print(f"{report.trials} kills, {report.mid_write} left a half-written temporary file behind")
    assert report.ok, "\n".join(report.problems)
    assert report.mid_write >= report.trials // 10, f"only {report.mid_write} of 200 kills hit a write in progress"


def test_a_second_runtime_on_the_same_retain_file_stops_and_names_the_holder(binary, tmp_path):
    f = tmp_path / "plc.retain"
    holder = h.Runtime(binary, "--no-rt", "--retain", str(f)).start()
    try:
        h.wait_until(f.exists, 3, "the first save")
        second = h.Runtime(binary, "--no-rt", "--retain", str(f))
        assert second.proc.wait(30 * h.SLOW) == 1, second.log
        second.wait_for(rf"error: retain: .*plc\.retain is in use by another runtime \(pid {holder.proc.pid} "
                        r"holds .*plc\.retain\.lock\); give each runtime its own retain file")
        assert "listening" not in second.log                   # stopped before serving anything
        with h.Client(holder.port) as c:                          # the holder is untouched
            assert h.read_diag(c)["state"] == h.STATE_RUNNING
    finally:
        holder.proc.send_signal(signal.SIGKILL)                    # the kernel drops the lock of a dead process
        holder.kill()
    with h.Runtime(binary, "--no-rt", "--retain", str(f)) as rt:
        rt.wait_for(r"retain: restored 6 bytes")
        assert (tmp_path / "plc.retain.lock").read_text() == f"{rt.proc.pid}\n"
