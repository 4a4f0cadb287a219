"""Statements: POU bodies and FUNCTIONs, one `s_<Kind>` method per statement kind, FB calls.
"""
from __future__ import annotations

from .. import ast as A
from .. import types as T
from ..diagnostics import InternalError
from ..symbols import EnumValueSym, FuncSym, VarSym
from .base import GenBase, cid


class StatementGen(GenBase):
    # ------------------------------------------------------------- POU bodies --
    def pou_body(self, pt: T.PouType) -> None:
        self.pou = pt.pou
        self.fn = None
        self.scope = pt.scope
        self.tmp = 0                # C temporaries are numbered per function: other POUs never shift them
        self.w(f"{self.linkage} void P_{pt.name}_body(P_{pt.name} *self) {{")
        self.ind += 1
        self.w("(void)self;                 /* a body may use only globals, or be empty */")
        for v in pt.scope.vars.values():
            if v.section == "VAR_TEMP":
                self.emit_init(f"self->{cid(v.name)}", v.type, v.init)
        self.fold_constants = True
        self.block(pt.pou.body)
        self.fold_constants = False
        self.ind -= 1
        self.w("}")
        self.w()
        self.pou = None

    def func_def(self, fs: FuncSym) -> None:
        self.pou = fs.pou
        self.fn = fs
        self.scope = fs.scope
        self.tmp = 0
        self.w(self.func_proto(fs) + " {")
        self.ind += 1
        self.w(f"{self.ctype(fs.ret)} RESULT__;")
        for v in fs.scope.params():
            self.w(f"(void){cid(v.name)};")
        self.w("*ENO__ = 1;")
        self.emit_init("RESULT__", fs.ret, None)
        for v in fs.scope.vars.values():
            if v.section in ("VAR", "VAR_TEMP"):
                self.w(f"{self.ctype(v.type)} {cid(v.name)};")
                self.emit_init(cid(v.name), v.type, v.init)
                self.w(f"(void){cid(v.name)};")        # a local may be set and never read
            elif v.section == "VAR_OUTPUT":
                self.emit_init(f"(*{cid(v.name)})", v.type, v.init)
        self.fold_constants = True
        self.block(fs.pou.body)
        self.fold_constants = False
        self.w("return RESULT__;")
        self.ind -= 1
        self.w("}")
        self.w()
        self.fn = None
        self.pou = None

    # --------------------------------------------------------------- statements --
    def block(self, stmts: list[A.Stmt]) -> None:
        for s in stmts:
            self.stmt(s)

    def stmt(self, s: A.Stmt) -> None:
        """One statement, by its kind's `s_<Kind>` method; a kind without one is a compiler bug."""
        A.handler(self, "s_", s, "the C generator", "the statement")(s)

    def s_Assign(self, s: A.Assign) -> None:
        self.w(f"{self.lv(s.target)} = {self.conv_to(s.value, s.target.ty)};")

    def s_CallStmt(self, s: A.CallStmt) -> None:
        self.call_stmt(s.call)

    def s_If(self, s: A.If) -> None:
        w = self.w
        for k, (cond, body) in enumerate(s.branches):
            w(f"{'if' if k == 0 else '} else if'} ({self.ex(cond)}) {{")
            self.ind += 1
            self.block(body)
            self.ind -= 1
        if s.orelse:
            w("} else {")
            self.ind += 1
            self.block(s.orelse)
            self.ind -= 1
        w("}")

    def s_Case(self, s: A.Case) -> None:
        self.case(s)

    def s_For(self, s: A.For) -> None:
        self.for_stmt(s)

    def s_While(self, s: A.While) -> None:
        self.w(f"while ({self.ex(s.cond)}) {{")
        self.ind += 1
        self.block(s.body)
        self.ind -= 1
        self.w("}")

    def s_Repeat(self, s: A.Repeat) -> None:
        self.w("do {")
        self.ind += 1
        self.block(s.body)
        self.ind -= 1
        self.w(f"}} while (!({self.ex(s.cond)}));")

    def s_Exit(self, s: A.Exit) -> None:
        self.w("break;")

    def s_Continue(self, s: A.Continue) -> None:
        self.w("continue;")          # in a FOR loop the C for's step clause still counts the variable on

    def s_Return(self, s: A.Return) -> None:
        self.w("return RESULT__;" if self.fn is not None else "return;")

    def s_Empty(self, s: A.Empty) -> None:
        pass

    def case(self, s: A.Case) -> None:
        self.tmp += 1
        sel = f"sel{self.tmp}"
        self.w("{")
        self.ind += 1
        self.w(f"int64_t {sel} = (int64_t)({self.ex(s.selector)});")
        first = True
        for labels, body in s.arms:
            conds = []
            for lab in labels:
                lo = self.label_value(lab.lo)
                if lab.hi is None:
                    conds.append(f"{sel} == {lo}")
                else:
                    conds.append(f"({sel} >= {lo} && {sel} <= {self.label_value(lab.hi)})")
            self.w(f"{'if' if first else '} else if'} ({' || '.join(conds) or '0'}) {{")
            first = False
            self.ind += 1
            self.block(body)
            self.ind -= 1
        if s.orelse is not None:
            if first:
                self.w("{")
            else:
                self.w("} else {")
            self.ind += 1
            self.block(s.orelse)
            self.ind -= 1
            self.w("}")
        elif not first:
            self.w("}")
        self.ind -= 1
        self.w("}")

    def label_value(self, e: A.Expr) -> str:
        if isinstance(e.sym, EnumValueSym):
            return str(e.sym.index)
        return f"INT64_C({self.const_int(e)})"

    def const_int(self, e: A.Expr) -> int:
        if isinstance(e, A.IntLit):
            return e.value
        if isinstance(e, A.Unary) and e.op == "-":
            return -self.const_int(e.operand)
        if isinstance(e, A.Unary) and e.op == "+":
            return self.const_int(e.operand)
        if isinstance(e, A.Name) and isinstance(e.sym, VarSym) and e.sym.const_value is not None:
            return int(e.sym.const_value)
        if isinstance(e, A.Binary):
            a, b = self.const_int(e.left), self.const_int(e.right)
            return {"+": a + b, "-": a - b, "*": a * b}.get(e.op, 0)
        raise InternalError(e.pos, f"the C generator cannot fold the constant {type(e).__name__}")

    def for_stmt(self, s: A.For) -> None:
        v = self.lv(s.var)
        t = T.resolve_base(s.var.ty)
        ct = self.ctype(t)
        ut = "uint" + str(t.bits) + "_t" if isinstance(t, T.Elementary) else "uint32_t"
        self.tmp += 1
        start = self.conv_to(s.start, t)        # before the loop's own variable is read from its local
        local = f"loop{self.tmp}" if self.for_in_local(s) else None
        if local is not None:
            # The loop reads its variable from a C local, which gcc keeps in a register (a store into an array of
            # the same type no longer makes it read the instance again), and writes the instance wherever the
            # local changes, so the two are equal at every point a fault, EXIT or RETURN may leave the loop.
            self.w("{")
            self.ind += 1
            self.w(f"{ct} {local};")
            self.for_locals[id(s.var.sym)] = local
            first, cur = f"{local} = {start}, {v} = {local}", local
        else:
            first, cur = f"{v} = {start}", v
        # as in MATIEC, the end and BY expressions are evaluated again on every pass
        end = self.conv_to(s.end, t)
        step = self.conv_to(s.step, t) if s.step is not None else "1"
        if s.step is None or self.const_value(s.step) is not None:
            cv = self.const_value(s.step) if s.step is not None else 1
            cond = f"{cur} <= {end}" if cv > 0 else f"{cur} >= {end}"
        else:
            cond = f"(({step}) > 0) ? ({cur} <= {end}) : ({cur} >= {end})"
        nxt = f"{cur} = PLC_ADD({ct}, {ut}, {cur}, {step})" + (f", {v} = {local}" if local is not None else "")
        self.w(f"for ({first}; {cond}; {nxt}) {{")
        self.ind += 1
        self.block(s.body)
        self.ind -= 1
        self.w("}")
        if local is not None:
            del self.for_locals[id(s.var.sym)]
            self.ind -= 1
            self.w("}")

    def for_in_local(self, s: A.For) -> bool:
        """Whether a FOR loop may read its variable from a C local: the variable is a VAR or VAR_TEMP of the
        function block or program (a FUNCTION's are C locals already), not located, of an integer type, and no
        FOR loop inside this one counts it (nothing else may write it inside the loop: the semantic passes refuse
        an assignment, an output or a VAR_IN_OUT of it; no other POU sees it)."""
        sym = s.var.sym
        if self.fn is not None or not isinstance(sym, VarSym) or sym.section not in ("VAR", "VAR_TEMP") \
                or sym.location is not None or sym.constant or not T.is_elem(sym.type, "int", "uint"):
            return False
        return not any(isinstance(n, A.For) and n.var.sym is sym for stmt in s.body for n in A.walk(stmt))

    def call_stmt(self, c: A.Call) -> None:
        if isinstance(c.target, VarSym):
            self.fb_call(c)
        else:
            self.w(f"(void)({self.ex(c)});")

    def fb_call(self, c: A.Call) -> None:
        sym: VarSym = c.target
        pt = T.resolve_base(sym.type)
        inst = self.var_ref(sym)
        en = next((a for a in c.args if a.name == "EN" and not a.output), None)
        eno = next((a for a in c.args if a.name == "ENO" and a.output), None)
        w = self.w
        inouts = []
        for a in c.args:
            p = a.param
            if p is None or a.value is None:
                continue
            if p.section == "VAR_INPUT":
                w(f"{inst}.{cid(p.name)} = {self.conv_to(a.value, p.type)};")
            elif p.section == "VAR_IN_OUT":
                w(f"{inst}.{cid(p.name)} = {self.lv(a.value)};")
                inouts.append((a, p))
        # As MATIEC: inputs are copied in and `=>` outputs out even when EN is FALSE;
        # EN only decides whether the body runs.  The body may clear ENO itself.
        if en is not None:
            w(f"{inst}.EN = {self.ex(en.value)};")
            w(f"if ({inst}.EN) {{")
            w(f"    {inst}.ENO = 1;")
            w(f"    P_{pt.name}_body(&{inst});")
            w("} else {")
            w(f"    {inst}.ENO = 0;")
            w("}")
        else:
            w(f"{inst}.ENO = 1;")
            w(f"P_{pt.name}_body(&{inst});")
        for a, p in inouts:
            w(f"{self.lv(a.value)} = {inst}.{cid(p.name)};")
        for a in c.args:
            p = a.param
            if p is None or a.value is None or p.section != "VAR_OUTPUT":
                continue
            val = f"{inst}.{cid(p.name)}"
            if a.negated:
                val = f"(!{val})"
            w(f"{self.lv(a.value)} = {val};")
        if eno is not None and eno.value is not None:
            w(f"{self.lv(eno.value)} = {inst}.ENO;")
