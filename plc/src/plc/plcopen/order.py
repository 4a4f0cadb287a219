"""The order in which the networks (rungs) of an LD or FBD body run (docs/ladder.md, "Order of rungs").

As Beremiz's generator runs them: networks with an `executionOrderId` first, in that order; the others top to
bottom as drawn (the topmost coil or output variable of each, then left to right, then localId), so a variable
is read where the drawing reads it.  Labels split a body into parts that keep their drawn (or execution) order.
"""
from __future__ import annotations

from .graph import Element

OUTPUTS = ("coil", "outVariable", "inOutVariable")


def comments_by_network(elems: list[Element], nets: list[list[Element]]) -> dict[int, list[Element]]:
    """The editor's comment boxes, each given to the first network drawn below it (keyed by id(network))."""
    out: dict[int, list[Element]] = {}
    for c in (e for e in elems if e.kind == "comment"):
        below = [n for n in nets if min(e.y for e in n) >= c.y]
        if below:
            target = min(below, key=lambda n: (min(e.y for e in n), min(e.x for e in n)))
            out.setdefault(id(target), []).append(c)
    return out


def drawn_key(net: list[Element]) -> tuple:
    """Where a network is drawn: its topmost output (coil, output or in-out variable), else its topmost
    element; then left to right, then localId."""
    outs = [e for e in net if e.kind in OUTPUTS] or net
    return min(e.key() for e in outs)


def first_order(net: list[Element]) -> int:
    """The smallest executionOrderId > 0 of a network, 0 when it has none."""
    return min((e.order for e in net if e.order > 0), default=0)


def order_networks(elems: list[Element], nets: list[list[Element]]) -> list:
    """Networks and labels in execution order (labels are Elements, networks lists of Elements)."""
    labels = sorted((e for e in elems if e.kind == "label"), key=lambda e: (e.order or 0, e.key()))
    all_ordered = nets and all(first_order(n) for n in nets) and all(lb.order > 0 for lb in labels)
    parts: list[list[list[Element]]] = [[] for _ in range(len(labels) + 1)]
    for n in nets:
        idx = 0
        for k, lb in enumerate(labels):
            if (first_order(n) > lb.order) if all_ordered else (drawn_key(n)[0] >= lb.y):
                idx = k + 1
        parts[idx].append(n)
    out: list = []
    for k, part in enumerate(parts):
        if k > 0:
            out.append(labels[k - 1])
        numbered = sorted((n for n in part if first_order(n)), key=first_order)
        out.extend(numbered + sorted((n for n in part if not first_order(n)), key=drawn_key))
    return out
