"""Reading a PLCopen TC6 XML file safely, and the small helpers every other module uses.

lxml parses with entity expansion, DTD loading and network access off; a document that declares
entities or a DTD is refused (no billion-laughs, no external entities).  Element lookups ignore the
namespace prefix, so files written with or without the `tc6_0201` default namespace read alike.
"""
from __future__ import annotations

import re

from lxml import etree

NS = "http://www.plcopen.org/xml/tc6_0201"
XHTML = "http://www.w3.org/1999/xhtml"
NS_PATTERN = re.compile(rb"plcopen\.org/xml/tc6_0201")


class XmlError(Exception):
    """A problem with the file as XML: message plus 1-based line and column (0 when unknown)."""

    def __init__(self, message: str, line: int = 0, col: int = 0):
        super().__init__(message)
        self.line = line
        self.col = col


def looks_like_plcopen(head: bytes) -> bool:
    """True when the first bytes of a file name the PLCopen TC6 0201 namespace."""
    return bool(NS_PATTERN.search(head))


def parse_bytes(data: bytes) -> etree._Element:
    """The root element of a PLCopen document; XmlError for anything unsafe or malformed."""
    parser = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False, huge_tree=False,
                             remove_blank_text=False, dtd_validation=False)
    try:
        root = etree.fromstring(data, parser)
    except etree.XMLSyntaxError as e:
        line, col = e.position if e.position else (0, 0)
        raise XmlError(f"not well-formed XML: {e.msg}", line, col + 1 if col else 0) from None
    info = root.getroottree().docinfo
    if info.internalDTD is not None or info.externalDTD is not None or info.doctype:
        raise XmlError("DTD and entity declarations are not accepted in a PLCopen file", 1, 1)
    if local(root) != "project":
        raise XmlError(f"the root element is <{local(root)}>, not a PLCopen <project>", root.sourceline or 0)
    if root.nsmap.get(None) not in (NS, None) and NS not in root.nsmap.values():
        raise XmlError(f"the project is not in the PLCopen TC6 0201 namespace ({NS})", root.sourceline or 0)
    return root


def local(el) -> str:
    """The element's name without namespace ('' for comments and processing instructions)."""
    tag = el.tag
    if not isinstance(tag, str):
        return ""
    return tag.rsplit("}", 1)[-1]


def children(el, name: str | None = None) -> list:
    return [c for c in el if local(c) and (name is None or local(c) == name)]


def child(el, name: str):
    for c in el:
        if local(c) == name:
            return c
    return None


def path(el, *names: str):
    """The first element reached by following child names, or None."""
    for n in names:
        if el is None:
            return None
        el = child(el, n)
    return el


def line_of(el) -> int:
    return getattr(el, "sourceline", None) or 0


def text_of(el) -> str:
    """All text below an element (xhtml paragraphs, CDATA), without the markup."""
    if el is None:
        return ""
    return "".join(el.itertext())


def flag(el, name: str) -> bool:
    return (el.get(name) or "").strip().lower() in ("true", "1")


def text_start(raw: bytes, el) -> tuple[int, int]:
    """1-based line and column where the text content of `el` starts in the raw file (after a CDATA
    opener); the element's own line and column 1 when it cannot be found."""
    line = line_of(el)
    if line <= 0:
        return 0, 0
    offsets = [0]
    for m in re.finditer(rb"\n", raw):
        offsets.append(m.end())
    start = offsets[line - 1] if line - 1 < len(offsets) else 0
    m = re.compile(rb"<(?:[\w.-]+:)?" + re.escape(local(el).encode()) + rb"\b[^>]*>").search(raw, start)
    if m is None:
        return line, 1
    pos = m.end()
    cdata = raw.startswith(b"<![CDATA[", pos)
    if cdata:
        pos += len(b"<![CDATA[")
    text_line = raw.count(b"\n", 0, pos) + 1
    col = pos - (raw.rfind(b"\n", 0, pos) + 1) + 1
    return text_line, col
