"""The order in which the networks (rungs) of an LD or FBD body run (docs/ladder.md, "Order of rungs").

With an `executionOrderId` > 0 on every network: that order.  Otherwise data flow between networks (a
network writing a variable before the networks reading it), top to bottom only as the tie-break and to
break cycles.  Labels split a body into parts that keep their drawn (or execution) order.
"""
from __future__ import annotations

import heapq
import re

from .graph import Element

IDENT = re.compile(r"[A-Za-z_]\w*")


def comments_by_network(elems: list[Element], nets: list[list[Element]]) -> dict[int, list[Element]]:
    """The editor's comment boxes, each given to the first network drawn below it (keyed by id(network))."""
    out: dict[int, list[Element]] = {}
    for c in (e for e in elems if e.kind == "comment"):
        below = [n for n in nets if min(e.y for e in n) >= c.y]
        if below:
            target = min(below, key=lambda n: (min(e.y for e in n), min(e.x for e in n)))
            out.setdefault(id(target), []).append(c)
    return out


def order_networks(elems: list[Element], nets: list[list[Element]]) -> list:
    """Networks and labels in execution order (labels are Elements, networks lists of Elements)."""
    labels = sorted((e for e in elems if e.kind == "label"), key=lambda e: (e.order or 0, e.key()))
    all_ordered = nets and all(any(e.order > 0 for e in n) for n in nets) and all(lb.order > 0 for lb in labels)

    def first_order(n):
        return min(e.order for e in n if e.order > 0)

    parts: list[list[list[Element]]] = [[] for _ in range(len(labels) + 1)]
    for n in nets:
        idx = 0
        for k, lb in enumerate(labels):
            if (first_order(n) > lb.order) if all_ordered else (min(e.y for e in n) >= lb.y):
                idx = k + 1
        parts[idx].append(n)
    out: list = []
    for k, part in enumerate(parts):
        if k > 0:
            out.append(labels[k - 1])
        if all_ordered:
            out.extend(sorted(part, key=first_order))
        else:
            out.extend(dataflow_order(part))
    return out


def dataflow_order(part: list[list[Element]]) -> list[list[Element]]:
    """Writers before readers (coils, output variables and block instances against contacts and input
    variables), top to bottom where nothing says otherwise or in a cycle."""
    writes, reads = [], []
    for n in part:
        w, r = set(), set()
        for e in n:
            if e.kind == "coil" or e.kind in ("outVariable", "inOutVariable"):
                m = IDENT.match(e.text)
                if m:
                    w.add(m.group(0).upper())
            if e.kind == "block" and e.instance:
                w.add(e.instance.upper())
            if e.kind in ("contact", "inVariable", "inOutVariable"):
                r.update(t.upper() for t in IDENT.findall(e.text))
        writes.append(w)
        reads.append(r)
    writers: dict[str, set[int]] = {}
    for j, w in enumerate(writes):
        for name in w:
            writers.setdefault(name, set()).add(j)
    deps = {i: set().union(*(writers.get(name, set()) for name in reads[i])) - {i} for i in range(len(part))}
    keyed = [(i, n) for i, n in enumerate(part)]
    order = topo(keyed, {i: deps[i] for i, _ in keyed},
                 lambda item: (min(e.y for e in item[1]), min(e.x for e in item[1]), min(e.id for e in item[1])),
                 ident=lambda item: item[0])
    return [n for _i, n in order]


def topo(items: list, deps: dict, key, ident=lambda a: a.id) -> list:
    """Kahn's algorithm: among ready items the smallest key first; a cycle is broken at its smallest key."""
    by_id = {ident(a): a for a in items}
    keys = {i: key(a) for i, a in by_id.items()}
    pending = {i: {d for d in deps[i] if d in by_id and d != i} for i in by_id}
    successors: dict = {i: [] for i in by_id}
    for i, ds in pending.items():
        for d in ds:
            successors[d].append(i)
    ready = [(keys[i], i) for i, ds in pending.items() if not ds]
    heapq.heapify(ready)
    remaining = set(by_id)
    out = []
    while remaining:
        if not ready:                        # a cycle: start it at its smallest key
            i = min(remaining, key=lambda n: (keys[n], n))
            heapq.heappush(ready, (keys[i], i))
        _k, i = heapq.heappop(ready)
        if i not in remaining:
            continue
        remaining.discard(i)
        out.append(by_id[i])
        for nxt in successors[i]:
            pending[nxt].discard(i)
            if not pending[nxt] and nxt in remaining:
                heapq.heappush(ready, (keys[nxt], nxt))
    return out
