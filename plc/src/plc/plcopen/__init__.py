"""PLCopen TC6 XML (v2.01) as a source format: the compiler's XML front end.

The interface to the rest of the toolchain is small on purpose:

    looks_like_plcopen(path)            is this file a PLCopen project?
    translate(name, data, diags)        -> Translation: the project as ST text with a line map, or None
    Translation.remap(diags)            point the diagnostics of the ST text back into the XML
    Translation.remap_tree(files)       the same for the positions of the parsed ST (before code generation)

Types, POUs (ST bodies as written, LD and FBD bodies translated, docs/ladder.md), global variables
and the configuration become ST; the compiler proper never sees XML.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

from .. import ast as A
from ..diagnostics import Diagnostics, Pos
from .datatypes import TypeError_
from .project import Origin, ProjectError, Unit, read_project
from .xmlfile import XmlError, looks_like_plcopen as _looks, parse_bytes

__all__ = ["looks_like_plcopen", "translate", "Translation", "Unit", "st_name"]

SNIFF_BYTES = 4096


def looks_like_plcopen(path: Path) -> bool:
    """True for a .xml file whose first bytes name the PLCopen TC6 0201 namespace."""
    if path.suffix.lower() != ".xml":
        return False
    try:
        with open(path, "rb") as f:
            return _looks(f.read(SNIFF_BYTES))
    except OSError:
        return False


def st_name(xml_name: str) -> str:
    """The name the generated ST text goes by inside the compiler (never shown for mapped lines)."""
    return f"{xml_name}#st"


@dataclass
class Translation:
    xml_name: str
    units: list[Unit]

    @property
    def st_name(self) -> str:
        return st_name(self.xml_name)

    @property
    def text(self) -> str:
        return "\n".join(line for u in self.units for line, _o in u.lines) + "\n"

    @functools.cached_property
    def origins(self) -> list[Origin]:
        """The origin of every line of `text`, in order."""
        return [o for u in self.units for _l, o in u.lines]

    def origin(self, st_line: int) -> Origin | None:
        table = self.origins
        return table[st_line - 1] if 1 <= st_line <= len(table) else None

    def where(self, pos: Pos) -> tuple[Pos, str]:
        """XML position and message prefix for a position in the generated ST text."""
        o = self.origin(pos.line)
        if o is None:
            return Pos(self.xml_name, 0, 0), ""
        if o.exact:
            return Pos(self.xml_name, o.line, pos.col + o.col_shift), prefix(o.pou, o.local_id)
        local_id, line = o.element_at(pos.col)
        return Pos(self.xml_name, line, 1), prefix(o.pou, local_id, o.variable)

    def remap(self, diags: Diagnostics) -> None:
        """Diagnostics on the generated ST: XML file, line (and column for ST bodies), POU and localId."""
        for d in diags.items:
            if d.pos.file == self.st_name:
                d.pos, pre = self.where(d.pos)
                d.message = pre + d.message

    def remap_tree(self, files: list) -> None:
        """Every source position of the parsed ST text moved into the XML, so what the generated C reports
        (fault records, assertion sites, test locations) names the XML file and line."""
        for f in files:
            if getattr(f, "path", None) == self.st_name:
                self._move(f, set())

    def _move(self, node, seen: set) -> None:
        if isinstance(node, (list, tuple)):
            for item in node:
                self._move(item, seen)
            return
        if not isinstance(node, A.Node) or id(node) in seen:
            return
        seen.add(id(node))
        for name, value in A.child_fields(node):
            if isinstance(value, Pos):
                if value.file == self.st_name:
                    setattr(node, name, self.where(value)[0])
            else:
                self._move(value, seen)


def prefix(pou: str, local_id: int | None, variable: str = "") -> str:
    """'in POU, element localId N: ' (or 'variable V' for a declaration line) before a message."""
    if not pou:
        return ""
    if local_id is not None:
        return f"in {pou}, element localId {local_id}: "
    if variable:
        return f"in {pou}, variable {variable}: "
    return f"in {pou}: "


def translate(name: str, data: bytes, diags: Diagnostics) -> Translation | None:
    """The project in `data` as ST units; None (with an error in diags) when it cannot be read."""
    try:
        root = parse_bytes(data)
        units, errors, warnings = read_project(root, data)
    except XmlError as e:
        diags.error(Pos(name, e.line, e.col or 1), str(e))
        return None
    except ProjectError as e:
        diags.error(Pos(name, e.line, 1), prefix(e.pou, e.local_id) + str(e))
        return None
    except TypeError_ as e:
        diags.error(Pos(name, e.line, 1), str(e))
        return None
    for message, line, pou, local_id in warnings:
        diags.warning(Pos(name, line, 1), prefix(pou, local_id) + message)
    for e in errors:
        diags.error(Pos(name, e.line, 1), prefix(e.pou, e.local_id) + str(e))
    return Translation(name, units) if not errors else None
