"""What the register map implies for a run: the host-writable coils and registers are exactly the host_to_plc
signals (any other write gets exception 02), and the retained signals' holding registers are saved with the
RETAIN variables. `plc run` and a service release take them from here (atc.runsetup) wherever the user's run
configuration does not set `[modbus] writable_coils`, `writable_registers` or `[retain] registers`; nothing of
the map is written into the user's file.
"""
from __future__ import annotations

from .model import RegisterMap, Signal


def ranges(addresses: list[int]) -> list[str]:
    """Sorted addresses folded into 'first-last' ranges (a single address stays 'n')."""
    out: list[str] = []
    start = prev = None
    for a in sorted(set(addresses)):
        if prev is not None and a == prev + 1:
            prev = a
            continue
        if start is not None:
            out.append(f"{start}-{prev}" if prev != start else f"{start}")
        start = prev = a
    if start is not None:
        out.append(f"{start}-{prev}" if prev != start else f"{start}")
    return out


def _words(sigs: list[Signal]) -> list[int]:
    return [a for s in sigs for a in range(s.address, s.last + 1)]


def writable_coils(rmap: RegisterMap) -> list[str]:
    """Whole bytes: an FC15 host (mb2hal) writes its command coils by whole bytes (OpenPLC applies FC15 so), and
    `plc map check` keeps anything else out of those bytes."""
    coils = [s for s in rmap.signals if s.host_writable and s.table == "coil"]
    return ranges([a for byte in {s.address // 8 for s in coils} for a in range(8 * byte, 8 * byte + 8)])


def writable_registers(rmap: RegisterMap) -> list[str]:
    return ranges(_words([s for s in rmap.signals if s.host_writable and s.table == "holding_register"]))


def retained_registers(rmap: RegisterMap) -> list[str]:
    return ranges(_words([s for s in rmap.signals if s.retained and s.table == "holding_register"]))
