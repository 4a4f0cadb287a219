"""The elements of an LD or FBD body and the wires between them, read from the XML.

Every element has a `localId`; an input point lists `connection`s to the `refLocalId` (and, for block
outputs, the `formalParameter`) it reads.  Several connections into one point are a wired OR.  A
`network` is a set of elements joined by wires or by connector/continuation names; power rails join
nothing (OpenPLC Editor draws one pair of rails for every rung).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from .xmlfile import child, children, flag, line_of, local, text_of

RAILS = ("leftPowerRail", "rightPowerRail")
SUPPORTED = {"leftPowerRail", "rightPowerRail", "contact", "coil", "block", "inVariable", "outVariable",
             "inOutVariable", "connector", "continuation", "jump", "label", "return", "comment"}
SFC_ELEMENTS = {"step", "macroStep", "transition", "selectionDivergence", "selectionConvergence",
                "simultaneousDivergence", "simultaneousConvergence", "jumpStep", "actionBlock"}


class GraphError(Exception):
    def __init__(self, message: str, line: int, local_id: int | None = None):
        super().__init__(message)
        self.line = line
        self.local_id = local_id


@dataclass
class Ref:
    """One wire into an input point: the element it comes from and that element's output pin."""
    source: int
    pin: str            # upper-case formal parameter ('' for single-output elements)
    line: int


@dataclass
class Pin:
    name: str           # upper case; '' for the single input/output of contacts, coils, variables
    refs: list[Ref] = field(default_factory=list)
    negated: bool = False
    edge: str = "none"


@dataclass
class Element:
    id: int
    kind: str
    line: int
    x: float
    y: float
    order: int                                          # executionOrderId (0: not given)
    inputs: dict[str, Pin] = field(default_factory=dict)
    outputs: dict[str, Pin] = field(default_factory=dict)
    inouts: list[str] = field(default_factory=list)     # block in-out pins (upper case)
    pin_text: dict[str, str] = field(default_factory=dict)   # pin spelling as written
    text: str = ""            # variable / expression / label / connector name / comment
    type_name: str = ""       # block type
    instance: str = ""        # block instance name
    negated: bool = False
    edge: str = "none"
    storage: str = "none"
    network: int = -1

    def key(self) -> tuple:
        """Tie-break position: top to bottom, then left to right, then localId."""
        return (self.y, self.x, self.id)


def _pos(el) -> tuple[float, float]:
    p = child(el, "position")
    if p is None:
        return 0.0, 0.0
    try:
        return float(p.get("x", 0)), float(p.get("y", 0))
    except ValueError:
        return 0.0, 0.0


def _refs(point, line: int, owner: int | None = None) -> list[Ref]:
    out = []
    if point is None:
        return out
    for c in children(point, "connection"):
        ref = c.get("refLocalId")
        try:
            src = int(ref)
        except (TypeError, ValueError):
            raise GraphError(f"connection with refLocalId={ref!r} (not a number)", line_of(c) or line,
                             owner) from None
        out.append(Ref(src, (c.get("formalParameter") or "").upper(), line_of(c) or line))
    return out


def read_elements(body) -> list[Element]:
    """The elements of an <LD> or <FBD> body, in file order."""
    elems: list[Element] = []
    seen: dict[int, int] = {}
    for el in children(body):
        kind = local(el)
        line = line_of(el)
        raw_id = el.get("localId")
        named = int(raw_id) if (raw_id or "").strip().isdigit() else None
        if kind in SFC_ELEMENTS:
            raise GraphError(f"<{kind}> is an SFC element: SFC is not supported", line, named)
        if kind not in SUPPORTED:
            raise GraphError(f"<{kind}> is not supported in an LD/FBD body", line, named)
        try:
            lid = int(raw_id)
        except (TypeError, ValueError):
            raise GraphError(f"<{kind}> has no numeric localId ({raw_id!r})", line) from None
        if lid in seen:
            raise GraphError(f"localId {lid} is used twice (first at line {seen[lid]})", line, lid)
        seen[lid] = line
        x, y = _pos(el)
        try:
            order = int(el.get("executionOrderId") or 0)
        except ValueError:
            order = 0
        e = Element(lid, kind, line, x, y, order)
        _fill(e, el)
        elems.append(e)
    return elems


def _fill(e: Element, el) -> None:
    kind = e.kind
    if kind in ("contact", "coil"):
        e.text = text_of(child(el, "variable")).strip()
        e.negated = flag(el, "negated")
        e.edge = (el.get("edge") or "none").strip().lower()
        e.storage = (el.get("storage") or "none").strip().lower()
        e.inputs[""] = Pin("", _refs(child(el, "connectionPointIn"), e.line, e.id))
        e.outputs[""] = Pin("")
        if not e.text:
            raise GraphError(f"{kind} without a variable", e.line, e.id)
        if e.edge not in ("none", "rising", "falling"):
            raise GraphError(f"{kind} edge={e.edge!r} (none, rising or falling)", e.line, e.id)
        if e.storage not in ("none", "set", "reset"):
            raise GraphError(f"coil storage={e.storage!r} (none, set or reset)", e.line, e.id)
    elif kind == "leftPowerRail":
        e.outputs[""] = Pin("")
    elif kind in ("rightPowerRail", "outVariable", "connector", "jump", "return"):
        points = children(el, "connectionPointIn")
        refs = [r for p in points for r in _refs(p, e.line, e.id)]
        e.inputs[""] = Pin("", refs)
        if kind == "outVariable":
            e.text = text_of(child(el, "expression")).strip()
            e.negated = flag(el, "negated")
        elif kind == "connector":
            e.text = (el.get("name") or "").strip()
        elif kind == "jump":
            e.text = (el.get("label") or "").strip()
    elif kind == "inVariable":
        e.text = text_of(child(el, "expression")).strip()
        e.negated = flag(el, "negated")
        e.edge = (el.get("edge") or "none").strip().lower()
        e.outputs[""] = Pin("")
    elif kind == "inOutVariable":
        e.text = text_of(child(el, "expression")).strip()
        e.negated = flag(el, "negatedOut")
        e.inputs[""] = Pin("", _refs(child(el, "connectionPointIn"), e.line, e.id), negated=flag(el, "negatedIn"))
        e.outputs[""] = Pin("")
    elif kind == "continuation":
        e.text = (el.get("name") or "").strip()
        e.outputs[""] = Pin("")
    elif kind == "label":
        e.text = (el.get("label") or "").strip()
    elif kind == "comment":
        e.text = text_of(child(el, "content")).strip()
    elif kind == "block":
        e.type_name = (el.get("typeName") or "").strip()
        e.instance = (el.get("instanceName") or "").strip()
        if not e.type_name:
            raise GraphError("block without a typeName", e.line, e.id)
        for v in children(child(el, "inputVariables") if child(el, "inputVariables") is not None else el,
                          "variable"):
            name = (v.get("formalParameter") or "").strip()
            e.pin_text[name.upper()] = name
            e.inputs[name.upper()] = Pin(name.upper(), _refs(child(v, "connectionPointIn"), line_of(v), e.id),
                                         flag(v, "negated"), (v.get("edge") or "none").lower())
        inouts = child(el, "inOutVariables")
        for v in children(inouts, "variable") if inouts is not None else []:
            name = (v.get("formalParameter") or "").strip()
            e.pin_text[name.upper()] = name
            e.inputs[name.upper()] = Pin(name.upper(), _refs(child(v, "connectionPointIn"), line_of(v), e.id))
            e.outputs[name.upper()] = Pin(name.upper())
            e.inouts.append(name.upper())
        outs = child(el, "outputVariables")
        for v in children(outs, "variable") if outs is not None else []:
            name = (v.get("formalParameter") or "").strip()
            e.pin_text[name.upper()] = name
            e.outputs[name.upper()] = Pin(name.upper(), negated=flag(v, "negated"))
    if kind in ("label", "jump", "connector", "continuation") and not e.text:
        raise GraphError(f"{kind} without a name", e.line, e.id)


def check_refs(elems: list[Element]) -> None:
    """Every wire names an existing element and one of its outputs (GraphError at the first bad one)."""
    by_id = {e.id: e for e in elems}
    for e in elems:
        for pin in e.inputs.values():
            for r in pin.refs:
                src = by_id.get(r.source)
                if src is None:
                    raise GraphError(f"{e.kind} {e.id} is wired to localId {r.source}, which does not exist",
                                     r.line, e.id)
                if not src.outputs:
                    raise GraphError(f"{e.kind} {e.id} is wired to {src.kind} {src.id}, which has no output",
                                     r.line, e.id)
                if src.kind == "block":
                    if r.pin == "" and len(src.outputs) == 1:
                        r.pin = next(iter(src.outputs))
                    elif r.pin == "" and "OUT" in src.outputs:
                        r.pin = "OUT"
                    if r.pin not in src.outputs:
                        raise GraphError(f"{e.kind} {e.id} reads output {r.pin or '(none)'} of block {src.id} "
                                         f"({src.type_name}), which has no such output", r.line, e.id)
                else:
                    r.pin = ""


def networks(elems: list[Element]) -> list[list[Element]]:
    """Connected groups of elements (wires and connector names join them; rails and comments do not)."""
    parent = {e.id: e.id for e in elems}

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def union(a: int, b: int) -> None:
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)

    by_id = {e.id: e for e in elems}
    connectors: dict[str, int] = {}
    for e in elems:
        if e.kind == "connector":
            connectors.setdefault(e.text.upper(), e.id)
    for e in elems:
        if e.kind in RAILS or e.kind in ("comment", "label"):
            continue
        for pin in e.inputs.values():
            for r in pin.refs:
                if by_id[r.source].kind not in RAILS:
                    union(e.id, r.source)
        if e.kind == "continuation" and e.text.upper() in connectors:
            union(e.id, connectors[e.text.upper()])
    groups: dict[int, list[Element]] = {}
    for e in elems:
        if e.kind in RAILS or e.kind in ("comment", "label"):
            continue
        groups.setdefault(find(e.id), []).append(e)
    out = list(groups.values())
    for i, g in enumerate(out):
        for e in g:
            e.network = i
    return out


def _name(e: Element) -> str:
    """An element as a diagnostic names it: kind, localId and the variable or name it carries."""
    if e.kind in ("connector", "continuation"):
        return f"{e.kind} '{e.text}' ({e.id})"
    if e.kind in ("contact", "coil", "inVariable", "outVariable"):
        return f"{e.kind} {e.id} ({e.text})"
    if e.kind == "block":
        return f"block {e.id} ({e.type_name})"
    return f"{e.kind} {e.id}"


def check_connectors(elems: list[Element]) -> None:
    """Every continuation reads exactly one connector of its name, and that connector has a wire into it
    (GraphError at the continuation).  A continuation without any connector is reported where it is read."""
    by_name: dict[str, list[Element]] = {}
    for e in elems:
        if e.kind == "connector":
            by_name.setdefault(e.text.upper(), []).append(e)
    for e in elems:
        if e.kind != "continuation":
            continue
        conns = by_name.get(e.text.upper(), [])
        if len(conns) > 1:
            raise GraphError(f"continuation '{e.text}' ({e.id}) could read any of {len(conns)} connectors of that "
                             f"name (localId {', '.join(str(c.id) for c in conns)}): give each connector its own name",
                             e.line, e.id)
        if conns and not conns[0].inputs[""].refs:
            raise GraphError(f"continuation '{e.text}' ({e.id}) reads connector '{conns[0].text}' "
                             f"({conns[0].id}), which has nothing wired into it", e.line, e.id)


def check_loops(elems: list[Element], language: str) -> None:
    """A wire loop that meets no block and no in-out variable has no value to start from: neither IEC
    61131-3 nor Beremiz gives it a meaning (a loop through a block reads the block's output of the previous
    scan, one through an in-out variable reads the variable; docs/ladder.md, "Feedback").  GraphError at
    the element the loop comes back into.  Iterative, so a long chain of elements cannot exhaust the stack."""
    by_id = {e.id: e for e in elems}
    connector = {e.text.upper(): e for e in elems if e.kind == "connector"}
    readers: set[int] = {r.source for e in elems for p in e.inputs.values() for r in p.refs}
    readers |= {connector[e.text.upper()].id for e in elems if e.kind == "continuation" and e.text.upper() in connector}

    def upstream(e: Element) -> list[int]:
        if e.kind in ("block", "inOutVariable"):
            return []                    # they break a loop
        if e.kind == "continuation":
            conn = connector.get(e.text.upper())
            return [conn.id] if conn is not None else []
        return [r.source for p in e.inputs.values() for r in p.refs if r.source in by_id]

    state: dict[int, int] = {}           # 1: on the current path, 2: done
    # elements nothing reads first (coils at the end of a rung, output variables, the right rail), so the
    # loop is reported where the flow that reaches an output comes back
    roots = sorted(elems, key=lambda e: e.id in readers)
    for root in roots:
        if root.id in state:
            continue
        path = [root]
        stack = [iter(upstream(root))]
        state[root.id] = 1
        while stack:
            nxt = next(stack[-1], None)
            if nxt is None:
                state[path.pop().id] = 2
                stack.pop()
                continue
            if state.get(nxt) == 2:
                continue
            src = by_id[nxt]
            if state.get(nxt) == 1:
                start = next(k for k, p in enumerate(path) if p.id == nxt)
                raise GraphError(_loop_message(path[start:], language), src.line, src.id)
            state[nxt] = 1
            path.append(src)
            stack.append(iter(upstream(src)))


def _loop_message(loop: list[Element], language: str) -> str:
    """loop[0] is the element the loop comes back into, each next element feeds the one before it."""
    what = "power flow" if language == "LD" else "the signal"
    head = loop[0]
    how = ": its input is wired to its own output" if len(loop) == 1 else \
        " through " + ", ".join(_name(e) for e in reversed(loop[1:]))
    return (f"{what} loops back into {_name(head)}{how}; no block or in-out variable on the loop holds a value, "
            "so the loop has no meaning in IEC 61131-3")
