"""System tests: `plc run` with the real application and the simulated carousel, driven over Modbus/TCP by
`plc host` (separate processes, as an integrator runs them).  Loopback only; every wait is bounded."""
from __future__ import annotations

import re
import signal
import socket
import subprocess
import sys
import threading
import time
from itertools import pairwise
from pathlib import Path

import pytest

from plc.modbus import ModbusClient
from atc.host.tags import Tags, load_map
from atc.runsetup import runtime_setup

REPO = Path(__file__).resolve().parents[2]
RMAP = load_map(REPO / "modbus_map" / "map.toml")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Plc:
    """`plc run st_src --config machines/default/runtime.toml` on a free port with its own retain file."""

    def __init__(self, tmp: Path):
        self.tmp, self.port, self.proc = tmp, free_port(), None
        self.src = REPO / "st_src"                 # another application: a copy with other generated tables
        self.log = tmp / "plc.log"

    def start(self, timeout: float = 180.0) -> None:
        cmd = [sys.executable, "-m", "plc.cli", "run", str(self.src), "--config",
               str(REPO / "machines" / "default" / "runtime.toml"), "--io", "sim", "--port", str(self.port), "--retain",
               str(self.tmp / "plc.retain"), "--build-dir", str(REPO / "build" / "runtime")]
        if self.src != REPO / "st_src":
            # a copy outside the project gets no application setup from it: the copy's simulated plant by name
            cmd += ["--sim-flag", runtime_setup(REPO / "modbus_map" / "map.toml", self.tmp).sim_flag]
        offset = self.log.stat().st_size if self.log.exists() else 0
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen(cmd, cwd=REPO / "plc", stdout=log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise AssertionError(f"plc run exited {self.proc.returncode}:\n{self.log.read_text()[-3000:]}")
            if f"listening on 127.0.0.1:{self.port}" in self.log.read_text(errors="replace")[offset:]:
                return
            time.sleep(0.1)
        raise AssertionError(f"plc run did not listen within {timeout} s:\n{self.log.read_text()[-3000:]}")

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)

    def host(self, *words: str, timeout: float = 90.0) -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-m", "plc.cli", "host", "--port", str(self.port), *words]
        return subprocess.run(cmd, cwd=REPO / "plc", capture_output=True, text=True, timeout=timeout)

    def tags(self) -> tuple[ModbusClient, Tags]:
        client = ModbusClient("127.0.0.1", self.port)
        client.connect()
        return client, Tags(RMAP, client)


@pytest.fixture(scope="module")
def plc(tmp_path_factory):
    p = Plc(tmp_path_factory.mktemp("plc"))
    p.start()
    yield p
    p.stop()


def ok(result: subprocess.CompletedProcess) -> str:
    assert result.returncode == 0, f"exit {result.returncode}\n{result.stdout}\n{result.stderr}"
    return result.stdout


def m6_seconds(out: str) -> float:
    return float(re.search(r"M6: tool \d+ in spindle after ([0-9.]+) s", out).group(1))


def test_t5_m6_changes_the_tool_and_prints_it(plc):
    out = ok(plc.host("clear", "T5 M6"))
    assert out.splitlines()[-1] == "tool 5 in spindle"
    client, tags = plc.tags()
    with client:
        assert tags.get("ToolInSpindle") == 5
        assert tags.get("PocketTool5") == 0
    print(f"M6 T5 (empty spindle, Get Tool only): {m6_seconds(out):.2f} s")


def test_a_change_puts_the_old_tool_back_into_its_pocket(plc):
    ok(plc.host("T5 M6"))
    out = ok(plc.host("T3 M6"))
    assert out.splitlines()[-1] == "tool 3 in spindle"
    client, tags = plc.tags()
    with client:
        values = tags.read("ToolInSpindle", "PocketTool5", "PocketTool3", "FaultReason")
    assert values == {"ToolInSpindle": 3, "PocketTool5": 5, "PocketTool3": 0, "FaultReason": 0}
    print(f"M6 T5 -> T3 (Put Tool + Get Tool): {m6_seconds(out):.2f} s")


def test_t0_unloads_and_the_same_tool_is_no_change(plc):
    ok(plc.host("T2 M6"))
    out = ok(plc.host("T2 M6"))
    assert "nothing to change" in out or "M6: tool 2" in out
    assert ok(plc.host("T0 M6")).splitlines()[-1] == "tool 0 in spindle"


def test_t0_is_legal_with_an_empty_spindle_and_the_next_m6_completes(plc):
    """Issue 13: `plc host T0` then `plc host "T5 M6"` used to exit 3 (soft fault 106 latched by the T0 prepare)."""
    ok(plc.host("clear", "T0 M6"))                  # an empty spindle to start from
    assert ok(plc.host("T0 M6")).splitlines()[-1] == "tool 0 in spindle"
    ok(plc.host("T0"))
    client, tags = plc.tags()
    with client:
        assert tags.read("FaultReason", "ToolInSpindle") == {"FaultReason": 0, "ToolInSpindle": 0}
    assert ok(plc.host("T5 M6")).splitlines()[-1] == "tool 5 in spindle"
    assert ok(plc.host("T0 M6")).splitlines()[-1] == "tool 0 in spindle"


def test_a_pocket_outside_the_carousel_is_a_soft_fault_and_clear_recovers(plc):
    result = plc.host("T0 M6", "T60 M6")
    out = result.stdout
    assert result.returncode == 3, out + result.stderr
    assert "soft fault" in out and "#5601 = 106" in out
    assert out.splitlines()[-1] == "tool 0 in spindle"
    assert "clear: no fault" in ok(plc.host("clear"))
    assert ok(plc.host("T4 M6")).splitlines()[-1] == "tool 4 in spindle"


def test_estop_during_a_change_is_a_hard_fault_the_host_reports_and_exits_1(plc):
    ok(plc.host("clear", "T1 M6"))
    client, tags = plc.tags()
    with client:
        def press() -> None:          # open the simulated E-stop chain once the change runs
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and not tags.get("ChangerBusy"):
                time.sleep(0.01)
            tags.write(SimEStop=True)
        presser = threading.Thread(target=press)
        presser.start()
        result = plc.host("T6 M6")
        presser.join(35)
        tags.write(SimEStop=False)
    assert result.returncode == 1, result.stdout + result.stderr
    assert "toolchanger error -101" in result.stdout
    out = ok(plc.host("clear"))
    assert "clear: no fault" in out
    assert ok(plc.host("T6 M6")).splitlines()[-1] == "tool 6 in spindle"


def test_abort_and_status(plc):
    out = ok(plc.host("abort", "status"))
    assert "acknowledged by the PLC" in out and "tool in spindle" in out


def test_a_host_that_exits_normally_left_and_a_killed_one_lost_its_link(plc):
    """Issue 27: the runtime's log said "host link lost" (a warning) every time `plc host` ended normally. A
    clean exit writes its last heartbeat (65535) and the log says the host left; a killed host still loses its
    link. Each waits for the line that proves the PLC saw the link end."""
    def lines_after(offset: int, pattern: str, timeout: float = 30.0) -> str:
        deadline = time.monotonic() + timeout
        while True:
            text = plc.log.read_text(errors="replace")[offset:]
            if re.search(pattern, text):
                return text
            assert time.monotonic() < deadline, f"no {pattern!r} in the log:\n{text[-3000:]}"
            time.sleep(0.2)

    # The PLC tells a host's end by its heartbeat standing still for the link time-out (2 s), then names it by the
    # last value. So the previous test's host may be logged as leaving after any offset taken now, or, on a fast
    # machine, never (this host beats before the time-out ran out). Start from a link the PLC has seen drop:
    # every session is then one "host link restored" and one end, recognised by its own lines.
    client, tags = plc.tags()
    with client:
        deadline = time.monotonic() + 30
        while tags.get("HostLinkOk"):
            assert time.monotonic() < deadline, "the link of the previous test's host never dropped"
            time.sleep(0.1)
    offset = plc.log.stat().st_size
    ok(plc.host("status"))
    text = lines_after(offset, r"host link restored(.*\n)*.*host left: its last heartbeat was 65535 \(a clean exit\)")
    session = text[text.index("host link restored"):]
    assert "host link lost" not in session, text
    offset = plc.log.stat().st_size
    victim = subprocess.Popen([sys.executable, "-m", "plc.cli", "host", "--port", str(plc.port)], cwd=REPO / "plc",
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines_after(offset, r"host link restored")
    victim.send_signal(signal.SIGKILL)
    victim.wait(10)
    text = lines_after(offset, r"host link restored(.*\n)*.*warning: host link lost: no heartbeat change from the host")
    session = text[text.index("host link restored"):]
    assert "host left" not in session, text


def test_the_tool_in_the_spindle_survives_a_restart_of_the_plc(tmp_path):
    p = Plc(tmp_path)
    p.start()
    try:
        ok(p.host("T5 M6"))
        time.sleep(0.5)                       # the retain writer saves within 200 ms of the change
    finally:
        p.stop()
    p.start()
    try:
        out = ok(p.host("status"))
        assert "connected to 127.0.0.1" in out and ": tool 5 in spindle" in out.splitlines()[0]
        assert ok(p.host("T2 M6")).splitlines()[-1] == "tool 2 in spindle"
    finally:
        p.stop()


def _located(first: int, last: int) -> tuple[int, int]:
    """The first and last holding register of the map's signals between first and last (Signal.words each)."""
    from atc.host.tags import load_map
    regs = [a for sig in load_map(REPO / "modbus_map" / "map.toml").signals
            if sig.table == "holding_register" and first <= sig.address <= last
            for a in range(sig.address, sig.address + sig.words)]
    return min(regs), max(regs)


MW_FIRST, MW_LAST = _located(1024, 2047)    # the located %MW words of the map
MD_FIRST, MD_LAST = _located(2048, 4095)    # the located %MD words (high word first)


def read_span(tags: Tags, first: int, last: int) -> list[int]:
    """Holding registers first..last, in requests of at most 124 words (Modbus allows 125; a %MD pair stays in
    one request: the tool table made the %MW span longer than one request)."""
    words: list[int] = []
    for at in range(first, last + 1, 124):
        words += tags.client.read_holding(at, min(124, last + 1 - at))
    return words


def mw_words(tags: Tags) -> tuple[list[int], list[int]]:
    """The %MW words and the %MD double words, read at rest."""
    mw = read_span(tags, MW_FIRST, MW_LAST)
    md = read_span(tags, MD_FIRST, MD_LAST)
    return mw, [(md[i] << 16) | md[i + 1] for i in range(0, len(md), 2)]


def openplc_checksum(words: tuple[list[int], list[int]]) -> int:
    """OpenPLC v3's persistent-storage change check: a 32-bit XOR of every %MW word and every %MD double word
    (webserver/core/persistent_storage.cpp, calculate_combined_checksum)."""
    out = 0
    for w in words[0] + words[1]:
        out ^= w
    return out


def test_an_abort_at_the_handover_is_recovered_with_home_and_confirm(plc):
    """T5 M6 with tool 2 in the spindle, aborted by a second host while Put Tool has the collet open: the first host
    ends at once; the next M6 is refused naming the recovery; `home`, then `confirm` of the tool the simulated
    spindle really holds; then T5 M6 completes.  Along the way, OpenPLC's persistent-storage check (an XOR of the
    %MW and %MD words) changes whenever a %MW word changed."""
    ok(plc.host("clear", "T2 M6"))
    client, tags = plc.tags()
    with client:
        snapshots = [mw_words(tags)]
        # The test answers the mailbox itself (MbxHostActive; the first host runs with --no-mailbox so that it does
        # not answer too) and leaves the MOVEABS of Put step 16 (spindle up, collet open) unanswered: the sequence
        # waits there however slow the machine is.
        tags.write(MbxHostActive=True)
        first = subprocess.Popen([sys.executable, "-m", "plc.cli", "host", "--port", str(plc.port), "--timeout", "600",
                                  "--no-mailbox", "T5 M6"], cwd=REPO / "plc", stdout=subprocess.PIPE,
                                 stderr=subprocess.STDOUT, text=True)
        try:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                s = tags.read("SeqKind", "SeqStep", "MbxRequestPending", "MbxRequestId")
                if s["SeqKind"] == 3 and s["SeqStep"] == 16:
                    break
                if s["MbxRequestPending"]:
                    tags.write(MbxAnswerResult=1)
                    tags.write(MbxAnswerId=s["MbxRequestId"])
                time.sleep(0.005)
            else:
                raise AssertionError("Put Tool never reached step 16")
            # the second host: an HMI's raw abort (reason first, then emc-abort, held until its ack)
            tags.write(EmcReason=8)
            tags.write(EmcAbort=True)
            deadline = time.monotonic() + 30
            while not tags.get("EmcAbortAck") and time.monotonic() < deadline:
                time.sleep(0.005)
            tags.write(EmcAbort=False)
            out_first, _ = first.communicate(timeout=120)
        finally:
            tags.write(MbxHostActive=False)
            if first.poll() is None:
                first.kill()
        assert first.returncode == 1, out_first
        assert "timeout:" not in out_first and "M6 aborted by" in out_first, out_first
        s = tags.read("FaultReason", "Recovery", "ToolInSpindle", "UncertainTool")
        assert s["FaultReason"] == -103 and s["Recovery"] == 3, s      # step 16: home, then confirm
        snapshots.append(mw_words(tags))

        # where a CNC executing the handover's Z move would have stopped: part-way up, the spindle nose still in
        # the holder the fork now carries (the simulated changer takes the host's report)
        tags.write(HostPosZ=-350)
        ok(plc.host("clear"))
        refused = plc.host("T5 M6")
        assert refused.returncode == 1 and "toolchanger error -107" in refused.stdout, refused.stdout
        home = ok(plc.host("clear", "home"))
        # the Home sequence found the collet open: Z up to the clear height (P1 -5) first, then the arm (its only
        # move; the host started from the reported Z -35)
        assert re.findall(r"mailbox #\d+: (MOVEABS .*): done", home) == ["MOVEABS Z-5 (G53 G1, F 10 units/s)"], home
        s = tags.read("Recovery", "ToolInSpindle", "UncertainTool", "SimSpindleTool", "HostPosZ")
        assert s["HostPosZ"] == -50, s
        assert not s["Recovery"] & 1, s
        assert s["Recovery"] == 2 and s["ToolInSpindle"] == -1 and s["UncertainTool"] == 2, s
        assert "plc host confirm 2" in home, home
        wrong = plc.host("confirm", "4")
        assert wrong.returncode == 1 and "confirm 2" in wrong.stdout, wrong.stdout
        refused = plc.host("T5 M6")
        assert refused.returncode == 1 and "toolchanger error -108" in refused.stdout, refused.stdout
        ok(plc.host("clear", "confirm", str(s["SimSpindleTool"])))
        s = tags.read("Recovery", "ToolInSpindle", "SimSpindleTool")
        assert s["Recovery"] == 0 and s["ToolInSpindle"] == s["SimSpindleTool"], s
        snapshots.append(mw_words(tags))
        assert ok(plc.host("T5 M6")).splitlines()[-1] == "tool 5 in spindle"
        s = tags.read("SimSpindleTool", "PocketTool2", "PocketTool5")
        assert (s["SimSpindleTool"], s["PocketTool2"], s["PocketTool5"]) == (5, 2, 0), s
        snapshots.append(mw_words(tags))
    for a, b in pairwise(snapshots):
        if a[0] != b[0]:
            assert openplc_checksum(a) != openplc_checksum(b), \
                "the %MW words changed but OpenPLC's XOR checksum did not: it would not save them"
