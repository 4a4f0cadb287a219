"""`plc hmi`: the live toolchanger page, served with aiohttp on 127.0.0.1.

One poller reads every signal of the register map over Modbus (a few batched requests, --poll-ms apart) and
pushes what changed to every open page over a WebSocket, so five pages cost the PLC what one does.  The
toolchanger part needs only the map, so it works against an OpenPLC runtime serving our deploy file; the
diagnostic block and the watch/force panel need our runtime (its monitoring channel) and are left out
quietly when absent.

Commands (home, +/-1 pocket, go to pocket, clear fault, confirm the tool, enable or disable a user procedure)
are requests through the map's host signals: the PLC decides, and refuses what its interlocks and its state do
not allow (the answer says why).  Go to pocket is the PLC's go-to (GotoRequest/GotoPocket, answered in
GotoAnswer): the carousel turns to that pocket whatever the spindle holds; +/-1 is a go-to of the neighbour of the
pocket at the change position.
Every command, write and force needs the token (the monitor's, var/monitor.token); without it the page is
read-only.  The alarm history is a JSON-lines file (default var/alarms.jsonl) and survives restarts.

Exit status: 0 after Ctrl-C, 2 usage, map or bind problems.
"""
from __future__ import annotations

import argparse
import asyncio
import hmac
import json
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from plc.hmi import status
from plc.hmi.monitor import Monitor, MonitorError
from plc.modbus import LinkError, ModbusClient, ModbusException
from plc.project import add_view_options

from plc import cliargs, runtime
from plc.io_config import RUNTIME_INPUTS

from .. import project
from ..host.session import HostError, Session, Timeouts
from ..host.tags import MapError, Tags
from ..map.cli import default_map
from ..runsetup import SIM_FLAG_SIGNAL
from ..seq.assemble import check_set
from ..seq.diagnostics import Diagnostics as SeqDiagnostics
from ..seq.stgen import _message_numbers
from ..tools import ANSWERS, EDIT_RESET, Table, ToolsError, append_audit, open_audit
from . import mapinfo

STATIC = Path(__file__).parent / "static"
ALARM_KEEP = 500                 # alarms kept in the history file
POST_RATE = 20.0                 # requests a second per client address (bursts of POST_BURST)
POST_BURST = 40.0
WATCH_MAX = 32
BIT_GAP = 512                    # one coil and one discrete-input read per poll (a few hundred bits each)
COUNTER_PUSH_S = 0.25            # pushes when only counters and heartbeats moved
GOTO_TIMEOUT_S = 60.0            # a go-to's turn until its answer
# GotoAnswer (modbus_map/map.toml states) -> what the operator reads; {p} the pocket, {n} the pockets
GOTO_TEXT = {
    "Done": "pocket {p} at the change position",
    "Stopped": "the turn to pocket {p} was stopped (an abort, a fault or the machine interlocks: door, air, spindle)",
    "RefusedBusy": "the changer is busy (a change, a prepare, homing or a turn runs or is asked)",
    "RefusedFaulted": "a fault is latched: clear it first",
    "RefusedNotHomed": "the carousel is not homed: home it first",
    "RefusedRecovery": "an interrupted change left a recovery to do first (home the changer, confirm the tool)",
    "RefusedInterlock": "the interlocks forbid turning (arm out, collet open, or guard door, air, spindle)",
    "RefusedBadPocket": "pocket {p} is not on the carousel (1..{n})",
    "RefusedNoCarousel": "this machine has fixed pockets (a rack): there is no carousel to turn",
}


@dataclass
class Options:
    plc_host: str = "127.0.0.1"
    plc_port: int = 5020
    map_path: Path = Path("modbus_map/map.toml")
    monitor_socket: Path | None = None
    token_file: Path | None = None
    alarms: Path = Path("var/alarms.jsonl")
    poll_ms: int = 20
    pockets: int | None = None


@dataclass
class Hub:
    """What the pages see: the latest values, pushed on change."""
    opts: Options
    info: mapinfo.MapInfo
    token: str | None
    pockets: int
    values: dict = field(default_factory=dict)
    diag: dict | None = None
    link: dict = field(default_factory=dict)
    watch: dict = field(default_factory=dict)        # path -> value (monitor)
    watch_paths: list[str] = field(default_factory=list)
    watch_error: str = ""
    forces: list = field(default_factory=list)
    scan: int | None = None
    alarms: list = field(default_factory=list)
    sockets: set = field(default_factory=set)
    seq: int = 0
    plc_error: str = ""
    changed_at: float = 0.0                          # monotonic time of the poll that saw the last change
    polled_at: float = 0.0                           # wall time when the last poll's answers were in
    procedures: list = field(default_factory=list)   # the user procedures of the sequence set (procedures_of)
    texts: dict = field(default_factory=dict)        # their ErrMsg texts by F_SequenceMessage number
    _beats: dict = field(default_factory=dict)
    _buckets: dict = field(default_factory=dict)

    # ----------------------------------------------------------- alarms --
    def load_alarms(self) -> None:
        try:
            lines = self.opts.alarms.read_text(encoding="utf-8").splitlines()
        except OSError:
            return
        for line in lines[-ALARM_KEEP:]:
            try:
                self.alarms.append(json.loads(line))
            except ValueError:
                continue                 # a line cut by a crash: the others stay

    def _save_alarms(self) -> None:
        self.opts.alarms.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.opts.alarms.with_suffix(".tmp")
        tmp.write_text("".join(json.dumps(a) + "\n" for a in self.alarms[-ALARM_KEEP:]), encoding="utf-8")
        tmp.replace(self.opts.alarms)

    def plc_time(self, values: dict) -> dict:
        """The PLC's own time of this poll, when it gives one: our runtime's diagnostic block counts scans (32 bit)
        and their period; the map's ScanCount (16 bit, every poll) says how many scans ran since that block was
        read. OpenPLC gives none: {}."""
        d = self.diag
        if not d or "scan_count" not in d or "ScanCount" not in values or not d.get("base_tick_us"):
            return {}
        scan = d["scan_count"] + (int(values["ScanCount"]) - d["scan_count"]) % 65536
        return {"plc_scan": scan, "plc_s": round(scan * d["base_tick_us"] / 1e6, 3)}

    def _fault_changed(self, old: int, new: int, values: dict | None = None) -> None:
        now = time.time()
        stamp = self.plc_time(values or {})
        if old:
            for a in reversed(self.alarms):
                if a["code"] == old and not a.get("cleared"):
                    a["cleared"] = now
                    if stamp:
                        a["cleared_plc_s"] = stamp["plc_s"]
                    break
        if new:
            r = self.info.reason(new)
            self.alarms.append({"code": new, "name": r["name"], "text": r["text"], "cause": r.get("cause", ""),
                                "remedy": r.get("remedy", ""), "raised": now, **stamp})
        self._save_alarms()

    # ------------------------------------------------------------- state --
    def apply(self, values: dict, diag: dict | None) -> bool:
        """Take one poll; True when the pages must hear of it now (a signal changed that is not a counter)."""
        now = time.monotonic()
        noisy = {self.info.rmap.link.plc_alive, self.info.rmap.link.host_heartbeat, "PlcHeartbeat", "ScanCount"}
        changed = any(values.get(k) != self.values.get(k) for k in values if k not in noisy) \
            or set(values) != set(self.values)
        old_fault = int(self.values.get("FaultReason", 0) or 0)
        new_fault = int(values.get("FaultReason", 0) or 0)
        if self.values and old_fault != new_fault or (not self.values and new_fault and not any(
                a["code"] == new_fault and not a.get("cleared") for a in self.alarms)):
            self._fault_changed(old_fault if self.values else 0, new_fault, values)
        for name in (self.info.rmap.link.plc_alive, "PlcHeartbeat", self.info.rmap.link.host_heartbeat):
            if name in values and self._beats.get(name, (None,))[0] != values[name]:
                self._beats[name] = (values[name], now)
        self.link = {name: round((now - at) * 1000) for name, (_v, at) in self._beats.items()}
        if values != self.values:
            self.changed_at = now
        self.values, self.diag = values, diag
        return changed

    def snapshot(self) -> dict:
        self.seq += 1
        fault = int(self.values.get("FaultReason", 0) or 0)
        return {"t": "state", "seq": self.seq, "values": self.values, "diag": self.diag, "heartbeat_age_ms": self.link,
                "fault": self.info.reason(fault) if fault else None, "alarms": self.alarms[-20:],
                "watch": self.watch, "watch_error": self.watch_error, "forces": self.forces, "scan": self.scan,
                "plc_error": self.plc_error, "polled_at_ms": self.polled_at * 1000}

    # ------------------------------------------------------------ guards --
    def allow(self, peer: str) -> bool:
        now = time.monotonic()
        tokens, at = self._buckets.get(peer, (POST_BURST, now))
        tokens = min(POST_BURST, tokens + (now - at) * POST_RATE)
        if tokens < 1:
            self._buckets[peer] = (tokens, now)
            return False
        self._buckets[peer] = (tokens - 1, now)
        return True

    def token_ok(self, given: str | None) -> bool:
        return bool(self.token) and given is not None and hmac.compare_digest(given.encode(), self.token.encode())


def not_simulated(info: mapinfo.MapInfo) -> list[str]:
    """The machine's inputs that nothing drives while the simulated plant runs (the plant models stand in for them
    inside the program; their wires read 0): every input but the simulation flag and the runtime's own inputs
    (forces active, remote I/O module lost)."""
    return [s.name for s in info.rmap.signals if s.direction == "input" and s.type == "BOOL"
            and s.name != SIM_FLAG_SIGNAL and not (s.table == "discrete_input" and s.address in RUNTIME_INPUTS)
            and not s.name.startswith("IoModule")]


def fault_lines(info: mapinfo.MapInfo) -> list[str]:
    """BOOL lines whose TRUE is a fault (drawn as one when active): the iov2 fault lines, a lost remote I/O
    module."""
    return [s.name for s in info.rmap.signals if s.type == "BOOL"
            and s.name.endswith(("Fault", "Faulted", "Lost")) and not s.name.startswith("Clear")]


MODES = ("every {interval} ms", "at program start", "after a successful end", "on error or stop")


def procedures_of(root: Path) -> tuple[list[dict], dict[int, str]]:
    """The user procedures of the project's sequence set (docs/procedures.md) as the page lists them, and their
    ErrMsg texts by number; nothing when the set is missing or has errors (`plc seq check` says why)."""
    diags = SeqDiagnostics()
    try:
        assembly = check_set(root / project.sequence_index(root), diags)
    except OSError:
        return [], {}
    if assembly is None:
        return [], {}
    numbers = _message_numbers(assembly)
    procs = [{"slot": p.slot, "id": p.id, "name": p.name, "mode": p.mode, "enabled": p.enabled,
              "when": MODES[p.mode].format(interval=p.interval_ms), "stop_on_error": p.stop_on_error,
              "can_stop_gcode": p.can_stop_gcode} for p, _ in assembly.procedures]
    texts = {numbers[p.err_msg]: p.err_msg for p, _ in assembly.procedures if p.err_msg}
    return procs, texts


def _pockets(info: mapinfo.MapInfo, given: int | None) -> int:
    if given:
        return given
    machine = info.rmap.root / project.description(info.rmap.root)
    try:
        data = tomllib.loads(machine.read_text(encoding="utf-8"))
        n = data.get("carousel", {}).get("pockets") or data.get("rack", {}).get("positions")
        if isinstance(n, int) and 2 <= n <= 50:
            return n
    except (OSError, tomllib.TOMLDecodeError):
        pass
    return sum(1 for s in info.rmap.signals if s.name.startswith("PocketTool")) or 12


# ---------------------------------------------------------------- pollers

def _read_all(tags: Tags, names: tuple[str, ...], client: ModbusClient, want_diag: bool) -> tuple[dict, dict | None]:
    values = tags.read(*names)
    diag = None
    if want_diag:
        try:
            diag = status.read(client)
        except ModbusException:
            diag = None                  # OpenPLC: no diagnostic block
    return values, diag


async def poll_plc(hub: Hub) -> None:
    """Read the map's signals every poll_ms; push to the pages when anything changed."""
    loop = asyncio.get_running_loop()
    names = tuple(s.name for s in hub.info.rmap.signals)
    client = None
    tags = None
    want_diag = True
    last_diag = last_push = 0.0
    while True:
        t0 = time.monotonic()
        try:
            if client is None:
                client = ModbusClient(hub.opts.plc_host, hub.opts.plc_port, unit=hub.info.rmap.linuxcnc.slave_id)
                await loop.run_in_executor(None, client.connect)
                tags = Tags(hub.info.rmap, client, bit_gap=BIT_GAP)
            diag_due = want_diag and t0 - last_diag >= 0.5
            values, diag = await loop.run_in_executor(None, _read_all, tags, names, client, diag_due)
            hub.polled_at = time.time()
            if diag_due:
                last_diag = t0
                want_diag = diag is not None or hub.diag is not None
            hub.plc_error = ""
            # a real change goes out at once; counters and heartbeats alone 4 times a second
            if hub.apply(values, diag if diag_due else hub.diag) or t0 - last_push >= COUNTER_PUSH_S:
                last_push = t0
                await broadcast(hub)
        except (LinkError, ModbusException, OSError) as exc:
            if client is not None:
                client.close()
            client = None
            if hub.plc_error != str(exc):
                hub.plc_error = str(exc)
                await broadcast(hub)
            await asyncio.sleep(1.0)
            continue
        await asyncio.sleep(max(0.0, hub.opts.poll_ms / 1000 - (time.monotonic() - t0)))


async def poll_monitor(hub: Hub) -> None:
    """The watch panel: the watched paths and the forces, 10 times a second, from our runtime's monitor."""
    if hub.opts.monitor_socket is None:
        return
    loop = asyncio.get_running_loop()
    mon: Monitor | None = None
    while True:
        try:
            if mon is None:
                mon = Monitor(hub.opts.monitor_socket, timeout=5.0)
                await loop.run_in_executor(None, mon.connect)
            paths = list(hub.watch_paths)
            forces = await loop.run_in_executor(None, mon.forces)
            watch, scan, error = {}, hub.scan, ""
            if paths:
                try:
                    scan, watch = await loop.run_in_executor(None, mon.read_scan, *paths)
                except MonitorError as exc:
                    error = str(exc)
            if (watch, forces, error) != (hub.watch, hub.forces, hub.watch_error):
                hub.watch, hub.forces, hub.watch_error, hub.scan = watch, forces, error, scan
                await broadcast(hub)
            hub.scan = scan
        except MonitorError as exc:
            if mon is not None:
                mon.close()
            mon = None
            hub.watch_error = f"no monitoring channel: {exc}"
            await asyncio.sleep(2.0)
            continue
        await asyncio.sleep(0.1)


async def broadcast(hub: Hub) -> None:
    if not hub.sockets:
        return
    text = json.dumps(hub.snapshot())
    for ws in list(hub.sockets):
        try:
            await ws.send_str(text)
        except (ConnectionError, RuntimeError):
            hub.sockets.discard(ws)


# ---------------------------------------------------------------- commands

def run_command(hub: Hub, cmd: str, arg, peer: str = "?") -> dict:
    """One operator command as requests on the map; the PLC's answer as a sentence. `peer`: the page's client
    address, named in the audit log."""
    rmap = hub.info.rmap
    client = ModbusClient(hub.opts.plc_host, hub.opts.plc_port, unit=rmap.linuxcnc.slave_id)
    client.connect()
    session = Session(rmap, client, say=lambda _t: None, timeouts=Timeouts(request=60.0))
    try:
        if cmd not in ("home", "clear", "goto", "step", "confirm", "tool-reset", "procedure"):
            return {"ok": False, "error": f"unknown command '{cmd}' (home, step, goto, clear, confirm, tool-reset, "
                                          "procedure)"}
        if cmd == "tool-reset":
            return tool_reset(hub, session.tags, arg)
        if cmd == "procedure":
            return procedure_switch(hub, session.tags, arg, peer)
        if cmd == "step" and arg not in (1, -1):
            return {"ok": False, "error": "step is +1 or -1"}
        if cmd in ("goto", "confirm") and (not isinstance(arg, int) or isinstance(arg, bool)):
            return {"ok": False, "error": f"{cmd} needs a number"}
        if cmd in ("goto", "step") and not session.tags.has("GotoRequest"):
            return {"ok": False,
                    "error": "this PLC's register map has no GotoRequest: the page cannot turn the carousel"}
        session.start()            # the host heartbeat while the command runs: the PLC serves a live host only
        if cmd == "home":
            outcome = session.home()
        elif cmd == "clear":
            outcome = session.clear()
        elif cmd == "confirm":
            outcome = session.confirm(arg)
        else:
            if cmd == "step":
                current = int(session.tags.get("CurrentPocket"))
                if current < 1:
                    return {"ok": False, "error": "the pocket at the change position is not known (the carousel "
                            "turns or is not homed): +/-1 needs it; home, or go to a pocket by number"}
                arg = (current - 1 + arg) % hub.pockets + 1
            return goto(session, hub, arg)
        return {"ok": bool(outcome.ok), "text": outcome.text} if outcome.ok else {"ok": False, "error": outcome.text}
    except HostError as exc:
        return {"ok": False, "error": str(exc)}
    finally:
        session.stop()
        client.close()


def tool_reset(hub: Hub, tags, tool) -> dict:
    """A tool's time used back to 0 (after a regrind or a new tool) through the PLC's edit command, audited as
    `plc tools reset` is (docs/tools.md), in the audit log beside the token file."""
    if not isinstance(tool, int) or isinstance(tool, bool) or tool < 1:
        return {"ok": False, "error": "tool-reset needs a tool number"}
    if not tags.has("ToolEditRequest"):
        return {"ok": False, "error": "this PLC's register map has no tool table"}
    table = Table(tags, audit_file(hub))
    try:
        _, rows, _ = table.rows()
        row = next((r for r in rows if r.tool == tool), None)
        if row is None:
            return {"ok": False, "error": f"T{tool} is in no row of the PLC's tool table"}
        what = f"reset row {row.row} T{tool} (page)"
        answer = table.edit(EDIT_RESET, row.row, what)
    except ToolsError as exc:
        return {"ok": False, "error": str(exc)}
    if answer != 1:
        return {"ok": False, "error": f"T{tool}: {ANSWERS.get(answer, f'answer {answer}')}"}
    return {"ok": True, "text": f"T{tool}: time used reset to 0"}


def audit_file(hub: Hub) -> Path:
    """The audit log beside the token file, where the runtime logs monitor writes and `plc tools` its edits."""
    token_dir = hub.opts.token_file.parent if hub.opts.token_file else Path("var")
    return token_dir / runtime.DEFAULT_AUDIT_FILE.name


def procedure_switch(hub: Hub, tags, arg, peer: str = "?") -> dict:
    """Enable or disable a user procedure at run time: its bit in ProcDisabled (0 = as compiled, retained by the
    PLC). A procedure the sequence set compiles disabled cannot be enabled here; one that runs when disabled runs
    to its end. Audited: one line per switch in the audit log with the page's client address; a switch the log
    cannot take is not made."""
    slot = arg.get("slot") if isinstance(arg, dict) else None
    enable = arg.get("enabled") if isinstance(arg, dict) else None
    if not isinstance(slot, int) or isinstance(slot, bool) or not 1 <= slot <= 16 or not isinstance(enable, bool):
        return {"ok": False, "error": 'procedure needs {"slot": 1..16, "enabled": true|false}'}
    if not tags.has("ProcDisabled"):
        return {"ok": False, "error": "this PLC's register map has no user procedures"}
    proc = next((p for p in hub.procedures if p["slot"] == slot), None)
    if proc is None:
        return {"ok": False, "error": f"the sequence set has no procedure {slot}"}
    if enable and not proc["enabled"]:
        return {"ok": False, "error": f"procedure {proc['id']} ({proc['name']}) is disabled in the sequence set "
                                      "(enabled = false): the page cannot enable it"}
    what = (f"page {peer} procedure {proc['id']} ({proc['name']}) slot {slot} "
            f"{'enable' if enable else 'disable'}")
    try:
        fd = open_audit(audit_file(hub))
    except ToolsError as exc:
        return {"ok": False, "error": f"not switched: {exc}"}
    bit = 1 << (slot - 1)
    try:
        mask = int(tags.get("ProcDisabled"))
        mask = mask & ~bit if enable else mask | bit
        tags.write(ProcDisabled=mask)
        taken = int(tags.get("ProcDisabled")) == mask
    except BaseException:
        append_audit(audit_file(hub), what, "no answer", fd)
        raise
    try:
        append_audit(audit_file(hub), what, f"done (ProcDisabled {mask})" if taken else "not taken", fd)
    except ToolsError as exc:
        return {"ok": False, "error": f"switched, but {exc}"}
    if not taken:
        return {"ok": False, "error": "the PLC did not take the new ProcDisabled"}
    return {"ok": True, "text": f"procedure {proc['id']} ({proc['name']}) {'enabled' if enable else 'disabled'}"}


def scans_after(tags, n: int, deadline: float) -> bool:
    """Wait until the PLC has run n scans after the host's last acknowledged write (counted from a ScanCount read
    now): a write is in the runtime's image before its acknowledgement, so the scan after the one running now
    takes it, and its outputs are published with the count after it. False when `deadline` passed first."""
    scan0 = int(tags.get("ScanCount"))
    while (int(tags.get("ScanCount")) - scan0) % 65536 < n:
        if time.monotonic() > deadline:
            return False
        time.sleep(0.002)
    return True


def goto(session: Session, hub: Hub, pocket: int) -> dict:
    """The PLC's go-to: GotoPocket and GotoRequest low seen by the PLC, GotoRequest raised, then the answer the PLC
    wrote on that edge until the turn ends. Both waits count scans from a ScanCount read after the runtime
    acknowledged the write (scans_after). Counted from a read before the write, a host that was not scheduled for a
    scan period between the two took a request the PLC had not yet seen for one it never saw (CI saw it once;
    here 12 of 3,000 go-tos at load 5 read their answer 3 to 5 scans after such a count); and a request raised
    right after the last one fell, within one scan, would be no edge for the PLC."""
    tags = session.tags
    deadline = time.monotonic() + GOTO_TIMEOUT_S
    tags.write(GotoRequest=False)
    tags.write(GotoPocket=pocket)
    if not scans_after(tags, 2, deadline):
        return {"ok": False, "error": f"go to pocket {pocket}: the PLC ran no scans for {GOTO_TIMEOUT_S:.0f} s"}
    tags.write(GotoRequest=True)
    scan0 = int(tags.get("ScanCount"))
    try:
        while True:
            s = tags.read("GotoAnswer", "ScanCount", "CurrentPocket", "FaultReason")
            answer = hub.info.state_name("GotoAnswer", s["GotoAnswer"])
            if (int(s["ScanCount"]) - scan0) % 65536 >= 2 and answer != "Turning":
                request_seen = bool(tags.get("GotoRequest")) if answer == "None" else True
                break
            if time.monotonic() > deadline:
                return {"ok": False, "error": f"go to pocket {pocket}: no answer from the PLC within "
                        f"{GOTO_TIMEOUT_S:.0f} s (GotoAnswer {answer})"}
            time.sleep(0.01)
    finally:
        tags.write(GotoRequest=False)
    if answer == "None":
        # the program answers every rising edge it sees (FB_AtcChanger): none after two scans means it saw none
        return {"ok": False, "error": f"go to pocket {pocket}: the PLC did not see the request (GotoAnswer None "
                f"{(int(s['ScanCount']) - scan0) % 65536} scans after GotoRequest was written; it read back "
                f"{'TRUE' if request_seen else 'FALSE'})"}
    text = GOTO_TEXT.get(answer, f"GotoAnswer {answer}").format(p=pocket, n=hub.pockets)
    if answer == "Done" and int(s["CurrentPocket"]) == pocket:
        return {"ok": True, "text": f"go to pocket {pocket}: {text}"}
    fault = int(s["FaultReason"])
    if fault:
        r = hub.info.reason(fault)
        text += f"; fault {fault} {r['name']}: {r['text']}"
    return {"ok": False, "error": f"go to pocket {pocket}: the PLC refused: {text}" if answer.startswith("Refused")
            else f"go to pocket {pocket}: {text}"}


# ---------------------------------------------------------------- web app

def make_app(hub: Hub):
    from aiohttp import WSMsgType, web

    command_lock = asyncio.Lock()

    def refuse(status_code: int, text: str):
        return web.json_response({"ok": False, "error": text}, status=status_code)

    async def guard(request, need_token: bool):
        peer = request.remote or "?"
        if not hub.allow(peer):
            return refuse(429, f"too many requests: at most {POST_RATE:.0f} a second")
        if need_token and not hub.token_ok(request.headers.get("X-Token")):
            return refuse(403, "read-only: this needs the token (var/monitor.token)" if hub.token else
                          "read-only: the page was started without a token file")
        return None

    async def body_of(request) -> dict | None:
        try:
            data = await request.json()
        except (ValueError, UnicodeDecodeError):
            return None
        return data if isinstance(data, dict) else None

    async def index(_request):
        return web.FileResponse(STATIC / "index.html")

    async def info(_request):
        sigs = [{"name": s.name, "table": s.table, "address": s.address, "type": s.type, "direction": s.direction,
                 "description": s.description,
                 "states": {str(k): v for k, v in hub.info.states.get(s.name, {}).items()}}
                for s in hub.info.rmap.signals]
        return web.json_response({"signals": sigs, "pockets": hub.pockets, "token_required": True,
                                  "not_simulated": not_simulated(hub.info), "fault_lines": fault_lines(hub.info),
                                  "writes_possible": bool(hub.token), "monitor": hub.opts.monitor_socket is not None,
                                  "reasons": {str(k): v for k, v in hub.info.reasons.items()},
                                  "procedures": hub.procedures, "texts": {str(k): v for k, v in hub.texts.items()}})

    async def alarms(_request):
        return web.json_response({"alarms": hub.alarms})

    async def auth(request):
        if (bad := await guard(request, True)) is not None:
            return bad
        return web.json_response({"ok": True})

    async def command(request):
        if (bad := await guard(request, True)) is not None:
            return bad
        data = await body_of(request)
        if data is None or not isinstance(data.get("cmd"), str):
            return refuse(400, 'expected JSON {"cmd": "home"|"step"|"goto"|"clear"|"confirm"|"tool-reset"|'
                               '"procedure", "arg": ...}')
        if command_lock.locked():
            return refuse(409, "another command is running")
        async with command_lock:
            loop = asyncio.get_running_loop()
            try:
                result = await loop.run_in_executor(None, run_command, hub, data["cmd"], data.get("arg"),
                                                    request.remote or "?")
            except (LinkError, ModbusException) as exc:
                result = {"ok": False, "error": f"the PLC did not take the request: {exc}"}
        return web.json_response(result, status=200 if result.get("ok") else 409)

    async def set_watch(request):
        if (bad := await guard(request, False)) is not None:
            return bad
        data = await body_of(request)
        paths = data.get("paths") if data else None
        if not isinstance(paths, list) or not all(isinstance(p, str) and 0 < len(p) < 200 for p in paths) \
                or len(paths) > WATCH_MAX:
            return refuse(400, f'expected JSON {{"paths": [up to {WATCH_MAX} variable paths]}}')
        if hub.opts.monitor_socket is None:
            return refuse(409, "no monitoring channel: watch and force need our runtime (plc run)")
        if paths:
            loop = asyncio.get_running_loop()
            try:
                with Monitor(hub.opts.monitor_socket, timeout=5.0) as m:
                    await loop.run_in_executor(None, lambda: m.read(*paths))
            except MonitorError as exc:
                return refuse(400, str(exc))
        hub.watch_paths = list(dict.fromkeys(paths))
        return web.json_response({"ok": True, "paths": hub.watch_paths})

    async def force(request):
        if (bad := await guard(request, True)) is not None:
            return bad
        data = await body_of(request)
        action = data.get("action") if data else None
        path = data.get("path") if data else None
        value = data.get("value", "") if data else None
        if action not in ("write", "force", "unforce-keep", "unforce-restore") or not isinstance(path, str) \
                or not isinstance(value, (str, int, float, bool)):
            return refuse(400, 'expected JSON {"action": "write"|"force"|"unforce-keep"|"unforce-restore", '
                               '"path": ..., "value": ...}')
        if hub.opts.monitor_socket is None or not hub.token:
            return refuse(409, "no monitoring channel with a token: writes and forces need our runtime")
        text = ("TRUE" if value else "FALSE") if isinstance(value, bool) else str(value)
        if "\n" in path or "\n" in text:
            return refuse(400, "a path or value is one line")

        def act() -> dict:
            with Monitor(hub.opts.monitor_socket, timeout=5.0) as m:
                m.auth(hub.token)
                if action == "write":
                    return {"ok": True, "scan": m.write(path, text)}
                if action == "force":
                    return {"ok": True, "scan": m.force(path, text)}
                return {"ok": True, "scan": m.unforce(path, restore=action == "unforce-restore")}
        try:
            result = await asyncio.get_running_loop().run_in_executor(None, act)
        except MonitorError as exc:
            return refuse(400, str(exc))
        return web.json_response(result)

    async def ws_handler(request):
        ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=4096)
        await ws.prepare(request)
        hub.sockets.add(ws)
        try:
            await ws.send_str(json.dumps(hub.snapshot()))
            async for msg in ws:
                if msg.type == WSMsgType.ERROR:
                    break                     # pages only listen: anything they send is ignored
        finally:
            hub.sockets.discard(ws)
        return ws

    async def start_pollers(app):
        app["tasks"] = [asyncio.create_task(poll_plc(hub)), asyncio.create_task(poll_monitor(hub))]

    async def stop_pollers(app):
        for t in app["tasks"]:
            t.cancel()
        for ws in list(hub.sockets):
            await ws.close()

    app = web.Application(client_max_size=64 * 1024)
    app.router.add_get("/", index)
    app.router.add_get("/api/info", info)
    app.router.add_get("/api/alarms", alarms)
    app.router.add_post("/api/auth", auth)
    app.router.add_post("/api/command", command)
    app.router.add_post("/api/watch", set_watch)
    app.router.add_post("/api/force", force)
    app.router.add_get("/ws", ws_handler)
    app.on_startup.append(start_pollers)
    app.on_shutdown.append(stop_pollers)
    return app


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="plc hmi", description="Serve the live toolchanger page: the carousel, tools, "
                                "iov2 lines, changer and sequence state, faults with cause and remedy, alarm history, "
                                "scan and Modbus statistics, commands, and a watch/force panel.",
                                epilog="exit status: 0 after Ctrl-C, 2 usage, map or bind problems")
    p.add_argument("--bind", default="127.0.0.1", help="address the page is served on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8080, help="HTTP port (default 8080; 0 = any free port, printed)")
    p.add_argument("--plc-host", default=None, help="PLC address (default: the map's [linuxcnc] host)")
    p.add_argument("--plc-port", type=int, default=None,
                   help="PLC Modbus port (default: the machine's run configuration, else the map's 5020)")
    p.add_argument("--map", type=Path, default=None, metavar="FILE", help="register map (modbus_map/map.toml)")
    p.add_argument("--monitor", type=Path, default=None, metavar="SOCKET",
                   help="our runtime's monitor socket, for watch/force (default: the machine's, "
                        f"{runtime.DEFAULT_MONITOR_SOCKET} for the default machine)")
    p.add_argument("--no-monitor", action="store_true", help="no watch/force panel (e.g. against OpenPLC)")
    p.add_argument("--token-file", type=Path, default=None, metavar="FILE",
                   help="the token that unlocks commands and forces (default: the machine's, "
                        f"{runtime.DEFAULT_TOKEN_FILE} for the default machine); absent: read-only")
    p.add_argument("--alarms", type=Path, default=None, metavar="FILE",
                   help="alarm history file (default: beside the machine's monitor socket, var/alarms.jsonl for "
                        "the default machine)")
    p.add_argument("--poll-ms", type=int, default=20, metavar="MS", help="Modbus poll period (default 20)")
    p.add_argument("--pockets", type=int, default=None, help="pockets drawn (default: machines/default/machine.toml)")
    add_view_options(p)
    return p


def main(argv: list[str]) -> int:
    parser = build_parser()
    args, code = cliargs.parse(parser, argv)
    if args is None:
        return code
    try:
        from aiohttp import web
    except ImportError:
        print("plc hmi: error: aiohttp is not installed (scripts/setup installs it)", file=sys.stderr)
        return 2
    if not 5 <= args.poll_ms <= 10000:
        print("plc hmi: error: --poll-ms is 5..10000", file=sys.stderr)
        return 2
    try:
        info = mapinfo.load(args.map or default_map())
    except MapError as exc:
        print(f"plc hmi: error: {exc}", file=sys.stderr)
        return 2
    machine_port, machine_socket, machine_token = runtime.project_endpoint(info.rmap.root)
    args.monitor = args.monitor or machine_socket
    args.token_file = args.token_file or machine_token
    args.alarms = args.alarms or machine_socket.parent / "alarms.jsonl"
    token = None
    try:
        token = args.token_file.read_text(encoding="utf-8").split()[0]
    except (OSError, IndexError):
        print(f"plc hmi: no token in {args.token_file}: the page is read-only", file=sys.stderr)
    opts = Options(plc_host=args.plc_host or info.rmap.linuxcnc.host,
                   plc_port=args.plc_port if args.plc_port is not None else machine_port if machine_port is not None
                   else info.rmap.linuxcnc.port,
                   map_path=info.rmap.path, monitor_socket=None if args.no_monitor else args.monitor,
                   token_file=args.token_file, alarms=args.alarms, poll_ms=args.poll_ms, pockets=args.pockets)
    hub = Hub(opts, info, token, _pockets(info, args.pockets))
    hub.procedures, hub.texts = procedures_of(info.rmap.root)
    hub.load_alarms()
    app = make_app(hub)

    async def serve() -> None:
        runner = web.AppRunner(app)
        await runner.setup()
        site = web.TCPSite(runner, args.bind, args.port)
        try:
            await site.start()
        except OSError as exc:
            await runner.cleanup()
            raise SystemExit(f"plc hmi: error: cannot listen on {args.bind}:{args.port}: {exc.strerror or exc}") \
                from None
        port = site._server.sockets[0].getsockname()[1] if site._server and site._server.sockets else args.port
        print(f"plc hmi: http://{args.bind}:{port}/ (PLC {opts.plc_host}:{opts.plc_port}"
              f"{', monitor ' + str(opts.monitor_socket) if opts.monitor_socket else ''})", flush=True)
        try:
            await asyncio.Event().wait()
        finally:
            await runner.cleanup()

    try:
        asyncio.run(serve())
    except KeyboardInterrupt:
        return 0
    except SystemExit as exc:
        print(exc, file=sys.stderr)
        return 2
    return 0
