"""The type of the value on every wire of an LD or FBD body (docs/ladder.md, "Types of block outputs").

A generated temporary needs a declared type, and a generic standard function (MOVE, SEL, MUX, LIMIT, MAX,
ADD, GT, ...) has none of its own: its type is the one its wires carry.  Every connection point is a node;
a wire, a connector/continuation pair, an in-out variable and the pins of a generic function that share one
type (ADD's inputs and output, SEL's IN0, IN1 and output, ...) join nodes into groups, and a group takes the
type of whatever typed source or sink it holds: a declared variable, a typed literal, a contact or coil, a
pin of a function block or of a function with a declared type, upstream or downstream alike.  An untyped
literal (5, 2.5) types a group only when nothing else does.
"""
from __future__ import annotations

from collections.abc import Callable

from .graph import RAILS, Element

# the input pins of a standard function that share the type of its output, by kind (plc/src/plc/stdfuncs.py);
# "*" is every input but EN and the pins listed after it
SAME_AS_OUT = {"num1": ("IN",), "real1": ("IN",), "move": ("IN",), "not": ("IN",), "shift": ("IN",),
               "expt": ("IN1",), "limit": ("MN", "IN", "MX"), "sel": ("IN0", "IN1"), "arith": ("*",),
               "minmax": ("*",), "logic": ("*",), "mux": ("*", "K")}
SAME_INPUTS = {"compare": ("*",)}          # inputs of one type, the output fixed (BOOL)
BOOL_PINS = {"sel": ("G",)}


class WireTypes:
    """Union-find over connection points: ("o", localId, pin) for outputs, ("i", localId, pin) for inputs."""

    def __init__(self, elems: list[Element], connectors: dict[str, Element], sig, expr_type: Callable,
                 fixed_results: dict[str, str]):
        self.parent: dict[tuple, tuple] = {}
        self.strong: dict[tuple, str] = {}       # root -> type from a declaration, a typed literal, a pin type
        self.weak: dict[tuple, str] = {}         # root -> type of an untyped literal
        self.sig = sig
        self.expr_type = expr_type
        self.fixed_results = fixed_results
        for e in elems:
            self.element(e, connectors)
        for e in elems:
            for pin, p in e.inputs.items():
                if len(p.refs) == 1:
                    r = p.refs[0]
                    self.union(("i", e.id, pin), ("o", r.source, r.pin))
                elif len(p.refs) > 1:                       # a wired OR
                    self.give(("i", e.id, pin), "BOOL")
                    for r in p.refs:
                        self.give(("o", r.source, r.pin), "BOOL")

    # ------------------------------------------------------------------ union-find --
    def find(self, k: tuple) -> tuple:
        self.parent.setdefault(k, k)
        while self.parent[k] != k:
            self.parent[k] = self.parent[self.parent[k]]
            k = self.parent[k]
        return k

    def union(self, a: tuple, b: tuple) -> None:
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return
        self.parent[rb] = ra
        for table in (self.strong, self.weak):
            if rb in table:
                table.setdefault(ra, table.pop(rb))

    def give(self, k: tuple, t: str | None, weak: bool = False) -> None:
        if t:
            (self.weak if weak else self.strong).setdefault(self.find(k), t.upper())

    def type_of(self, k: tuple) -> str | None:
        r = self.find(k)
        return self.strong.get(r) or self.weak.get(r)

    # -------------------------------------------------------------------- elements --
    def literal(self, k: tuple, text: str, negated: bool = False) -> None:
        if negated:
            self.give(k, "BOOL")
            return
        t = self.expr_type(text)
        untyped = "#" not in text and text.strip().upper() not in ("TRUE", "FALSE")
        self.give(k, t, weak=untyped and t in ("INT", "REAL") and not self.declared(text))

    def declared(self, text: str) -> bool:
        return self.expr_type(text) is not None and text.strip()[:1].isalpha()

    def element(self, e: Element, connectors: dict[str, Element]) -> None:
        o, i = ("o", e.id, ""), ("i", e.id, "")
        if e.kind in ("contact", "coil") or e.kind in RAILS or e.kind in ("jump", "return"):
            self.give(o, "BOOL")
            self.give(i, "BOOL")
        elif e.kind == "inVariable":
            self.literal(o, e.text, e.negated or e.edge in ("rising", "falling"))
        elif e.kind == "outVariable":
            self.literal(i, e.text, e.negated)
        elif e.kind == "inOutVariable":
            if e.negated or e.inputs[""].negated:
                self.give(o, "BOOL")
                self.give(i, "BOOL")
            else:
                self.union(i, o)
                self.literal(o, e.text)
        elif e.kind == "continuation":
            conn = connectors.get(e.text.upper())
            if conn is not None:
                self.union(o, ("i", conn.id, ""))
        elif e.kind == "block":
            self.block(e)

    def block(self, e: Element) -> None:
        s = self.sig(e)
        for pin in e.inouts:
            self.union(("i", e.id, pin), ("o", e.id, pin))
        for pin in ("EN", "ENO"):
            self.give(("i" if pin == "EN" else "o", e.id, pin), "BOOL")
        for pin, p in e.inputs.items():
            if p.negated or p.edge in ("rising", "falling"):
                self.give(("i", e.id, pin), "BOOL")
            self.give(("i", e.id, pin), s.inputs.get(pin))
        for pin, p in e.outputs.items():
            if p.negated:
                self.give(("o", e.id, pin), "BOOL")
            self.give(("o", e.id, pin), s.outputs.get(pin))
        if s.kind == "FUNCTION" and "OUT" in e.outputs:
            self.give(("o", e.id, "OUT"), s.ret)
        if s.kind != "STD":
            return
        self.give(("o", e.id, "OUT"), self.fixed_results.get(s.std_kind))
        for pin in BOOL_PINS.get(s.std_kind, ()):
            self.give(("i", e.id, pin), "BOOL")
        for table, with_out in ((SAME_AS_OUT, True), (SAME_INPUTS, False)):
            spec = table.get(s.std_kind)
            if spec is None:
                continue
            pins = [p for p in e.inputs if p != "EN" and p not in spec[1:]] if spec[0] == "*" else \
                [p for p in spec if p in e.inputs]
            keys = [("i", e.id, p) for p in pins] + ([("o", e.id, "OUT")] if with_out and "OUT" in e.outputs else [])
            for k in keys[1:]:
                self.union(keys[0], k)
