"""Call typing for the bodies pass: user functions, FB instances, standard functions and conversions;
argument binding (`Arg.param`) and assignment compatibility.
"""
from __future__ import annotations

from .. import ast as A
from .. import types as T
from ..diagnostics import Pos
from ..stdfuncs import STD_FUNCS, conversion
from ..symbols import ConversionSym, FuncSym, Scope
from .context import Pass


class CallTyping(Pass):
    """Asked by expression typing and the bodies pass; no pass of its own."""
    pass_name = "calls"

    # ------------------------------------------------------------------ calls --
    def call_expr(self, c: A.Call, scope, expected) -> T.Type:
        sym = scope.lookup(c.func) if scope else None
        if sym is not None:
            if isinstance(T.resolve_base(sym.type), T.PouType):
                self.err(c.pos, f"'{c.text}' is a function block instance: call it as a statement, then read its "
                         "outputs", f"{c.text}(...); x := {c.text}.Q;")
            else:
                self.err(c.pos, f"'{c.text}' is a variable, not a function")
            return T.ERROR
        if not c.args:
            self.port(c.pos, "empty-call")
        fs = self.st.prog.funcs.get(c.func)
        if fs is not None:
            c.target = fs
            self.user_call(c, fs, scope)
            self.mark_assert_site(c, fs)
            return fs.ret
        conv = conversion(c.func)
        if conv is not None:
            return self.conversion_call(c, conv, scope)
        std = STD_FUNCS.get(c.func)
        if std is not None:
            c.target = std
            return std.check(self, c, scope, expected)
        if c.func in self.st.prog.pous:
            self.err(c.pos, f"'{c.text}' is a {self.st.prog.pous[c.func].kind}: declare an instance and call that")
            return T.ERROR
        self.err(c.pos, f"unknown function '{c.text}'",
                 self.type_pass.suggest(c.func, list(self.st.prog.funcs) + list(STD_FUNCS)))
        return T.ERROR

    def mark_assert_site(self, c: A.Call, fs: FuncSym) -> None:
        if self.st.test_build and fs.builtin and (fs.name.startswith("ASSERT") or fs.name == "FAIL"):
            c.site = self.st.prog.site(c.pos, self.st.current_pou.text if self.st.current_pou else "")

    def user_call(self, c: A.Call, fs: FuncSym, scope) -> None:
        self.bind_args(c, fs.scope, fs.text, fs.text, is_fb=False)

    def bind_args(self, c: A.Call, callee: Scope, callee_name: str, call_name: str, is_fb: bool) -> None:
        """Match a call's arguments to the callee's parameters and check each (FB instances and FUNCTIONs); the
        parameter an argument binds, by name or by position, is its `param`."""
        params = callee.params()
        positional = [a for a in c.args if a.name is None]
        formal = [a for a in c.args if a.name is not None]
        if positional and formal:
            self.err(c.pos, f"call of {c.text} mixes positional and formal (name :=) arguments")
            if is_fb:
                return
        ins = [p for p in params if p.section in ("VAR_INPUT", "VAR_IN_OUT")]
        if positional:
            if len(positional) > len(ins):
                self.err(positional[len(ins)].pos, f"too many arguments for {callee_name} (it has {len(ins)} inputs)")
            if not is_fb and len(positional) < len(ins) and not formal:
                missing = [p.text for p in ins[len(positional):]]
                self.err(c.pos, f"call of {callee_name} is missing {', '.join(missing)}",
                         "a positional call must give every input")
        by_position = iter(p.name for p in ins)
        seen = set()
        for a in c.args:
            name = a.name if a.name is not None else next(by_position, None)
            if name is None:            # a positional argument past the inputs: reported above
                if not is_fb and a.value is not None:
                    self.expr_typing.expr(a.value, self.st.scope, None)
                continue
            if name in seen:
                self.err(a.pos, f"parameter '{a.text or name}' given twice")
                continue
            seen.add(name)
            if name in ("EN", "ENO"):
                self.en_eno_arg(a)
                continue
            p = callee.lookup(name)
            if p is None or p.section not in ("VAR_INPUT", "VAR_OUTPUT", "VAR_IN_OUT"):
                self.err(a.pos, f"{callee_name} has no parameter '{a.text or name}'",
                         self.type_pass.suggest(name, [q.name for q in params]))
                continue
            a.param = p
            if p.section == "VAR_OUTPUT":
                if not a.output:
                    self.err(a.pos, f"'{p.text}' is an output: write `{p.text} => variable`")
                elif a.value is not None:
                    tt = self.stmt_pass.lvalue(a.value, "write an output into")
                    self.assign_compat(a.value, p.type, tt, a.pos, f"output {p.text}")
                continue
            if a.output:
                self.err(a.pos, f"'{p.text}' is an input: write `{p.text} := value`")
                continue
            if a.value is None:
                if p.section == "VAR_IN_OUT" and not is_fb:
                    self.err(a.pos, f"VAR_IN_OUT '{p.text}' must be connected with :=")
                continue
            if p.section == "VAR_IN_OUT":
                at = self.stmt_pass.lvalue(a.value, "pass as VAR_IN_OUT")
                if not self.stmt_pass.is_lvalue(a.value):
                    self.err(a.pos, f"VAR_IN_OUT '{p.text}' needs a variable, not an expression")
                elif not T.same_type(at, p.type) and not isinstance(at, T.ErrorType):
                    self.err(a.pos, f"VAR_IN_OUT '{p.text}' is {p.type}, the argument is {at}")
                elif not is_fb and isinstance(a.value, A.Index):
                    self.port(a.pos, "inout-element")
            else:
                at = self.expr_typing.expr(a.value, self.st.scope, p.type)
                self.assign_compat(a.value, at, p.type, a.pos, f"input {p.text}")
        for p in params:
            if p.section == "VAR_IN_OUT" and p.name not in seen:
                self.err(c.pos, f"call of {call_name} must connect VAR_IN_OUT '{p.text}'")

    def en_eno_arg(self, a: A.Arg) -> None:
        """EN := condition and ENO => variable, accepted by every call."""
        if a.name == "EN" and not a.output:
            if a.value is None:
                self.err(a.pos, "EN := needs a value")
                return
            self.expr_typing.expr(a.value, self.st.scope, T.BOOL)
            self.assign_compat(a.value, a.value.ty, T.BOOL, a.pos, "EN")
        elif a.name == "ENO" and a.output:
            if a.value is not None:
                tt = self.stmt_pass.lvalue(a.value, "write ENO into")
                self.assign_compat(a.value, T.BOOL, tt, a.pos, "ENO")
        else:
            self.err(a.pos, f"{a.name} must be passed with {'=>' if a.name == 'ENO' else ':='}")

    def conversion_call(self, c: A.Call, conv, scope) -> T.Type:
        src, dst, generic = conv
        c.target = ConversionSym(src, dst)
        for a in c.args:
            if a.name in ("EN", "ENO"):
                self.en_eno_arg(a)
        inputs = [a for a in c.args if a.name not in ("EN", "ENO")]
        if len(inputs) != 1 or inputs[0].output:
            self.err(c.pos, f"{c.text} takes exactly one input")
            for a in inputs:
                if a.value is not None and not a.output:
                    self.expr_typing.expr(a.value, scope, None)
            return dst
        a = inputs[0]
        c.std_args = [a.value]
        if a.name not in (None, "IN"):
            self.err(a.pos, f"{c.text} has no parameter '{a.text}'", "its input is IN")
        if generic:
            self.port(c.pos, "generic-conversion", call=c.text, type=dst.name)
        at = self.expr_typing.expr(a.value, scope, src)
        ab = T.resolve_base(at)
        if isinstance(ab, T.ErrorType):
            return dst
        if generic:
            if isinstance(ab, T.LiteralType):
                self.expr_typing.fix_literal(a.value, T.LINT if ab.cat == "int" else T.LREAL)
                ab = T.resolve_base(a.value.ty)
            c.target = ConversionSym(ab, dst)
        elif not T.same_type(ab, src) and not isinstance(ab, T.LiteralType):
            self.err(a.pos, f"{c.text} needs a {src.name} input, not {at}",
                     f"use {T.resolve_base(at).name}_TO_{dst.name}" if isinstance(ab, T.Elementary) else None)
        if c.func in ("TIME_TO_DINT", "DINT_TO_TIME", "TIME_TO_INT", "INT_TO_TIME", "TIME_TO_UDINT",
                      "UDINT_TO_TIME", "TIME_TO_LINT", "LINT_TO_TIME", "TIME_TO_ULINT", "ULINT_TO_TIME",
                      "TIME_TO_UINT", "UINT_TO_TIME", "TIME_TO_SINT", "SINT_TO_TIME", "TIME_TO_USINT", "USINT_TO_TIME"):
            self.port(c.pos, "time-conversion", call=c.text)
        return dst

    # ------------------------------------------------------------ compatibility --
    def assign_compat(self, e: A.Expr | None, src: T.Type, dst: T.Type, pos: Pos, what: str) -> bool:
        if src is None or dst is None:
            return True
        sb, db = T.resolve_base(src), T.resolve_base(dst)
        if isinstance(sb, T.ErrorType) or isinstance(db, T.ErrorType):
            return True
        if isinstance(sb, T.LiteralType):
            if e is not None:
                self.expr_typing.fix_literal(e, dst)
                if isinstance(e.ty, T.LiteralType):
                    if sb.cat == "real" and T.is_elem(db, "int", "uint", "bit"):
                        self.err(pos, f"{what}: a REAL literal cannot go into {dst}")
                    elif T.is_elem(db, "bool"):
                        self.err(pos, f"{what}: an integer literal cannot go into BOOL", "use TRUE or FALSE")
                    else:
                        self.err(pos, f"{what}: a number cannot go into {dst}")
                    return False
                self.check_subrange(e, dst)
            return True
        if T.same_type(sb, db):
            if isinstance(dst, T.SubrangeType) and e is not None:
                self.check_subrange(e, dst)
            if isinstance(sb, T.StructType) and sb is not db:
                self.err(pos, f"{what}: {src} is not {dst}")
                return False
            return True
        if isinstance(sb, T.Elementary) and isinstance(db, T.Elementary):
            hint = f"convert explicitly: {sb.name}_TO_{db.name}(...)"
            if sb.is_int and db.is_int and sb.size < db.size:
                self.err(pos, f"{what}: implicit conversion from {sb.name} to {db.name} "
                         "(MATIEC does not widen implicitly)", hint, code="type-widening")
            else:
                self.err(pos, f"{what}: type mismatch, {src} cannot go into {dst}", hint, code="type-mismatch")
            return False
        self.err(pos, f"{what}: type mismatch, {src} cannot go into {dst}", code="type-mismatch")
        return False

    def check_subrange(self, e: A.Expr, dst: T.Type) -> None:
        if isinstance(dst, T.SubrangeType):
            v = self.const_eval.const_int(e)
            if v is not None and not (dst.lo <= v <= dst.hi):
                self.err(e.pos, f"value {v} is outside the subrange {dst.lo}..{dst.hi} of {dst.name}")
