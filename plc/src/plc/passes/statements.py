"""Pass 6, bodies: every statement of every POU body checked (conditions, assignments, CASE, FOR, calls as
statements); expressions are typed by expressions.py and calls.py.
"""
from __future__ import annotations

from .. import ast as A
from .. import types as T
from ..diagnostics import Pos
from ..symbols import EN, EnumValueSym, VarSym
from .context import Pass, LoopCtx


class StatementPass(Pass):
    pass_name = "bodies"

    def __init__(self, st) -> None:
        super().__init__(st)
        self.loop = LoopCtx()                        # loop nesting of the statement being checked

    def run(self) -> None:
        skip = self.st.skip_bodies
        for name, pou in self.st.pou_decls.items():
            if skip is not None and skip(pou):
                continue
            self.st.current_pou = pou
            if pou.kind == "FUNCTION":
                self.st.scope = self.st.prog.funcs[name].scope
                self.st.func = self.st.prog.funcs[name]
            else:
                self.st.scope = self.st.prog.pous[name].scope
                self.st.func = None
            self.loop = LoopCtx()
            self.stmts(pou.body)
            self.st.current_pou = None

    def stmts(self, body: list[A.Stmt]) -> None:
        for s in body:
            self.stmt(s)

    def stmt(self, s: A.Stmt) -> None:
        """One statement, by its kind's `s_<Kind>` method; a kind without one is a compiler bug."""
        A.handler(self, "s_", s, "semantic analysis", "the statement")(s)

    def s_Assign(self, s: A.Assign) -> None:
        self.assign(s)

    def s_CallStmt(self, s: A.CallStmt) -> None:
        self.call_stmt(s)

    def s_If(self, s: A.If) -> None:
        for cond, body in s.branches:
            self.condition(cond, "IF")
            self.stmts(body)
        if s.orelse is not None:
            self.stmts(s.orelse)

    def s_Case(self, s: A.Case) -> None:
        self.case(s)

    def s_For(self, s: A.For) -> None:
        self.for_stmt(s)

    def s_While(self, s: A.While) -> None:
        self.condition(s.cond, "WHILE")
        self.loop.loop_depth += 1
        self.stmts(s.body)
        self.loop.loop_depth -= 1

    def s_Repeat(self, s: A.Repeat) -> None:
        self.loop.loop_depth += 1
        self.stmts(s.body)
        self.loop.loop_depth -= 1
        self.condition(s.cond, "UNTIL")

    def s_Exit(self, s: A.Exit) -> None:
        if self.loop.loop_depth == 0:
            self.err(s.pos, "EXIT outside a loop")

    def s_Continue(self, s: A.Continue) -> None:
        if self.loop.loop_depth == 0:
            self.err(s.pos, "CONTINUE outside a loop")

    def s_Return(self, s: A.Return) -> None:
        pass

    def s_Empty(self, s: A.Empty) -> None:
        pass

    def condition(self, e: A.Expr, what: str) -> None:
        t = self.expr_typing.expr(e, self.st.scope, T.BOOL)
        if not isinstance(t, T.ErrorType) and not T.is_elem(t, "bool"):
            self.err(e.pos, f"{what} condition must be BOOL, not {t}")

    def assign(self, s: A.Assign) -> None:
        tt = self.lvalue(s.target, "assign to")
        vt = self.expr_typing.expr(s.value, self.st.scope, tt if not isinstance(tt, T.ErrorType) else None)
        if isinstance(T.resolve_base(tt), T.PouType):
            self.err(s.pos, "function block instances cannot be assigned")
            return
        self.call_typing.assign_compat(s.value, vt, tt, s.value.pos, "assignment")

    def lvalue(self, target: A.Expr, verb: str) -> T.Type:
        """Check an assignment target; report writes to constants, inputs and the FOR variable."""
        t = self.expr_typing.expr(target, self.st.scope, None, lvalue=True)
        root = target
        path_through_instance = False
        while isinstance(root, (A.Member, A.Index, A.BitAccess)):
            if isinstance(root, A.Member) and isinstance(T.resolve_base(root.base.ty or T.ERROR), T.PouType):
                inst_t = T.resolve_base(root.base.ty)
                member = inst_t.scope.lookup(root.name) if inst_t.scope else None
                output = member.section == "VAR_OUTPUT" if member is not None else root.name == "ENO"
                if output:
                    self.err(root.pos, f"cannot {verb} output '{root.text or root.name}' of an instance from outside",
                             "outputs are written by the function block itself")
                elif member is not None and member.section in ("VAR", "VAR_TEMP", "VAR_EXTERNAL"):
                    self.err(root.pos, f"'{root.text or root.name}' is internal to {inst_t.name} and cannot be "
                             "written from outside")
                path_through_instance = True
            root = root.base
        if isinstance(root, A.Direct):
            if root.area == "I":
                self.err(root.pos, f"cannot {verb} the input {root.text}")
            return t
        if isinstance(root, A.Name) and isinstance(root.sym, VarSym):
            sym = root.sym
            if sym.constant or (sym.global_sym is not None and sym.global_sym.constant):
                self.err(target.pos, f"cannot {verb} CONSTANT '{sym.text}'")
            elif sym.location is not None and sym.location.area == "I" and not path_through_instance:
                self.err(target.pos, f"cannot {verb} '{sym.text}': it is located at the input {sym.location.text}")
            elif sym.section == "VAR_INPUT" and not path_through_instance and target is root \
                    and self.st.current_pou is not None and self.st.current_pou.kind != "FUNCTION" \
                    and not self.in_builtin():
                self.err(target.pos, f"cannot {verb} input '{sym.text}' inside its own function block",
                         "copy it to a local variable first")
            if sym in self.loop.for_vars:
                self.err(target.pos, f"cannot {verb} the FOR control variable '{sym.text}' inside its loop")
        elif isinstance(root, A.Name) and root.sym is EN:
            self.err(target.pos, f"cannot {verb} EN: it is an input")
        elif isinstance(root, A.Name) and isinstance(root.sym, EnumValueSym):
            self.err(target.pos, f"cannot {verb} the enumeration value '{root.name}'")
        return t

    def case(self, s: A.Case) -> None:
        st = self.expr_typing.expr(s.selector, self.st.scope, None)
        b = T.resolve_base(st)
        if isinstance(b, T.LiteralType):
            b = T.DINT
        if not (isinstance(b, T.EnumType) or (isinstance(b, T.Elementary) and b.cat in ("int", "uint", "bit"))) \
                and not isinstance(b, T.ErrorType):
            self.err(s.selector.pos, f"CASE selector must be an integer or enumeration, not {st}")
            b = T.ERROR
        seen: list[tuple[int, int, Pos]] = []
        for labels, body in s.arms:
            for lab in labels:
                values = []
                for e in (lab.lo, lab.hi):
                    if e is None:
                        continue
                    lt = self.expr_typing.expr(e, self.st.scope, b if not isinstance(b, T.ErrorType) else None)
                    if isinstance(b, T.ErrorType) or isinstance(lt, T.ErrorType):
                        continue
                    if isinstance(b, T.EnumType):
                        if not (isinstance(e.sym, EnumValueSym) and e.sym.type is b):
                            self.err(e.pos, f"CASE label must be a value of {b.name}")
                            continue
                        values.append(e.sym.index)
                    else:
                        if not self.scope_pass.is_constant_expr(e):
                            self.err(e.pos, "CASE labels must be constants")
                            continue
                        if isinstance(e, A.Name) or (isinstance(e, A.Unary) and isinstance(e.operand, A.Name)):
                            self.port(e.pos, "case-constant")
                        if not (isinstance(T.resolve_base(lt), T.LiteralType) or T.same_type(lt, b)):
                            self.err(e.pos, f"CASE label of type {lt} does not match the selector type {b}")
                            continue
                        v = self.const_eval.const_int(e)
                        if v is None:
                            self.err(e.pos, "CASE label must be an integer constant")
                            continue
                        if isinstance(b, T.Elementary) and not (b.lo <= v <= b.hi):
                            self.err(e.pos, f"CASE label {v} is out of range for {b.name}")
                        values.append(v)
                if len(values) == (2 if lab.hi is not None else 1):
                    lo, hi = values[0], values[-1]
                    for (a, z, p) in seen:
                        if lo <= z and a <= hi:
                            self.err(lab.pos, "duplicate CASE label", f"already covered at {p}")
                            break
                    seen.append((lo, hi, lab.pos))
            self.stmts(body)
        if s.orelse is not None:
            self.stmts(s.orelse)

    def for_stmt(self, s: A.For) -> None:
        vt = self.expr_typing.expr(s.var, self.st.scope, None)
        sym = s.var.sym
        if isinstance(sym, VarSym):
            if not T.is_elem(vt, "int", "uint"):
                self.err(s.var.pos, f"FOR control variable must be an integer, not {vt}")
            if sym.constant:
                self.err(s.var.pos, f"FOR control variable '{sym.text}' is CONSTANT")
        for e in (s.start, s.end, s.step):
            if e is None:
                continue
            et = self.expr_typing.expr(e, self.st.scope, vt if not isinstance(vt, T.ErrorType) else None)
            self.call_typing.assign_compat(e, et, vt, e.pos, "FOR bound")
        if s.step is not None and self.const_eval.const_int(s.step) == 0:
            self.err(s.step.pos, "FOR step BY 0 never ends")
        self.loop.loop_depth += 1
        if isinstance(sym, VarSym):
            self.loop.for_vars.append(sym)
        self.stmts(s.body)
        if isinstance(sym, VarSym):
            self.loop.for_vars.pop()
        self.loop.loop_depth -= 1

    def call_stmt(self, s: A.CallStmt) -> None:
        c = s.call
        sym = self.st.scope.lookup(c.func) if self.st.scope else None
        if sym is None and c.func in self.st.global_scope:
            sym = self.st.global_scope[c.func]
        if sym is not None and isinstance(T.resolve_base(sym.type), T.PouType):
            self.fb_call(c, sym)
            return
        if sym is not None and not isinstance(sym.type, T.ErrorType):
            self.err(c.pos, f"'{c.text}' is a variable of type {sym.type}, not a function block instance")
            return
        if sym is not None:
            return
        # a function call used as a statement
        self.port(c.pos, "call-statement")
        self.expr_typing.expr(c, self.st.scope, None)

    # -------------------------------------------------------------- FB calls --
    def fb_call(self, c: A.Call, sym: VarSym) -> None:
        ft = T.resolve_base(sym.type)
        c.target = sym
        c.ty = None
        if ft.scope is not None:
            self.call_typing.bind_args(c, ft.scope, ft.name, sym.text, is_fb=True)

    def is_lvalue(self, e: A.Expr) -> bool:
        if isinstance(e, A.Name):
            return isinstance(e.sym, VarSym)
        if isinstance(e, (A.Member, A.Index)):
            return self.is_lvalue(e.base)
        return isinstance(e, A.Direct)
