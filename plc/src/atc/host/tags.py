"""Read and write register-map signals by name over Modbus, with their types.

Reads are batched: the signals asked for are grouped per table into few requests (runs of nearby
addresses).  Coils are read before registers, so a number read together with a bit is never older than
the bit (the PLC writes a reason no later than the fault bit that announces it).  Writes of several
registers that sit next to each other go out as one FC16, so the runtime applies them between two scans.

Coils are written one at a time (FC5), each request naming the one coil it sets.  OpenPLC v3 applies FC15 byte
by byte (writing 2 coils would also rewrite the other 6 of their byte), and a read-modify-write of the byte is
no cure when two hosts share it: a host that read the byte just before another dropped its coil writes that
coil back TRUE (a lost update: a second host's emc-abort stayed up after it had dropped it, and the first host
waited for its acknowledgement to fall).  With FC5 a write carries no coil the host did not mean, on our runtime
and on OpenPLC's alike.  The coils this host holds TRUE are remembered (meant()): a command coil that reads
FALSE while held was dropped by another client.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

from plc.diagnostics import Diagnostics
from plc.modbus import ModbusClient

from ..map.model import RegisterMap, Signal, load

READ_GAP = 16
MAX_REGISTERS = 125
MAX_BITS = 2000
ORDER = {"coil": 0, "discrete_input": 1, "input_register": 2, "holding_register": 3}


class MapError(Exception):
    """The register map could not be read (message includes file:line)."""


def load_map(path: Path) -> RegisterMap:
    diags = Diagnostics()
    rmap = load(path, diags)
    if rmap is None or diags.has_errors():
        raise MapError("\n".join(d.render() for d in diags.errors) or f"cannot read {path}")
    return rmap


def decode(sig: Signal, words: list[int]) -> int | float | bool:
    if sig.type == "BOOL":
        return bool(words[0])
    if sig.type == "INT":
        return words[0] - 0x10000 if words[0] & 0x8000 else words[0]
    if sig.type in ("UINT", "WORD"):
        return words[0]
    raw = (words[0] << 16) | words[1]
    if sig.type == "DINT":
        return raw - 0x100000000 if raw & 0x80000000 else raw
    if sig.type == "REAL":
        return struct.unpack(">f", struct.pack(">I", raw))[0]
    return raw


def encode(sig: Signal, value) -> list[int]:
    if sig.type == "BOOL":
        return [1 if value else 0]
    if sig.type == "REAL":
        raw = struct.unpack(">I", struct.pack(">f", float(value)))[0]
        return [raw >> 16, raw & 0xFFFF]
    v = int(value)
    if sig.words == 1:
        return [v & 0xFFFF]
    v &= 0xFFFFFFFF
    return [v >> 16, v & 0xFFFF]


@dataclass
class _Run:
    table: str
    first: int
    last: int
    signals: list[Signal]


class Tags:
    """The register map's signals on one Modbus connection."""

    def __init__(self, rmap: RegisterMap, client: ModbusClient, bit_gap: int = READ_GAP):
        self.rmap = rmap
        self.client = client
        self.bit_gap = bit_gap                      # unused bits a coil/discrete read may span (fewer requests)
        self._plans: dict[tuple[str, ...], list[_Run]] = {}
        self._owned: dict[int, bool] = {}           # coil address -> TRUE while this host holds the coil TRUE

    def signal(self, name: str) -> Signal:
        sig = self.rmap.signal(name)
        if sig is None:
            raise KeyError(f"the register map has no signal {name}")
        return sig

    def has(self, name: str) -> bool:
        return self.rmap.signal(name) is not None

    def _plan(self, names: tuple[str, ...]) -> list[_Run]:
        plan = self._plans.get(names)
        if plan is not None:
            return plan
        sigs = sorted((self.signal(n) for n in names), key=lambda s: (ORDER[s.table], s.address))
        runs: list[_Run] = []
        for sig in sigs:
            bits = sig.table in ("coil", "discrete_input")
            limit = MAX_BITS if bits else MAX_REGISTERS
            gap = self.bit_gap if bits else READ_GAP
            run = runs[-1] if runs else None
            if run and run.table == sig.table and sig.address - run.last - 1 <= gap \
                    and sig.last - run.first < limit:
                run.last = max(run.last, sig.last)
                run.signals.append(sig)
            else:
                runs.append(_Run(sig.table, sig.address, sig.last, [sig]))
        self._plans[names] = runs
        return runs

    def read_together(self, names: tuple[str, ...], group: tuple[str, ...]) -> bool:
        """True if read(*names) fetches every signal of `group` in one request (one consistent view)."""
        return any(all(n in {s.name for s in run.signals} for n in group) for run in self._plan(tuple(names)))

    def read(self, *names: str) -> dict[str, int | float | bool]:
        """Current values of the named signals (one request per run of nearby addresses)."""
        out: dict[str, int | float | bool] = {}
        for run in self._plan(tuple(names)):
            count = run.last - run.first + 1
            if run.table == "coil":
                raw = [int(b) for b in self.client.read_coils(run.first, count)]
            elif run.table == "discrete_input":
                raw = [int(b) for b in self.client.read_discrete_inputs(run.first, count)]
            elif run.table == "input_register":
                raw = self.client.read_input_registers(run.first, count)
            else:
                raw = self.client.read_holding(run.first, count)
            for sig in run.signals:
                at = sig.address - run.first
                out[sig.name] = decode(sig, raw[at:at + sig.words])
        return out

    def get(self, name: str):
        return self.read(name)[self.signal(name).name]

    def write(self, **values) -> None:
        """Write signals: registers next to each other in one FC16 (in address order), then coils (one FC5 each)."""
        sigs = sorted(((self.signal(n), v) for n, v in values.items()), key=lambda p: (p[0].table != "holding_register",
                                                                                       p[0].address))
        i = 0
        while i < len(sigs):
            sig, value = sigs[i]
            words = encode(sig, value)
            j = i + 1
            while j < len(sigs) and sigs[j][0].table == sig.table and sigs[j][0].address == sig.address + len(words):
                words += encode(*sigs[j])
                j += 1
            if sig.table == "holding_register":
                if len(words) == 1:
                    self.client.write_register(sig.address, words[0])
                else:
                    self.client.write_registers(sig.address, words)
            elif sig.table == "coil":
                self._write_coils(sig.address, [bool(w) for w in words])
            else:
                raise KeyError(f"{sig.name} is a {sig.table}: not writable")
            i = j

    def _write_coils(self, address: int, values: list[bool]) -> None:
        """Set coils address.. to values, one FC5 each (see the module text); TRUE ones are held, FALSE ones not."""
        for i, v in enumerate(values):
            self.client.write_coil(address + i, v)
            if v:
                self._owned[address + i] = True
            else:
                self._owned.pop(address + i, None)   # a dropped request is not held

    def meant(self, name: str) -> bool | None:
        """TRUE while this host holds the coil TRUE; None otherwise (never written, or dropped)."""
        return self._owned.get(self.signal(name).address)
