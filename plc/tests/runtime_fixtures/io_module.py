"""A remote I/O module for hardware-in-the-loop tests, on an independent Modbus stack (pymodbus, server side).

It plays the machine behind `plc run --io modbus`: it reads the outputs the PLC writes (motor, direction, brake,
arm, collet coils) and drives the sensors (home, pocket, code, arm, collet discrete inputs) from its own small
model with its own timing -- not the ST plant models of st_src/.  The model is evaluated when a request arrives,
from the monotonic clock, so sensor edges fall where the mechanics put them whatever the poll rate.

Tools: pocket n holds tool n at the start, the spindle is empty.  A tool moves only where the mechanics put it,
with the arm forward at a pocket: the collet opening lets the spindle's tool go into the fork (Put); the collet
closing on an empty spindle clamps the fork's tool (Get), unless the spindle let that tool go during the same
stay forward.  So `spindle_tool` is the tool the machine really holds, whatever the PLC believes.

Faults to inject (`module.mode`): "normal", "silent" (requests are dropped: the module stops answering; only
those of some units with `set_mode("silent", units=...)`, one board of an RS-485 line falling silent),
"slow" (each answer waits `slow_s`), "exception" (every request answered with exception 02), "garbage" (every
answer corrupted on the wire).  `events` records what the module saw, stamped with time.monotonic() (the
runtime logs CLOCK_MONOTONIC too, so both can be compared).

Transports: TCP on loopback (port 0: a free port) or RTU on a serial device (one end of a socat pty pair); with
several `units` the same machine answers under each unit id (boards sharing one RS-485 line).
"""
from __future__ import annotations

import asyncio
import logging
import threading
import time
from dataclasses import dataclass, field

from pymodbus.datastore import ModbusServerContext
from pymodbus.datastore.context import ModbusBaseSlaveContext
from pymodbus.framer import FramerType
from pymodbus.server import ModbusSerialServer, ModbusTcpServer

# pymodbus logs every exception response it sends as an error: the fault modes send thousands on purpose
logging.getLogger("pymodbus").setLevel(logging.CRITICAL)

DI_COUNT = 32          # the module's discrete inputs 0..31
COIL_COUNT = 8         # its coils 0..7


@dataclass
class Wiring:
    """Which module input/coil carries which machine signal (module addresses)."""
    estop_ok: int = 0
    guard_closed: int = 1
    air_ok: int = 2
    spindle_stopped: int = 3
    pocket: int = 16
    home: int | None = 17                    # None: a carousel without a home input
    arm_at_forward: int = 18
    arm_at_reverse: int = 19
    collet_opened: int = 20
    codes: tuple[int, ...] = ()              # code input 1.. (weight 1, 2, 4, ...)
    motor_on: int = 0                        # coils
    brake_off: int = 1
    arm_forward: int = 2
    collet_open: int = 3
    dir_positive: int = 4
    dir_negative: int | None = None          # separate +DIR/-DIR outputs; None: enable + positive-dir wiring


@dataclass
class Mechanics:
    """The machine's own timing (deliberately not the values of machines/default/machine.toml's [simulation])."""
    pockets: int = 6
    pocket_time_s: float = 0.15              # one pitch
    window: float = 0.2                      # sensor active within +-window pitch of a pocket centre
    arm_travel_s: float = 0.4
    collet_s: float = 0.08
    brake_s: float = 0.04
    start_pocket: int = 3
    pocket_codes: tuple[int, ...] = ()       # code shown at pocket n (code carousels)


@dataclass
class Machine:
    wiring: Wiring
    mech: Mechanics
    coils: list[bool] = field(default_factory=lambda: [False] * COIL_COUNT)
    position: float = 0.0                    # in pitches, 0 = pocket 1 centre
    arm: float = 0.0                         # 0 back .. 1 forward
    collet: float = 0.0                      # 0 closed .. 1 open
    brake_free_at: float | None = None
    last: float = field(default_factory=time.monotonic)
    crashes: list[str] = field(default_factory=list)
    spindle_tool: int = 0                    # the tool clamped in the spindle, 0 = none
    pocket_tools: dict[int, int] = field(default_factory=dict)   # pocket -> tool, 0 = empty
    fork_pocket: int = 0                     # pocket at the spindle while the arm is forward, 0 = arm not forward
    released: bool = False                   # the spindle let its tool go during this stay forward (Put)

    def __post_init__(self) -> None:
        self.position = float(self.mech.start_pocket - 1)
        self.pocket_tools = {n: n for n in range(1, self.mech.pockets + 1)}

    def _move_tools(self, now: float, was_forward: bool, was_open: bool) -> None:
        forward, is_open = self.arm >= 1.0, self.collet >= 1.0
        if forward and not was_forward:
            self.fork_pocket = self.at_pocket()
            if self.fork_pocket == 0:
                self.crashes.append(f"arm forward between two pockets at {now:.3f}")
            self.released = False
        elif not forward and was_forward:
            self.fork_pocket = 0
        p = self.fork_pocket
        if not forward or p == 0:
            return
        if is_open and not was_open and self.spindle_tool:       # Put: the spindle lets go into the fork
            if self.pocket_tools.get(p, 0):
                self.crashes.append(f"tool {self.spindle_tool} put into the full pocket {p} at {now:.3f}")
            self.pocket_tools[p], self.spindle_tool, self.released = self.spindle_tool, 0, True
        elif was_open and not is_open and not self.released and not self.spindle_tool and self.pocket_tools.get(p, 0):
            self.spindle_tool, self.pocket_tools[p] = self.pocket_tools[p], 0      # Get: the collet clamps it

    def advance(self, now: float) -> None:
        dt = max(0.0, now - self.last)
        self.last = now
        w, m = self.wiring, self.mech
        if self.coils[w.motor_on] or (w.dir_negative is not None and self.coils[w.dir_negative]):
            if w.dir_negative is None:
                direction = 1 if self.coils[w.dir_positive] else -1
            else:
                direction = int(self.coils[w.dir_positive]) - int(self.coils[w.dir_negative])
            braked = self.brake_free_at is None or now < self.brake_free_at
            if direction and not braked:
                if self.arm > 0.0:
                    self.crashes.append(f"carousel turned with the arm out at {now:.3f}")
                self.position = (self.position + direction * dt / m.pocket_time_s) % m.pockets
        was_forward, was_open = self.arm >= 1.0, self.collet >= 1.0     # open: as its sensor says
        step_arm = dt / m.arm_travel_s
        self.arm = min(1.0, self.arm + step_arm) if self.coils[w.arm_forward] else max(0.0, self.arm - step_arm)
        step_collet = dt / m.collet_s
        self.collet = min(1.0, self.collet + step_collet) if self.coils[w.collet_open] \
            else max(0.0, self.collet - step_collet)
        self._move_tools(now, was_forward, was_open)

    def set_coils(self, now: float, address: int, values: list[bool]) -> None:
        self.advance(now)
        w = self.wiring
        old_brake = self.coils[w.brake_off]
        for i, v in enumerate(values):
            if 0 <= address + i < COIL_COUNT:
                self.coils[address + i] = bool(v)
        if self.coils[w.brake_off] and not old_brake:
            self.brake_free_at = now + self.mech.brake_s
        elif not self.coils[w.brake_off]:
            self.brake_free_at = None

    def at_pocket(self) -> int:
        """Pocket (1..) whose sensor window the carousel is in, 0 between windows."""
        nearest = round(self.position) % self.mech.pockets
        off = abs(self.position - round(self.position))
        return nearest + 1 if off <= self.mech.window else 0

    def inputs(self, now: float) -> list[bool]:
        self.advance(now)
        w = self.wiring
        di = [False] * DI_COUNT
        for a in (w.estop_ok, w.guard_closed, w.air_ok, w.spindle_stopped):
            di[a] = True
        pocket = self.at_pocket()
        di[w.pocket] = pocket != 0
        if w.home is not None:
            di[w.home] = pocket == 1
        di[w.arm_at_forward] = self.arm >= 1.0
        di[w.arm_at_reverse] = self.arm <= 0.0
        di[w.collet_opened] = self.collet >= 1.0
        if w.codes and pocket:
            code = self.mech.pocket_codes[pocket - 1]
            for i, a in enumerate(w.codes):
                di[a] = bool(code >> i & 1)
        return di


class _Context(ModbusBaseSlaveContext):
    """pymodbus datastore answering from the machine model."""

    def __init__(self, module: "IoModule") -> None:
        self.module = module

    def reset(self) -> None:
        pass

    def validate(self, fc_as_hex, address, count=1) -> bool:
        if self.module.mode == "exception":
            self.module.note("exception", fc_as_hex)
            return False
        table = self.decode(fc_as_hex)
        size = {"d": DI_COUNT, "c": COIL_COUNT}.get(table, 0)
        return 0 <= address and address + count <= size

    async def async_getValues(self, fc_as_hex, address, count=1):
        if self.module.mode == "slow":
            await asyncio.sleep(self.module.slow_s)
        return self.getValues(fc_as_hex, address, count)

    async def async_setValues(self, fc_as_hex, address, values):
        if self.module.mode == "slow":
            await asyncio.sleep(self.module.slow_s)
        self.setValues(fc_as_hex, address, values)

    def getValues(self, fc_as_hex, address, count=1):
        now = time.monotonic()
        m = self.module
        with m.lock:
            if self.decode(fc_as_hex) == "d":
                values = m.machine.inputs(now)[address:address + count]
                m.answered = now
                m.reads += 1
                if m.on_read:
                    m.on_read(now, values, address)
                return values
            return m.machine.coils[address:address + count]

    def setValues(self, fc_as_hex, address, values):
        now = time.monotonic()
        m = self.module
        with m.lock:
            before = list(m.machine.coils)
            m.machine.set_coils(now, address, list(values))
            m.answered = now
            m.writes += 1
            if m.machine.coils != before:
                m.note("coils", list(m.machine.coils), now)
            if m.on_write:
                m.on_write(now, list(m.machine.coils))


class IoModule:
    """The module: a pymodbus server in a thread of its own, TCP (`port`) or RTU (`serial`)."""

    def __init__(self, wiring: Wiring | None = None, mech: Mechanics | None = None, *, serial: str | None = None,
                 baud: int = 115200, units: tuple[int, ...] = (1,)) -> None:
        self.machine = Machine(wiring or Wiring(), mech or Mechanics())
        self.serial, self.baud, self.units = serial, baud, units
        self.mode = "normal"
        self.slow_s = 0.0
        self.silent_units: tuple[int, ...] | None = None     # "silent": None = every unit
        self.lock = threading.Lock()
        self.events: list[tuple[float, str, object]] = []
        self.answered = 0.0          # monotonic time of the last request answered
        self.dropped_since: float | None = None
        self.reads = self.writes = self.dropped = 0
        self.on_read = self.on_write = None      # callbacks (bench), called under the lock
        self.port = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server = None
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, name="io-module", daemon=True)

    def note(self, kind: str, what: object, now: float | None = None) -> None:
        self.events.append((time.monotonic() if now is None else now, kind, what))

    # pymodbus hooks: drop requests ("silent"), corrupt answers ("garbage")
    def _trace_pdu(self, sending: bool, pdu):
        if not sending and self.mode == "silent" and (self.silent_units is None or pdu.dev_id in self.silent_units):
            with self.lock:
                self.dropped += 1
                if self.dropped_since is None:
                    self.dropped_since = time.monotonic()
            return None
        return pdu

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        if sending and self.mode == "garbage" and len(data) > 2:
            b = bytearray(data)
            b[0 if self.serial is None else -1] ^= 0xFF    # TCP: the transaction id; RTU: the CRC
            self.note("garbage", len(data))
            return bytes(b)
        return data

    def set_mode(self, mode: str, slow_s: float = 0.0, units: tuple[int, ...] | None = None) -> float:
        """Change the fault mode (`units`: the units it applies to, "silent" only; None: all); return the
        monotonic time of the change."""
        with self.lock:
            self.mode, self.slow_s, self.silent_units = mode, slow_s, units
            if mode != "silent":
                self.dropped_since = None
            now = time.monotonic()
            self.note("mode", mode, now)
        return now

    def _run(self) -> None:
        self._loop = asyncio.new_event_loop()
        asyncio.set_event_loop(self._loop)
        # several units answer for the same machine: an RS-485 line with one board per unit
        context = ModbusServerContext(slaves={u: _Context(self) for u in self.units}, single=False)

        async def main() -> None:
            if self.serial is None:
                self._server = ModbusTcpServer(context, framer=FramerType.SOCKET, address=("127.0.0.1", 0),
                                               trace_pdu=self._trace_pdu, trace_packet=self._trace_packet)
            else:
                self._server = ModbusSerialServer(context, framer=FramerType.RTU, port=self.serial,
                                                  baudrate=self.baud, trace_pdu=self._trace_pdu,
                                                  trace_packet=self._trace_packet)
            await self._server.serve_forever(background=True)
            if self.serial is None:
                self.port = self._server.transport.sockets[0].getsockname()[1]
            self._ready.set()
            await self._server.serving

        try:
            self._loop.run_until_complete(main())
        finally:
            self._ready.set()

    def start(self, timeout: float = 30.0) -> "IoModule":
        self._thread.start()
        if not self._ready.wait(timeout) or (self.serial is None and not self.port):
            raise RuntimeError("the test I/O module did not start")
        return self

    def stop(self) -> None:
        if self._loop is not None and self._server is not None:
            fut = asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop)
            try:
                fut.result(10)
            except Exception:     # best effort at teardown
                pass
        self._thread.join(10)

    def outputs_off(self) -> float:
        """The module's own watchdog: every coil off now (a silent module otherwise holds its last outputs);
        return the monotonic time."""
        with self.lock:
            now = time.monotonic()
            self.machine.set_coils(now, 0, [False] * COIL_COUNT)
            self.note("coils", list(self.machine.coils), now)
        return now

    def coil(self, name: str) -> bool:
        with self.lock:
            return self.machine.coils[getattr(self.machine.wiring, name)]
