"""LD and FBD bodies as Structured Text (docs/ladder.md states the rules this module implements).

Power flow is evaluated once per network: every element's output is computed one time, and a value
used more than once (a contact feeding coils in series or in parallel, a block output feeding two
blocks) goes into a temporary at its first use, so a coil that resets the variable of a contact does
not change what the coils after it receive (OpenPLC Editor #836).

The networks run in the order order.py gives them; forward jumps skip the networks up to their label.
Inside a network the actions (coils, blocks, output variables, jump, return) run in data-flow order
(execution order when every action has one), top-to-bottom as the tie-break; a block output read
before its block runs (feedback) gives the value of the previous scan.
"""
from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass, field

from .graph import RAILS, Element, GraphError, check_connectors, check_loops, check_refs, networks, read_elements
from .order import OUTPUTS, comments_by_network, order_networks
from .stexpr import AND_P, ATOM, FALSE, NOT_P, OR_P, SIMPLE, TRUE, Ex, Line, and_, cat, expr_of, join, not_, or_, tag
from .wiretypes import WireTypes

CONVERSION = re.compile(r"^(\w+)_TO_(\w+)$", re.I)
# standard functions that are operators in ST (they cannot be called by name), with their precedence
OPERATORS = {"AND": AND_P, "OR": OR_P, "XOR": 4, "NOT": NOT_P, "MOD": 7}
# the result type of a standard function of a fixed type, by its kind in plc/src/plc/stdfuncs.py (the others
# take the type of their generic inputs: wiretypes.SAME_AS_OUT)
STD_RESULT_TYPE = {"compare": "BOOL", "len": "INT", "find": "INT", "strint": "STRING", "mid": "STRING",
                   "concat": "STRING", "insert": "STRING", "delete": "STRING", "replace": "STRING", "trunc": "DINT"}


@dataclass
class Sig:
    """What the translation needs to know about a callable: kind, result type and pin types."""
    kind: str                                        # FUNCTION | FUNCTION_BLOCK | STD (standard function)
    ret: str | None = None
    inputs: dict[str, str] = field(default_factory=dict)
    outputs: dict[str, str] = field(default_factory=dict)
    std_kind: str = ""


@dataclass
class Context:
    """The POU being translated: its kind, the types of the names it sees, the callables it can use."""
    pou: str
    pou_kind: str
    var_types: dict[str, str]                        # upper-case name -> ST type text
    sigs: dict[str, Sig]                             # upper-case type name -> signature
    taken: set[str]                                  # upper-case names already declared


@dataclass
class BodyST:
    lines: list[Line]
    decls: list[tuple[str, str, str, int | None]]    # (name, type, comment, localId) of generated variables
    networks: int
    warnings: list[tuple[str, Element]] = field(default_factory=list)


class Translator:
    """One body: two passes over the actions of every network, the first counting how often each value is
    read, the second writing the ST (a value read more than once gets a temporary)."""

    def __init__(self, elems: list[Element], ctx: Context, language: str):
        self.ctx = ctx
        self.language = language
        self.elems = elems
        self.by_id = {e.id: e for e in elems}
        self.decls: list[tuple[str, str, str, int | None]] = []
        self.names: dict[tuple, str] = {}
        self.connectors = {e.text.upper(): e for e in elems if e.kind == "connector"}
        self.labels = {e.text.upper(): e.text for e in elems if e.kind == "label"}
        self.cyclic: set[int] = set()

    # ------------------------------------------------------------------ naming --
    def fresh(self, base: str, type_text: str, comment: str, key: tuple) -> str:
        if key in self.names:
            return self.names[key]
        name = base
        n = 2
        while name.upper() in self.ctx.taken:
            name = f"{base}x{n}"
            n += 1
        self.ctx.taken.add(name.upper())
        self.names[key] = name
        self.decls.append((name, type_text, comment, key[1] if isinstance(key[1], int) else None))
        return name

    # --------------------------------------------------------------- value keys --
    def key_out(self, eid: int, pin: str):
        e = self.by_id[eid]
        if e.kind == "coil":
            # a coil passes its input flow on; with nothing wired into it that flow is FALSE
            return self.key_in(eid, "") or ("false", eid, "")
        if e.kind == "continuation":
            conn = self.connectors.get(e.text.upper())
            if conn is None:
                raise GraphError(f"continuation '{e.text}' has no connector of that name", e.line, e.id)
            return self.key_in(conn.id, "")
        return ("o", eid, pin)

    def key_in(self, eid: int, pin: str):
        refs = self.by_id[eid].inputs[pin].refs
        if not refs:
            return None
        if len(refs) == 1:
            return self.key_out(refs[0].source, refs[0].pin)
        return ("i", eid, pin)

    # ----------------------------------------------------------------- values --
    def value(self, key, out: list[Line]) -> Ex | None:
        if key is None:
            return None
        if self.counting:
            self.counts[key] += 1
            if self.counts[key] == 1:
                self.compute(key, out)
            return Ex("?")
        if key in self.temps:
            return self.temps[key]
        if key in self.in_progress:
            e = self.by_id[key[1]]
            raise GraphError(f"{e.kind} {e.id} feeds its own input with no block in between (a loop of "
                             "power flow)", e.line, e.id)
        self.in_progress.add(key)
        ex = self.compute(key, out)
        self.in_progress.discard(key)
        if self.counts[key] > 1 and not ex.stable:
            name = self.temp_for(key)
            out.append(Line.of(key[1], name, " := ", ex, ";"))
            ex = Ex(name, ATOM, True)
            self.temps[key] = ex
        return ex

    def temp_for(self, key) -> str:
        kind, eid, pin = key
        e = self.by_id[eid]
        if kind == "i":
            return self.fresh(f"join{eid}", "BOOL", f"wired OR into {e.kind} {eid}", key)
        if e.kind == "block":
            t = self.output_type(e, pin)
            return self.fresh(f"{(pin or 'out').lower()}{eid}", t, f"output {pin} of {e.type_name} {eid}", key)
        t = "BOOL" if e.kind in ("contact", "leftPowerRail") or e.negated else \
            self.expr_type(e.text) or self.wires.type_of(("o", eid, ""))
        if t is None:
            raise GraphError(f"cannot tell the type of '{e.text}' ({e.kind} {eid}), read by several elements",
                             e.line, eid)
        return self.fresh(f"flow{eid}", t, f"power flow out of {e.kind} {eid}", key)

    def compute(self, key, out: list[Line]) -> Ex:
        kind, eid, pin = key
        e = self.by_id[eid]
        if kind == "false":
            return FALSE
        if kind == "i":
            vals = [self.value(self.key_out(r.source, r.pin), out) for r in e.inputs[pin].refs]
            return or_(vals) if not self.counting else Ex("?")
        if e.kind == "leftPowerRail":
            return TRUE
        if e.kind == "contact":
            flow = self.value(self.key_in(eid, ""), out)
            if self.counting:
                return Ex("?")
            return and_(flow if flow is not None else FALSE, self.contact_term(e, out))
        if e.kind in ("inVariable", "inOutVariable"):
            # a variable is read where it is used, even when several elements read it (docs/ladder.md)
            ex = tag(expr_of(e.text), eid)
            if e.kind == "inVariable" and e.edge in ("rising", "falling"):
                ex = self.edge(e, "", ex, out)
            ex = not_(ex) if e.negated else ex
            return Ex(ex.text, ex.prec, True, ex.spans)
        if e.kind == "block":
            return self.block_output(e, pin, out)
        raise GraphError(f"{e.kind} {eid} has no output to read", e.line, eid)

    def contact_term(self, e: Element, out: list[Line]) -> Ex:
        var = tag(expr_of(e.text), e.id)
        if e.edge in ("rising", "falling"):
            if e.negated:
                raise GraphError("a contact is either negated or edge-sensing, not both", e.line, e.id)
            return self.edge(e, "", var, out)
        return not_(var) if e.negated else var

    def edge(self, e: Element, pin: str, clk: Ex, out: list[Line]) -> Ex:
        """Call an R_TRIG/F_TRIG named after the element's localId (and pin) and read its Q."""
        if self.ctx.pou_kind == "FUNCTION":
            raise GraphError("an edge needs memory between calls: not possible in a FUNCTION (use a "
                             "FUNCTION_BLOCK)", e.line, e.id)
        fb, base = ("R_TRIG", "rise") if e.edge == "rising" else ("F_TRIG", "fall")
        name = self.fresh(f"{base}{e.id}{pin.capitalize()}", fb, f"{e.edge} edge of {e.kind} {e.id}",
                          ("edge", e.id, pin))
        if not self.counting:
            out.append(Line.of(e.id, f"{name}(CLK := ", clk, ");"))
        return Ex(f"{name}.Q", ATOM, True)

    # ------------------------------------------------------------------ blocks --
    def sig(self, e: Element) -> Sig:
        s = self.ctx.sigs.get(e.type_name.upper())
        if s is None:
            m = CONVERSION.match(e.type_name)
            if m:
                return Sig("STD", ret=m.group(2).upper(), inputs={"IN": ""}, outputs={"OUT": m.group(2).upper()})
            # declared in an ST file of the same build (the compiler checks it): an instance name makes it
            # a function block, otherwise a function
            return Sig("FUNCTION_BLOCK" if e.instance else "FUNCTION")
        return s

    def is_fb(self, e: Element) -> bool:
        return self.sig(e).kind == "FUNCTION_BLOCK"

    def fb_instance(self, e: Element) -> str:
        if not e.instance:
            raise GraphError(f"function block {e.type_name} ({e.id}) has no instanceName", e.line, e.id)
        if e.instance.upper() not in self.ctx.var_types:
            self.ctx.var_types[e.instance.upper()] = e.type_name
            if e.instance.upper() not in self.ctx.taken:
                self.ctx.taken.add(e.instance.upper())
                self.decls.append((e.instance, e.type_name, f"instance of block {e.id}", e.id))
        return e.instance

    def pure_function(self, e: Element) -> bool:
        """A function block with one output, no EN/ENO: its call is an expression."""
        if self.is_fb(e) or e.id in self.cyclic:
            return False
        en = e.inputs.get("EN")
        return ((en is None or not en.refs) and set(e.outputs) <= {"OUT", "ENO"}
                and not self.eno_used(e) and not e.inouts)

    def eno_used(self, e: Element) -> bool:
        return self.reads.get((e.id, "ENO"), 0) > 0

    def block_output(self, e: Element, pin: str, out: list[Line]) -> Ex:
        if self.is_fb(e):
            inst = self.fb_instance(e)
            if pin == "ENO":
                ex = Ex(self.fresh(f"eno{e.id}", "BOOL", f"ENO of block {e.id}", ("o", e.id, "ENO")), ATOM, True)
            else:
                ex = Ex(f"{inst}.{e.pin_text.get(pin, pin)}", ATOM, True)
        elif pin in e.inouts:
            ex = self.block_args(e, out, inout_only=pin)
        elif self.pure_function(e):
            ex = self.call_expr(e, out)
            if self.counting:
                return Ex("?")
        else:
            key = ("o", e.id, pin)
            self.temp_needed.add(key)
            if self.counting:
                return Ex("?")
            ex = Ex(self.temp_name(e, pin), ATOM, True)
        return not_(ex) if e.outputs[pin].negated else ex

    def call_expr(self, e: Element, out: list[Line]) -> Ex:
        """The call of a function block's function as an expression; AND, OR, XOR, NOT and MOD are
        operators in ST (they cannot be called by name)."""
        op = e.type_name.upper()
        if op in OPERATORS:
            vals = self.block_values(e, out)
            if self.counting:
                return Ex("?")
            if op == "NOT":
                return not_(vals[0]) if vals else FALSE
            prec = OPERATORS[op]
            return tag(cat(*join(f" {op} ", [v.at(prec + 1) for v in vals]), prec=prec), e.id)
        return tag(cat(f"{e.type_name}(", self.block_args(e, out), ")"), e.id)

    def block_values(self, e: Element, out: list[Line]) -> list[Ex]:
        vals = []
        for pin_name, pin in e.inputs.items():
            if pin_name == "EN" or not pin.refs:
                continue
            v = self.value(self.key_in(e.id, pin_name), out)
            if not self.counting and pin.negated:
                v = not_(v)
            vals.append(v)
        return vals

    def temp_name(self, e: Element, pin: str) -> str:
        if pin == "ENO":
            return self.fresh(f"eno{e.id}", "BOOL", f"ENO of block {e.id}", ("o", e.id, "ENO"))
        return self.temp_for(("o", e.id, pin))

    def output_type(self, e: Element, pin: str) -> str:
        """The type of a block output, from whatever typed reaches its wires (wiretypes.py)."""
        if pin == "ENO":
            return "BOOL"
        t = self.wires.type_of(("o", e.id, pin))
        if t:
            return t
        raise GraphError(f"cannot tell the type of output {pin} of {e.type_name} ({e.id}): nothing typed is wired "
                         "to it, upstream or downstream; give one of its inputs or the variable it feeds a "
                         "declared type, or use a typed literal (INT#5)", e.line, e.id)

    def expr_type(self, text: str) -> str | None:
        t = text.strip()
        up = t.upper()
        if up in self.ctx.var_types:
            return self.ctx.var_types[up]
        m = re.match(r"^([A-Za-z_]\w*)\s*\.\s*([A-Za-z_]\w*)$", t)
        if m:                            # a pin of a function block instance: timer.ET
            s = self.ctx.sigs.get(self.ctx.var_types.get(m.group(1).upper(), "").upper())
            pin = m.group(2).upper()
            if s is not None and s.kind == "FUNCTION_BLOCK":
                return s.outputs.get(pin) or s.inputs.get(pin) or None
        if up in ("TRUE", "FALSE"):
            return "BOOL"
        m = re.match(r"^([A-Za-z_]+)#", t)
        if m:
            p = m.group(1).upper()
            return {"T": "TIME", "TIME": "TIME", "D": "DATE", "DATE": "DATE", "TOD": "TOD", "TIME_OF_DAY": "TOD",
                    "DT": "DT", "DATE_AND_TIME": "DT"}.get(p, p)
        if re.match(r"^[+-]?\d[\d_]*$", t):
            return "INT"
        if re.match(r"^[+-]?\d[\d_]*\.\d+([eE][+-]?\d+)?$", t):
            return "REAL"
        return None

    def block_args(self, e: Element, out: list[Line], inout_only: str | None = None) -> Ex:
        args = []
        for pin_name, pin in e.inputs.items():
            if pin_name in ("EN",) or not pin.refs:
                continue
            if pin_name in e.inouts:
                src = self.by_id[pin.refs[0].source] if len(pin.refs) == 1 else None
                if src is None or src.kind not in ("inVariable", "inOutVariable") or not SIMPLE.match(src.text):
                    raise GraphError(f"in-out {pin_name} of {e.type_name} ({e.id}) must be wired to a variable",
                                     e.line, e.id)
                if inout_only == pin_name:
                    return tag(Ex(src.text, ATOM), src.id)
                args.append(cat(f"{e.pin_text.get(pin_name, pin_name)} := ", tag(Ex(src.text), src.id)))
                continue
            v = self.value(self.key_in(e.id, pin_name), out)
            if self.counting:
                continue
            if pin.edge in ("rising", "falling"):
                fake = Element(e.id, "block pin", e.line, 0, 0, 0, edge=pin.edge)
                v = self.edge(fake, pin_name, v, out)
            if pin.negated:
                v = not_(v)
            args.append(cat(f"{e.pin_text.get(pin_name, pin_name)} := ", v))
        return cat(*join(", ", args))

    def block_action(self, e: Element, out: list[Line]) -> None:
        en = None
        if "EN" in e.inputs and e.inputs["EN"].refs:
            en = self.value(self.key_in(e.id, "EN"), out)
            if en is not None and en.text == "TRUE":
                en = None
        args = self.block_args(e, out) if e.type_name.upper() not in OPERATORS else Ex("")
        if self.counting:
            if e.type_name.upper() in OPERATORS:
                self.call_expr(e, out)
            if self.is_fb(e):
                self.fb_instance(e)
            return
        parts = [cat("EN := ", en)] if en is not None else []
        if args.text:
            parts.append(args)
        if self.is_fb(e):
            inst = self.fb_instance(e)
            if self.eno_used(e):
                parts.append(f"ENO => {self.temp_name(e, 'ENO')}")
            out.append(Line.of(e.id, f"{inst}(", *join(", ", parts), ");"))
            return
        if self.pure_function(e):
            return                      # evaluated where its output is read
        if e.type_name.upper() in OPERATORS:
            expr = self.call_expr(e, out)
            target = self.temp_name(e, "OUT")
            if en is None:
                out.append(Line.of(e.id, f"{target} := ", expr, ";"))
            else:
                out.append(Line.of(e.id, "IF ", en, f" THEN {target} := ", expr, "; END_IF;"))
            if self.eno_used(e):
                out.append(Line.of(e.id, f"{self.temp_name(e, 'ENO')} := ", en if en is not None else TRUE, ";"))
            return
        if self.eno_used(e):
            parts.append(f"ENO => {self.temp_name(e, 'ENO')}")
        for pin in e.outputs:
            if pin not in ("OUT", "ENO") and pin not in e.inouts and self.reads.get((e.id, pin)):
                parts.append(f"{e.pin_text.get(pin, pin)} => {self.temp_name(e, pin)}")
        call = cat(f"{e.type_name}(", *join(", ", parts), ")")
        result = self.result_temp(e)
        if result is not None:
            out.append(Line.of(e.id, f"{result} := ", call, ";"))
        else:
            out.append(Line.of(e.id, call, ";"))

    def result_temp(self, e: Element) -> str | None:
        """Where a function's result goes: its OUT temporary, read or not (a bare function call is no statement
        in MATIEC); None when the result's type is unknown (nothing typed wired, a generic result)."""
        if self.reads.get((e.id, "OUT")):
            return self.temp_name(e, "OUT")
        key = ("o", e.id, "OUT")
        t = self.wires.type_of(key) if "OUT" in e.outputs else None
        ret = self.sig(e).ret
        if t is None and ret and not ret.upper().startswith("ANY"):
            t = ret
        if t is None:
            return None
        return self.fresh(f"out{e.id}", t, f"output OUT of {e.type_name} {e.id} (not read)", key)

    # ----------------------------------------------------------------- actions --
    def is_action(self, e: Element) -> bool:
        if e.kind == "block":
            return not self.pure_function(e)
        return e.kind in ("coil", "outVariable", "inOutVariable", "jump", "return")

    def action(self, e: Element, out: list[Line]) -> None:
        if e.kind == "block":
            self.block_action(e, out)
            return
        flow = self.value(self.key_in(e.id, ""), out)
        if self.counting:
            return
        if flow is None:
            if e.kind in ("coil", "jump", "return"):
                self.warnings.append((f"{e.kind} {e.id} has no power flow wired to it: it never acts", e))
            flow = FALSE
        if e.kind == "coil":
            self.coil(e, flow, out)
        elif e.kind in ("outVariable", "inOutVariable"):
            if e.kind == "inOutVariable" and e.inputs[""].negated:
                flow = not_(flow)
            val = not_(flow) if e.kind == "outVariable" and e.negated else flow
            blk = self.eno_guard(e)
            if blk is None:
                out.append(Line.of(e.id, tag(Ex(e.text), e.id), " := ", val, ";"))
            else:
                out.append(Line.of(e.id, f"IF {self.temp_name(blk, 'ENO')} THEN ", tag(Ex(e.text), e.id), " := ",
                                   val, "; END_IF;"))
        elif e.kind == "jump":
            out.append(Line.of(e.id, f"{self.jump_flag(e.text)} := ", flow, ";"))
        elif e.kind == "return":
            if flow.text == "TRUE":
                out.append(Line("RETURN;", e.id))
            else:
                out.append(Line.of(e.id, "IF ", flow, " THEN RETURN; END_IF;"))

    def eno_guard(self, e: Element) -> Element | None:
        """The block whose ENO guards the write of an output or in-out variable: one wired straight from an
        output of a block with EN connected (Beremiz writes the variable only when the block ran, so it keeps
        its value while EN is FALSE)."""
        refs = e.inputs[""].refs
        if len(refs) != 1 or refs[0].pin == "ENO":
            return None
        src = self.by_id[refs[0].source]
        if src.kind == "block" and "EN" in src.inputs and src.inputs["EN"].refs and refs[0].pin not in src.inouts:
            return src
        return None

    def coil(self, e: Element, flow: Ex, out: list[Line]) -> None:
        if e.negated and e.storage != "none":
            raise GraphError(f"a negated {e.storage} coil has no meaning in IEC 61131-3: use a {e.storage} coil "
                             "after a negated contact", e.line, e.id)
        if e.edge in ("rising", "falling"):
            flow = self.edge(e, "", flow, out)
        var = tag(Ex(e.text), e.id)
        if e.storage == "set":
            out.append(Line.of(e.id, "IF ", flow, " THEN ", var, " := TRUE; END_IF;"))
        elif e.storage == "reset":
            out.append(Line.of(e.id, "IF ", flow, " THEN ", var, " := FALSE; END_IF;"))
        else:
            out.append(Line.of(e.id, var, " := ", not_(flow) if e.negated else flow, ";"))

    def jump_flag(self, label: str) -> str:
        spelled = self.labels.get(label.upper(), label)
        return self.fresh(f"skipTo{spelled}", "BOOL", f"a jump to label {spelled} was taken",
                          ("jump", label.upper()))

    # --------------------------------------------------------------- ordering --
    def upstream_actions(self, e: Element) -> list[Element]:
        """The actions whose outputs reach e's inputs through pure elements (contacts, variables, functions
        written inline, connector/continuation pairs), in pin order, depth first."""
        found: dict[int, Element] = {}
        seen: set[int] = set()

        def walk(eid: int) -> None:
            for p in self.by_id[eid].inputs.values():
                for r in p.refs:
                    src = self.by_id[r.source]
                    if src.id in seen or src.kind in RAILS:
                        continue
                    seen.add(src.id)
                    if self.is_action(src):
                        found.setdefault(src.id, src)
                    elif src.kind == "continuation":
                        conn = self.connectors.get(src.text.upper())
                        if conn is not None and conn.id not in seen:
                            seen.add(conn.id)
                            walk(conn.id)
                    else:
                        walk(src.id)

        walk(e.id)
        return list(found.values())

    def blocks_in_cycles(self) -> set[int]:
        """Blocks whose output comes back to one of their inputs by wires (feedback with no variable on the
        loop): they run as statements, and the wire that closes the loop reads the value of the previous scan.
        An in-out variable on the loop breaks it: the block reads the variable."""
        found = set()
        for e in self.elems:
            if e.kind != "block":
                continue
            stack = [r.source for p in e.inputs.values() for r in p.refs]
            seen: set[int] = set()
            while stack:
                i = stack.pop()
                if i == e.id:
                    found.add(e.id)
                    break
                if i in seen:
                    continue
                seen.add(i)
                src = self.by_id[i]
                if src.kind == "inOutVariable":
                    continue
                if src.kind == "continuation" and src.text.upper() in self.connectors:
                    stack.append(self.connectors[src.text.upper()].id)
                stack.extend(r.source for p in src.inputs.values() for r in p.refs)
        return found

    def action_order(self, net: list[Element]) -> list[Element]:
        """The actions of a network in the order Beremiz's generator runs them: those with an
        executionOrderId first, in that order; then the outputs (coils, output and in-out variables) as drawn,
        top to bottom then left to right, each after the actions it reads (depth first, in pin order); then
        the blocks left over, as drawn; jump and return last.  An action met again while its own inputs are
        being evaluated (a feedback loop) is not waited for: the loop reads its value of the previous scan,
        or, for an in-out variable, the variable."""
        acts = [e for e in net if self.is_action(e)]
        late = {"jump": 1, "return": 1}
        numbered = sorted((a for a in acts if a.order > 0), key=lambda a: (late.get(a.kind, 0), a.order, a.id))
        rest = sorted((a for a in acts if a.order <= 0),
                      key=lambda a: (late.get(a.kind, 0), a.kind not in OUTPUTS, a.key()))
        out: list[Element] = []
        done: set[int] = {a.id for a in numbered}
        visiting: set[int] = set()

        def visit(a: Element) -> None:
            if a.id in done or a.id in visiting:
                return
            visiting.add(a.id)
            for u in self.upstream_actions(a):
                if u.network == a.network:
                    visit(u)
            visiting.discard(a.id)
            done.add(a.id)
            out.append(a)

        for a in rest:
            visit(a)
        head = [a for a in numbered if a.kind not in late]
        return head + [a for a in out if a.kind not in late] + [a for a in numbered if a.kind in late] + \
            [a for a in out if a.kind in late]

    # -------------------------------------------------------------- translate --
    def run(self) -> BodyST:
        check_refs(self.elems)
        check_connectors(self.elems)
        check_loops(self.elems, self.language)
        self.wires = WireTypes(self.elems, self.connectors, self.sig, self.expr_type, STD_RESULT_TYPE)
        self.warnings: list[tuple[str, Element]] = []
        self.reads = Counter()
        for e in self.elems:
            for p in e.inputs.values():
                for r in p.refs:
                    self.reads[(r.source, r.pin)] += 1
        for e in self.elems:
            if e.kind in ("outVariable", "inOutVariable") and self.eno_guard(e) is not None:
                self.reads[(self.eno_guard(e).id, "ENO")] += 1
        self.cyclic = self.blocks_in_cycles()
        nets = networks(self.elems)
        ordered = order_networks(self.elems, nets)
        self.comments = comments_by_network(self.elems, nets)
        # pass 1 counts how often each value is read; pass 2 writes the ST
        self.counting, self.counts, self.temps, self.temp_needed = True, Counter(), {}, set()
        self.in_progress: set = set()
        for item in ordered:
            if isinstance(item, list):
                for a in self.action_order(item):
                    self.action(a, [])
        self.counting = False
        return self.emit(ordered, len(nets))

    def emit(self, ordered: list, n_networks: int) -> BodyST:
        lines: list[Line] = []
        jumps = {}            # label -> first index of a network holding a jump to it
        positions = {}        # label -> index in ordered
        for i, item in enumerate(ordered):
            if isinstance(item, Element):
                positions[item.text.upper()] = i
        for i, item in enumerate(ordered):
            if isinstance(item, list):
                for e in item:
                    if e.kind == "jump":
                        target = positions.get(e.text.upper())
                        if target is None:
                            raise GraphError(f"jump to label '{e.text}', which this body does not have",
                                             e.line, e.id)
                        if target <= i:
                            return self.emit_segments(ordered, positions, n_networks)
                        jumps.setdefault(e.text.upper(), []).append((i, target))
        if jumps:
            lines.append(Line("(* jumps not taken yet in this call *)", None))
            for label in jumps:
                lines.append(Line(f"{self.jump_flag(label)} := FALSE;", None))
        open_guard: tuple[str, ...] = ()
        number = 0
        for i, item in enumerate(ordered):
            guard = tuple(sorted(self.jump_flag(lb) for lb, spans in jumps.items()
                                 if any(a < i < t for a, t in spans)))
            if guard != open_guard:
                if open_guard:
                    lines.append(Line("END_IF;", None))
                if guard:
                    lines.append(Line(f"IF NOT ({' OR '.join(guard)}) THEN" if len(guard) > 1
                                      else f"IF NOT {guard[0]} THEN", None))
                open_guard = guard
            ind = "    " if guard else ""
            if isinstance(item, Element):
                lines.append(Line(f"{ind}(* label {item.text} *)", item.id))
                continue
            number += 1
            lines.append(Line(f"{ind}(* {self.describe(item, number)} *)", min(e.id for e in item)))
            body: list[Line] = []
            for a in self.action_order(item):
                self.action(a, body)
            lines.extend(Line(ind + ln.text, ln.local_id,
                              tuple((a + len(ind), b + len(ind), i) for a, b, i in ln.spans))
                         for ln in body)
        if open_guard:
            lines.append(Line("END_IF;", None))
        return BodyST(lines, self.decls, n_networks, self.warnings)

    def emit_segments(self, ordered: list, positions: dict, n_networks: int) -> BodyST:
        """A body with a backward jump: the labels cut it into segments, run by a loop over a segment number.

            segment := 0;
            WHILE segment >= 0 DO
                CASE segment OF
                0: <networks up to the first label>      (a network after a taken jump is skipped)
                   IF skipToA THEN segment := 2; ELSE segment := 1; END_IF;
                1: (* label B *) ...
                END_CASE;
            END_WHILE;

        A jump sets its flag, the rest of its segment is skipped and the loop goes on at the label's segment,
        wherever it is; the last segment ends the loop. A backward jump taken on every pass loops forever,
        as on any PLC: the runtime's watchdog stops such a program."""
        segments: list[list] = [[]]
        starts: dict[str, int] = {}
        for item in ordered:
            if isinstance(item, Element):
                starts[item.text.upper()] = len(segments)
                segments.append([item])
            else:
                segments[-1].append(item)
        seg = self.fresh("segment", "INT", "the part of the body between two labels that runs next",
                         ("segment", 0))
        all_flags = sorted({self.jump_flag(e.text) for item in ordered if isinstance(item, list)
                            for e in item if e.kind == "jump"})
        lines: list[Line] = [Line(f"{seg} := 0;", None), Line(f"WHILE {seg} >= 0 DO", None),
                             Line(f"    CASE {seg} OF", None)]
        number = 0
        for k, items in enumerate(segments):
            lines.append(Line(f"    {k}:", None))
            ind = " " * 8
            lines.extend(Line(f"{ind}{f} := FALSE;", None) for f in all_flags)   # taken in this pass only
            flags: list[tuple[str, int]] = []       # jumps of this segment so far: flag, target segment
            for item in items:
                guard = list(dict.fromkeys(f for f, _t in flags))
                if isinstance(item, Element):
                    lines.append(Line(f"{ind}(* label {item.text} *)", item.id))
                    continue
                number += 1
                body: list[Line] = []
                for a in self.action_order(item):
                    self.action(a, body)
                g = ind + "    " if guard else ind
                if guard:
                    lines.append(Line(f"{ind}IF NOT ({' OR '.join(guard)}) THEN", None))
                lines.append(Line(f"{g}(* {self.describe(item, number)} *)", min(e.id for e in item)))
                lines.extend(Line(g + ln.text, ln.local_id, tuple((a + len(g), b + len(g), i) for a, b, i in ln.spans))
                             for ln in body)
                if guard:
                    lines.append(Line(f"{ind}END_IF;", None))
                for e in item:
                    if e.kind == "jump":
                        flags.append((self.jump_flag(e.text), starts[e.text.upper()]))
            after = k + 1 if k + 1 < len(segments) else -1
            if flags:
                for j, (flag, target) in enumerate(flags):
                    lines.append(Line(f"{ind}{'IF' if j == 0 else 'ELSIF'} {flag} THEN {seg} := {target};", None))
                lines.append(Line(f"{ind}ELSE {seg} := {after};", None))
                lines.append(Line(f"{ind}END_IF;", None))
            else:
                lines.append(Line(f"{ind}{seg} := {after};", None))
        lines += [Line("    END_CASE;", None), Line("END_WHILE;", None)]
        return BodyST(lines, self.decls, n_networks, self.warnings)

    def describe(self, net: list[Element], number: int) -> str:
        word = "rung" if self.language == "LD" else "network"
        ids = ", ".join(str(e.id) for e in sorted(net, key=lambda e: e.id))
        text = f"{word} {number} (localId {ids})"
        notes = [c.text for c in self.comments.get(id(net), [])]
        if notes:
            text += ": " + " / ".join(n.replace("(*", "( *").replace("*)", "* )") for n in notes)
        return text



def translate_body(body, ctx: Context, language: str) -> BodyST:
    """An <LD> or <FBD> element as ST lines (GraphError at the first problem)."""
    elems = read_elements(body)
    return Translator(elems, ctx, language).run()
