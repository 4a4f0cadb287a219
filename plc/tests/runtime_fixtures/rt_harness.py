"""Helpers for the runtime tests: build the runtime, run it, talk Modbus to it.

Set PLC_RUNTIME_SANITIZE=1 to run the same tests against the AddressSanitizer +
UndefinedBehaviorSanitizer build of the runtime.
"""

from __future__ import annotations

import hashlib
import os
import random
import re
import signal
import socket
import struct
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Callable

FIXTURES = Path(__file__).resolve().parent
from plc.runtime import build_runtime  # noqa: E402

SANITIZE = os.environ.get("PLC_RUNTIME_SANITIZE", "") not in ("", "0")
CACHE = Path(tempfile.gettempdir()) / "atc-plc-runtime-tests"
BASIC = FIXTURES / "fixture_basic.c"
# Multiplier of every time-out in these tests. Time-outs only bound a hang: a verdict never depends on how fast
# the machine is, so they are set far above the typical time (a loaded CI machine, a sanitizer build), and
# ATC_TIMEOUT_SCALE stretches them further on a machine slower still.
SLOW = float(os.environ.get("ATC_TIMEOUT_SCALE", "1")) * (12.0 if SANITIZE else 4.0)

SANITIZER_ENV = {
    "ASAN_OPTIONS": "abort_on_error=0:halt_on_error=1:detect_leaks=1:exitcode=86",
    "UBSAN_OPTIONS": "halt_on_error=1:print_stacktrace=1:exitcode=87",
}


def write_if_changed(path: Path, text: str) -> None:
    """Write a file of the runtime-test cache, which concurrent test runs on one machine share: atomically
    (a reader never sees it half-written), and only when its text differs."""
    if path.exists() and path.read_text() == text:
        return
    tmp = path.with_name(f"{path.name}.{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)


def runtime_binary(program_c: Path = BASIC, **defines: object) -> Path:
    """The runtime built with a fixture program; `defines` become #defines in a wrapper."""
    if defines:
        CACHE.mkdir(parents=True, exist_ok=True)
        lines = [f"#define {k} {v}" for k, v in sorted(defines.items())]
        lines.append(f'#include "{program_c}"')
        text = "\n".join(lines) + "\n"
        key = hashlib.sha256(text.encode()).hexdigest()[:12]
        wrapper = CACHE / f"wrap_{program_c.stem}_{key}.c"
        write_if_changed(wrapper, text)
        program_c = wrapper
    return build_runtime(program_c, CACHE, sanitize=SANITIZE)


# The configuration of a test program: PROGRAM Main as instance inst0, every 4 ms.
MAIN_EVERY_4MS = """\
CONFIGURATION Config0
    RESOURCE Res0 ON PLC
        TASK MainTask(INTERVAL := T#4ms, PRIORITY := 0);
        PROGRAM inst0 WITH MainTask : Main;
    END_RESOURCE
END_CONFIGURATION
"""


def st_runtime_binary(src: Path, files: dict[str, str]) -> Path:
    """The runtime built around an ST program compiled by our compiler: `files` (name -> text) are written to
    the directory `src`, which must compile without errors."""
    from plc import driver
    src.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (src / name).write_text(text)
    result = driver.compile_sources([src])
    assert not result.diags.has_errors() and result.c_text, "the ST test program must compile"
    c_file = src / "program.c"
    c_file.write_text(result.c_text)
    return build_runtime(c_file, CACHE, sanitize=SANITIZE)


def tool_binary(name: str) -> Path:
    """A test client of runtime_fixtures/NAME.c (mbload, mbfuzz, mbhostile), built once per source version
    (no sanitizer: it is the tester, not the tested; OpenSSL for mbload's TLS connections)."""
    src = FIXTURES / f"{name}.c"
    CACHE.mkdir(parents=True, exist_ok=True)
    out = CACHE / f"{name}-{int(src.stat().st_mtime_ns)}"
    if not out.exists():
        tmp = out.with_suffix(f".{os.getpid()}")
        subprocess.run(["gcc", "-std=c11", "-O2", "-Wall", "-Wextra", "-Werror", str(src), "-o", str(tmp),
                        "-lpthread", "-lssl", "-lcrypto"], check=True)
        os.replace(tmp, out)
    return out


def mbload_binary() -> Path:
    """The load client."""
    return tool_binary("mbload")


_REALTIME_REFUSED: dict[Path, str | None] = {}


def realtime_refused(binary: Path) -> str | None:
    """None when the runtime `binary` gets SCHED_FIFO here (root, CAP_SYS_NICE, RLIMIT_RTPRIO), else the runtime's
    own warning saying why not: the reason a real-time test prints when it skips."""
    if binary not in _REALTIME_REFUSED:
        result = subprocess.run([str(binary), "--port", "0", "--status", "off", "--watchdog", "0", "--duration",
                                 "0.05"], capture_output=True, text=True, timeout=60 * SLOW, stdin=subprocess.DEVNULL,
                                env={**os.environ, **SANITIZER_ENV})
        granted = re.search(r"scan thread is SCHED_FIFO priority \d+", result.stderr)
        refused = re.search(r"real-time scheduling not permitted \([^)]*\)", result.stderr)
        _REALTIME_REFUSED[binary] = None if granted else (refused.group(0) if refused else
                                                          "the runtime did not say:\n" + result.stderr)
    return _REALTIME_REFUSED[binary]


def wait_until(predicate: Callable[[], object], timeout: float, what: str, step: float = 0.01):
    """Poll predicate until it returns something true; fail after timeout seconds."""
    deadline = time.monotonic() + timeout * SLOW
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout * SLOW:.1f} s waiting for {what}")
        time.sleep(step)


class Runtime:
    """A running runtime process; its stderr is collected line by line."""

    def __init__(self, binary: Path, *args: str, cwd: Path | None = None, raw: bool = False,
                 env: dict[str, str] | None = None):
        """Start `binary` with test defaults (any free port, no status lines) before `args`,
        or with exactly `args` when raw; `env` is added to the environment."""
        env = {**os.environ, **SANITIZER_ENV, **(env or {})}
        defaults = [] if raw else ["--port", "0", "--status", "log", "--status-interval", "3600"]
        self.argv = [str(binary), *defaults, *args]
        self.proc = subprocess.Popen(self.argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, cwd=cwd, env=env, text=True,
                                     start_new_session=True)
        self.lines: list[str] = []
        self._cond = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self.port = 0

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            with self._cond:
                self.lines.append(line.rstrip("\n"))
                self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    @property
    def log(self) -> str:
        with self._cond:
            return "\n".join(self.lines)

    def wait_for(self, pattern: str, timeout: float = 5.0) -> re.Match:
        """Wait for a log line matching pattern (regex); return the match."""
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout * SLOW
        with self._cond:
            seen = 0
            while True:
                for line in self.lines[seen:]:
                    m = rx.search(line)
                    if m:
                        return m
                seen = len(self.lines)
                left = deadline - time.monotonic()
                if left <= 0 or (self.proc.poll() is not None and not self._reader.is_alive()):
                    raise AssertionError(f"no log line matching {pattern!r}; log so far:\n" + "\n".join(self.lines))
                self._cond.wait(min(left, 0.1))

    def start(self) -> "Runtime":
        m = self.wait_for(r"modbus: listening on [\d.]+:(\d+)")
        self.port = int(m.group(1))
        self.wait_for(r"running ")
        return self

    def wait(self, timeout: float) -> int:
        """Wait for the runtime to exit by itself and for its last log lines; return its exit status."""
        rc = self.proc.wait(timeout)
        self._reader.join(5)
        return rc

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 10.0) -> int:
        """Signal the runtime and wait for it; return its exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            rc = self.proc.wait(timeout * SLOW)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
            raise AssertionError(f"runtime did not stop within {timeout * SLOW:.0f} s; log:\n{self.log}") from None
        self._reader.join(5)
        return rc

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(10)
        self._reader.join(5)

    def assert_clean_exit(self, rc: int) -> None:
        log = self.log
        assert rc == 0, f"exit status {rc}; log:\n{log}"
        for marker in ("ERROR: AddressSanitizer", "ERROR: LeakSanitizer", "runtime error:"):
            assert marker not in log, f"sanitizer report in the log:\n{log}"

    def __enter__(self) -> "Runtime":
        return self.start()

    def __exit__(self, *exc) -> None:
        if self.proc.poll() is None:
            rc = self.stop()
            if exc[0] is None:
                self.assert_clean_exit(rc)
        else:
            self._reader.join(5)


# ---------------------------------------------------------------------- Modbus client

# libmodbus's names (modbus.h)
MODBUS_FC_READ_COILS = 0x01
MODBUS_FC_READ_DISCRETE_INPUTS = 0x02
MODBUS_FC_READ_HOLDING_REGISTERS = 0x03
MODBUS_FC_READ_INPUT_REGISTERS = 0x04
MODBUS_FC_WRITE_SINGLE_COIL = 0x05
MODBUS_FC_WRITE_SINGLE_REGISTER = 0x06
MODBUS_FC_WRITE_MULTIPLE_COILS = 0x0F
MODBUS_FC_WRITE_MULTIPLE_REGISTERS = 0x10
MODBUS_EXCEPTION_ILLEGAL_FUNCTION = 0x01
MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS = 0x02
MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE = 0x03


class ModbusError(Exception):
    def __init__(self, function: int, code: int):
        super().__init__(f"exception {code} to function {function}")
        self.function = function
        self.code = code


class Client:
    """A minimal Modbus/TCP client on a plain socket, one request at a time."""

    def __init__(self, port: int, host: str = "127.0.0.1", source: str | None = None, timeout: float = 3.0):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.sock.settimeout(timeout * SLOW)
        if source:
            self.sock.bind((source, 0))
        self.sock.connect((host, port))
        self.tid = 0

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def send_raw(self, data: bytes) -> None:
        self.sock.sendall(data)

    def recv_exact(self, n: int) -> bytes:
        out = b""
        while len(out) < n:
            chunk = self.sock.recv(n - len(out))
            if not chunk:
                raise ConnectionError("connection closed by the server")
            out += chunk
        return out

    def recv_frame(self) -> tuple[int, int, bytes]:
        """Receive one response: (transaction id, unit, PDU)."""
        head = self.recv_exact(7)
        tid, proto, length, unit = struct.unpack(">HHHB", head)
        assert proto == 0, f"protocol id {proto}"
        assert 2 <= length <= 254, f"MBAP length {length}"
        return tid, unit, self.recv_exact(length - 1)

    def request(self, pdu: bytes, unit: int = 1) -> bytes:
        self.tid = (self.tid + 1) & 0xFFFF
        self.send_raw(struct.pack(">HHHB", self.tid, 0, len(pdu) + 1, unit) + pdu)
        tid, runit, rsp = self.recv_frame()
        assert tid == self.tid, f"transaction id {tid}, expected {self.tid}"
        assert runit == unit, f"unit {runit}, expected {unit}"
        if rsp[0] == pdu[0] | 0x80:
            raise ModbusError(pdu[0], rsp[1])
        assert rsp[0] == pdu[0], f"function {rsp[0]} in response to {pdu[0]}"
        return rsp

    # reads
    def _read_bits(self, fc: int, addr: int, count: int) -> list[bool]:
        rsp = self.request(struct.pack(">BHH", fc, addr, count))
        assert rsp[1] == (count + 7) // 8 and len(rsp) == 2 + rsp[1]
        return [bool(rsp[2 + i // 8] >> (i % 8) & 1) for i in range(count)]

    def _read_regs(self, fc: int, addr: int, count: int) -> list[int]:
        rsp = self.request(struct.pack(">BHH", fc, addr, count))
        assert rsp[1] == 2 * count and len(rsp) == 2 + 2 * count
        return list(struct.unpack(f">{count}H", rsp[2:]))

    def read_coils(self, addr: int, count: int = 1) -> list[bool]:
        return self._read_bits(1, addr, count)

    def read_discrete(self, addr: int, count: int = 1) -> list[bool]:
        return self._read_bits(2, addr, count)

    def read_holding(self, addr: int, count: int = 1) -> list[int]:
        return self._read_regs(3, addr, count)

    def read_input(self, addr: int, count: int = 1) -> list[int]:
        return self._read_regs(4, addr, count)

    # writes
    def write_coil(self, addr: int, on: bool) -> None:
        pdu = struct.pack(">BHH", 5, addr, 0xFF00 if on else 0)
        assert self.request(pdu) == pdu

    def write_register(self, addr: int, value: int) -> None:
        pdu = struct.pack(">BHH", 6, addr, value & 0xFFFF)
        assert self.request(pdu) == pdu

    def write_coils(self, addr: int, values: list[bool]) -> None:
        packed = bytearray((len(values) + 7) // 8)
        for i, v in enumerate(values):
            if v:
                packed[i // 8] |= 1 << (i % 8)
        rsp = self.request(struct.pack(">BHHB", 15, addr, len(values), len(packed)) + bytes(packed))
        assert rsp == struct.pack(">BHH", 15, addr, len(values))

    def write_registers(self, addr: int, values: list[int]) -> None:
        data = struct.pack(f">{len(values)}H", *[v & 0xFFFF for v in values])
        rsp = self.request(struct.pack(">BHHB", 16, addr, len(values), len(data)) + data)
        assert rsp == struct.pack(">BHH", 16, addr, len(values))


# --------------------------------------------------------------- diagnostic registers

DIAG_BASE = 1024
DIAG = {  # offset, words
    "version": (0, 1), "state": (1, 1), "fault_kind": (2, 1), "fault_line": (3, 1), "fault_col": (4, 1),
    "flags": (5, 1), "base_tick_us": (6, 2), "scans": (8, 4),
    "scan_last_us": (12, 2), "scan_min_us": (14, 2), "scan_max_us": (16, 2), "scan_mean_us": (18, 2),
    "scan_p99_us": (20, 2), "wake_last_us": (22, 2), "wake_min_us": (24, 2), "wake_max_us": (26, 2),
    "wake_mean_us": (28, 2), "wake_p99_us": (30, 2), "overruns": (32, 2), "clients": (34, 1),
    "requests": (36, 2), "exceptions": (38, 2), "refused": (40, 2), "retain_saves": (42, 2),
    "scan_p50_us": (44, 2), "wake_p50_us": (46, 2), "uptime_s": (48, 2), "skipped": (50, 2),
    "dropped": (52, 2), "writes": (56, 2), "writes_refused": (58, 2),
}
STATE_RUNNING, STATE_FAULTED = 1, 2
FLAG_RETAIN_RESTORED, FLAG_RETAIN_REJECTED = 0x2, 0x4


def read_diag(client: Client) -> dict[str, int]:
    regs = client.read_input(DIAG_BASE, 64)
    out = {}
    for name, (off, words) in DIAG.items():
        value = 0
        for w in regs[off:off + words]:
            value = value << 16 | w
        out[name] = value
    return out


def wait_for_scans(scans: Callable[[], int], n: int, timeout: float = 5.0) -> int:
    """Wait until the scan counter read by `scans()` has advanced by n from its value now; return the value reached.

    The proof a negative check needs that the runtime had the chance to act: whatever it acknowledged before this
    call (a host write queued, a request refused, inputs it polled) has gone through the input latch and the output
    publication of at least n - 1 whole scans; the scan under way at the call may have latched its inputs before,
    so n is at least 2.  A counter that stops (a program stuck in run()) is a failure after the timeout, never a
    pass."""
    assert n >= 2, "one more scan may have latched its inputs before the call: wait for 2 at least"
    start = scans()

    def advanced() -> int:
        now = scans()
        return now if now >= start + n else 0

    return wait_until(advanced, timeout, f"{n} more scans than the {start} counted at the start")


def wait_scans(client: Client, n: int = 2, timeout: float = 5.0) -> int:
    """wait_for_scans on the runtime's diagnostic block (scans run, input registers 1032..1035) through client."""
    return wait_for_scans(lambda: read_diag(client)["scans"], n, timeout)


def wait_timeout_check(port: int, timeout: float = 10.0) -> None:
    """Wait until the server has checked its clients' time-outs at least one frame time-out after this call began.

    The proof for "the server kept this idle connection": a new connection sends the first 4 bytes of a request
    and nothing more; the server drops it by its frame time-out (--frame-timeout) no earlier than that long after
    it read them, in the same pass over every client that would have dropped any other connection it meant to.
    The connection is reset by the server; a hang is a failure after the timeout."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout * SLOW) as s:
        s.sendall(b"\x00\x01\x00\x00")
        try:
            while s.recv(4096):
                pass
        except ConnectionResetError:
            pass
        except socket.timeout:
            raise AssertionError(f"the server did not drop half a request within {timeout * SLOW:.0f} s") from None


def md(words: list[int]) -> int:
    """Two registers, high word first, as a signed 32-bit value."""
    v = words[0] << 16 | words[1]
    return v - (1 << 32) if v & 0x80000000 else v


def md_words(value: int) -> list[int]:
    v = value & 0xFFFFFFFF
    return [v >> 16, v & 0xFFFF]


# ---------------------------------------------------------------------- kill -9 trials

def kill_trials(binary: Path, directory: Path, trials: int, seed: int = 9,
                deadline_s: float | None = None) -> dict[str, int]:
    """Run the fixture runtime `trials` times, killing it with SIGKILL at random instants while its writer
    saves after every scan (--retain-interval 0), and check every retain file left behind.

    Counts: `killed_mid_write` (a .tmp file was left: the kill hit a save in progress), `corrupt` (a file that
    does not decode, or lacks the fixture's two entries), `lost` (a file older than a save completed before,
    a keep value other than the last one written, or a restart that did not restore both values),
    `rejected` (a restart that set the file aside), `applied_checked` (restarts whose applied scans counter
    was compared with the file).  `binary` must be the fixture built with a 1 ms tick."""
    from plc import retainfile

    f, tmp = directory / "plc.retain", directory / "plc.retain.tmp"
    keep_path, scans_path = "CONFIG0.RES0.MAIN.KEEP", "CONFIG0.RES0.MAIN.SCANS"
    rng = random.Random(seed)
    out = {"trials": 0, "killed_mid_write": 0, "corrupt": 0, "lost": 0, "rejected": 0, "applied_checked": 0}
    last_completed, keep = -1, 0
    started = time.monotonic()

    def decode() -> tuple[int, int] | None:
        try:
            active = retainfile.read(f).active()
            return active[keep_path].number(), active[scans_path].number()
        except (retainfile.RetainFileError, KeyError):
            return None

    for trial in range(trials):
        if deadline_s is not None and time.monotonic() - started > deadline_s * SLOW:
            raise AssertionError(f"too slow: {trial} of {trials} trials in {deadline_s * SLOW:.0f} s")
        saved_before = f.exists()
        rt = Runtime(binary, "--no-rt", "--retain", str(f), "--retain-interval", "0", "--status", "off")
        try:
            rt.start()
            if saved_before and ("retain: restored 2 of 2 values" not in rt.log):
                out["lost"] += 1
            out["rejected"] += "rejected" in rt.log
            if trial % 10 == 5 or (saved_before and trial % 20 == 1):
                with Client(rt.port) as c:
                    wait_until(lambda: read_diag(c)["scans"] >= 1, 2, "the first scan")
                    if saved_before and trial % 20 == 1:      # the runtime applied exactly that file
                        s1 = read_diag(c)["scans"]
                        w = c.read_holding(2058, 2)
                        s2 = read_diag(c)["scans"]
                        applied = w[0] << 16 | w[1]
                        out["lost"] += not (last_completed + s1 <= applied <= last_completed + s2)
                        out["applied_checked"] += 1
                    if trial % 10 == 5:                       # a new keep value, saved before the kill
                        keep = rng.randint(1, 30000)
                        c.write_register(1024 + 20, keep)
                        wait_until(lambda keep=keep: (decode() or (0, 0))[0] == keep, 3, "the new keep value saved")
            time.sleep(rng.uniform(0.0, 0.03))
            seen = decode()                                   # a completed save, whatever happens next
            time.sleep(rng.uniform(0.0, 0.004))
        finally:
            rt.proc.send_signal(signal.SIGKILL)
            rt.kill()
        out["trials"] += 1
        out["killed_mid_write"] += tmp.exists()
        if not f.exists():
            out["lost"] += saved_before
            continue                                          # killed before the very first save
        after = decode()
        if after is None:
            out["corrupt"] += 1
            continue
        seen_scans = seen[1] if seen else -1
        if not (after[1] >= seen_scans >= last_completed) or (keep and after[0] != keep):
            out["lost"] += 1
        last_completed = after[1]
    return out
