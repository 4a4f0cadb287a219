"""The runtime and its service manager: the notify protocol (READY, WATCHDOG pings while scans run, STATUS,
STOPPING) through a NOTIFY_SOCKET this test owns, and journald priorities when stderr is the journal.
Runs against the plain build, or the ASan/UBSan build with PLC_RUNTIME_SANITIZE=1.
"""
from __future__ import annotations

import os
import re
import socket
import subprocess
import time
from pathlib import Path

import pytest

import rt_harness as h


class NotifySocket:
    """The service manager's end of NOTIFY_SOCKET: a datagram socket the test binds."""

    def __init__(self, path: Path):
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.messages: list[tuple[float, str]] = []

    def receive(self, timeout: float) -> list[str]:
        """Every message that arrives within timeout seconds (each one split into its lines)."""
        out = []
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return out
            self.sock.settimeout(left)
            try:
                data = self.sock.recv(4096).decode()
            except socket.timeout:
                return out
            self.messages.append((time.monotonic(), data))
            out.extend(data.split("\n"))

    def drain(self) -> list[str]:
        """Every message already delivered, without waiting (a datagram is in the socket when its send returns)."""
        out = []
        self.sock.setblocking(False)
        try:
            while True:
                data = self.sock.recv(4096).decode()
                self.messages.append((time.monotonic(), data))
                out.extend(data.split("\n"))
        except BlockingIOError:
            return out
        finally:
            self.sock.setblocking(True)

    def wait_for(self, text: str, timeout: float) -> list[str]:
        seen: list[str] = []
        deadline = time.monotonic() + timeout * h.SLOW
        while time.monotonic() < deadline:
            seen += self.receive(0.05)
            if any(text in m for m in seen):
                return seen
        raise AssertionError(f"no {text!r} from the runtime; got {seen}")

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def notify(tmp_path):
    s = NotifySocket(tmp_path / "notify.sock")
    yield s
    s.close()


def test_ready_after_the_first_scan_then_watchdog_pings_while_scans_run(notify):
    env = {"NOTIFY_SOCKET": str(notify.path), "WATCHDOG_USEC": "200000"}
    with h.Runtime(h.runtime_binary(), "--no-rt", env=env) as rt, h.Client(rt.port) as c:
        seen = notify.wait_for("READY=1", 5)
        assert seen[0] == "READY=1" and h.read_diag(c)["scans"] >= 1
        assert "watchdog every 200 ms (pinged every 50 ms" in rt.log
        pings = notify.wait_for("WATCHDOG=1", 5)
        while sum(m == "WATCHDOG=1" for m in pings) < 5:
            pings += notify.wait_for("WATCHDOG=1", 5)
        rc = rt.stop()
    rt.assert_clean_exit(rc)
    assert "STOPPING=1" in notify.wait_for("STOPPING=1", 5)


def test_a_stuck_scan_stops_the_pings(notify):
    env = {"NOTIFY_SOCKET": str(notify.path), "WATCHDOG_USEC": "200000"}
    rt = h.Runtime(h.runtime_binary(), "--no-rt", "--watchdog", "100", "--status-interval", "0.1", env=env).start()
    try:
        with h.Client(rt.port) as c:
            notify.wait_for("WATCHDOG=1", 5)
            c.write_register(1024 + 10, 13)                   # the fixture loops forever in run()
        rt.wait_for(r"watchdog: the program has been inside run\(\)")
        notify.drain()                                        # a ping sent before the scan got stuck
        # the proof of time on the runtime's own clock: its log thread's status lines, 0.1 s apart on schedule;
        # the 1st and the 12th after the drain are more than 1 s apart (20 ping periods), every one with the
        # scan count the stuck scan left
        start = len(rt.log.splitlines())
        status = re.compile(r"status .*\| scans (\d+) \|")

        def counts() -> list[str]:
            return [m.group(1) for line in rt.log.splitlines()[start:] if (m := status.search(line))]

        h.wait_until(lambda: len(counts()) >= 12, 5, "12 status lines")
        assert len(set(counts())) == 1, f"the scan was not stuck throughout:\n{rt.log}"
        later = notify.drain()
        assert "WATCHDOG=1" not in later, later
    finally:
        rt.kill()                                             # what systemd does after WatchdogSec


def test_a_faulted_program_keeps_pinging_and_says_why(notify):
    env = {"NOTIFY_SOCKET": str(notify.path), "WATCHDOG_USEC": "200000"}
    with h.Runtime(h.runtime_binary(), "--no-rt", env=env) as rt, h.Client(rt.port) as c:
        notify.wait_for("READY=1", 5)
        c.write_register(1024 + 10, 7)                        # division by zero: program stopped, outputs safe
        seen = notify.wait_for("STATUS=FAULTED", 5)
        assert any("fault kind 1 at line 42" in m for m in seen), seen
        after = notify.wait_for("WATCHDOG=1", 5)
        assert "WATCHDOG=1" in after


def test_log_lines_carry_journald_priorities_when_stderr_is_the_journal(tmp_path):
    log = tmp_path / "journal"
    with open(log, "wb") as f:
        st = os.fstat(f.fileno())
        env = {**os.environ, **h.SANITIZER_ENV, "JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"}
        subprocess.run([str(h.runtime_binary()), "--port", "0", "--no-rt", "--duration", "0.3", "--watchdog", "0"],
                       stdout=subprocess.DEVNULL, stderr=f, env=env, timeout=30 * h.SLOW, check=True)
    lines = log.read_text().splitlines()
    assert lines and all(re.match(r"<[346]>", line) for line in lines), lines
    assert any(line.startswith("<4>warning: scan watchdog off") for line in lines), lines
    assert any(line.startswith("<6>running CONFIG0") for line in lines), lines


