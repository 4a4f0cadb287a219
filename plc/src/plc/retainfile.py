"""The runtime's retained-data file, read from Python (plc/runtime/retain.c writes it; its header comment is the
format's reference).  Used by `plc retain show`, the upgrade check of `plc deploy` and the tests.

Format version 2: a header (magic, version, entry count, generation, body length), one entry per retained
value (flags, path, type, location, value bytes), a CRC-32 of everything before it.  Format version 1 (one
block of values, no names) is recognised but cannot be decoded without the program that wrote it.
"""
from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

MAGIC = b"ATCPLCR1"
HEADER = 28
TRAILER = 4
ENTRY_HEAD = 12
KEPT_ASIDE = 0x01


class RetainFileError(Exception):
    """The file is not a complete, consistent retain file; str() says why."""


@dataclass
class Entry:
    path: str
    type: str
    where: str            # "%MW0" for registers, "" for a variable
    value: bytes
    kept_aside: bool = False

    def number(self) -> int | float | None:
        """The value as a number when its type says how (registers: big-endian words), else None."""
        signed = {"SINT": 1, "INT": 2, "DINT": 4, "LINT": 8}
        unsigned = {"BOOL": 1, "USINT": 1, "BYTE": 1, "UINT": 2, "WORD": 2, "UDINT": 4, "DWORD": 4,
                     "ULINT": 8, "LWORD": 8}
        order = "big" if self.where else "little"
        if self.type in signed and len(self.value) == signed[self.type]:
            return int.from_bytes(self.value, order, signed=True)
        if self.type in unsigned and len(self.value) == unsigned[self.type]:
            return int.from_bytes(self.value, order)
        if self.type in ("REAL", "LREAL") and len(self.value) in (4, 8):
            fmt = (">" if self.where else "<") + ("f" if len(self.value) == 4 else "d")
            return struct.unpack(fmt, self.value)[0]
        return None


@dataclass
class RetainFile:
    version: int
    generation: int
    entries: list[Entry] = field(default_factory=list)

    def active(self) -> dict[str, Entry]:
        """The entries saved by the program that wrote the file, by path."""
        return {e.path: e for e in self.entries if not e.kept_aside}

    def kept_aside(self) -> list[Entry]:
        return [e for e in self.entries if e.kept_aside]


def decode(data: bytes) -> RetainFile:
    """Check and decode a retain file's bytes; raise RetainFileError when anything is wrong."""
    if len(data) < HEADER + TRAILER:
        raise RetainFileError(f"size {len(data)} bytes: too short for a retain file")
    if data[:8] != MAGIC:
        raise RetainFileError("not a retain file (magic)")
    version, count, gen_lo, gen_hi, length = struct.unpack("<IIIII", data[8:28])
    if version not in (1, 2):
        raise RetainFileError(f"unknown format version {version}")
    if length != len(data) - HEADER - TRAILER:
        raise RetainFileError(f"body length {length} differs from the file size {len(data)}")
    (crc,) = struct.unpack("<I", data[-4:])
    if zlib.crc32(data[:-4]) != crc:
        raise RetainFileError("CRC mismatch: the file is corrupt")
    out = RetainFile(version, gen_hi << 32 | gen_lo)
    if version == 1:
        return out
    body, at = data[HEADER:-TRAILER], 0
    for i in range(count):
        if len(body) - at < ENTRY_HEAD:
            raise RetainFileError(f"entry {i + 1} of {count} is cut short")
        flags, _, p, t, w, size = struct.unpack("<BBHHHI", body[at:at + ENTRY_HEAD])
        at += ENTRY_HEAD
        if len(body) - at < p + t + w + size:
            raise RetainFileError(f"entry {i + 1} of {count} is cut short")
        text = body[at:at + p + t + w].decode("ascii", errors="replace")
        at += p + t + w
        out.entries.append(Entry(text[:p], text[p:p + t], text[p + t:], bytes(body[at:at + size]),
                                 bool(flags & KEPT_ASIDE)))
        at += size
    if at != len(body):
        raise RetainFileError(f"{len(body) - at} bytes after the last entry")
    return out


def read(path: Path) -> RetainFile:
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise RetainFileError(f"cannot read it: {exc.strerror}") from None
    return decode(data)


def describe(entry: Entry) -> str:
    n = entry.number()
    value = repr(n) if n is not None else entry.value.hex()
    where = f" at {entry.where}" if entry.where else ""
    aside = "  (kept aside: saved by an earlier program version)" if entry.kept_aside else ""
    return f"{entry.path} : {entry.type}{where} = {value}{aside}"
