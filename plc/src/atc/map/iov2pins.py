"""The toolchanger pins of LinuxCNC 2.9's iov2 (docs/iov2.md): name -> (HAL type, direction).

Direction is iov2's: OUT = iov2 drives it (CNC -> toolchanger, host_to_plc), IN = iov2 reads it
(toolchanger -> CNC, plc_to_host).  toolchanger-clear-fault is an iov2 input driven by the operator (a GUI
button or `halcmd sets`), so the PLC's ClearFault shares that signal as a second reader.
"""
from __future__ import annotations

PREFIX = "iocontrol.0."

PINS: dict[str, tuple[str, str]] = {
    "tool-prepare": ("bit", "OUT"),
    "tool-prep-number": ("s32", "OUT"),
    "tool-prep-pocket": ("s32", "OUT"),
    "tool-prepared": ("bit", "IN"),
    "tool-change": ("bit", "OUT"),
    "tool-number": ("s32", "OUT"),
    "tool-changed": ("bit", "IN"),
    "start-change": ("bit", "OUT"),
    "start-change-ack": ("bit", "IN"),
    "emc-abort": ("bit", "OUT"),
    "emc-reason": ("s32", "OUT"),
    "emc-abort-ack": ("bit", "IN"),
    "toolchanger-fault": ("bit", "IN"),
    "toolchanger-reason": ("s32", "IN"),
    "toolchanger-fault-ack": ("bit", "OUT"),
    "toolchanger-faulted": ("bit", "OUT"),
    "toolchanger-clear-fault": ("bit", "IN"),
    "state": ("s32", "OUT"),
    "user-enable-out": ("bit", "OUT"),
    "emc-enable-in": ("bit", "IN"),
    "user-request-enable": ("bit", "OUT"),
}

# The pins of iocontrol v1 (EMCIO = io, and LinuxCNC 2.10 where iov2 is gone): prepare and change pairs only.
V1_PINS = frozenset({"tool-prepare", "tool-prep-number", "tool-prep-pocket", "tool-prepared", "tool-change",
                     "tool-number", "tool-changed", "user-enable-out", "emc-enable-in", "user-request-enable"})

# iov2 inputs that an operator drives; a host_to_plc signal may read them alongside iov2.
OPERATOR_INPUTS = frozenset({"toolchanger-clear-fault"})


def lookup(pin: str) -> tuple[str, str] | None:
    """(type, direction) of an iocontrol.0.* pin, None when iov2 has no such pin."""
    if not pin.startswith(PREFIX):
        return None
    return PINS.get(pin[len(PREFIX):])
