"""The pieces behind the page and the events: the diagnostic block's layout agrees with runtime.h, the event
description carries every map signal, state name and reason text, `plc status` and `plc monitor` fail
politely, and the page's HTTP guards refuse what they must (no PLC needed for these)."""
from __future__ import annotations

import re
from pathlib import Path

from atc.hmi import mapinfo
from code_rules import c_enum, c_tokens
from plc.hmi import status
from plc.hmi import cli as monitor_cli
from plc.resources import RUNTIME_SRC

REPO = Path(__file__).resolve().parents[2]


def diag_offsets(header: str) -> dict[str, int]:
    """runtime.h's enum diag_offset as status.DIAG names it (DIAG_SCAN_COUNT -> scan_count), read from C tokens."""
    return {name.removeprefix("DIAG_").lower(): value
            for name, value in c_enum(c_tokens(header, "runtime.h"), "diag_offset").items()}


def test_the_diagnostic_layout_agrees_with_runtime_h():
    offsets = diag_offsets((RUNTIME_SRC / "runtime.h").read_text())
    assert len(offsets) > 20, offsets
    assert {k: v[0] for k, v in status.DIAG.items()} == offsets


def test_the_layout_reader_takes_the_enum_as_c_does():
    header = ("/* enum diag_offset { DIAG_OLD = 99 }; was the layout */\n"
              "enum other { DIAG_VERSION = 7 };\n"
              "enum diag_offset {\n    DIAG_VERSION = 0,    /* DIAG_STATE = 5 in a comment */\n"
              "    DIAG_STATE,\n    DIAG_SCAN_COUNT = 0x8,\n    DIAG_LAST\n};\n")
    assert diag_offsets(header) == {"version": 0, "state": 1, "scan_count": 8, "last": 9}


def test_the_diagnostic_block_decodes_high_word_first():
    words = [0] * status.DIAG_COUNT
    words[1] = 1                                  # RUNNING
    words[8:12] = [0, 0, 1, 2]                    # 65538 scans
    words[20:22] = [0, 1234]                      # scan p99
    d = status.decode(words)
    assert d["state"] == 1 and d["scan_count"] == 65538 and d["scan_p99_us"] == 1234
    assert any("RUNNING" in line for line in status.render(d))


def test_the_event_description_names_signals_states_and_reasons():
    info = mapinfo.load(REPO / "modbus_map" / "map.toml")
    text = mapinfo.events_description(info)
    rows = [line.split("\t") for line in text.splitlines() if not line.startswith("#")]
    signals = {row[1] for row in rows if row[0] == "signal"}
    assert signals == {s.name for s in info.rmap.signals}
    assert ["state", "ChangerState", "1", "AtcIdle"] in rows
    reasons = {int(row[1]): row[3] for row in rows if row[0] == "reason"}
    assert reasons == {r.code: r.text for r in info.rmap.reasons}
    assert all(len(row) in (4, 5) for row in rows), "tab-separated, no tab inside a field"


def test_every_hard_or_soft_reason_has_a_cause_and_a_remedy():
    info = mapinfo.load(REPO / "modbus_map" / "map.toml")
    missing = [r.name for r in info.rmap.reasons if r.severity != "none" and not (r.cause and r.remedy)]
    assert not missing, f"reason codes without cause or remedy: {missing}"


def test_plc_status_without_a_plc_exits_2(capsys):
    import socket
    with socket.socket() as s:                    # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert status.main(["--port", str(port)]) == 2
    assert "plc status: error" in capsys.readouterr().err


def test_plc_monitor_without_a_runtime_exits_2(tmp_path, capsys):
    assert monitor_cli.main(["--socket", str(tmp_path / "none.sock"), "read", "X"]) == 2
    assert "is `plc run` running" in capsys.readouterr().err


def test_plc_monitor_watch_names_the_period_it_can_serve(tmp_path, capsys):
    # issue 27: `--period 5` was answered in the channel's words ("sub MS PATH...: MS is the period...")
    assert monitor_cli.main(["--socket", str(tmp_path / "none.sock"), "watch", "X", "--period", "5"]) == 2
    err = capsys.readouterr().err
    assert "argument --period: 5 ms: the update period is 10..10000 ms" in err and "sub MS" not in err, err


class _TwelveCounters:
    """A monitor whose program has twelve FB instances with a COUNT, and one STEPS array."""
    def list(self, prefix):
        paths = [f"CONFIG0.RES0.INST0.C{i}.COUNT" for i in range(1, 13)] + ["CONFIG0.RES0.INST0.COUNTS",
                                                                            "CONFIG0.RES0.INST0.STEPS"]
        return [{"path": p} for p in paths if prefix in p]


def test_an_ambiguous_monitor_tail_lists_ten_of_the_variables_it_names_and_counts_the_rest():
    text = monitor_cli.ambiguity(_TwelveCounters(), "count")
    assert text == ("; it names 12: " + ", ".join(f"CONFIG0.RES0.INST0.C{i}.COUNT" for i in range(1, 11))
                    + " and 2 more (plc monitor vars COUNT)"), text
    assert monitor_cli.tail_length("CONFIG0.RES0.INST0.STEPS", "INST0.STEPS[3].LINE") == len("INST0.STEPS")
    assert monitor_cli.tail_length("CONFIG0.RES0.INST0.COUNTS", "COUNT") == 0


def _page_client(tmp_path):
    """The page's web app against a PLC that is not there (the guards answer before any PLC is asked)."""
    import socket
    from aiohttp.test_utils import TestClient, TestServer
    from atc.hmi import server
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    info = mapinfo.load(REPO / "modbus_map" / "map.toml")
    opts = server.Options(plc_port=port, monitor_socket=None, alarms=tmp_path / "alarms.jsonl")
    hub = server.Hub(opts, info, "the-right-token-0123", 6)
    return TestClient(TestServer(server.make_app(hub)))


def test_the_page_refuses_commands_without_the_right_token_bad_json_and_floods(tmp_path):
    import asyncio
    import time

    async def run():
        client = _page_client(tmp_path)
        await client.start_server()
        try:
            r = await client.post("/api/command", json={"cmd": "home"})
            assert r.status == 403 and "token" in (await r.json())["error"]
            r = await client.post("/api/command", json={"cmd": "home"}, headers={"X-Token": "wrong"})
            assert r.status == 403
            r = await client.post("/api/command", data=b"{not json", headers={"X-Token": "the-right-token-0123"})
            assert r.status == 400 and "expected JSON" in (await r.json())["error"]
            r = await client.post("/api/force", json={"action": "force", "path": "%IX0.0", "value": 1},
                                  headers={"X-Token": "the-right-token-0123"})
            assert r.status == 409 and "monitoring channel" in (await r.json())["error"]
            r = await client.post("/api/watch", json={"paths": ["A"] * 100})
            assert r.status == 400
            t0 = time.monotonic()
            codes = [(await client.post("/api/auth", json={})).status for _ in range(120)]
            elapsed = time.monotonic() - t0
            assert set(codes) <= {403, 429}
            # a burst of 40, then 20 a second, whatever the machine's speed
            assert codes.count(403) <= 40 + 20 * elapsed + 1, (codes.count(403), elapsed)
            info = await (await client.get("/api/info")).json()
            assert info["pockets"] == 6 and any(s["name"] == "ToolPrepare" for s in info["signals"])
        finally:
            await client.close()
    asyncio.run(run())


def test_plc_run_puts_the_monitor_files_beside_the_retain_file_and_makes_a_private_token(tmp_path):
    import os
    from plc import runtime
    cfg = runtime.RunConfig(retain_file=tmp_path / "var" / "plc.retain")
    cfg.events_file = tmp_path / "events.txt"
    argv = runtime.runtime_argv(Path("/bin/true"), cfg)
    at = {argv[i]: argv[i + 1] for i in range(len(argv) - 1) if argv[i].startswith("--")}
    assert at["--monitor"] == str(tmp_path / "var" / "plc.monitor")
    assert at["--monitor-token"] == str(tmp_path / "var" / "monitor.token")
    assert at["--audit"] == str(tmp_path / "var" / "audit.log")
    assert at["--events"] == str(tmp_path / "events.txt")
    runtime.ensure_token(tmp_path / "var" / "monitor.token")
    token = (tmp_path / "var" / "monitor.token").read_text().strip()
    assert len(token) >= 32 and oct(os.stat(tmp_path / "var" / "monitor.token").st_mode & 0o777) == "0o600"
    runtime.ensure_token(tmp_path / "var" / "monitor.token")      # kept, not replaced
    assert (tmp_path / "var" / "monitor.token").read_text().strip() == token
    cfg.monitor = False
    assert "--monitor" not in runtime.runtime_argv(Path("/bin/true"), cfg)


def test_the_run_configuration_reads_the_monitor_section(tmp_path):
    import pytest
    from plc import runtime
    f = tmp_path / "run.toml"
    f.write_text('[monitor]\nenabled = true\nsocket = "run/m.sock"\n')
    cfg = runtime.load_config(f)
    assert cfg.monitor and cfg.monitor_socket == tmp_path / "run" / "m.sock"
    f.write_text('[monitor]\nsocket = 3\n')
    with pytest.raises(runtime.ConfigError, match=r"\[monitor\] socket: expected a file name"):
        runtime.load_config(f)


def test_the_page_knows_the_inputs_the_simulation_leaves_alone_its_fault_lines_and_the_plcs_time():
    from atc.hmi import server
    info = mapinfo.load(REPO / "modbus_map" / "map.toml")
    free = server.not_simulated(info)
    assert {"EStopOk", "GuardDoorClosed", "AirPressureOk", "SpindleStopped"} <= set(free)
    assert not {"SimulatedPlant", "ForcesActive", "IoModule1Lost"} & set(free), "the runtime sets these in sim too"
    assert set(server.fault_lines(info)) >= {"ToolchangerFault", "IoModule1Lost"}
    assert "ClearFault" not in server.fault_lines(info)
    hub = server.Hub(server.Options(), info, None, 6)
    assert hub.plc_time({"ScanCount": 5}) == {}, "no diagnostic block (OpenPLC): no PLC time"
    hub.diag = {"scan_count": 65530, "base_tick_us": 4000}
    assert hub.plc_time({"ScanCount": 2}) == {"plc_scan": 65538, "plc_s": 262.152}, "ScanCount wrapped since"


def test_the_page_lists_the_shipped_procedures_and_switches_them_through_procdisabled(tmp_path):
    # issue 31: the page's procedures come from the sequence set; its switch writes the run-time mask
    # ProcDisabled (bit slot-1) through the "procedure" command, audited with the page's client, and refuses what
    # it cannot do
    from host_fake_plc import Addr, FakePlc
    from atc.hmi import server
    procs, texts = server.procedures_of(REPO)
    assert [(p["slot"], p["id"], p["name"], p["when"], p["enabled"]) for p in procs] == [
        (1, 0, "lube", "every 240000 ms", False), (2, 3, "alarm light", "on error or stop", False)], \
        "the set ships its example procedures disabled (safe defaults: their I/O may not be wired)"
    assert "lubrication: no oil pressure within 15 s" in texts.values()
    shipped = procs
    procs = [dict(p, enabled=True) for p in shipped]    # as an integrator enables them once the I/O is wired
    info = mapinfo.load(REPO / "modbus_map" / "map.toml")
    addr = Addr(coil={s.name: s.address for s in info.rmap.signals if s.table == "coil"},
                reg={s.name: s.address for s in info.rmap.signals if s.table == "holding_register"})
    with FakePlc(addr) as fake:
        hub = server.Hub(server.Options(plc_port=fake.port, token_file=tmp_path / "monitor.token"), info, "token",
                         6, procedures=procs)
        answer = server.run_command(hub, "procedure", {"slot": 2, "enabled": False}, "192.168.1.7")
        assert answer == {"ok": True, "text": "procedure 3 (alarm light) disabled"}
        assert fake.r("ProcDisabled") == 2
        assert server.run_command(hub, "procedure", {"slot": 1, "enabled": False}, "192.168.1.7")["ok"]
        assert fake.r("ProcDisabled") == 3
        assert server.run_command(hub, "procedure", {"slot": 2, "enabled": True}, "10.0.0.3")["ok"]
        assert fake.r("ProcDisabled") == 1
        audit = (tmp_path / "audit.log").read_text().splitlines()
        assert [line.split(" ", 3)[3] for line in audit] == [
            "page 192.168.1.7 procedure 3 (alarm light) slot 2 disable -> done (ProcDisabled 2)",
            "page 192.168.1.7 procedure 0 (lube) slot 1 disable -> done (ProcDisabled 3)",
            "page 10.0.0.3 procedure 3 (alarm light) slot 2 enable -> done (ProcDisabled 1)"]
        assert all(re.match(r"\d{4}-\d\d-\d\dT[\d:.]+Z uid=\d+ pid=\d+ ", line) for line in audit)
        assert "no procedure 5" in server.run_command(hub, "procedure", {"slot": 5, "enabled": True})["error"]
        assert "needs" in server.run_command(hub, "procedure", {"slot": "1", "enabled": True})["error"]
        hub.procedures = shipped
        refused = server.run_command(hub, "procedure", {"slot": 1, "enabled": True})
        assert not refused["ok"] and "disabled in the sequence set" in refused["error"]
        assert fake.r("ProcDisabled") == 1, "a refused switch writes nothing"
        assert len((tmp_path / "audit.log").read_text().splitlines()) == 3, "and logs nothing"
        (tmp_path / "audit.log").rename(tmp_path / "audit.old")
        (tmp_path / "audit.log").mkdir()                     # a log that cannot be appended to: no switch
        unaudited = server.run_command(hub, "procedure", {"slot": 2, "enabled": False}, "10.0.0.3")
        assert not unaudited["ok"] and "cannot append to the audit log" in unaudited["error"], unaudited
        assert fake.r("ProcDisabled") == 1, "a switch the audit log cannot take is not made"


def test_a_go_to_is_answered_when_the_host_is_late_between_its_requests_or_quick_after_the_last(tmp_path):
    """The page's go-to counts the scans that prove the PLC saw GotoRequest low and then its rise from ScanCount
    reads made after the runtime acknowledged each write. So a host that is not scheduled for a few scan periods
    between its requests (a busy machine: seen in CI as 'the PLC did not see the request') gets the answer to its
    own request: every write of the page's session waits 20 ms (5 scans of the 4 ms task) before it goes out. And
    go-tos given back to back without that wait are each an edge for the PLC. The go-tos alternate between the
    pocket at the change position (Done) and one beyond the carousel (refused), so an answer read before the PLC
    took the request would be the previous one's, or none."""
    import time

    import rt_harness as h
    from atc.hmi import server
    from atc.host.session import Session, Timeouts
    from atc.host.tags import load_map
    from atc.runsetup import runtime_setup
    from plc import driver, runtime
    from plc.modbus import ModbusClient

    map_path = REPO / "modbus_map" / "map.toml"
    built = driver.compile_sources([REPO / "st_src"], portability=False)
    assert built.ok
    (tmp_path / "program.c").write_text(built.c_text)
    setup = runtime_setup(map_path, tmp_path)
    binary = runtime.build_runtime(tmp_path / "program.c", h.CACHE, sanitize=h.SANITIZE, observer=setup.observer)
    rt = h.Runtime(binary, "--no-rt", "--sim-flag", setup.sim_flag, "--writable-registers", "512-8191").start()
    client = ModbusClient("127.0.0.1", rt.port, timeout=10 * h.SLOW)
    client.connect()
    session = Session(load_map(map_path), client, say=lambda _t: None, timeouts=Timeouts(request=60 * h.SLOW))
    try:
        session.start()
        assert session.prepare(3, 3).ok and session.change().ok, "a change homes the carousel first"
        hub = server.Hub(server.Options(plc_port=rt.port), mapinfo.load(map_path), None, 6)
        here = int(session.tags.get("CurrentPocket"))
        assert 1 <= here <= 6
        prompt = session.tags.write

        def late_write(**values):
            time.sleep(0.02)
            prompt(**values)
        expected = [{"ok": True, "text": f"go to pocket {here}: pocket {here} at the change position"},
                    {"ok": False, "error": "go to pocket 9: the PLC refused: pocket 9 is not on the carousel (1..6)"}]
        session.tags.write = late_write
        late = [server.goto(session, hub, pocket) for pocket in (here, 9) * 5]
        session.tags.write = prompt
        quick = [server.goto(session, hub, pocket) for pocket in (here, 9) * 5]
        assert late == expected * 5, late
        assert quick == expected * 5, quick
    finally:
        session.stop()
        client.close()
        rc = rt.stop()
    rt.assert_clean_exit(rc)
