"""A fake PLC for the `plc host` tests: a Modbus/TCP server on loopback with an OpenPLC-shaped image and a
scripted toolchanger end of iov2 behind it, so tests can make the PLC do what the real program rarely does
(hold a stale ack, fault with a given reason in a given phase, never answer, stop its heartbeat).

Every write request and every step of the fake's own logic goes into one log, in order: ("write", function,
address, values), then ("set", coil, value) for each coil the write changed, or ("event", text), so a test can
check the order of what the host did against what the PLC showed.  With whole_bytes=True, FC15 is applied the
way OpenPLC v3 applies it: 8 coils per data byte from the start address, the padding bits of the last byte
included (writing 2 coils at 406 also writes 408..413).  The toolchanger logic runs in its own thread every
`scan` seconds, like a scan.
"""
from __future__ import annotations

import socket
import struct
import threading
import time
from dataclasses import dataclass


@dataclass
class Behaviour:
    ack_prepare: bool = True          # answer tool-prepare
    ack_change: bool = True           # answer tool-change
    ack_abort: bool = True            # answer emc-abort
    change_scans: int = 5             # scans between tool-change and tool-changed
    fault_on_change: int | None = None  # raise toolchanger-fault with this reason instead of tool-changed
    fault_on_prepare: int | None = None  # raise a fault with this reason during the prepare (still answered)
    homed: bool = True                # CarouselHomed: the carousel's position is known
    stale_prepared: bool = False      # start with tool-prepared stuck high for `stale_scans`
    stale_scans: int = 20
    heartbeat: bool = True            # PlcAlive and PlcHeartbeat move
    fault_on_abort: int | None = None  # an abort during a change latches this fault (the real PLC: -103)
    recovery: int = 0                 # Recovery (+1 home, +2 confirm) and UncertainTool set with a fault
    uncertain_tool: int = 0
    left_beat: int | None = None      # a host that just left wrote this last: HostLinkOk TRUE at the start


@dataclass
class Addr:
    """Addresses of the signals the fake uses (from the register map)."""
    coil: dict[str, int]
    reg: dict[str, int]


class FakePlc:
    def __init__(self, addr: Addr, behaviour: Behaviour | None = None, scan: float = 0.004,
                 whole_bytes: bool = False):
        self.addr = addr
        self.whole_bytes = whole_bytes
        self.b = behaviour or Behaviour()
        self.scan = scan
        self.coils = [False] * 800
        self.regs = [0] * 8192
        self.log: list[tuple] = []
        self.lock = threading.Lock()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(4)
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.stop_event = threading.Event()
        self.threads = [threading.Thread(target=self._serve, daemon=True),
                        threading.Thread(target=self._plc, daemon=True)]
        self._state: dict[str, object] = {"stale": self.b.stale_scans if self.b.stale_prepared else 0}
        if self.b.stale_prepared:
            self.coils[addr.coil["ToolPrepared"]] = True
        if "CarouselHomed" in addr.coil:
            self.coils[addr.coil["CarouselHomed"]] = self.b.homed

    # ----------------------------------------------------------------- helpers --
    def c(self, name: str) -> bool:
        return self.coils[self.addr.coil[name]]

    def set_c(self, name: str, value: bool) -> None:
        self.coils[self.addr.coil[name]] = value

    def r(self, name: str) -> int:
        v = self.regs[self.addr.reg[name]]
        return v - 0x10000 if v & 0x8000 else v

    def set_r(self, name: str, value: int) -> None:
        self.regs[self.addr.reg[name]] = value & 0xFFFF

    def event(self, text: str) -> None:
        self.log.append(("event", text))

    @property
    def events(self) -> list[str]:
        return [e[1] for e in self.log if e[0] == "event"]

    def index(self, entry) -> int:
        """Position of the first log entry equal to `entry` (a tuple) or, for a str, the first event with it."""
        for i, e in enumerate(self.log):
            if (isinstance(entry, str) and e[0] == "event" and entry in e[1]) or e == entry:
                return i
        raise AssertionError(f"{entry!r} not in the fake PLC's log")

    def __enter__(self) -> "FakePlc":
        for t in self.threads:
            t.start()
        return self

    def __exit__(self, *_exc) -> None:
        self.stop_event.set()
        for t in self.threads:
            t.join(timeout=2)
        self.sock.close()

    # ------------------------------------------------------------------ server --
    def _serve(self) -> None:
        conns: list[socket.socket] = []
        while not self.stop_event.is_set():
            try:
                conn, _ = self.sock.accept()
                conn.settimeout(0.2)
                conns.append(conn)
                threading.Thread(target=self._client, args=(conn,), daemon=True).start()
            except socket.timeout:
                continue
            except OSError:
                break
        for conn in conns:
            conn.close()

    def _recv(self, conn: socket.socket, n: int) -> bytes | None:
        data = b""
        while len(data) < n:
            if self.stop_event.is_set():
                return None
            try:
                chunk = conn.recv(n - len(data))
            except socket.timeout:
                continue
            except OSError:
                return None
            if not chunk:
                return None
            data += chunk
        return data

    def _client(self, conn: socket.socket) -> None:
        while True:
            head = self._recv(conn, 7)
            if head is None:
                return
            tid, _proto, length, unit = struct.unpack(">HHHB", head)
            pdu = self._recv(conn, length - 1)
            if pdu is None:
                return
            with self.lock:
                answer = self._answer(pdu)
            try:
                conn.sendall(struct.pack(">HHHB", tid, 0, len(answer) + 1, unit) + answer)
            except OSError:
                return

    def _answer(self, pdu: bytes) -> bytes:
        fc = pdu[0]
        if fc in (1, 3):
            address, count = struct.unpack(">HH", pdu[1:5])
            if fc == 1:
                bits = self.coils[address:address + count]
                data = bytearray((count + 7) // 8)
                for i, b in enumerate(bits):
                    if b:
                        data[i // 8] |= 1 << (i % 8)
                return bytes([fc, len(data)]) + bytes(data)
            regs = self.regs[address:address + count]
            return bytes([fc, 2 * count]) + b"".join(struct.pack(">H", v) for v in regs)
        if fc == 5:
            address, value = struct.unpack(">HH", pdu[1:5])
            self.log.append(("write", 5, address, [int(value == 0xFF00)]))
            self._set_coils(address, [value == 0xFF00])
            return pdu[:5]
        if fc == 6:
            address, value = struct.unpack(">HH", pdu[1:5])
            self.regs[address] = value
            self.log.append(("write", 6, address, [value]))
            return pdu[:5]
        if fc == 15:
            address, count, nbytes = struct.unpack(">HHB", pdu[1:6])
            applied = 8 * nbytes if self.whole_bytes else count
            values = [bool(pdu[6 + i // 8] >> (i % 8) & 1) for i in range(applied)]
            self.log.append(("write", 15, address, [int(v) for v in values[:count]]))
            self._set_coils(address, values[:len(self.coils) - address])
            return pdu[:5]
        if fc == 16:
            address, count, _n = struct.unpack(">HHB", pdu[1:6])
            values = list(struct.unpack(f">{count}H", pdu[6:6 + 2 * count]))
            self.regs[address:address + count] = values
            self.log.append(("write", 16, address, values))
            return pdu[:5]
        return bytes([fc | 0x80, 1])

    def _set_coils(self, address: int, values: list[bool]) -> None:
        for i, v in enumerate(values):
            if self.coils[address + i] != v:
                self.coils[address + i] = v
                self.log.append(("set", address + i, int(v)))

    # ------------------------------------------------------------ toolchanger --
    def _plc(self) -> None:
        st = self._state
        if self.b.left_beat is not None:
            self.regs[self.addr.reg["HostHeartbeat"]] = self.b.left_beat
            self.set_c("HostLinkOk", True)
        st.update(prev_prepare=False, prev_change=False, change_count=0, alive_at=time.monotonic(),
                  prep_tool=0, fault=False, beat=self.r("HostHeartbeat"), link_ok=False, beat_at=time.monotonic())
        while not self.stop_event.wait(self.scan):
            with self.lock:
                self._step(st)

    def _raise_fault(self, reason: int, phase: str) -> None:
        self.set_r("ToolchangerReason", reason)
        self.set_r("FaultReason", reason)
        self.set_c("ToolchangerFault", True)
        self.set_r("Recovery", self.b.recovery)
        self.set_r("UncertainTool", self.b.uncertain_tool)
        self.event(f"fault {reason} in {phase}")

    def _step(self, st: dict) -> None:
        b, now = self.b, time.monotonic()
        if b.heartbeat:
            self.set_r("PlcHeartbeat", (self.r("PlcHeartbeat") + 1) & 0xFFFF)
            if now - st["alive_at"] >= 0.1:
                self.set_c("PlcAlive", not self.c("PlcAlive"))
                st["alive_at"] = now
        beat = self.regs[self.addr.reg["HostHeartbeat"]]
        if beat != st["beat"]:
            st["beat"], st["beat_at"] = beat, now
        self.set_c("HostLinkOk", now - st["beat_at"] < 1.0 and st["beat"] != 0)
        # fault handshake: toolchanger-fault held until toolchanger-fault-ack
        if self.c("ToolchangerFault") and self.c("ToolchangerFaultAck"):
            self.set_c("ToolchangerFault", False)
            self.event("fault acked")
        if self.c("ClearFault"):
            self.set_r("FaultReason", 0)
        # prepare
        prepare = self.c("ToolPrepare")
        if st["stale"]:
            st["stale"] -= 1
            if st["stale"] == 0:
                self.set_c("ToolPrepared", False)
                self.event("stale tool-prepared dropped")
        elif prepare and not st["prev_prepare"]:
            st["prep_tool"] = self.r("ToolPrepNumber")
            self.event(f"prepare latched tool {st['prep_tool']} pocket {self.r('ToolPrepPocket')}")
            if b.fault_on_prepare is not None:
                self._raise_fault(b.fault_on_prepare, "prepare")
        if prepare and b.ack_prepare and not st["stale"]:
            self.set_c("ToolPrepared", True)
        elif not prepare and not st["stale"]:
            self.set_c("ToolPrepared", False)
        st["prev_prepare"] = prepare
        # start-change
        self.set_c("StartChangeAck", self.c("StartChange"))
        # change
        change = self.c("ToolChange")
        if change and not st["prev_change"]:
            st["change_count"] = 0
            self.event("change started")
        if change:
            st["change_count"] += 1
            if st["change_count"] == b.change_scans:
                if b.fault_on_change is not None:
                    self._raise_fault(b.fault_on_change, "change")
                elif b.ack_change:
                    self.set_r("ToolInSpindle", st["prep_tool"])
                    self.set_c("ToolChanged", True)
        else:
            self.set_c("ToolChanged", False)
        st["prev_change"] = change
        # abort: acked in every state
        if self.c("EmcAbort") and b.ack_abort:
            if not self.c("EmcAbortAck"):
                self.event(f"abort reason {self.r('EmcReason')}")
                if b.fault_on_abort is not None and change:
                    self._raise_fault(b.fault_on_abort, "change (aborted)")
            self.set_c("EmcAbortAck", True)
        elif not self.c("EmcAbort"):
            self.set_c("EmcAbortAck", False)
