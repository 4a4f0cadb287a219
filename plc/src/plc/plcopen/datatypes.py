"""PLCopen data types and initial values as ST text.

A `<type>` (or `<baseType>`) element holds one child: an elementary type (`<INT/>`, `<string
length="20"/>`), `<derived name="..."/>`, `<array>`, `<enum>`, `<struct>`, `<subrangeSigned>` /
`<subrangeUnsigned>` or `<pointer>`.  Initial values are `<simpleValue value="..."/>`,
`<arrayValue>` (with `repetitionValue`) or `<structValue>` (with `member`).
"""
from __future__ import annotations

from .xmlfile import child, children, local, line_of

ELEMENTARY = {
    "BOOL", "SINT", "INT", "DINT", "LINT", "USINT", "UINT", "UDINT", "ULINT", "REAL", "LREAL", "TIME", "DATE",
    "DT", "TOD", "BYTE", "WORD", "DWORD", "LWORD", "LTIME",
}


class TypeError_(Exception):
    """A type the translation cannot express, with the line of the offending element."""

    def __init__(self, message: str, line: int):
        super().__init__(message)
        self.line = line


def type_text(holder, indent: str = "") -> str:
    """ST spelling of the type held by `holder` (a <type>, <baseType> or <returnType> element)."""
    kids = children(holder)
    if not kids:
        raise TypeError_(f"<{local(holder)}> names no type", line_of(holder))
    return _spec(kids[0], indent)


def _spec(el, indent: str) -> str:
    name = local(el)
    if name.upper() in ELEMENTARY and name not in ("string", "wstring"):
        return name.upper()
    if name in ("string", "wstring"):
        length = el.get("length")
        base = name.upper()
        return f"{base}[{length}]" if length else base
    if name == "derived":
        ref = el.get("name")
        if not ref:
            raise TypeError_("<derived> without a name", line_of(el))
        return ref
    if name == "array":
        dims = [f"{d.get('lower', '0')}..{d.get('upper', '0')}" for d in children(el, "dimension")]
        if not dims:
            raise TypeError_("<array> without <dimension>", line_of(el))
        base = child(el, "baseType")
        if base is None:
            raise TypeError_("<array> without <baseType>", line_of(el))
        return f"ARRAY[{', '.join(dims)}] OF {type_text(base, indent)}"
    if name in ("subrangeSigned", "subrangeUnsigned"):
        rng = child(el, "range")
        base = child(el, "baseType")
        if rng is None or base is None:
            raise TypeError_(f"<{name}> needs <range> and <baseType>", line_of(el))
        return f"{type_text(base, indent)} ({rng.get('lower', '0')}..{rng.get('upper', '0')})"
    if name == "enum":
        values = [v.get("name") for v in children(child(el, "values") if child(el, "values") is not None else el,
                                                   "value")]
        if not values or not all(values):
            raise TypeError_("<enum> needs named <value>s", line_of(el))
        return "(" + ", ".join(values) + ")"
    if name == "struct":
        lines = ["STRUCT"]
        for v in children(el, "variable"):
            t = child(v, "type")
            if t is None:
                raise TypeError_(f"struct member {v.get('name')} has no <type>", line_of(v))
            init = initial_value(child(v, "initialValue"))
            lines.append(f"{indent}        {v.get('name')} : {type_text(t, indent + '    ')}"
                         + (f" := {init}" if init else "") + ";")
        lines.append(f"{indent}    END_STRUCT")
        return "\n".join(lines)
    if name == "pointer":
        raise TypeError_("pointer types are not supported (MATIEC has no POINTER TO)", line_of(el))
    raise TypeError_(f"unknown type element <{name}>", line_of(el))


def initial_value(holder) -> str | None:
    """ST text of an <initialValue> (None when absent)."""
    if holder is None:
        return None
    kids = children(holder)
    return _value(kids[0]) if kids else None


def _value(el) -> str:
    name = local(el)
    if name == "simpleValue":
        return (el.get("value") or "").strip()
    if name == "arrayValue":
        items = []
        for v in children(el, "value"):
            inner = children(v)
            text = _value(inner[0]) if inner else ""
            rep = v.get("repetitionValue")
            items.append(f"{rep}({text})" if rep and rep != "1" else text)
        return "[" + ", ".join(items) + "]"
    if name == "structValue":
        items = []
        for v in children(el, "value"):
            inner = children(v)
            items.append(f"{v.get('member')} := {_value(inner[0]) if inner else ''}")
        return "(" + ", ".join(items) + ")"
    raise TypeError_(f"unknown initial value <{name}>", line_of(el))
