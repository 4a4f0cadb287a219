"""The runtime's real-time paths, run for real: SCHED_FIFO, locked memory, every thread at its documented priority,
and the watchdog preempting a program that spins at SCHED_FIFO on a machine with one CPU allowed.

Each test needs SCHED_FIFO (root, CAP_SYS_NICE or RLIMIT_RTPRIO); where the runtime is refused it, the test is
skipped with the runtime's own reason.  Runs against the ASan/UBSan build with PLC_RUNTIME_SANITIZE=1.
"""

from __future__ import annotations

import os
import re
import signal
import time
from pathlib import Path

import pytest

import rt_harness as h

# A program that spins in ST: a host writes spin := 1 and the next run() never returns.
SPIN = """\
PROGRAM Main
VAR
    spin AT %MW10 : INT;            (* written by the host: 1 = loop forever *)
    alive AT %QX0.0 : BOOL := TRUE; (* a coil the watchdog must clear *)
    scans AT %MD0 : DINT;           (* runs of the program *)
    toggle : BOOL;
END_VAR
scans := scans + 1;
WHILE spin <> 0 DO
    toggle := NOT toggle;
END_WHILE;
END_PROGRAM
"""
PRIORITY = 50                       # the runtime's default --rt-priority


@pytest.fixture(scope="module")
def binary() -> Path:
    return h.runtime_binary()


@pytest.fixture(scope="module")
def spin_binary(tmp_path_factory) -> Path:
    return h.st_runtime_binary(tmp_path_factory.mktemp("spin"), {"Main.st": SPIN, "Config0.st": h.MAIN_EVERY_4MS})


def require_realtime(binary: Path) -> None:
    refused = h.realtime_refused(binary)
    if refused:
        pytest.skip(f"SCHED_FIFO not permitted on this machine: {refused}")


def threads(pid: int) -> dict[str, list[int]]:
    """The process's threads by name (/proc/PID/task/TID/comm): thread ids."""
    out: dict[str, list[int]] = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            name = Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip()
        except FileNotFoundError:
            continue
        out.setdefault(name, []).append(int(tid))
    return out


def scheduling(tid: int) -> tuple[int, int]:
    """(policy, SCHED_FIFO priority) of a thread."""
    return os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority


def status_kib(pid: int, field: str) -> int:
    text = Path(f"/proc/{pid}/status").read_text()
    return int(re.search(rf"^{field}:\s+(\d+) kB", text, re.M).group(1))


def test_every_thread_runs_at_its_documented_priority_with_memory_locked(binary, tmp_path):
    require_realtime(binary)
    args = ["--rt-priority", "30", "--retain", str(tmp_path / "plc.retain"), "--monitor", str(tmp_path / "mon"),
            "--io", "modbus", "--io-device", "name=m tcp=127.0.0.1:9 di=0:8:0"]    # port 9: refused, retried
    with h.Runtime(binary, *args) as rt, h.Client(rt.port) as c:
        rt.wait_for(r"scan thread is SCHED_FIFO priority 30, memory locked")
        rt.wait_for(r"watchdog: thread is SCHED_FIFO priority 31, above the scan")
        rt.wait_for(r"modbus: server thread is SCHED_FIFO priority 20")
        assert h.read_diag(c)["flags"] & 0x1, "diagnostic flag 1: SCHED_FIFO"
        pid = rt.proc.pid
        named = threads(pid)
        expected = {                                     # README, "Threads, priorities and locks"
            "watchdog": (os.SCHED_FIFO, 31), "io-poll": (os.SCHED_FIFO, 25), "io-loss-watch": (os.SCHED_FIFO, 25),
            "modbus-server": (os.SCHED_FIFO, 20),
            "log": (os.SCHED_OTHER, 0), "monitor": (os.SCHED_OTHER, 0), "retain-writer": (os.SCHED_OTHER, 0),
        }
        assert scheduling(pid) == (os.SCHED_FIFO, 30)   # the scan runs on the main thread
        for name, policy in expected.items():
            assert name in named, f"no thread named {name}: {sorted(named)}"
            for tid in named[name]:
                assert scheduling(tid) == policy, (name, scheduling(tid))
        others = set(named) - set(expected) - {Path(binary).name[:15]}
        assert not others, f"threads the README does not list: {others}"
        # mlockall(MCL_CURRENT | MCL_FUTURE): what is resident is locked (AddressSanitizer turns mlockall into a
        # no-op that returns 0, so the sanitizer build says "memory locked" and locks nothing)
        if not h.SANITIZE:
            status = Path(f"/proc/{pid}/status").read_text()
            assert status_kib(pid, "VmLck") >= status_kib(pid, "VmRSS") // 2 > 0, status


def test_the_watchdog_stops_a_program_spinning_at_sched_fifo_on_one_cpu(spin_binary):
    """The whole runtime on one CPU (taskset -c, not --cpu: every thread), SCHED_FIFO, an endless WHILE in ST: the
    watchdog, one level above the scan, preempts it, forces the outputs safe and lowers the stuck scan, so the
    Modbus server (below the scan, on the same CPU) answers the host again; SIGTERM then ends the runtime."""
    require_realtime(spin_binary)
    cpu = min(os.sched_getaffinity(0))
    rt = h.Runtime("taskset", "-c", str(cpu), str(spin_binary), "--port", "0", "--status", "log",
                   "--status-interval", "3600", "--watchdog", "300", raw=True)
    try:
        rt.start()
        rt.wait_for(rf"scan thread is SCHED_FIFO priority {PRIORITY}, memory locked")
        rt.wait_for(rf"watchdog: thread is SCHED_FIFO priority {PRIORITY + 1}, above the scan")
        pid = rt.proc.pid
        for tids in threads(pid).values():              # one CPU for every thread of the runtime
            for tid in tids:
                assert os.sched_getaffinity(tid) == {cpu}, tid
        with h.Client(rt.port) as c:
            h.wait_until(lambda: h.md(c.read_holding(2048, 2)) >= 5, 5, "five runs of the program")
            assert c.read_coils(0) == [True]
            c.write_register(1024 + 10, 1)               # spin := 1: the next run() never returns
            m = rt.wait_for(r"error: watchdog: the program has been inside run\(\) for (\d+) ms \(limit 300 ms\); "
                            r"outputs forced safe, program stopped, Modbus still serving; the stuck scan thread "
                            r"lowered to SCHED_IDLE")
            assert int(m.group(1)) >= 300
            # the Modbus server runs on the CPU the program spins on: it answers with the fault
            d = h.read_diag(c)
            assert (d["state"], d["fault_kind"]) == (h.STATE_FAULTED, 90)
            assert c.read_coils(0, 800) == [False] * 800
            assert os.sched_getscheduler(pid) == os.SCHED_IDLE
            runs = h.md(c.read_holding(2048, 2))
            scans = d["scans"]
            h.wait_until(lambda: h.read_diag(c)["requests"] >= d["requests"] + 20, 5, "20 more requests answered")
            assert h.md(c.read_holding(2048, 2)) == runs and h.read_diag(c)["scans"] == scans   # still stuck
        stopped_at = time.monotonic()
        rc = rt.stop(signal.SIGTERM)
        assert rc == 0, rt.log
        assert "SIGTERM received while the program is stuck: exiting with outputs safe" in rt.log
        assert time.monotonic() - stopped_at < 10 * h.SLOW
    finally:
        rt.kill()                                        # whatever happened: no spinning process left behind
