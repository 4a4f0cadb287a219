"""The CNC end of the iov2 protocol over the register map: what LinuxCNC's iov2 does, for `plc host`.

Every handshake is four-phase (docs/iov2.md): numbers are written before the request bit rises; the
request is held until its ack rises, then dropped; the next request waits until that ack has dropped.
A rising ToolchangerFault is answered at any time, in every wait, as iov2 does: the reason is read, the
host's fault latch (ToolchangerFaulted) is set, ToolchangerFaultAck follows the fault line.  What a fault
means for an M6 follows LinuxCNC: the change is aborted (emc-abort, reason 101); reason > 0 is a soft fault
(the program continues without the change), reason <= 0 aborts the program (< 0 with the operator error
"toolchanger error N").  A prepare is not ended by a fault: the PLC still answers it.

The PLC must stay alive: PlcAlive or PlcHeartbeat must change at least every [link] plc_timeout_ms, else
the link counts as lost.  A background thread changes HostHeartbeat every host_heartbeat_period_ms.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Callable

from plc.modbus import LinkError, ModbusClient

from ..hmi.mapinfo import load as load_names
from ..map.model import RegisterMap
from .mailbox import RECORD, REQUEST
from .tags import Tags

# emc-reason values LinuxCNC uses (docs/iov2.md)
REASON_TASK_ABORT = 8
REASON_MOTION_OR_IO_ERROR = 3
REASON_ABORT_BY_TOOLCHANGER_FAULT = 101

WATCH = ("ToolPrepared", "ToolChanged", "StartChangeAck", "EmcAbortAck", "ToolchangerFault", "PlcReady",
         "CarouselHomed", "ChangerBusy", "HostLinkOk", "PlcAlive", "ToolchangerReason", "PlcHeartbeat",
         "IovState", "ChangerState", "FaultReason", "ToolInSpindle", "CurrentPocket", "EmcAbort", "ToolChange",
         "StartChange", "Recovery", "UncertainTool", "SimSpindleTool", "ToolPrepare")
REQUESTS = ("ToolPrepare", "StartChange", "ToolChange", "EmcAbort")   # the host's command coils
RECOVERY_HOME, RECOVERY_CONFIRM = 1, 2   # bits of the Recovery register
REASON_CONFIRM_TOOL = -108               # a change refused until the tool in the spindle is confirmed
REASON_CHANGE_INTERRUPTED = -103         # a Put/Get stopped part-way: Recovery says what became uncertain


LEFT_BEAT = 0xFFFF                       # the heartbeat a host writes last when it exits cleanly (LinuxCNC's
                                         # sawtooth stays in 0..1000)


def next_beat(beat: int) -> int:
    """The next host heartbeat: 0..65534, never LEFT_BEAT."""
    return (beat + 1) % 0xFFFF


class HostError(Exception):
    """A command could not complete (timeout, lost link, refused); the message says why."""


class LinkLost(HostError):
    pass


@dataclass
class Outcome:
    ok: bool                  # the program would continue (completed, or skipped by a soft fault)
    text: str
    reason: int = 0           # toolchanger reason of a fault that ended the command, 0 if none
    changed: bool = False


@dataclass
class Timeouts:
    request: float = 60.0     # a prepare or change until its ack
    ack_drop: float = 5.0     # an ack until it drops after the request dropped
    abort: float = 10.0       # emc-abort until emc-abort-ack
    link: float = 10.0        # start-up: until the PLC reports the host link up


# the user procedures' status registers (modbus_map/map.toml), read together for `status`
PROCEDURE_STATUS = ("ProcBusy", "ProcId", "ProcStep", "ProcLine", "ProcLastId", "ProcLastResult", "ProcLastReason",
                    "ProcLastDuration", "ProcLastAgo", "ProcFailCount", "ProcFaultId", "ProcFaultText")
PROCEDURE_FAILED = -150   # the reason a procedure with can_stop_gcode latches (modbus_map/reason_codes.toml)


@dataclass
class Session:
    rmap: RegisterMap
    client: ModbusClient
    say: Callable[[str], None] = print
    timeouts: Timeouts = field(default_factory=Timeouts)
    start_change: bool = True
    poll_interval: float = 0.01
    tags: Tags = field(init=False)
    faulted: bool = False               # the host's latch, as iov2's toolchanger-faulted
    fault_reason: int = 0
    tool_number: int = 0                # tool in the spindle as the host knows it (iov2 tool-number)
    prepared: tuple[int, int] | None = None
    _fault_acked: bool = False
    _new_fault: int | None = None
    _told: int | None = None            # the fault whose line (reason and text) this host printed last
    _beat: int = 0
    _beat_error: Exception | None = None
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None
    _alive: tuple = ()
    _alive_at: float = 0.0
    _names: dict | None = None          # signal -> value -> name (loaded on the first status)
    mailbox: object | None = None       # a host.mailbox.Mailbox served on every poll (attach_mailbox)

    def __post_init__(self) -> None:
        self.tags = Tags(self.rmap, self.client)
        self.watch = tuple(n for n in WATCH if self.tags.has(n))

    def attach_mailbox(self, mailbox) -> None:
        """Serve the PLC's sequence mailbox on every poll (also while a change waits for tool-changed)."""
        watch = self.watch + tuple(n for n in REQUEST if n not in self.watch)
        if not self.tags.read_together(watch, RECORD):
            raise ValueError("the mailbox record (" + ", ".join(RECORD) + ") is not one block of holding registers "
                             "of the register map: a host would execute fields of two reads")
        self.mailbox = mailbox
        self.watch = watch

    # ---------------------------------------------------------------- start / stop --
    def start(self) -> dict:
        """Restore the host's view from the PLC, start the heartbeat, wait for the PLC to see the link; requests
        of a host that stopped are taken over first (take_over)."""
        s = self.tags.read(*self.watch)
        left = [n for n in REQUESTS if s.get(n)]
        orphaned = bool(left) and not self._another_host_alive()
        self.tool_number = int(s.get("ToolInSpindle", 0))
        self.faulted = bool(self.tags.get("ToolchangerFaulted")) if self.tags.has("ToolchangerFaulted") else False
        self.fault_reason = int(s.get("FaultReason", 0)) if self.faulted else 0
        restore = {"ToolNumber": self.tool_number}
        if self.tags.has("HostToolRestore"):
            restore["HostToolRestore"] = self.tool_number
        self.tags.write(**restore)
        # the first beat at once: HostLinkOk may still be TRUE from a host that just left (the PLC counts its link
        # time-out from that host's last beat), and a command sent before this host's own first beat would meet
        # the link lost while the changer is busy
        name = self.rmap.link.host_heartbeat
        self._beat = next_beat(int(self.tags.get(name)))
        self.tags.write(**{name: self._beat})
        self._thread = threading.Thread(target=self._heartbeat, name="host-heartbeat", daemon=True)
        self._thread.start()
        self._alive, self._alive_at = self._alive_key(s), time.monotonic()
        if "HostLinkOk" in self.watch:
            s = self.wait(lambda s: s["HostLinkOk"], self.timeouts.link, "the PLC to see the host heartbeat "
                          "(HostLinkOk)")
        if orphaned:
            s = self.take_over(left)
        return s

    def _another_host_alive(self) -> bool:
        """Does another host beat? This host beats meanwhile (the PLC must not lose the link while it looks: a
        busy changer faults after host_timeout_ms without a beat) and reads its own value back: a live host
        writes its own every host_heartbeat_period_ms / 2, so within a few periods a read shows a value this
        host did not write. Watched for half the PLC's own link time-out."""
        name = self.rmap.link.host_heartbeat
        period = self.rmap.link.host_heartbeat_period_ms / 1000.0
        beat = (int(self.tags.get(name)) + 0x5A5A) & 0xFFFF       # far from any other host's counter
        deadline = time.monotonic() + max(4 * period, self.rmap.link.host_timeout_ms / 2000.0)
        while time.monotonic() < deadline:
            beat = next_beat(beat)
            self.tags.write(**{name: beat})
            time.sleep(period / 4)
            if int(self.tags.get(name)) != beat:
                return True
        self._beat = beat
        return False

    def take_over(self, left: list[str]) -> dict:
        """Requests a host left set when it stopped (killed, link lost) are ended the way their handshake ends: a
        request the PLC had already answered is dropped (that change or prepare was done, and said so); a request
        still running is aborted (emc-abort, task abort) so the PLC stops what the dead host started and reports
        what it needs (a fault to clear, a recovery). The mailbox is not served meanwhile: the dead host's moves
        are not executed for it. Returns the PLC's values afterwards."""
        mailbox, self.mailbox = self.mailbox, None
        try:
            s = self.poll()
            done = {"ToolPrepare": "ToolPrepared", "StartChange": "StartChangeAck", "ToolChange": "ToolChanged",
                    "EmcAbort": "EmcAbortAck"}
            running = [n for n in left if n != "EmcAbort" and not s.get(done[n])]
            if running:
                self._abort(REASON_TASK_ABORT)
                self.say(f"took over from a host that stopped: its {', '.join(running)} aborted (emc-abort "
                         f"{REASON_TASK_ABORT}); the PLC reports what it needs below")
            else:
                self.tags.write(**{n: False for n in left})
                for name in left:
                    self.wait(lambda s, a=done[name]: not s[a], self.timeouts.ack_drop, f"{done[name]} to drop")
                self.say(f"took over from a host that stopped: its {', '.join(left)} had been answered and "
                         "are dropped")
            s = self.poll()
            self.tool_number = int(s.get("ToolInSpindle", self.tool_number))
            self.tags.write(ToolNumber=self.tool_number)
            return s
        finally:
            self.mailbox = mailbox

    def stop(self) -> None:
        """End the heartbeat; a clean exit writes LEFT_BEAT last (a running host never writes it), so the PLC's log
        says the host left rather than that its link was lost."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            try:
                self.tags.write(**{self.rmap.link.host_heartbeat: LEFT_BEAT})
            except Exception:                # the link may be gone already: nothing to tell then
                pass

    def _heartbeat(self) -> None:
        period = self.rmap.link.host_heartbeat_period_ms / 1000.0 / 2
        name = self.rmap.link.host_heartbeat
        while not self._stop.wait(period):
            self._beat = next_beat(self._beat)
            try:
                self.tags.write(**{name: self._beat})
            except Exception as exc:          # reported by the next poll of the command loop
                self._beat_error = exc
                return

    # ------------------------------------------------------------------- polling --
    def _alive_key(self, s: dict) -> tuple:
        return (s.get("PlcAlive"), s.get("PlcHeartbeat"))

    def poll(self) -> dict:
        """One look at the PLC: the link checks and the fault handshake; returns the watched values."""
        if self._beat_error is not None:
            raise LinkLost(f"host heartbeat could not be written: {self._beat_error}")
        try:
            s = self.tags.read(*self.watch)
        except LinkError as exc:
            raise LinkLost(str(exc)) from None
        now = time.monotonic()
        key = self._alive_key(s)
        if key != self._alive:
            self._alive, self._alive_at = key, now
        elif now - self._alive_at > self.rmap.link.plc_timeout_ms / 1000.0:
            raise LinkLost(f"the PLC stopped: PlcAlive and PlcHeartbeat unchanged for more than "
                           f"{self.rmap.link.plc_timeout_ms} ms (program stopped or faulted?)")
        self._fault_step(s)
        if self.mailbox is not None:
            self.mailbox.step(s)
        return s

    def _fault_step(self, s: dict) -> None:
        if s["ToolchangerFault"] and not self._fault_acked:
            reason = int(s["ToolchangerReason"])
            self.faulted, self.fault_reason, self._new_fault = True, reason, reason
            self.tags.write(ToolchangerFaulted=True)
            self.tags.write(ToolchangerFaultAck=True)
            self._fault_acked = True
            self._tell_fault(reason)
        elif not s["ToolchangerFault"] and self._fault_acked:
            self.tags.write(ToolchangerFaultAck=False)
            self._fault_acked = False

    def take_fault(self) -> int | None:
        """The reason of a fault reported since the last call, or None."""
        reason, self._new_fault = self._new_fault, None
        return reason

    def interrupted(self, s: dict, holding: str) -> bool:
        """The command this host holds (the request coil `holding`) has ended without its ack: the PLC latched a
        fault (even if another host acknowledged its fault line before we saw it), or another host raised
        emc-abort or dropped our request."""
        if self._new_fault is not None or s.get("FaultReason", 0) != 0:
            return True
        if s.get("EmcAbort") and not self.tags.meant("EmcAbort"):
            return True
        return holding in s and self.tags.meant(holding) is True and not s[holding]

    def wait(self, cond: Callable[[dict], bool], timeout: float, what: str,
             stop_on_fault: bool = False, holding: str = "") -> dict:
        """Poll until cond(values) holds; HostError on timeout; with stop_on_fault, return at once when the
        command ends otherwise (a fault, another host's abort: see interrupted; a new fault is seen with
        take_fault)."""
        deadline = time.monotonic() + timeout
        while True:
            s = self.poll()
            if cond(s):
                return s
            if stop_on_fault and self.interrupted(s, holding):
                return s
            if time.monotonic() > deadline:
                raise HostError(f"timeout: waited {timeout:g} s for {what} ({self.describe(s)})")
            time.sleep(self.poll_interval)

    # -------------------------------------------------------------------- texts --
    def reason_text(self, code: int) -> str:
        for r in self.rmap.reasons:
            if r.code == code:
                return r.text
        return "unknown reason"

    @staticmethod
    def severity(code: int) -> str:
        return "hard: the program aborts" if code < 0 else "soft: the program continues without the change" \
            if code > 0 else "reason 0: the program aborts"

    def describe(self, s: dict) -> str:
        keys = [k for k in ("IovState", "ChangerState", "ChangerBusy", "FaultReason", "PlcReady", "HostLinkOk")
                if k in s]
        return ", ".join(f"{k} {int(s[k]) if not isinstance(s[k], bool) else s[k]}" for k in keys)

    # ----------------------------------------------------------------- commands --
    def prepare(self, tool: int, pocket: int) -> Outcome:
        """T word: tool-prep-number/pocket, then tool-prepare until tool-prepared (faults do not end it)."""
        t0 = time.monotonic()
        self.wait(lambda s: not s["ToolPrepared"], self.timeouts.ack_drop, "tool-prepared of the last prepare to drop")
        self.tags.write(ToolPrepNumber=tool, ToolPrepPocket=pocket)
        self.tags.write(ToolPrepare=True)
        try:
            s = self.wait(lambda s: s["ToolPrepared"], self.timeouts.request, f"tool-prepared for T{tool}")
        except HostError:
            self.tags.write(ToolPrepare=False)
            raise
        self.tags.write(ToolPrepare=False)
        self.wait(lambda s: not s["ToolPrepared"], self.timeouts.ack_drop, "tool-prepared to drop")
        self.prepared = (tool, pocket)
        took = f"in {time.monotonic() - t0:.2f} s"
        # iov2 answers every prepare, a faulted changer's too: say "prepared" only for what the PLC saw done
        reason = self._new_fault if self._new_fault is not None else int(s.get("FaultReason", 0))
        if reason:
            return Outcome(True, f"T{tool}: prepare answered {took} without pre-positioning the carousel: "
                           f"toolchanger fault {reason}: {self.reason_text(reason)}", reason)
        if "CarouselHomed" in s and not s["CarouselHomed"]:
            return Outcome(True, f"T{tool}: prepare answered {took} without pre-positioning the carousel: it is not "
                           f"homed (the change homes it or is refused until it is)")
        return Outcome(True, f"T{tool}: prepared (pocket {pocket}) {took}")

    def change(self) -> Outcome:
        """M6: start-change, then tool-change until tool-changed; a fault aborts it the way LinuxCNC does."""
        t0 = time.monotonic()
        if self.prepared is None or self.prepared[0] == self.tool_number:
            return Outcome(True, f"M6: nothing to change, tool {self.tool_number} stays in the spindle")
        tool, _pocket = self.prepared
        self.take_fault()
        if self.faulted:
            return self._fault_ends_change(self.fault_reason, refused=True)
        if self.start_change and self.tags.has("StartChange"):
            self.wait(lambda s: not s["StartChangeAck"], self.timeouts.ack_drop, "start-change-ack to drop")
            self.tags.write(StartChange=True)
            s = self.wait(lambda s: s["StartChangeAck"], self.timeouts.request, "start-change-ack",
                          stop_on_fault=True, holding="StartChange")
            reason = self.fault_of(s)
            if reason is None and not s["StartChangeAck"]:
                return self._ended_by_another_host("StartChange")
            if reason is not None and reason <= 0 and not s["StartChangeAck"]:
                return self._abort_for_fault(reason, REASON_MOTION_OR_IO_ERROR)
            self.tags.write(StartChange=False)
            self.wait(lambda s: not s["StartChangeAck"], self.timeouts.ack_drop, "start-change-ack to drop")
            if reason is not None:
                return self._fault_ends_change(reason, refused=False)
        self.wait(lambda s: not s["ToolChanged"], self.timeouts.ack_drop, "tool-changed of the last change to drop")
        if self.tags.has("SpindleOn") and self.tags.get("SpindleOn"):
            self.tags.write(SpindleOn=False)          # M6 stops the spindle (LinuxCNC's M6 does)
        self.tags.write(ToolNumber=self.tool_number)
        self.tags.write(ToolChange=True)
        try:
            s = self.wait(lambda s: s["ToolChanged"], self.timeouts.request, f"tool-changed for tool {tool}",
                          stop_on_fault=True, holding="ToolChange")
        except HostError as exc:
            self._abort(REASON_TASK_ABORT)
            raise HostError(f"{exc}; the change was aborted (emc-abort {REASON_TASK_ABORT})") from None
        reason = self.fault_of(s)
        if not s["ToolChanged"] and reason is not None:
            return self._fault_ends_change(reason, refused=False)
        if not s["ToolChanged"]:
            return self._ended_by_another_host("ToolChange")
        self.tags.write(ToolChange=False)
        self.wait(lambda s: not s["ToolChanged"], self.timeouts.ack_drop, "tool-changed to drop")
        took = time.monotonic() - t0
        asked = tool
        if self.tags.has("PreparedTool"):
            # the PLC's tool table took a sister of a worn tool (docs/tools.md): the CNC now holds that one, as
            # LinuxCNC's remap says with M61 Q<PreparedTool>, and uses its offsets
            tool = int(self.tags.get("PreparedTool")) or tool
        self.tool_number, self.prepared = tool, None
        self.tags.write(ToolNumber=tool)
        plc_tool = int(self.tags.get("ToolInSpindle"))
        text = f"M6: tool {tool} in spindle after {took:.2f} s"
        if tool != asked:
            text = f"M6: T{asked} is worn out: its sister T{tool} in spindle after {took:.2f} s (the PLC's tool table)"
        if plc_tool != tool:
            return Outcome(False, text + f", but the PLC reports tool {plc_tool}", changed=True)
        return Outcome(True, text, changed=True)

    def fault_of(self, s: dict) -> int | None:
        """The fault that ended a wait: the one this host answered, or the PLC's latched reason when another
        host answered the fault line before this one saw it (the host latch is set as iov2 would)."""
        reason = self.take_fault()
        if reason is None and int(s.get("FaultReason", 0)) != 0:
            reason = int(s["FaultReason"])
            self.faulted, self.fault_reason = True, reason
            self.tags.write(ToolchangerFaulted=True)
            self._tell_fault(reason)
        return reason

    def _tell_fault(self, reason: int) -> None:
        """The fault line, as iov2's operator error; said once: the command it ends refers to it."""
        self._told = reason
        self.say(f"toolchanger fault {reason}: {self.reason_text(reason)} ({self.severity(reason)})")

    def _ended_by_another_host(self, holding: str) -> Outcome:
        """Another host aborted (or dropped our request): drop ours and report; nothing is left to acknowledge."""
        self.tags.write(**{holding: False})
        self.prepared = None
        return Outcome(False, f"M6 aborted by another host (emc-abort or {holding} dropped by another client)")

    def _fault_ends_change(self, reason: int, refused: bool) -> Outcome:
        """LinuxCNC: an M6 meeting a fault is aborted with reason 101; then the reason decides for the program."""
        self._abort(REASON_ABORT_BY_TOOLCHANGER_FAULT)
        what = "refused: the toolchanger is faulted" if refused else "aborted by a toolchanger fault"
        if reason > 0:
            return Outcome(True, f"M6 {what} ({reason}: {self.reason_text(reason)}); soft fault: the change is "
                           f"skipped, the program continues (#5600 = 1, #5601 = {reason})", reason)
        if reason == 0:
            self._abort(REASON_MOTION_OR_IO_ERROR)
            return Outcome(False, f"M6 {what} with reason 0: the program aborts", reason)
        self._abort(REASON_MOTION_OR_IO_ERROR)
        text = f"M6 {what}: toolchanger error {reason}"
        if reason != self._told:                    # not on the fault line just above
            text += f": {self.reason_text(reason)}"
        s = self.poll()
        if int(s.get("Recovery", 0)) or reason == REASON_CHANGE_INTERRUPTED:
            text += "; " + self.recovery_advice(s)
        return Outcome(False, text, reason)

    def _abort_for_fault(self, reason: int, emc_reason: int) -> Outcome:
        self._abort(emc_reason)
        return Outcome(False, f"M6 aborted at start-change: toolchanger error {reason}: {self.reason_text(reason)}",
                       reason)

    def _abort(self, emc_reason: int) -> bool:
        """emc-abort: reason first, then emc-abort, then the requests drop; held until emc-abort-ack. The coil is
        shared: another host ending its own abort drops ours too. Then its abort (which the PLC acknowledged) has
        stopped the changer and ours is not repeated, unless the changer still runs (then it is raised once
        more). False when the abort that ended it was another host's."""
        for _attempt in range(2):
            self.wait(lambda s: not s["EmcAbortAck"], self.timeouts.ack_drop,
                      "emc-abort-ack of the last abort to drop")
            self.tags.write(EmcReason=emc_reason)
            self.tags.write(EmcAbort=True)
            drop = {n: False for n in ("ToolPrepare", "ToolChange", "StartChange") if self.tags.has(n)}
            self.tags.write(**drop)
            try:
                s = self.wait(lambda s: s["EmcAbortAck"] or not s["EmcAbort"], self.timeouts.abort,
                              f"emc-abort-ack (reason {emc_reason})")
            finally:
                self.tags.write(EmcAbort=False)
            if s["EmcAbortAck"]:
                self.wait(lambda s: not s["EmcAbortAck"], self.timeouts.ack_drop, "emc-abort-ack to drop")
                self.prepared = None
                return True
            if not s["ChangerBusy"]:
                break                  # dropped by another host's abort, which stopped everything already
        self.prepared = None
        return False

    def abort(self, emc_reason: int = REASON_TASK_ABORT) -> Outcome:
        if not self._abort(emc_reason):
            return Outcome(True, f"abort (emc-reason {emc_reason}): another host's abort, acknowledged by the PLC, "
                           "stopped the changer first")
        return Outcome(True, f"abort (emc-reason {emc_reason}) acknowledged by the PLC")

    def spindle(self, on: bool) -> Outcome:
        """M3/M4 (on) and M5 (off): the CNC's spindle-on line (SpindleOn), which the PLC's tool life counts; M3 is
        refused while the PLC inhibits the spindle (SpindleInhibit: the probe tool is in it), as LinuxCNC's
        spindle.0.inhibit keeps the spindle still."""
        if not self.tags.has("SpindleOn"):
            return Outcome(False, "this PLC's register map has no SpindleOn: no spindle line to the PLC")
        if on and self.tags.has("SpindleInhibit") and self.tags.get("SpindleInhibit"):
            return Outcome(False, f"M3: the spindle stays off: the PLC inhibits it (SpindleInhibit: the probe tool "
                                  f"T{int(self.tags.get('ToolInSpindle'))} is in the spindle)")
        self.tags.write(SpindleOn=on)
        return Outcome(True, "spindle on" if on else "spindle off")

    def clear(self) -> Outcome:
        """Operator clear: the host's latch drops and ClearFault pulses (the PLC clears on its rising edge)."""
        # The PLC's latch first: a host latch dropping while the PLC is still faulted makes it report again.
        self.tags.write(ClearFault=False)
        self.tags.write(ClearFault=True)
        try:
            s = self.wait(lambda s: s["FaultReason"] == 0 and not s["ToolchangerFault"], 1.0,
                          "the PLC to clear its fault")
        except HostError:
            s = self.poll()
        finally:
            self.tags.write(ClearFault=False)
        if s["FaultReason"] == 0:
            self.faulted, self.fault_reason = False, 0
            self.tags.write(ToolchangerFaulted=False)
        if s["FaultReason"] != 0:
            reason = int(s["FaultReason"])
            return Outcome(False, f"clear: the PLC keeps fault {reason}: {self.reason_text(reason)} "
                           "(is its cause still there?)", reason)
        return Outcome(True, "clear: no fault")

    def home(self) -> Outcome:
        t0 = time.monotonic()
        self.tags.write(HomeRequest=False)
        self.tags.write(HomeRequest=True)
        try:
            # the PLC takes the request on a later scan: an idle changer is no homing done, even when not homed
            s = self.wait(lambda s: s["ChangerBusy"] or s.get("FaultReason", 0) != 0, self.timeouts.ack_drop,
                          "homing to start")
            if s["ChangerBusy"]:
                s = self.wait(lambda s: not s["ChangerBusy"], self.timeouts.request, "homing to end")
        finally:
            self.tags.write(HomeRequest=False)
        if not s["CarouselHomed"]:
            return Outcome(False, f"home: the carousel is not homed ({self.describe(s)})")
        text = f"home: carousel homed in {time.monotonic() - t0:.2f} s"
        recovery = int(s.get("Recovery", 0))
        if recovery & RECOVERY_HOME:
            return Outcome(False, text + ", but the PLC still asks to home the changer (is it faulted? clear first)")
        if recovery & RECOVERY_CONFIRM:
            text += "; " + self.confirm_advice(s)
        return Outcome(True, text)

    def pocketless(self, s: dict) -> bool:
        """The uncertain tool has no pocket on this machine (retained data saved on one with more pockets:
        README, "Retained data on another machine"): only an empty spindle can be confirmed."""
        count = int(self.tags.get("PocketCount")) if self.tags.has("PocketCount") else 0
        return 0 < count < int(s.get("UncertainTool", 0))

    def recovery_advice(self, s: dict) -> str:
        """The recovery the PLC asks for before the next change (FaultReason, Recovery, UncertainTool), in this
        host's commands: only the steps it asks."""
        recovery = int(s.get("Recovery", 0))
        steps = ["`plc host clear`"] if int(s.get("FaultReason", 0)) else []
        if recovery & RECOVERY_HOME:
            steps.append("`plc host home` (home the changer)")
        if recovery & RECOVERY_CONFIRM:
            steps.append("confirm the tool: " + self.confirm_advice(s))
        if not recovery & (RECOVERY_HOME | RECOVERY_CONFIRM):
            return "the PLC asks no recovery (nothing uncertain)" + (f": {steps[0]}" if steps else "")
        return "recovery the PLC asks: " + ", then ".join(steps)

    def confirm_advice(self, s: dict) -> str:
        """What the operator does to confirm the tool in the spindle (Recovery asks to confirm)."""
        tool = int(s.get("UncertainTool", 0))
        if self.pocketless(s):
            return (f"tool {tool} has no pocket on this machine: take it out of the spindle by hand, then "
                    "`plc host confirm 0` (empty spindle)")
        return (f"tool {tool} is in the spindle or in its pocket: look, then `plc host confirm {tool}` or "
                "`plc host confirm 0` (empty spindle)")

    def confirm(self, tool: int) -> Outcome:
        """The operator says which tool is in the spindle after an interrupted change (ConfirmTool)."""
        s = self.poll()
        recovery = int(s.get("Recovery", 0))
        uncertain = int(s.get("UncertainTool", 0))
        if recovery & RECOVERY_HOME:
            return Outcome(False, "confirm: home the changer first (`plc host home`): homing may still move the tool")
        if not recovery & RECOVERY_CONFIRM:
            return Outcome(False, f"confirm: nothing to confirm, the PLC knows tool {int(s['ToolInSpindle'])} is in "
                           "the spindle")
        if tool not in (0, uncertain) or (tool and self.pocketless(s)):
            return Outcome(False, "confirm: " + self.confirm_advice(s))
        where = "taken out (no pocket here)" if self.pocketless(s) else "in its pocket"
        self.tags.write(ConfirmToolNumber=tool)
        self.tags.write(ConfirmTool=False)
        self.tags.write(ConfirmTool=True)
        try:
            s = self.wait(lambda s: not int(s["Recovery"]) & RECOVERY_CONFIRM, 2.0, "the PLC to take the tool")
        finally:
            self.tags.write(ConfirmTool=False)
        self.tool_number = int(s["ToolInSpindle"])
        self.tags.write(ToolNumber=self.tool_number)
        return Outcome(True, f"confirm: tool {self.tool_number} in the spindle"
                       + ("" if tool else f", tool {uncertain} {where}"))

    def _named(self, signal: str, s: dict) -> str:
        """A coded signal's value with its name from the map ("4 AtcPutting")."""
        if signal not in s:
            return "-"
        if self._names is None:
            try:
                self._names = load_names(self.rmap.path).states
            except Exception:          # names are a comfort: a map that loads here always has them
                self._names = {}
        value = s[signal]
        name = self._names.get(signal, {}).get(int(value))
        return f"{value} {name}" if name else f"{value}"

    def procedure_lines(self, reasons: dict[int, str], fault: int) -> list[str]:
        """The user procedures (docs/procedures.md): the running one with its step and line, the last one's result,
        time and reason, the failure count, and while the PLC's fault is PROCEDURE_FAILED (-150) the ErrMsg of the
        procedure that raised it. [] when the map has no procedures."""
        if not all(self.tags.has(n) for n in PROCEDURE_STATUS):
            return []
        p = self.tags.read(*PROCEDURE_STATUS)
        texts = getattr(self.mailbox, "texts", {})
        running = (f"procedure {p['ProcId']} running, step {p['ProcStep']}, source line {p['ProcLine']}"
                   if p["ProcBusy"] else "procedure: none running")
        lines = [f"{running}   failures since start {p['ProcFailCount']}"]
        last = int(p["ProcLastId"])
        if last >= 0 and int(p["ProcLastResult"]):
            reason = int(p["ProcLastReason"])
            why = f" ({reason} {reasons.get(reason, '?')})" if reason else ""
            lines.append(f"last procedure {last}: {self._named('ProcLastResult', p)}{why}, ran "
                         f"{int(p['ProcLastDuration']) / 10:.1f} s, ended {p['ProcLastAgo']} s ago")
        fault_id = int(p["ProcFaultId"])
        if fault == PROCEDURE_FAILED and fault_id >= 0:
            text = texts.get(int(p["ProcFaultText"]), f"(message {p['ProcFaultText']})")
            lines.append(f"procedure {fault_id} stopped the program: {text}")
        return lines

    def status(self) -> list[str]:
        s = self.poll()
        names = {r.code: r.name for r in self.rmap.reasons}
        lines = [
            f"tool in spindle {s.get('ToolInSpindle')}  (host: {self.tool_number})   pocket at the change position "
            f"{s.get('CurrentPocket')}",
            f"PlcReady {s.get('PlcReady')}  HostLinkOk {s.get('HostLinkOk')}  CarouselHomed {s.get('CarouselHomed')}  "
            f"ChangerBusy {s.get('ChangerBusy')}",
            f"IovState {self._named('IovState', s)}  ChangerState {self._named('ChangerState', s)}",
        ]
        seq = {n: v for n, v in self.tags.read(*[n for n in ("SeqKind", "SeqStep", "SeqLine")
                                                  if self.tags.has(n)]).items()}
        if seq:
            kind = int(seq.get("SeqKind", 0))
            lines.append(f"sequence {self._named('SeqKind', seq)}" + (
                f", step {seq.get('SeqStep')}, source line {seq.get('SeqLine')}" if kind else " (none running)"))
        lines += self.procedure_lines(names, int(s.get("FaultReason", 0)))
        recovery = int(s.get("Recovery", 0))
        if recovery:
            todo = [t for bit, t in ((RECOVERY_HOME, "home the changer"),
                                     (RECOVERY_CONFIRM, f"confirm the tool ({self.confirm_advice(s)})"))
                    if recovery & bit]
            lines.append("recovery before the next change: " + ", then ".join(todo))
        if s.get("SimSpindleTool"):
            lines.append(f"simulated plant: the spindle holds tool {s['SimSpindleTool']}")
        reason = int(s.get("FaultReason", 0))
        fault = f"{reason} {names.get(reason, '?')}: {self.reason_text(reason)}" if reason else "none"
        lines.append(f"PLC fault: {fault}   host fault latch: "
                     f"{f'set ({self.fault_reason})' if self.faulted else 'clear'}")
        if self.prepared:
            lines.append(f"prepared: tool {self.prepared[0]} pocket {self.prepared[1]}")
        return lines
