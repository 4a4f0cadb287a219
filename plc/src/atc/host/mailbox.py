"""The host end of the PLC's sequence mailbox (docs/sequences.md "Host mailbox", F_SeqHostCommand), for `plc host`.

A sequence step that only the CNC can do (MOVEABS, MOVETOEDGE, FEEDRATE, SPINDLE, MESSAGE, DIALOG) is published by
the PLC as a request: MbxRequestId (new for every request), MbxOpcode and the arguments (MbxAxisMask, MbxX..MbxC and
MbxValue in thousandths, MbxText).  What a host executes comes from one read of the mailbox record (holding
2048..2069: the arguments, MbxArgsOpcode/Text/Mask and last MbxArgsId, the request id): the runtime answers a
read between two scans, so one read shows one request, whatever another read (block 0..13) shows meanwhile.
The PLC waits for these requests to be answered only while the host holds the
coil MbxHostActive TRUE; else it acknowledges them itself.  The host answers with MbxAnswerResult, then (in a
later write) MbxAnswerId = the request's id, so the PLC never takes an id with the previous result.

`plc host` has no axes: it prints each request as a CNC would execute it (tracking the position and feed the
requests set), answers moves and spindle commands at once, asks the operator for DIALOG and MESSAGE (the PLC skips
MESSAGE itself when the sequence runs from an M6) or answers them by the configured choice.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ..seq.assemble import check_set
from ..seq.diagnostics import Diagnostics
from ..seq.stgen import _message_numbers
from .tags import Tags

MOVEABS, MOVETOEDGE, FEEDRATE, SPINDLE_CW, SPINDLE_CCW, SPINDLE_STOP, MESSAGE, DIALOG = range(1, 9)
OPCODE_NAMES = {MOVEABS: "MOVEABS", MOVETOEDGE: "MOVETOEDGE", FEEDRATE: "FEEDRATE", SPINDLE_CW: "SPINDLE CW",
                SPINDLE_CCW: "SPINDLE CCW", SPINDLE_STOP: "SPINDLE STOP", MESSAGE: "MESSAGE", DIALOG: "DIALOG"}
RESULT_OK, RESULT_EDGE, RESULT_NO_EDGE, RESULT_CANCEL, RESULT_FAILED = 1, 2, 3, -1, -2
AXES = ("X", "Y", "Z", "A", "B", "C")            # bit i of MbxAxisMask = AXES[i], argument register Mbx<axis>
# the mailbox record: one contiguous block of holding registers, read in one transaction (Tags.read); the request
# the host executes is made of these fields only
RECORD = tuple(f"Mbx{a}" for a in AXES) + ("MbxValue", "MbxArgsOpcode", "MbxArgsText", "MbxArgsMask", "MbxArgsId")
REQUEST = ("MbxRequestId", "MbxOpcode", "MbxText", "MbxAxisMask") + RECORD
MAILBOX = ("MbxHostActive", "MbxAnswerId", "MbxAnswerResult") + REQUEST
# where the host's spindle is, in 1/10 unit: the PLC sends the carousel forward only when it matches the targets of
# the sequence's moves (FB_SequenceRunner, -214)
POSITION = ("HostPosX", "HostPosY", "HostPosZ")


def mailbox_in_map(tags: Tags) -> bool:
    return all(tags.has(n) for n in MAILBOX)


def message_texts(index: Path) -> dict[int, str]:
    """Message number -> text of the MESSAGE/DIALOG steps of a sequence set (sequences.toml), numbered as
    `plc seq compile` numbers them for F_SequenceMessage.  ValueError with the checker's findings if it has errors."""

    diags = Diagnostics()
    assembly = check_set(index, diags)
    if assembly is None or diags.has_errors():
        raise ValueError("\n".join(d.render() for d in diags.errors) or f"cannot read {index}")
    return {number: text for text, number in _message_numbers(assembly).items()}


@dataclass
class Request:
    id: int
    opcode: int
    text: int
    axes: dict[str, float]       # axis -> target (MOVEABS) or distance (MOVETOEDGE), units
    value: float                 # feed (units/s) or spindle speed (rpm)

    @staticmethod
    def from_record(s: dict) -> "Request":
        """The request one read of the mailbox record shows (RECORD; no field of another read)."""
        mask = int(s["MbxArgsMask"])
        axes = {a: int(s[f"Mbx{a}"]) / 1000.0 for i, a in enumerate(AXES) if mask & (1 << i)}
        return Request(int(s["MbxArgsId"]), int(s["MbxArgsOpcode"]), int(s["MbxArgsText"]), axes,
                       int(s["MbxValue"]) / 1000.0)


def _num(v: float) -> str:
    return f"{v:.3f}".rstrip("0").rstrip(".") if v != int(v) else f"{int(v)}"


@dataclass
class Mailbox:
    """Serves the mailbox on the session's connection: call announce() once, step() on every poll, retire() at
    the end.  `ask(prompt) -> str` reads the operator's answer (OK/Cancel); `answer` is "ask" (the operator is
    asked), "ok" or "cancel" (scripted use); `edge` the result a MOVETOEDGE gets (True: edge reached)."""
    tags: Tags
    say: Callable[[str], None]
    ask: Callable[[str], str] = input
    answer: str = "ask"
    edge: bool = True
    texts: dict[int, str] = field(default_factory=dict)
    position: dict[str, float] = field(default_factory=dict)
    feed: float = 0.0
    spindle: str = "stopped"
    served: int = 0
    _last_id: int = -1

    def report_position(self) -> dict[str, int]:
        """HostPosX/Y/Z of the position the requests set (in the same write as what follows it)."""
        if not all(self.tags.has(n) for n in POSITION):
            return {}
        return {f"HostPos{a}": max(-32768, min(32767, round(self.position.get(a, 0.0) * 10))) for a in "XYZ"}

    def announce(self) -> None:
        """MbxHostActive TRUE; a request already pending (the PLC answered nothing yet) is served by step(). A host
        that starts knows no position of its own: it starts where the last host reported the machine (HostPosX/Y/Z),
        since nothing moved the machine in between (a recovery after an interrupted change starts there)."""
        if not self.position and all(self.tags.has(n) for n in POSITION):
            last = self.tags.read(*POSITION)
            self.position = {n[-1]: int(last[n]) / 10 for n in POSITION}
        self.tags.write(**self.report_position())
        self.tags.write(MbxHostActive=True)
        self.say("mailbox: this host executes the sequences' requests (MbxHostActive)")

    def retire(self) -> None:
        """MbxHostActive FALSE: the PLC acknowledges its requests itself again."""
        self.tags.write(MbxHostActive=False)

    def step(self, s: dict) -> Request | None:
        """Serve the request the mailbox record in s shows (s must hold one read of RECORD), once per id; returns
        the request served, else None."""
        rid, opcode = int(s.get("MbxArgsId", 0)), int(s.get("MbxArgsOpcode", 0))
        if opcode == 0 or rid == 0 or rid == self._last_id:
            return None
        req = Request.from_record(s)
        self._last_id = rid
        result = self.execute(req)
        now = self.tags.read("MbxArgsId", "MbxArgsOpcode")
        if int(now["MbxArgsId"]) != rid or int(now["MbxArgsOpcode"]) == 0:
            self.say(f"mailbox #{rid}: withdrawn by the PLC before the answer (abort or timeout); not answered")
            return req
        self.tags.write(**self.report_position(), MbxAnswerResult=result)
        self.tags.write(MbxAnswerId=rid)
        self.served += 1
        return req

    def describe(self, req: Request) -> str:
        axes = " ".join(f"{a}{_num(v)}" for a, v in req.axes.items())
        if req.opcode == MOVEABS:
            return f"MOVEABS {axes} (G53 G1, F {_num(self.feed)} units/s)"
        if req.opcode == MOVETOEDGE:
            return f"MOVETOEDGE {axes} (relative probing move until the edge input switches, F {_num(self.feed)})"
        if req.opcode == FEEDRATE:
            return f"FEEDRATE {_num(req.value)} units/s"
        if req.opcode in (SPINDLE_CW, SPINDLE_CCW):
            return f"{OPCODE_NAMES[req.opcode]} {_num(req.value)} rpm ({'M3' if req.opcode == SPINDLE_CW else 'M4'})"
        if req.opcode == SPINDLE_STOP:
            return "SPINDLE STOP (M5)"
        if req.opcode in (MESSAGE, DIALOG):
            return f"{OPCODE_NAMES[req.opcode]} {req.text}: {self.texts.get(req.text, f'(message {req.text})')}"
        return f"unknown request code {req.opcode}"

    def execute(self, req: Request) -> int:
        """What a CNC would do, shown; the result code for the answer."""
        text = f"mailbox #{req.id}: {self.describe(req)}"
        if req.opcode == MOVEABS:
            self.position.update(req.axes)
            self.say(text + ": done")
            return RESULT_OK
        if req.opcode == MOVETOEDGE:
            if self.edge:
                for a, d in req.axes.items():
                    self.position[a] = self.position.get(a, 0.0) + d / 2
                self.say(text + ": edge reached")
                return RESULT_EDGE
            for a, d in req.axes.items():
                self.position[a] = self.position.get(a, 0.0) + d
            self.say(text + ": whole distance, no edge")
            return RESULT_NO_EDGE
        if req.opcode == FEEDRATE:
            self.feed = req.value
            self.say(text + ": set")
            return RESULT_OK
        if req.opcode in (SPINDLE_CW, SPINDLE_CCW, SPINDLE_STOP):
            self.spindle = "stopped" if req.opcode == SPINDLE_STOP else self.describe(req).split(" (")[0]
            self.say(text + ": done")
            return RESULT_OK
        if req.opcode in (MESSAGE, DIALOG):
            return self._operator(req, text)
        self.say(text + ": refused")
        return RESULT_FAILED

    def _operator(self, req: Request, text: str) -> int:
        if self.answer in ("ok", "cancel"):
            self.say(text + f": answered {self.answer.upper()} (--answer {self.answer})")
            return RESULT_OK if self.answer == "ok" else RESULT_CANCEL
        while True:
            try:
                reply = self.ask(f"{text}  [OK/cancel] ").strip().lower()
            except EOFError:
                self.say("mailbox: no operator input (end of input): answered CANCEL")
                return RESULT_CANCEL
            if reply in ("", "ok", "o", "y", "yes"):
                return RESULT_OK
            if reply in ("cancel", "c", "n", "no"):
                return RESULT_CANCEL
            self.say("answer OK (Enter) or cancel")
