"""The application's events on the runtime's log and status line, with the real application and the simulated
carousel: tool change (from, to, duration), prepare, fault raised and cleared with its text from
reason_codes.toml, abort with its reason, E-stop, homing, host link restored and the host leaving.

The events file is the one `plc run` writes from the register map (atc.hmi.mapinfo); the host is atc.host's
Session, the E-stop a forced input (the simulated plant's SimulatedPlant input off: the application then reads
the real E-stop chain, which is open).  Every wait is bounded (SLOW); no verdict depends on speed.
"""
from __future__ import annotations

import re
import shutil
import threading
from pathlib import Path

import pytest

import rt_harness as h
from plc import driver, runtime
from atc.hmi import mapinfo
from atc.runsetup import runtime_setup
from plc.hmi import status
from plc.hmi.monitor import Monitor
from plc.modbus import ModbusClient
from atc.host.session import Session, Timeouts
from seq_testlib import run_cli as seq_cli

REPO = Path(__file__).resolve().parents[2]
TOKEN = "events-test-token-0123456789"


def build_app(st_dir: Path, tmp: Path) -> tuple[Path, Path, mapinfo.MapInfo, str]:
    result = driver.compile_sources([st_dir], portability=False)
    assert result.ok, "the application must compile"
    c_file = tmp / "program.c"
    c_file.write_text(result.c_text)
    info = mapinfo.load(REPO / "modbus_map" / "map.toml")
    setup = runtime_setup(REPO / "modbus_map" / "map.toml", tmp)     # what `plc run` of the project links and passes
    binary = runtime.build_runtime(c_file, h.CACHE, sanitize=h.SANITIZE, observer=setup.observer)
    return binary, setup.events_file, info, setup.sim_flag


@pytest.fixture(scope="module")
def app(tmp_path_factory) -> tuple[Path, Path, mapinfo.MapInfo, str]:
    return build_app(REPO / "st_src", tmp_path_factory.mktemp("app"))


@pytest.fixture(scope="module")
def app_procs_enabled(tmp_path_factory) -> tuple[Path, Path, mapinfo.MapInfo, str]:
    """The application with the shipped sequence set's procedures enabled, as an integrator enables them once
    their I/O is wired (the set ships them disabled): a copy of the set with `enabled = true`, compiled into a copy
    of st_src by `plc seq compile`."""
    tmp = tmp_path_factory.mktemp("app_procs")
    shutil.copytree(REPO / "configs" / "sequences", tmp / "sequences")
    index = tmp / "sequences" / "sequences.toml"
    text, enabled = re.subn(r"(?m)^enabled = false\b", "enabled = true", index.read_text(encoding="utf-8"))
    assert enabled == 2, "the shipped set has two procedures, both disabled"
    index.write_text(text, encoding="utf-8")
    shutil.copytree(REPO / "st_src", tmp / "st_src")
    run = seq_cli("compile", index, "--out", tmp / "st_src" / "sequence" / "generated" / "SequenceTables.st")
    assert run.status == 0, run.err
    return build_app(tmp / "st_src", tmp)


def app_runtime(app, tmp_path: Path) -> h.Runtime:
    """The application's runtime with its events, the monitor on tmp_path/m.sock (token TOKEN) and status lines."""
    binary, events, _info, sim_flag = app
    (tmp_path / "token").write_text(TOKEN)
    return h.Runtime(binary, "--no-rt", "--sim-flag", sim_flag, "--events", str(events),
                     "--monitor", str(tmp_path / "m.sock"), "--monitor-token", str(tmp_path / "token"),
                     "--status-interval", "0.2", "--writable-registers", "512-8191")


def test_the_log_tells_changes_faults_aborts_estop_homing_and_the_host_link(app, tmp_path):
    info = app[2]
    sock = tmp_path / "m.sock"
    with app_runtime(app, tmp_path) as rt:
        rt.wait_for(r"events: \d+ of \d+ application signals watched, \d+ reason texts")
        rt.wait_for(r"changer: tool 0 in the spindle, state AtcIdle")
        rt.wait_for(r"homing done: carousel homed, pocket 1 at the change position")
        client = ModbusClient("127.0.0.1", rt.port, timeout=5 * h.SLOW)
        client.connect()
        session = Session(info.rmap, client, say=lambda _t: None, timeouts=Timeouts(request=60 * h.SLOW))
        try:
            session.start()
            rt.wait_for(r"host link restored")
            assert session.prepare(3, 3).ok
            rt.wait_for(r"prepare tool 3 \(pocket 3\) requested")
            rt.wait_for(r"prepare tool 3 done in \d+\.\d{3} s")
            assert session.change().ok
            m = rt.wait_for(r"tool change T0 -> T3 done in (\d+\.\d{3}) s")
            assert float(m.group(1)) > 0
            rt.wait_for(r"changer AtcIdle -> AtcGetting")
            rt.wait_for(r"sequence GET started")
            rt.wait_for(r"status RUN \| tool 3 \| changer AtcIdle \| no fault")

            with Monitor(sock, timeout=5 * h.SLOW) as mon:            # E-stop: the sim's plant switched off
                mon.auth(TOKEN)
                mon.force("%IX49.7", False)
                rt.wait_for(r"warning: E-stop: the E-stop chain opened")
                rt.wait_for(r"error: fault -101 ESTOP raised: E-stop chain opened: toolchanger stopped, outputs safe")
                rt.wait_for(r"status RUN \| tool 3 \| changer \w+ \| fault -101 ESTOP")
                # issue 27: `plc status` tells the application's fault and exits 1 while the runtime runs
                h.wait_until(lambda: status.read(client)["app_fault"] == -101, 5, "the fault in the diag block")
                assert status.main(["--port", str(rt.port)]) == 1
                assert any("application fault -101 latched" in line for line in status.render(status.read(client)))
                mon.unforce("%IX49.7", restore=True)
                rt.wait_for(r"E-stop released: the E-stop chain is closed")
            # iov2 answers a faulted changer's prepare: the log must not call it done
            assert "without pre-positioning" in session.prepare(5, 5).text
            rt.wait_for(r"warning: prepare tool 5 answered after \d+\.\d{3} s without pre-positioning: fault -101 "
                        r"ESTOP")
            assert "prepare tool 5 done" not in rt.log
            assert session.clear().ok
            rt.wait_for(r"fault -101 ESTOP cleared")
            h.wait_until(lambda: status.read(client)["app_fault"] == 0, 5, "the fault gone from the diag block")
            assert status.main(["--port", str(rt.port)]) == 0
            assert session.home().ok
            rt.wait_for(r"homing started")
            rt.wait_for(r"homing ended: carousel homed, pocket \d+ at the change position")

            session.abort(8)
            rt.wait_for(r"warning: abort from the host: reason 8 TASK_ABORT")
        finally:
            session.stop()
            client.close()
        # a host that stops cleanly writes its last heartbeat (65535): it left (a killed one loses its link:
        # test_host_system.test_a_host_that_exits_normally_left_and_a_killed_one_lost_its_link)
        rt.wait_for(r"host left: its last heartbeat was 65535 \(a clean exit\)", timeout=30)
        assert "host link lost" not in rt.log, rt.log
    texts = {r.code: r.text for r in info.rmap.reasons}
    assert texts[-101] in rt.log, "the fault text comes from reason_codes.toml"
    for line in rt.log.splitlines():          # every tool change line names both tools
        if "tool change" in line:
            assert re.search(r"tool change T\d+ -> T\d+ ", line), line


def test_a_force_during_a_prepare_turn_drops_the_position_and_nothing_claims_the_turn(app, tmp_path):
    """Issue 37: a forced value is not the machine's.  The runtime raises ForcesActive (%IX49.6, DI 398) while
    any variable is forced; a force during a prepare's turn faults the changer with -115, the prepare is not
    called done, and once the force ends and the fault is cleared the PLC asks for homing and refuses the change
    until homed; after `home` the change loads the tool, and the simulated spindle really holds it."""
    info = app[2]
    sock = tmp_path / "m.sock"
    with app_runtime(app, tmp_path) as rt:
        rt.wait_for(r"homing done: carousel homed, pocket 1 at the change position")
        client = ModbusClient("127.0.0.1", rt.port, timeout=5 * h.SLOW)
        client.connect()
        session = Session(info.rmap, client, say=lambda _t: None, timeouts=Timeouts(request=60 * h.SLOW))
        answers: list = []
        try:
            session.start()
            rt.wait_for(r"host link restored")
            with Monitor(sock, timeout=5 * h.SLOW) as mon:
                mon.auth(TOKEN)
                assert client.read_discrete_inputs(398, 1) == [False], "no force: ForcesActive FALSE"
                preparer = threading.Thread(target=lambda: answers.append(session.prepare(4, 4)))
                preparer.start()
                h.wait_until(lambda: mon.read("ATC.MACHINE.CAROUSELLINESACTIVE")
                             ["CONFIG0.RES0.ATC.MACHINE.CAROUSELLINESACTIVE"] is True, 10 * h.SLOW,
                             "the prepare's turn under way")
                mon.force("%IX2.5", True)                       # any variable: here the tool length sensor
                rt.wait_for(r"fault -115 FORCES_ACTIVE raised")
                assert client.read_discrete_inputs(398, 1) == [True], "the host sees ForcesActive"
                preparer.join(30 * h.SLOW)
                assert answers and "without pre-positioning" in answers[0].text, answers
                assert "prepare tool 4 done" not in rt.log
                kept = session.clear()
                assert not kept.ok and kept.reason == -115, f"a clear while forced leaves the fault: {kept}"
                mon.unforce_all()
                h.wait_until(lambda: client.read_discrete_inputs(398, 1) == [False], 5 * h.SLOW, "ForcesActive dropped")
            assert session.clear().ok
            s = session.poll()
            assert s["Recovery"] & 1 and not s["CarouselHomed"], f"homing asked after the force: {s}"
            assert session.prepare(4, 4).ok
            refused = session.change()
            assert not refused.ok and refused.reason == -107, refused
            assert session.clear().ok
            assert session.home().ok
            assert session.prepare(4, 4).ok
            assert session.change().ok
            with Monitor(sock, timeout=5 * h.SLOW) as mon:
                held = mon.read("ATC.MACHINE.SIMSPINDLETOOL", "ATC.MACHINE.SIMCRASH")
            assert held == {"CONFIG0.RES0.ATC.MACHINE.SIMSPINDLETOOL": 4,
                            "CONFIG0.RES0.ATC.MACHINE.SIMCRASH": False}, held
            assert session.poll()["ToolInSpindle"] == 4
        finally:
            session.stop()
            client.close()


def test_the_log_tells_a_user_procedure_start_and_end(app_procs_enabled, tmp_path):
    # issue 31: the program-stopped coil (what LinuxCNC's halui feeds through mb2hal) runs the shipped mode-3
    # procedure, id 3 (OUT 6 1), here enabled: the log names its start and its end with the result
    info = app_procs_enabled[2]
    coil = {s.name: s.address for s in info.rmap.signals if s.table == "coil"}
    reg = {s.name: s.address for s in info.rmap.signals if s.table == "holding_register"}
    with app_runtime(app_procs_enabled, tmp_path) as rt:
        rt.wait_for(r"changer: tool 0 in the spindle, state AtcIdle")
        client = ModbusClient("127.0.0.1", rt.port, timeout=5 * h.SLOW)
        client.connect()
        try:
            client.write_coil(coil["ProgramStopped"], True)
            rt.wait_for(r"procedure 3 started")
            rt.wait_for(r"procedure 3 ended: DONE")
            assert client.read_holding(reg["ProcLastId"], 1) == [3]
            assert client.read_coils(coil["UserOut6"], 1) == [True], "the alarm light is on"
        finally:
            client.close()


def test_the_shipped_set_enables_no_procedure(app, tmp_path):
    # safe defaults: the application built from the shipped set has its example procedures compiled disabled, so
    # the PLC reports none that may run (ProcEnabled 0) and none ever ended (ProcLastId -1)
    reg = {s.name: s.address for s in app[2].rmap.signals if s.table == "holding_register"}
    with app_runtime(app, tmp_path) as rt:
        rt.wait_for(r"changer: tool 0 in the spindle, state AtcIdle")
        client = ModbusClient("127.0.0.1", rt.port, timeout=5 * h.SLOW)
        client.connect()
        try:
            assert client.read_holding(reg["ProcEnabled"], 1) == [0], "no procedure may run"
            assert client.read_holding(reg["ProcLastId"], 1) == [0xFFFF], "none has run (-1)"
        finally:
            client.close()


def test_the_pages_procedure_switch_survives_a_restart(app_procs_enabled, tmp_path):
    # issue 31: ProcDisabled (the page's switches) is a retained register: `plc run` passes it in
    # --retain-registers (from the map), and the PLC restarted on the same retained file still has the procedure
    # disabled (ProcEnabled without its bit), as it keeps the pocket table
    binary, events, info, sim_flag = app_procs_enabled
    reg = {s.name: s.address for s in info.rmap.signals if s.table == "holding_register"}
    retained = runtime_setup(REPO / "modbus_map" / "map.toml", tmp_path).retain_registers
    assert any(int(r.split("-")[0]) <= reg["ProcDisabled"] <= int(r.split("-")[-1]) for r in retained), retained
    args = ("--no-rt", "--sim-flag", sim_flag, "--events", str(events), "--writable-registers", "512-8191",
            "--retain", str(tmp_path / "plc.retain"), "--retain-registers", ",".join(retained))
    for start in (1, 2):
        with h.Runtime(binary, *args) as rt:
            rt.wait_for(r"changer: tool 0 in the spindle, state AtcIdle")
            client = ModbusClient("127.0.0.1", rt.port, timeout=5 * h.SLOW)
            client.connect()
            try:
                if start == 1:
                    h.wait_until(lambda c=client: c.read_holding(reg["ProcEnabled"], 1) == [3], 5 * h.SLOW,
                                 "both procedures enabled (built enabled, nothing disabled)")
                    client.write_register(reg["ProcDisabled"], 2)
                    h.wait_until(lambda c=client: c.read_holding(reg["ProcEnabled"], 1) == [1], 5 * h.SLOW,
                                 "the alarm light (slot 2) disabled")
                else:
                    assert client.read_holding(reg["ProcDisabled"], 1) == [2], "the switch was not retained"
                    h.wait_until(lambda c=client: c.read_holding(reg["ProcEnabled"], 1) == [1], 5 * h.SLOW,
                                 "the alarm light still disabled after the restart")
            finally:
                client.close()
