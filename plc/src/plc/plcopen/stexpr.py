"""ST expressions as the LD/FBD translation builds them: text, precedence, and which element wrote which
part of the text (so a diagnostic inside a generated line finds its element).
"""
from __future__ import annotations

import re
from dataclasses import dataclass

ATOM, NOT_P, AND_P, OR_P, LOW = 10, 8, 5, 3, 0
SIMPLE = re.compile(r"^(?:[A-Za-z_][\w]*(?:\.[A-Za-z_]\w*|\[[^\]]*\])*|%[IQM][XBWDL]?[\d.]+|[\w#.+\-:']+)$")


@dataclass
class Ex:
    """An ST expression, its precedence (ATOM binds tightest) and which element wrote which part of it
    (spans of (start, end, localId), so a diagnostic inside the text finds its element)."""
    text: str
    prec: int = ATOM
    stable: bool = False     # a constant, a temporary or an FB output: reading it twice reads the same value
    spans: tuple = ()

    def at(self, prec: int) -> "Ex":
        if self.prec >= prec:
            return self
        return Ex(f"({self.text})", ATOM, self.stable, tuple((a + 1, b + 1, i) for a, b, i in self.spans))


def cat(*parts, prec: int = ATOM, stable: bool = False) -> Ex:
    """Strings and expressions joined into one expression, the spans shifted to their place."""
    text, spans = "", []
    for p in parts:
        if isinstance(p, Ex):
            spans += [(a + len(text), b + len(text), i) for a, b, i in p.spans]
            text += p.text
        else:
            text += p
    return Ex(text, prec, stable, tuple(spans))


def tag(ex: Ex, local_id: int) -> Ex:
    """The whole expression marked as written by element local_id."""
    return Ex(ex.text, ex.prec, ex.stable, ex.spans + ((0, len(ex.text), local_id),))


def join(sep: str, items: list) -> list:
    """items with sep between them (for cat)."""
    out: list = []
    for k, it in enumerate(items):
        if k:
            out.append(sep)
        out.append(it)
    return out


TRUE = Ex("TRUE", ATOM, True)
FALSE = Ex("FALSE", ATOM, True)


def and_(a: Ex, b: Ex) -> Ex:
    if a.text == "TRUE":
        return b
    if b.text == "TRUE":
        return a
    return cat(a.at(AND_P), " AND ", b.at(AND_P + 1), prec=AND_P)


def or_(items: list[Ex]) -> Ex:
    if any(i.text == "TRUE" for i in items):
        return TRUE
    if len(items) == 1:
        return items[0]
    return cat(*join(" OR ", [i.at(OR_P + 1) for i in items]), prec=OR_P)


def not_(a: Ex) -> Ex:
    if a.text == "TRUE":
        return FALSE
    if a.text == "FALSE":
        return TRUE
    return cat("NOT ", a.at(NOT_P), prec=NOT_P)


def expr_of(text: str) -> Ex:
    """A variable or expression as written in the XML (an expression other than a name is parenthesised
    where it is used)."""
    text = text.strip()
    return Ex(text, ATOM) if SIMPLE.match(text) else Ex(text, LOW)


@dataclass
class Line:
    """One line of generated ST, the element it belongs to and the parts other elements wrote."""
    text: str
    local_id: int | None
    spans: tuple = ()          # (start, end, localId) of the parts other elements wrote

    @staticmethod
    def of(local_id: int | None, *parts) -> "Line":
        ex = cat(*parts)
        return Line(ex.text, local_id, ex.spans)
