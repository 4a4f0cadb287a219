"""The runtime's scan loop: tasks, virtual clock, statistics, faults, signals, start-up checks.

Runs against the plain build, or the ASan/UBSan build with PLC_RUNTIME_SANITIZE=1.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import struct
import subprocess
import tempfile
import time
from pathlib import Path

import pytest

import rt_harness as h


@pytest.fixture(scope="module")
def binary() -> Path:
    return h.runtime_binary()


def run_to_end(binary: Path, *args: str, timeout: float = 20) -> tuple[int, str]:
    result = subprocess.run([str(binary), *args], capture_output=True, timeout=timeout * h.SLOW,
                            env={**os.environ, **h.SANITIZER_ENV}, stdin=subprocess.DEVNULL)
    return result.returncode, result.stderr.decode(errors="replace")   # bytes: keep the \r of the status line


def clock_and_tick(c: h.Client) -> tuple[int, int]:
    words = c.read_holding(2060, 4)                              # %MD6 clock ms, %MD7 tick
    return words[0] << 16 | words[1], words[2] << 16 | words[3]


# ------------------------------------------------------------------- tasks, clock

def test_program_clock_is_virtual_tick_times_base_tick(binary):
    with h.Runtime(binary, "--no-rt") as rt, h.Client(rt.port) as c:
        seen = set()
        deadline = time.monotonic() + 5 * h.SLOW
        while len(seen) < 5:
            assert time.monotonic() < deadline, "ticks did not advance"
            clock_ms, tick = clock_and_tick(c)
            assert clock_ms == 4 * tick                          # both from the same scan
            seen.add(tick)
            time.sleep(0.01)


def test_slow_task_runs_on_every_fifth_tick(binary):
    with h.Runtime(binary, "--no-rt") as rt, h.Client(rt.port) as c:
        h.wait_until(lambda: clock_and_tick(c)[1] >= 20, 5, "tick 20")
        _, before = clock_and_tick(c)
        slow = c.read_holding(30)[0]                             # %QW30: runs of the 20 ms task
        _, after = clock_and_tick(c)
        assert before // 5 + 1 <= slow <= after // 5 + 1
        assert after >= 20


def test_scan_statistics_are_published_in_the_diagnostic_block(binary):
    # how fast the machine scans is a benchmark's business (scripts/bench-runtime); here only what must hold
    # however loaded it is: scans advance, never more than one per 4 ms tick, and the figures are consistent
    with h.Runtime(binary, "--no-rt") as rt, h.Client(rt.port) as c:
        first = h.read_diag(c)
        h.wait_until(lambda: h.read_diag(c)["scans"] >= first["scans"] + 50, 5 * h.SLOW, "50 more scans")
        d = h.read_diag(c)
        assert d["state"] == h.STATE_RUNNING and d["base_tick_us"] == 4000
        # at most one scan per tick, judged on the runtime's own clock (a reader's clock sees the counters late
        # by however long the machine made it wait): every tick since start is a scan or a skipped tick
        ticks_per_s = 1_000_000 // d["base_tick_us"]
        assert d["scans"] + d["skipped"] <= (d["uptime_s"] + 1) * ticks_per_s + 1
        assert d["scan_min_us"] <= d["scan_mean_us"] <= d["scan_max_us"]
        assert d["scan_p50_us"] <= d["scan_p99_us"] <= d["scan_max_us"]
        assert d["wake_min_us"] <= d["wake_mean_us"] <= d["wake_max_us"]
        assert d["wake_p50_us"] <= d["wake_p99_us"] <= d["wake_max_us"]
        assert d["overruns"] <= d["scans"]


def test_status_line_on_a_terminal_and_as_log_lines(binary):
    rc, err = run_to_end(binary, "--no-rt", "--port", "0", "--status", "tty", "--duration", "0.8")
    assert rc == 0, err
    assert "\r\x1b[K" in err and re.search(r"RUN \| scans \d+ \| scan us last \d+ p99 \d+ max \d+", err)
    rc, err = run_to_end(binary, "--no-rt", "--port", "0", "--status", "log", "--status-interval", "0.2",
                         "--duration", "2")
    assert rc == 0, err
    assert "\r" not in err
    assert len(re.findall(r"^\S+ plc-runtime: status RUN \| scans \d+", err, re.M)) >= 2


def test_realtime_scheduling_is_used_or_reported_once(binary):
    rc, err = run_to_end(binary, "--port", "0", "--status", "off", "--duration", "0.3")
    assert rc == 0, err
    lines = err.splitlines()
    scan = [ln for ln in lines if "scan thread is SCHED_FIFO" in ln or "real-time scheduling not permitted" in ln]
    assert len(scan) == 1, err
    for thread in ("modbus: server thread", "watchdog: thread"):    # SCHED_FIFO below/above the scan, or why not
        assert len([ln for ln in lines if thread in ln]) == 1, err


@pytest.fixture(params=["no-rt", "SCHED_FIFO"])
def scheduling(request, binary) -> tuple[str, ...]:
    """The scheduling options of a test run both ways: --no-rt, and SCHED_FIFO where the machine permits it."""
    if request.param == "no-rt":
        return ("--no-rt",)
    refused = h.realtime_refused(binary)
    if refused:
        pytest.skip(f"SCHED_FIFO not permitted on this machine: {refused}")
    return ()


def scans_go_on(c: h.Client, n: int = 10) -> None:
    first = h.read_diag(c)["scans"]
    h.wait_until(lambda: h.read_diag(c)["scans"] >= first + n, 5, f"{n} more scans")


def cpus_allowed(pid: int, tid: int) -> set[int]:
    """The CPUs thread `tid` of process `pid` may run on (Cpus_allowed_list of /proc)."""
    text = Path(f"/proc/{pid}/task/{tid}/status").read_text()
    listed = re.search(r"^Cpus_allowed_list:\s*(\S+)", text, re.M).group(1)
    out: set[int] = set()
    for part in listed.split(","):
        lo, _, hi = part.partition("-")
        out |= set(range(int(lo), int(hi or lo) + 1))
    return out


def test_cpu_pins_the_scan_thread_only_and_scans_go_on(binary):
    cpu = min(os.sched_getaffinity(0))                   # CPU 0 unless this test is kept off it
    with h.Runtime(binary, "--no-rt", "--cpu", str(cpu)) as rt, h.Client(rt.port) as c:
        scans_go_on(c)
        assert f"scan thread pinned to CPU {cpu}" in rt.log, rt.log
        pid = rt.proc.pid
        assert cpus_allowed(pid, pid) == {cpu}           # the scan runs on the main thread
        others = [int(t) for t in os.listdir(f"/proc/{pid}/task") if int(t) != pid]
        assert others, "the runtime has no other threads?"
        for tid in others:                               # Modbus server, log, retain, watchdog: not pinned
            assert cpus_allowed(pid, tid) == os.sched_getaffinity(0), tid


def test_without_cpu_nothing_is_pinned(binary):
    rc, err = run_to_end(binary, "--no-rt", "--port", "0", "--status", "off", "--duration", "0.2")
    assert rc == 0 and "pinned" not in err, err


@pytest.mark.parametrize("value, message", [
    ("999", "--cpu: CPU 999 is not online (online CPUs: 0"),
    ("-1", "--cpu: '-1' is not a CPU number"),
    ("one", "--cpu: 'one' is not a CPU number"),
    ("99999", "--cpu: '99999' is not a CPU number"),
])
def test_a_cpu_that_is_not_online_is_a_usage_error(binary, value, message):
    if value == "999" and os.cpu_count() and os.cpu_count() > 999:
        pytest.skip("this machine has a CPU 999")
    rc, err = run_to_end(binary, "--no-rt", "--port", "0", "--cpu", value, "--duration", "5")
    assert rc == 2 and message in err and "running" not in err, err


def cpu_latency_request() -> int | None:
    """The kernel's aggregate PM QoS CPU latency request (us), None when it cannot be read here."""
    try:
        with open("/dev/cpu_dma_latency", "rb") as f:
            return struct.unpack("i", f.read(4))[0]
    except OSError:
        return None


def test_cpu_latency_is_requested_while_running_and_withdrawn_at_the_end(binary):
    before = cpu_latency_request()
    if before is None or not os.access("/dev/cpu_dma_latency", os.W_OK):
        pytest.skip("/dev/cpu_dma_latency cannot be read and written here (needs root or a udev rule)")
    if before <= 7:
        pytest.skip(f"another program already holds a CPU latency request of {before} us")
    with h.Runtime(binary, "--no-rt", "--cpu-latency", "7") as rt, h.Client(rt.port) as c:
        scans_go_on(c)
        assert "CPU idle exit latency limited to 7 us while running (PM QoS)" in rt.log, rt.log
        assert cpu_latency_request() == 7
    h.wait_until(lambda: cpu_latency_request() == before, 5, f"the request back at {before} us")


def test_a_cpu_latency_that_cannot_be_requested_is_a_warning_and_scans_go_on(binary):
    # As a user without access to /dev/cpu_dma_latency: the runtime warns once and runs
    if os.geteuid() != 0:
        rc, err = run_to_end(binary, "--no-rt", "--port", "0", "--status", "off", "--cpu-latency", "0",
                             "--duration", "0.3")
        assert rc == 0 and "cannot limit the CPUs' idle exit latency to 0 us" in err, err
        return
    setpriv = shutil.which("setpriv")
    if not setpriv:
        pytest.skip("setpriv (util-linux) is needed to run the runtime as an unprivileged user")
    where = Path(tempfile.mkdtemp(prefix="plc-nobody-", dir="/tmp"))    # not under pytest's 0700 folders
    try:
        where.chmod(0o755)
        copy = where / "plc-runtime"
        shutil.copy(binary, copy)
        copy.chmod(0o755)
        proc = subprocess.run([setpriv, "--reuid=65534", "--regid=65534", "--clear-groups", str(copy), "--no-rt",
                               "--port", "0", "--status", "off", "--cpu-latency", "0", "--duration", "0.3"],
                              capture_output=True, text=True, timeout=60 * h.SLOW, cwd=where,
                              env={**os.environ, **h.SANITIZER_ENV}, stdin=subprocess.DEVNULL)
    finally:
        shutil.rmtree(where, ignore_errors=True)
    assert proc.returncode == 0, proc.stderr
    assert "cannot limit the CPUs' idle exit latency to 0 us (/dev/cpu_dma_latency: Permission denied)" \
        in proc.stderr and "run time of 0.3 s reached" in proc.stderr, proc.stderr


@pytest.mark.parametrize("value", ["-1", "fast", "2000000001"])
def test_a_bad_cpu_latency_is_a_usage_error(binary, value):
    rc, err = run_to_end(binary, "--no-rt", "--port", "0", "--cpu-latency", value, "--duration", "5")
    assert rc == 2 and f"--cpu-latency: '{value}' is not a number of microseconds" in err and "running" not in err, err


def test_duration_ends_with_a_summary_line(binary):
    rc, err = run_to_end(binary, "--no-rt", "--port", "0", "--status", "off", "--duration", "0.5")
    assert rc == 0, err
    m = re.search(r"stats scans=(\d+) overruns=(\d+) skipped=(\d+) period_us=4000\.0 .*wake_us_p99=([\d.]+)", err)
    assert m, err
    scans, skipped = int(m.group(1)), int(m.group(3))
    assert scans >= 1 and scans + skipped <= 0.5 / 0.004 + 2    # at most one scan per tick of the 0.5 s


# ---------------------------------------------------------------------- faults

def test_a_program_fault_stops_it_with_outputs_safe_while_modbus_answers(binary):
    with h.Runtime(binary, "--no-rt") as rt, h.Client(rt.port) as c:
        c.write_register(512, 10)                                # %QW512 -> %IW512 -> %QW1 = 11
        h.wait_until(lambda: c.read_holding(1) == [11], 2, "%QW1 = 11")
        assert c.read_coils(0) == [True]
        c.write_register(1024 + 10, 7)                           # %MW10 = 7: 100 / (7 - 7)
        h.wait_until(lambda: h.read_diag(c)["state"] == h.STATE_FAULTED, 2, "the fault")
        d = h.read_diag(c)
        assert (d["fault_kind"], d["fault_line"], d["fault_col"]) == (1, 42, 27)
        assert c.read_coils(0, 800) == [False] * 800             # all coils safe
        assert c.read_holding(1) == [11]                         # %QW status words kept for the host
        h.wait_until(lambda: c.read_input(512) == [0], 2, "the I/O layer to get zero words")
        rt.wait_for(r"error: program fault at tick \d+: integer division by zero \(kind 1\) in MAIN at "
                    r"fixture_basic\.st:42:27; program stopped, outputs safe, Modbus still serving")
        _, tick = clock_and_tick(c)
        h.wait_scans(c, 5)                                       # the scan loop runs on, the program does not
        assert clock_and_tick(c)[1] == tick
        c.write_coil(400, True)                                  # outputs stay safe
        h.wait_scans(c)
        assert c.read_coils(400) == [False]
        c.write_register(1024 + 300, 99)                         # memory is still memory
        h.wait_scans(c)
        assert c.read_holding(1024 + 300) == [99]


def test_the_watchdog_forces_outputs_safe_when_run_never_returns(binary, scheduling):
    rt = h.Runtime(binary, *scheduling, "--watchdog", "300").start()
    try:
        with h.Client(rt.port) as c:
            c.write_register(512, 10)
            h.wait_until(lambda: c.read_holding(1) == [11], 2, "%QW1 = 11")
            c.write_register(1024 + 10, 13)                      # the program loops forever
            rt.wait_for(r"error: watchdog: the program has been inside run\(\) for \d+ ms \(limit 300 ms\); "
                        r"outputs forced safe")
            d = h.read_diag(c)
            assert (d["state"], d["fault_kind"]) == (h.STATE_FAULTED, 90)
            assert c.read_coils(0, 800) == [False] * 800
            assert c.read_holding(1) == [11]                     # status words stay readable
            assert c.read_holding(1024 + 30) == [4242]           # Modbus keeps answering
            # a SCHED_FIFO scan stuck in run() is lowered so that the threads below it run
            assert ("the stuck scan thread lowered to SCHED_IDLE" in rt.log) == (not scheduling), rt.log
    finally:
        rc = rt.stop(signal.SIGTERM)
    rt.assert_clean_exit(rc)
    assert "SIGTERM received while the program is stuck: exiting with outputs safe" in rt.log


def test_a_program_returning_after_the_watchdog_fired_stays_stopped(binary, scheduling):
    with h.Runtime(binary, *scheduling, "--watchdog", "300") as rt, h.Client(rt.port) as c:
        c.write_register(1024 + 10, 14)                          # one run() call of 1.5 s
        rt.wait_for(r"watchdog: the program has been inside run\(\)")
        rt.wait_for(r"program returned from run\(\) after the watchdog fired at tick \d+; it stays stopped")
        if not scheduling:                                       # lowered while stuck, SCHED_FIFO once back
            rt.wait_for(r"run\(\) returned: the scan thread is SCHED_FIFO priority 50 again")
            assert os.sched_getscheduler(rt.proc.pid) == os.SCHED_FIFO
        scans = h.read_diag(c)["scans"]
        h.wait_until(lambda: h.read_diag(c)["scans"] > scans + 5, 2, "the scan loop to go on")
        assert h.read_diag(c)["state"] == h.STATE_FAULTED and c.read_coils(0) == [False]
    assert "SIGTERM received: stopping" in rt.log                # an orderly stop by the scan thread


# --------------------------------------------------------------------- signals

@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_signal_stops_with_outputs_safe_and_exit_0(binary, sig):
    rt = h.Runtime(binary, "--no-rt").start()
    with h.Client(rt.port) as c:
        assert c.read_coils(0) == [True]
    rc = rt.stop(sig)
    rt.assert_clean_exit(rc)
    log = rt.log
    order = [log.index(f"{sig.name} received: stopping"),
             log.index("outputs safe (all coils cleared, I/O outputs at zero)"),
             log.index("stats scans="), log.rindex("plc-runtime: stopped")]
    assert order == sorted(order), log


# ----------------------------------------------------------------- I/O layers

def test_io_none_does_not_loop_outputs_back(binary):
    with h.Runtime(binary, "--no-rt", "--io", "none") as rt, h.Client(rt.port) as c:
        c.write_register(512, 77)
        c.write_coil(400, True)
        h.wait_scans(c)                                          # both writes went through a whole scan
        assert c.read_input(512) == [0] and c.read_discrete(400) == [False]
        assert c.read_holding(1) == [1]                          # %QW1 := %IW512 + 1 with %IW512 = 0
    assert "I/O layer none" in rt.log


# ------------------------------------------------------------- start-up checks

@pytest.mark.parametrize("args, message", [
    (["--port", "70000"], "--port: '70000' is not a port number"),
    (["--io", "gpio"], "unknown I/O layer 'gpio'"),
    (["--bind", "999.1.1.1"], "--bind: '999.1.1.1' is not an IPv4 address"),
    (["--writable-coils", "700-900"], "outside 0-799"),
    (["--writable-registers", "12x"], "cannot read '12x'"),
    (["--allow", "localhost"], "--allow: 'localhost' is not an IPv4 address"),
    (["--max-clients", "0"], "--max-clients"),
    (["--frobnicate"], "unknown or incomplete option '--frobnicate'"),
    (["extra"], "unexpected argument 'extra'"),
])
def test_bad_options_are_usage_errors(binary, args, message):
    rc, err = run_to_end(binary, *args)
    assert rc == 2 and message in err, err
    assert "Traceback" not in err


def test_help_and_version(binary):
    result = subprocess.run([str(binary), "--help"], capture_output=True, text=True, timeout=10)
    assert result.returncode == 0 and "--writable-registers" in result.stdout
    result = subprocess.run([str(binary), "--version"], capture_output=True, text=True, timeout=10)
    assert result.returncode == 0 and result.stdout.startswith("plc-runtime ")


def test_a_port_in_use_fails_start_up_with_exit_2(binary):
    """An environment problem (exit 2, as a usage error; issue 27), found before anything is written."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        rc, err = run_to_end(binary, "--no-rt", "--port", str(port))
    assert rc == 2 and f"cannot listen on 127.0.0.1:{port}" in err, err


def test_a_missing_retain_directory_fails_start_up(binary, tmp_path):
    rc, err = run_to_end(binary, "--no-rt", "--port", "0", "--retain", str(tmp_path / "nope" / "plc.retain"))
    assert rc == 1 and "does not exist or is not writable" in err, err


def test_a_located_variable_of_the_wrong_size_is_refused():
    rc, err = run_to_end(h.runtime_binary(FIXTURE_BAD_LOCATED=1), "--no-rt", "--port", "0")
    assert rc == 1
    assert "located variable CONFIG0.RES0.MAIN.PRESET at %MW30: its type takes 8 bytes, the address 2" in err


def test_a_program_for_another_abi_is_refused():
    rc, err = run_to_end(h.runtime_binary(FIXTURE_ABI_VERSION=99), "--no-rt", "--port", "0")
    assert rc == 1 and "program built for ABI 99, this runtime speaks ABI 2" in err, err
