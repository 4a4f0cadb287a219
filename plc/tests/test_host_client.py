"""`plc host` against a fake PLC (tests/host_fake_plc.py): the iov2 host end's handshakes, write order, fault
handling, timeouts, link loss, exit codes.  The real runtime with the real program is in test_host_system.py."""
from __future__ import annotations

import io
import socket
from pathlib import Path

import pytest

from host_fake_plc import Addr, Behaviour, FakePlc
from atc.host import cli
from atc.host.tags import load_map

REPO = Path(__file__).resolve().parents[2]
MAP = REPO / "modbus_map" / "map.toml"
RMAP = load_map(MAP)
ADDR = Addr(coil={s.name: s.address for s in RMAP.signals if s.table == "coil"},
            reg={s.name: s.address for s in RMAP.signals if s.table == "holding_register"})


def coil(name: str) -> int:
    return ADDR.coil[name]


def reg(name: str) -> int:
    return ADDR.reg[name]


def run(fake: FakePlc, capsys, *words: str, extra: tuple[str, ...] = ()) -> tuple[int, str, str]:
    status = cli.main(["--port", str(fake.port), "--map", str(MAP), *extra, *words])
    out = capsys.readouterr()
    return status, out.out, out.err


def test_t5_m6_prepares_then_changes_and_prints_the_tool(capsys):
    with FakePlc(ADDR) as fake:
        status, out, err = run(fake, capsys, "T5 M6")
    assert status == 0, out + err
    assert "tool 5 in spindle" in out.splitlines()[-1]
    assert fake.index("prepare latched tool 5 pocket 5") < fake.index("change started")


def test_numbers_are_written_before_the_request_bit_and_together(capsys):
    with FakePlc(ADDR) as fake:
        status, out, err = run(fake, capsys, "T7")
    assert status == 0, out + err
    numbers = ("write", 16, reg("ToolPrepNumber"), [7, 7])
    assert reg("ToolPrepPocket") == reg("ToolPrepNumber") + 1
    assert fake.index(numbers) < fake.index(("set", coil("ToolPrepare"), 1))
    assert fake.index(("set", coil("ToolPrepare"), 1)) < fake.index(("set", coil("ToolPrepare"), 0))


def test_the_host_beats_before_its_first_command(capsys):
    """Issue 27: HostLinkOk can still be TRUE from a host that just left (the PLC counts its time-out from that
    host's last beat); a command sent before this host's own first beat met "host link lost while busy" (-102)
    when the time-out fell just after it. The first heartbeat is written before anything is asked."""
    with FakePlc(ADDR, Behaviour(left_beat=0xFFFF)) as fake:
        status, out, err = run(fake, capsys, "T7")
    assert status == 0, out + err
    beat = reg("HostHeartbeat")
    first_beat = next(i for i, e in enumerate(fake.log) if e[0] == "write" and e[2] == beat)
    assert first_beat < fake.index(("set", coil("ToolPrepare"), 1))
    assert first_beat < fake.index(("write", 16, reg("ToolPrepNumber"), [7, 7]))


def test_request_waits_for_a_stale_ack_to_drop_first(capsys):
    with FakePlc(ADDR, Behaviour(stale_prepared=True, stale_scans=60)) as fake:
        status, out, err = run(fake, capsys, "T4")
    assert status == 0, out + err
    assert fake.index("stale tool-prepared dropped") < fake.index(("set", coil("ToolPrepare"), 1))


def test_each_request_is_dropped_after_its_ack_and_the_next_waits_for_the_ack_to_drop(capsys):
    with FakePlc(ADDR, Behaviour(change_scans=3)) as fake:
        status, out, err = run(fake, capsys, "T2 M6", extra=("--no-start-change",))
    assert status == 0, out + err
    writes = [e for e in fake.log if e[0] == "set" and e[1] in (coil("ToolPrepare"), coil("ToolChange"))]
    assert [(e[1], e[2]) for e in writes] == [(coil("ToolPrepare"), 1), (coil("ToolPrepare"), 0),
                                                 (coil("ToolChange"), 1), (coil("ToolChange"), 0)]


def test_start_change_handshake_comes_before_tool_change(capsys):
    with FakePlc(ADDR) as fake:
        status, out, err = run(fake, capsys, "T2 M6")
    assert status == 0, out + err
    assert fake.index(("set", coil("StartChange"), 0)) < fake.index(("set", coil("ToolChange"), 1))


def test_pocket_comes_from_the_tool_table(capsys, tmp_path):
    table = tmp_path / "tool.tbl"
    table.write_text("T5 P12 D0.5 ;five\nT6 P3\n")
    with FakePlc(ADDR) as fake:
        status, out, err = run(fake, capsys, "T5", extra=("--tool-table", str(table)))
    assert status == 0, out + err
    assert "prepare latched tool 5 pocket 12" in fake.events


def test_hard_fault_during_change_prints_the_reason_acks_it_and_exits_1(capsys):
    with FakePlc(ADDR, Behaviour(fault_on_change=-101)) as fake:
        status, out, err = run(fake, capsys, "T5 M6")
        latched = fake.c("ToolchangerFaulted")
    assert status == 1
    text = next(r.text for r in RMAP.reasons if r.code == -101)
    assert "toolchanger error -101" in out and text in out
    assert "fault acked" in fake.events
    assert fake.index("fault acked") < fake.index("abort reason 101") < fake.index("abort reason 3")
    assert latched


@pytest.mark.parametrize("recovery,asked,not_asked", [
    (0, "the PLC asks no recovery (nothing uncertain): `plc host clear`", ("plc host home", "confirm")),
    (1, "recovery the PLC asks: `plc host clear`, then `plc host home` (home the changer)", ("confirm",)),
    (3, "recovery the PLC asks: `plc host clear`, then `plc host home` (home the changer), then confirm the "
        "tool: tool 5 is in the spindle or in its pocket: look, then `plc host confirm 5`", ()),
])
def test_an_interrupted_change_is_told_once_with_only_the_recovery_the_plc_asks(capsys, recovery, asked,
                                                                                  not_asked):
    # issue 27: the -103 text said "then confirm the tool" with nothing to confirm, and plc host printed it twice
    with FakePlc(ADDR, Behaviour(fault_on_change=-103, recovery=recovery, uncertain_tool=5)) as fake:
        status, out, err = run(fake, capsys, "T5 M6")
    assert status == 1, out + err
    text = next(r.text for r in RMAP.reasons if r.code == -103)
    assert out.count(text) == 1, out
    assert "confirm the tool" not in text, "the reason's own text may not promise a confirmation"
    outcome = next(line for line in out.splitlines() if line.startswith("M6 aborted"))
    assert outcome.startswith("M6 aborted by a toolchanger fault: toolchanger error -103; " + asked), outcome
    assert not any(word in outcome for word in not_asked), outcome


def test_soft_fault_skips_the_change_and_the_program_continues(capsys):
    with FakePlc(ADDR, Behaviour(fault_on_change=106)) as fake:
        status, out, err = run(fake, capsys, "T5 M6")
        tool = fake.r("ToolInSpindle")
    assert status == 3, out + err
    assert "soft fault" in out and "#5601 = 106" in out
    assert out.splitlines()[-1] == "tool 0 in spindle" and tool == 0
    assert "abort reason 101" in fake.events


def test_a_fault_does_not_end_a_prepare_and_refuses_the_next_m6(capsys):
    with FakePlc(ADDR, Behaviour(fault_on_prepare=106)) as fake:
        status, out, err = run(fake, capsys, "T5 M6", "status")
        started = "change started" in fake.events
    assert status == 3, out + err
    assert "host fault latch: set (106)" in out
    assert "T5: prepare answered" in out and "without pre-positioning the carousel: toolchanger fault 106" in out
    assert "T5: prepared" not in out, "a faulted changer's answer is no completed prepare"
    assert "M6 refused: the toolchanger is faulted" in out
    assert not started


def test_a_prepare_answered_while_the_carousel_is_not_homed_is_not_called_prepared(capsys):
    with FakePlc(ADDR, Behaviour(homed=False)) as fake:
        status, out, err = run(fake, capsys, "T5")
    assert status == 0, out + err
    assert "T5: prepare answered" in out and "without pre-positioning the carousel: it is not homed" in out
    assert "T5: prepared" not in out


def test_clear_drops_the_host_latch_after_the_plc_cleared(capsys):
    with FakePlc(ADDR, Behaviour(fault_on_change=106)) as fake:
        run(fake, capsys, "T5 M6")
        assert fake.c("ToolchangerFaulted")
        status, out, err = run(fake, capsys, "clear")
        clear_on = fake.index(("set", coil("ClearFault"), 1))
        latch_off = max(i for i, e in enumerate(fake.log) if e == ("set", coil("ToolchangerFaulted"), 0))
        assert not fake.c("ToolchangerFaulted") and not fake.c("ClearFault")
    assert status == 0, out + err
    assert clear_on < latch_off


def test_timeout_aborts_the_change_with_a_clear_message(capsys):
    with FakePlc(ADDR, Behaviour(ack_change=False)) as fake:
        status, out, err = run(fake, capsys, "T5 M6", extra=("--timeout", "0.5"))
    assert status == 1
    assert "timeout: waited 0.5 s for tool-changed for tool 5" in err
    assert "abort reason 8" in fake.events


def test_lost_plc_heartbeat_is_reported(capsys):
    with FakePlc(ADDR, Behaviour(heartbeat=False, ack_prepare=False)) as fake:
        status, out, err = run(fake, capsys, "T5", extra=("--timeout", "60"))   # link loss shows first
    assert status == 1
    assert "the PLC stopped: PlcAlive and PlcHeartbeat unchanged" in err


def test_abort_writes_the_reason_before_raising_emc_abort(capsys):
    with FakePlc(ADDR) as fake:
        status, out, err = run(fake, capsys, "abort", "100")
    assert status == 0, out + err
    reason = [i for i, e in enumerate(fake.log) if e[0] == "write" and e[2] == reg("EmcReason") and e[3] == [100]]
    assert reason and reason[0] < fake.index(("set", coil("EmcAbort"), 1))
    assert "abort reason 100" in fake.events


def test_host_heartbeat_keeps_changing_during_a_long_change(capsys):
    with FakePlc(ADDR, Behaviour(change_scans=300)) as fake:
        status, out, err = run(fake, capsys, "T5 M6")
    assert status == 0, out + err
    beats = [e[3][0] for e in fake.log if e[0] == "write" and e[2] == reg("HostHeartbeat")]
    assert len(beats) >= 10 and len(set(beats)) == len(beats)


def test_m6_without_a_prepare_changes_nothing(capsys):
    with FakePlc(ADDR) as fake:
        status, out, err = run(fake, capsys, "M6")
    assert status == 0, out + err
    assert "nothing to change" in out and "change started" not in fake.events


def test_interactive_prompt_runs_commands_until_quit(capsys, monkeypatch):
    monkeypatch.setattr("sys.stdin", io.StringIO("T3\nM6\nstatus\nquit\n"))
    with FakePlc(ADDR) as fake:
        status, out, err = run(fake, capsys)
    assert status == 0, out + err
    assert "M6: tool 3 in spindle" in out and "tool in spindle 3" in out


def test_unknown_command_is_a_usage_error_before_connecting(capsys):
    status = cli.main(["--port", "1", "--map", str(MAP), "T5 M7"])
    assert status == 2
    assert "unknown command 'M7'" in capsys.readouterr().err


def test_refused_connection_is_reported(capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    status = cli.main(["--port", str(port), "--map", str(MAP), "status"])
    assert status == 2
    assert "cannot connect" in capsys.readouterr().err


@pytest.mark.parametrize("words,expected", [(["T5 M6"], ["T5", "M6"]), (["t5m6"], ["T5", "M6"]),
                                            (["abort", "8"], ["ABORT", "8"]), (["T0", "M06"], ["T0", "M06"])])
def test_commands_are_read_like_gcode_words(words, expected):
    assert cli.tokens(words) == expected


def test_status_shows_the_user_procedures_and_the_errmsg_of_one_that_stopped_the_program(capsys):
    # issue 31: the running procedure with its step and source line, the last one's result, time and reason,
    # and while the PLC's fault is -150 the ErrMsg of the procedure that raised it (the sequence set's text)
    with FakePlc(ADDR) as fake:
        fake.set_c("ProcBusy", True)
        for name, value in (("ProcId", 3), ("ProcStep", 1), ("ProcLine", 2), ("ProcLastId", 0), ("ProcLastResult", 2),
                            ("ProcLastReason", -201), ("ProcLastDuration", 150), ("ProcLastAgo", 42),
                            ("ProcFailCount", 1), ("ProcFaultId", 0), ("ProcFaultText", 1), ("FaultReason", -150)):
            fake.set_r(name, value)
        status, out, err = run(fake, capsys, "status")
    assert status == 0, out + err
    assert "procedure 3 running, step 1, source line 2   failures since start 1" in out
    assert "last procedure 0: 2 ERRORS (-201 SEQ_WAITIN_TIMEOUT), ran 15.0 s, ended 42 s ago" in out
    assert "procedure 0 stopped the program: lubrication: no oil pressure within 15 s" in out
    assert "PLC fault: -150 PROCEDURE_FAILED" in out


def test_status_names_no_procedure_fault_while_the_fault_is_another(capsys):
    with FakePlc(ADDR) as fake:
        fake.set_r("ProcFaultId", 0)
        fake.set_r("ProcLastId", -1)
        status, out, err = run(fake, capsys, "status")
    assert status == 0, out + err
    assert "procedure: none running   failures since start 0" in out
    assert "last procedure" not in out and "stopped the program" not in out
