"""kill -9 trials of the retained store, shared by the test suite (200 trials) and the
benchmark (scripts/bench-hardening --kill-trials 1000).

Each trial starts the runtime (1 ms scans, a save after every scan), kills it with SIGKILL
at a random instant while the writer is saving, and checks what is on disk: the file must
be one complete save (magic, size, CRC), never older than a save already seen complete,
and the next start must restore it without rejecting it.  Every 20th trial also checks
that the runtime applied exactly that file (the retained scan counter goes on from it).
"""

from __future__ import annotations

import random
import signal
import struct
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import rt_harness as h

HEADER = 28
PAYLOAD = 6                                   # keep (2 bytes) + scans (4 bytes), native little-endian


class Corrupt(Exception):
    pass


def parse(path: Path, payload: int = PAYLOAD) -> dict:
    """Check a retain file the way the runtime must (magic, size, CRC) and decode it."""
    data = path.read_bytes()
    if len(data) != HEADER + payload + 4:
        raise Corrupt(f"size {len(data)}")
    if data[:8] != b"ATCPLCR1":
        raise Corrupt("magic")
    version, layout, gen_lo, gen_hi, length = struct.unpack("<IIIII", data[8:28])
    if version != 1 or length != payload:
        raise Corrupt(f"version {version}, length {length}")
    (crc,) = struct.unpack("<I", data[-4:])
    if zlib.crc32(data[:-4]) != crc:
        raise Corrupt("CRC")
    out = {"layout": layout, "generation": gen_hi << 32 | gen_lo}
    if payload == PAYLOAD:
        out["keep"], out["scans"] = struct.unpack("<hI", data[HEADER:HEADER + payload])
    return out


def keep_and_scans(c: h.Client) -> tuple[int, int]:
    keep = c.read_holding(1024 + 21)[0]
    return keep - 65536 if keep & 0x8000 else keep, (lambda w: w[0] << 16 | w[1])(c.read_holding(2058, 2))


@dataclass
class TrialReport:
    trials: int = 0
    mid_write: int = 0                        # kills that left a half-written temporary file
    lost: int = 0                             # the file went back behind a save seen complete
    corrupt: int = 0                          # the file was damaged, or the next start rejected it
    not_applied: int = 0                      # the runtime did not go on from the file it restored
    seconds: float = 0.0
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.lost == self.corrupt == self.not_applied == 0


def kill_trials(directory: Path, trials: int, seed: int = 9, hang_limit_s: float | None = None) -> TrialReport:
    binary = h.runtime_binary(FIXTURE_BASE_TICK_NS="1000000u")
    f = directory / "plc.retain"
    tmp = directory / "plc.retain.tmp"
    rng = random.Random(seed)
    report = TrialReport()
    last_completed = -1
    started = time.monotonic()
    deadline = started + (hang_limit_s if hang_limit_s is not None else 1.2 * trials) * h.SLOW
    for trial in range(trials):
        if time.monotonic() > deadline:
            raise AssertionError(f"kill trials hung: {trial} of {trials} done")
        saved_before = f.exists()
        rt = h.Runtime(binary, "--no-rt", "--retain", str(f), "--retain-interval", "0", "--status", "off")
        seen = -1
        try:
            rt.start()
            if saved_before and ("retain: restored 6 bytes" not in rt.log or "rejected" in rt.log):
                report.corrupt += 1
                report.problems.append(f"trial {trial}: the start did not restore the file:\n{rt.log}")
            if saved_before and trial % 20 == 1:              # the runtime applied exactly that file
                with h.Client(rt.port) as c:
                    h.wait_until(lambda: h.read_diag(c)["scans"] >= 1, 2, "the first scan")
                    s1 = h.read_diag(c)["scans"]
                    scans = keep_and_scans(c)[1]
                    s2 = h.read_diag(c)["scans"]
                if not last_completed + s1 <= scans <= last_completed + s2:
                    report.not_applied += 1
                    report.problems.append(f"trial {trial}: scans {scans} not in "
                                           f"{last_completed}+[{s1}, {s2}]")
            time.sleep(rng.uniform(0.0, 0.03))
            try:
                seen = parse(f)["scans"] if f.exists() else -1    # a completed save, whatever happens next
            except Corrupt as exc:
                report.corrupt += 1
                report.problems.append(f"trial {trial}: a complete save read back damaged: {exc}")
            time.sleep(rng.uniform(0.0, 0.004))
        finally:
            rt.proc.send_signal(signal.SIGKILL)
            rt.kill()
        report.trials += 1
        report.mid_write += tmp.exists()
        if not f.exists():
            if saved_before:
                report.lost += 1
                report.problems.append(f"trial {trial}: the file disappeared")
            continue                                          # killed before the very first save
        try:
            after = parse(f)                                  # complete and consistent
        except Corrupt as exc:
            report.corrupt += 1
            report.problems.append(f"trial {trial}: {exc}")
            f.unlink()
            last_completed = -1
            continue
        if not after["scans"] >= seen >= last_completed:
            report.lost += 1
            report.problems.append(f"trial {trial}: file {after['scans']}, seen {seen}, before {last_completed}")
        last_completed = after["scans"]
    report.seconds = time.monotonic() - started
    return report
