"""The shipped LinuxCNC configuration (configs/linuxcnc/) agrees with the project's own data: the tool data comes
from the PLC (docs/tools.md), the remap's pins fit motion's, the operator texts of the tool table's reasons are
those of modbus_map/reason_codes.toml. Text checks; LinuxCNC itself runs in scripts/e2e-linuxcnc."""
from __future__ import annotations

import re
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / "configs" / "linuxcnc"


def ini_values(section: str, key: str) -> list[str]:
    values, current = [], None
    for line in (CONFIG / "atc-sim.ini").read_text().splitlines():
        m = re.fullmatch(r"\s*\[(\w+)\]\s*", line)
        if m:
            current = m.group(1)
        elif current == section and re.match(rf"\s*{key}\s*=", line):
            values.append(line.split("=", 1)[1].strip())
    return values


def test_the_shipped_machine_takes_its_tools_from_the_plc_and_documents_the_table_file():
    assert ini_values("EMCIO", "DB_PROGRAM") == ["bin/atc-tooldb --port 5020 --offsets atc-tooldb.tbl"]
    assert ini_values("EMCIO", "TOOL_TABLE") == []              # LinuxCNC would ignore it beside DB_PROGRAM
    assert re.search(r"(?m)^# TOOL_TABLE = atc-sim\.tbl$", (CONFIG / "atc-sim.ini").read_text())
    assert (CONFIG / "bin" / "atc-tooldb").stat().st_mode & 0o111
    port = re.search(r"(?m)^TCP_PORT\s*=\s*(\d+)", (CONFIG / "atc_mb2hal.ini").read_text()).group(1)
    assert f"--port {port} " in ini_values("EMCIO", "DB_PROGRAM")[0]     # one PLC for mb2hal and atc-tooldb
    offsets = (CONFIG / "atc-tooldb.tbl").read_text().splitlines()
    table = (CONFIG / "atc-sim.tbl").read_text().splitlines()
    assert [line.split()[0] for line in offsets] == [line.split()[0] for line in table]


def test_the_remap_reads_the_prepared_tool_from_a_pin_motion_has():
    hal = (CONFIG / "atc-remap.hal").read_text()
    m = re.search(r"(?m)^net atc-prepared-tool-float => motion\.analog-in-(\d+)$", hal)
    assert m, "atc-remap.hal does not put the PLC's PreparedTool on a motion.analog-in pin"
    pin = int(m.group(1))
    assert pin < int(ini_values("EMCMOT", "NUM_AIO")[0])
    assert len(re.findall(rf"=> motion\.analog-in-{pin:02d}\b", hal)) == 1
    ngc = (CONFIG / "nc_subs" / "atc_m6.ngc").read_text()
    assert f"M66 E{pin} L0" in ngc and "M61 Q#<loaded>" in ngc


def test_the_worn_out_refusals_show_the_texts_of_the_reason_table():
    with open(REPO / "modbus_map" / "reason_codes.toml", "rb") as f:
        texts = {r["code"]: r["text"] for r in tomllib.load(f)["reason"]}
    ngc = (CONFIG / "nc_subs" / "atc_fault.ngc").read_text()
    assert f"(debug, toolchanger fault 109: {texts[109]})" in ngc
    assert f"(abort, toolchanger error -109: {texts[-109]})" in ngc


def test_the_spindle_guard_watches_the_plcs_inhibit():
    hal = (CONFIG / "atc-sim.hal").read_text()
    for line in ("net atc-spindle-inhibit spindle.0.inhibit", "loadusr -W atc-spindle-guard",
                 "net atc-spindle-inhibit => atc-spindle-guard.inhibit",
                 "net atc-spindle-speed-cmd spindle.0.speed-cmd-rps => atc-spindle-guard.speed-cmd",
                 "net atc-tool-in-spindle => atc-spindle-guard.tool"):
        assert re.search(rf"(?m)^{re.escape(line)}$", hal), line
    assert (CONFIG / "bin" / "atc-spindle-guard").stat().st_mode & 0o111


def test_the_program_state_reaches_the_plcs_procedure_coils():
    """bin/atc-program-state drives the three program coils (their signals are the generated HAL file's, from the
    map's hal names), reads the abort lines and the PLC's fault, and finds the sequence set the PLC is built from;
    ON_ABORT_COMMAND (the abort toggle) stays when the remap block is removed."""
    hal = (CONFIG / "atc-sim.hal").read_text()
    with open(REPO / "modbus_map" / "map.toml", "rb") as f:
        signals = {s["name"]: s for s in tomllib.load(f)["signal"]}
    lines = [f"net {signals['ProgramRunning']['hal']} atc-program-state.running",
             f"net {signals['ProgramEndedOk']['hal']} atc-program-state.ended-ok",
             f"net {signals['ProgramStopped']['hal']} atc-program-state.stopped",
             "net atc-emc-abort => atc-program-state.emc-abort",
             "net atc-program-abort-toggle motion.digital-out-02 => atc-program-state.abort-toggle",
             f"net {signals['FaultReason']['hal']} => atc-program-state.fault-reason",
             f"net {signals['ProcFaultId']['hal']} => atc-program-state.proc-fault-id"]
    for line in lines:
        assert re.search(rf"(?m)^{re.escape(line)}$", hal), line
    m = re.search(r"(?m)^loadusr -W atc-program-state --sequences (\S+)$", hal)
    assert m and (CONFIG / m.group(1)).resolve() == REPO / "configs" / "sequences" / "sequences.toml"
    assert (CONFIG / "bin" / "atc-program-state").stat().st_mode & 0o111
    generated = (CONFIG / "atc_iov2.hal").read_text()
    assert re.search(r"(?m)^net atc-emc-abort iocontrol\.0\.emc-abort\b", generated)
    for name in ("ProgramRunning", "ProgramEndedOk", "ProgramStopped"):
        assert re.search(rf"(?m)^net {signals[name]['hal']} mb2hal\.atc-bits-out\.{name}\.bit$", generated), name
    ini = (CONFIG / "atc-sim.ini").read_text()
    assert ini_values("RS274NGC", "ON_ABORT_COMMAND") == ["O <atc_on_abort> call"]
    remap = ini[ini.index("# ---- LinuxCNC executes the moves"):ini.index("# ---- end of the remap")]
    assert "ON_ABORT_COMMAND" not in remap
    ngc = (CONFIG / "nc_subs" / "atc_on_abort.ngc").read_text()
    assert "M64 P2" in ngc and "M65 P2" in ngc and "#<_hal[motion.digital-out-02]>" in ngc
    assert int(ini_values("EMCMOT", "NUM_DIO")[0]) > 2


def test_the_210_host_file_drives_the_abort_line_the_remap_waits_on():
    """LinuxCNC 2.10 has no iov2 (docs/linuxcnc.md, "LinuxCNC 2.10"): atc-host-210.hal raises the PLC's EmcAbort
    from the ON_ABORT toggle and from motion going off, ends it on the PLC's EmcAbortAck, and shows it to the
    remap, which waits for it to fall before it raises a change. It loads only components no other shipped HAL
    file loads (a component loads once), and needs none of iov2's pins."""
    hal = (CONFIG / "atc-host-210.hal").read_text()
    for line in ("net atc-program-abort-toggle => atc-210-abort-toggled.in",
                 "net atc-210-motion-enabled motion.motion-enabled => atc-210-motion-off.in",
                 "net atc-emc-abort atc-210-abort-pending.fault-out => mb2hal.atc-bits-out.EmcAbort.bit "
                 "motion.digital-in-07",
                 "net atc-emc-abort-ack mb2hal.atc-bits-in.EmcAbortAck.bit => atc-210-abort-pending.reset",
                 "net atc-210-fault-report mb2hal.atc-bits-in.ToolchangerFault.bit => "
                 "mb2hal.atc-bits-out.ToolchangerFaultAck.bit"):
        assert re.search(rf"(?m)^{re.escape(line)}$", hal), line
    # the prepare's answer reaches task only through the gate (armed once the answer was seen low during the
    # request); no other iov2 or iocontrol pin is used
    for line in ("unlinkp iocontrol.0.tool-prepared",
                 "net atc-tool-prepared => atc-210-prep-nack.in-00 atc-210-prep-answer.in-00",
                 "net atc-tool-prepare => atc-210-prep-armed.in-00",
                 "net atc-210-tool-prepared atc-210-prep-answer.and => iocontrol.0.tool-prepared"):
        assert re.search(rf"(?m)^{re.escape(line)}$", hal), line
    assert set(re.findall(r"iocontrol\.0\.[\w-]+", re.sub(r"(?m)#.*$", "", hal))) == {"iocontrol.0.tool-prepared"}
    generated = (CONFIG / "atc_io.hal").read_text()
    assert re.search(r"(?m)^net atc-tool-prepare iocontrol\.0\.tool-prepare\b", generated)
    assert "net atc-tool-prepared mb2hal.atc-bits-in.ToolPrepared.bit => iocontrol.0.tool-prepared\n" in generated
    mb2hal = (CONFIG / "atc_mb2hal.ini").read_text()
    names = {n for m in re.finditer(r"(?m)^PIN_NAMES=(.*)$", mb2hal) for n in m.group(1).split(",")}
    assert {"EmcAbort", "EmcAbortAck", "ToolchangerFault", "ToolchangerFaultAck"} <= names
    loaded = {}
    for path in CONFIG.glob("*.hal"):
        for m in re.finditer(r"(?m)^loadrt\s+(\w+)", path.read_text()):
            loaded.setdefault(m.group(1), []).append(path.name)
    for comp in re.findall(r"(?m)^loadrt\s+(\w+)", hal):
        assert loaded[comp] == ["atc-host-210.hal"], f"{comp} is loaded by {loaded[comp]} too"
    assert 7 < int(ini_values("EMCMOT", "NUM_DIO")[0])
    ngc = (CONFIG / "nc_subs" / "atc_m6.ngc").read_text()
    wait, raise_request = ngc.index("M66 P7 L4 Q#<timeout>"), ngc.index("M64 P0")
    assert wait < raise_request
    # the 2.9 machine leaves the pin without a writer, so the wait ends at once there
    assert not any("digital-in-07" in p.read_text() for p in CONFIG.glob("*.hal") if p.name != "atc-host-210.hal")
