"""RETAIN data: saved atomically, restored at start, never half-applied, safe against kill -9.

The fixture program retains `keep` (INT, set from %MW20 when non-zero, shown in %MW21)
and `scans` (UDINT, +1 every scan, shown in %MD5 = holding registers 2058-2059).
Runs against the plain build, or the ASan/UBSan build with PLC_RUNTIME_SANITIZE=1.
"""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

import rt_harness as h
from plc import retainfile

KEEP, SCANS = "CONFIG0.RES0.MAIN.KEEP", "CONFIG0.RES0.MAIN.SCANS"
HEADER = retainfile.HEADER


@pytest.fixture(scope="module")
def binary() -> Path:
    return h.runtime_binary()


def parse(path: Path) -> dict:
    """Check a retain file the way the runtime must (magic, size, CRC, entry table) and decode it."""
    f = retainfile.decode(path.read_bytes())
    assert f.version == 2
    out = {"generation": f.generation, "entries": f.entries}
    active = f.active()
    if KEEP in active:
        out["keep"] = active[KEEP].number()
    if SCANS in active:
        out["scans"] = active[SCANS].number()
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
        rt.wait_for(r"retain: restored 2 of 2 values from ")
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
        h.wait_scans(c, 25)                                  # 24 scans that found the data changed and held it
        assert parse(f) == first                             # back: the one-hour interval
    after = parse(f)
    # the verdict that needs no timing: `scans` changes every scan, so a save handed over during the run would
    # have left the data changed again at the stop, which saves once more: the stop's save is the next
    # generation after the first only if nothing was handed over in between
    assert after["keep"] == -77 and after["generation"] == first["generation"] + 1


def test_retained_holding_registers(binary, tmp_path):
    f = tmp_path / "plc.retain"
    args = ("--no-rt", "--retain", str(f), "--retain-registers", "1100-1103,2100-2101")
    with h.Runtime(binary, *args) as rt, h.Client(rt.port) as c:
        c.write_registers(1100, [11, 12, 13, 14, 15])        # 1104 is not retained
        c.write_registers(2100, [0xABCD, 0x1234])            # %MD26
    saved = {e.path: (e.type, e.where, e.number()) for e in parse(f)["entries"]}
    assert saved == {KEEP: ("INT", "", 0), SCANS: ("UDINT", "", saved[SCANS][2]),
                     "%MW76": ("WORD", "%MW76", 11), "%MW77": ("WORD", "%MW77", 12),
                     "%MW78": ("WORD", "%MW78", 13), "%MW79": ("WORD", "%MW79", 14),
                     "HR2100": ("WORD", "HR2100", 0xABCD), "HR2101": ("WORD", "HR2101", 0x1234)}
    with h.Runtime(binary, *args) as rt, h.Client(rt.port) as c:
        assert c.read_holding(1100, 5) == [11, 12, 13, 14, 0]
        assert c.read_holding(2100, 2) == [0xABCD, 0x1234]


def test_registers_no_longer_retained_are_named_and_kept_aside(binary, tmp_path):
    f = tmp_path / "plc.retain"
    with h.Runtime(binary, "--no-rt", "--retain", str(f), "--retain-registers", "1100-1101") as rt, \
            h.Client(rt.port) as c:
        c.write_register(1024 + 20, 99)
        c.write_registers(1100, [7, 8])
        h.wait_until(lambda: keep_and_scans(c)[0] == 99, 2, "keep = 99")
    with h.Runtime(binary, "--no-rt", "--retain", str(f), "--retain-registers", "1100") as rt, \
            h.Client(rt.port) as c:
        rt.wait_for(r"warning: retain: %MW77 \(WORD at %MW77\) is not retained by this program: its saved value "
                    r"is kept aside in the file")
        rt.wait_for(r"restored 3 of 3 values .*\(0 new, 1 kept aside now, 0 from earlier versions\)")
        h.wait_until(lambda: h.read_diag(c)["scans"] >= 1, 2, "the first scan")
        assert keep_and_scans(c)[0] == 99 and c.read_holding(1100, 2) == [7, 0]
        assert h.read_diag(c)["flags"] & h.FLAG_RETAIN_RESTORED
    aside = [e for e in parse(f)["entries"] if e.kept_aside]
    assert [(e.path, e.number()) for e in aside] == [("%MW77", 8)]
    with h.Runtime(binary, "--no-rt", "--retain", str(f), "--retain-registers", "1100-1101") as rt, \
            h.Client(rt.port) as c:                           # the earlier layout again: the value comes back
        rt.wait_for(r"restored 4 of 4 values")
        h.wait_until(lambda: h.read_diag(c)["scans"] >= 1, 2, "the first scan")
        assert c.read_holding(1100, 2) == [7, 8]
    assert not any(e.kept_aside for e in parse(f)["entries"])


def make_saved_file(binary: Path, f: Path, keep: int) -> None:
    with h.Runtime(binary, "--no-rt", "--retain", str(f)) as rt, h.Client(rt.port) as c:
        c.write_register(1024 + 20, keep)
        h.wait_until(lambda: keep_and_scans(c)[0] == keep, 2, "keep")
    assert parse(f)["keep"] == keep


def test_a_damaged_file_is_reported_and_ignored(binary, tmp_path):
    """A damaged file as the running runtime reports it (log, diagnostic flag, values over Modbus). Each reason
    a file is refused for, every prefix of a file (a torn write) and every one-bit change of it are the C unit
    test's (tests/c_unit/test_retain.c)."""
    f = tmp_path / "plc.retain"
    make_saved_file(binary, f, 555)
    data = f.read_bytes()
    damaged = data[:HEADER] + bytes([data[HEADER] ^ 0x40]) + data[HEADER + 1:]
    why = r"CRC mismatch: the file is corrupt"
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


def test_kill_9_during_retained_writes_never_loses_or_corrupts_a_value(tmp_path):
    """200 runs killed at random instants while the writer saves after every 1 ms scan
    (scripts/bench-runtime --kill-trials N runs more)."""
    result = h.kill_trials(h.runtime_binary(FIXTURE_BASE_TICK_NS="1000000u"), tmp_path, 200, deadline_s=240)
    print(result)
    assert result["corrupt"] == 0 and result["lost"] == 0 and result["rejected"] == 0, result
    assert result["applied_checked"] >= 5, result
    assert result["killed_mid_write"] >= 20, f"only {result['killed_mid_write']} of 200 kills hit a write in progress"


def test_plc_retain_show_lists_every_value_and_marks_those_kept_aside(binary, tmp_path):
    f = tmp_path / "plc.retain"
    with h.Runtime(binary, "--no-rt", "--retain", str(f), "--retain-registers", "1100-1101") as rt, \
            h.Client(rt.port) as c:
        c.write_registers(1100, [7, 8])
        c.write_register(1024 + 20, -3)
        h.wait_until(lambda: keep_and_scans(c)[0] == -3, 2, "keep = -3")
    with h.Runtime(binary, "--no-rt", "--retain", str(f), "--retain-registers", "1100"):
        pass
    cmd = [sys.executable, "-m", "plc.cli", "retain", "show", str(f)]
    out = subprocess.run(cmd, cwd=Path(__file__).resolve().parents[1], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert "format version 2" in lines[0] and "4 entries (1 kept aside)" in lines[0]
    assert f"  {KEEP} : INT = -3" in lines and "  %MW76 : WORD at %MW76 = 7" in lines
    assert "  %MW77 : WORD at %MW77 = 8  (kept aside: saved by an earlier program version)" in lines
    f.write_bytes(f.read_bytes()[:-1])
    bad = subprocess.run(cmd, cwd=Path(__file__).resolve().parents[1], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 1 and "body length" in bad.stderr and "Traceback" not in bad.stderr


def test_a_second_runtime_on_the_same_retain_file_stops_and_names_the_holder(binary, tmp_path):
    f = tmp_path / "plc.retain"
    holder = h.Runtime(binary, "--no-rt", "--retain", str(f)).start()
    try:
        h.wait_until(f.exists, 3, "the first save")
        second = h.Runtime(binary, "--no-rt", "--retain", str(f))
        assert second.wait(30 * h.SLOW) == 1, second.log
        second.wait_for(rf"error: retain: .*plc\.retain is in use by another runtime \(pid {holder.proc.pid} "
                        r"holds .*plc\.retain\.lock\); give each runtime its own retain file")
        assert "listening" not in second.log                   # stopped before serving anything
        with h.Client(holder.port) as c:                          # the holder is untouched
            assert h.read_diag(c)["state"] == h.STATE_RUNNING
    finally:
        holder.proc.send_signal(signal.SIGKILL)                    # the kernel drops the lock of a dead process
        holder.kill()
    with h.Runtime(binary, "--no-rt", "--retain", str(f)) as rt:
        rt.wait_for(r"retain: restored 2 of 2 values")
        assert (tmp_path / "plc.retain.lock").read_text() == f"{rt.proc.pid}\n"
