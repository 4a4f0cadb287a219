"""Calls: user FUNCTIONs, type conversions, standard functions (their emitters live in stdfuncs.py).
"""
from __future__ import annotations

from .. import ast as A
from .. import types as T
from ..diagnostics import InternalError
from ..stdfuncs import StdFunc
from ..symbols import ConversionSym, FuncSym
from .base import GenBase


class CallGen(GenBase):
    # -------------------------------------------------------------------- calls --
    def x_Call(self, c: A.Call) -> str:
        tgt = c.target
        eno = next((a for a in c.args if a.name == "ENO" and a.output and a.value is not None), None)
        if isinstance(tgt, FuncSym):
            expr = self.user_call(c, tgt, f"&{self.lv(eno.value)}" if eno is not None else "&(uint8_t){1}")
        elif isinstance(tgt, ConversionSym):
            expr = self.conversion(c, tgt.src, tgt.dst)
        elif isinstance(tgt, StdFunc):
            expr = self.std_call(c, tgt)
        else:
            raise InternalError(c.pos, f"call of {c.func} reached the C generator unresolved")
        en = next((a for a in c.args if a.name == "EN" and not a.output), None)
        if en is not None or eno is not None:
            ct = self.ctype(c.ty)
            cond = self.ex(en.value) if en is not None else "1"
            set1 = f"{self.lv(eno.value)} = 1, " if eno is not None else ""
            set0 = f"{self.lv(eno.value)} = 0, " if eno is not None else ""
            expr = f"(({cond}) ? ({set1}{expr}) : ({set0}({ct}){{0}}))"
        if c.site >= 0:
            first = next((a for a in c.args if a.param is not None
                          and a.param.section == "VAR_IN_OUT"), None)
            ctx = f"&{self.lv(first.value)}" if first is not None else "NULL"
            expr = f"plc_assert_done({expr}, {self.site_ref(c.site)}, {ctx})"
        return expr

    def user_call(self, c: A.Call, fs: FuncSym, eno_ptr: str) -> str:
        by_param = {a.param.name: a for a in c.args if a.param is not None}    # formal or positional
        args = []
        for p in fs.scope.params():
            a = by_param.get(p.name)
            ct = self.ctype(p.type)
            if p.section == "VAR_INPUT":
                if a is None or a.value is None:
                    args.append(self.default_value(p.type) if p.init is None or not isinstance(p.init, A.Expr)
                                else self.conv_to(p.init, p.type))
                else:
                    args.append(self.conv_to(a.value, p.type))
            elif p.section == "VAR_IN_OUT":
                args.append(f"&{self.lv(a.value)}" if a is not None and a.value is not None else f"&({ct}){{0}}")
            else:
                if a is not None and a.value is not None and not a.negated:
                    args.append(f"&{self.lv(a.value)}")
                else:
                    args.append(f"&({ct}){{0}}")
        args.append(eno_ptr)
        return f"U_{fs.name}({', '.join(args)})"

    def conversion(self, c: A.Call, src: T.Type, dst: T.Type) -> str:
        arg = c.std_args[0]
        x = self.ex(arg)
        s, d = T.resolve_base(src), T.resolve_base(dst)
        if isinstance(T.resolve_base(arg.ty), T.Elementary):
            s = T.resolve_base(arg.ty)
        dc = d.ctype
        if s is d:
            return x
        sc, dcat = s.cat, d.cat
        if dcat == "string":
            if sc == "bool":
                return f"plc_str_bool({x})"
            if sc == "int":
                return f"plc_str_i64((int64_t)({x}))"
            if sc == "uint":
                return f"plc_str_u64((uint64_t)({x}))"
            if sc == "bit":
                return f"plc_str_hex((uint64_t)({x}), {s.bits})"
            if sc == "real":
                return f"plc_str_{'real' if s.bits == 32 else 'lreal'}((double)({x}))"
            if sc in ("time", "date", "tod", "dt"):
                return f"plc_str_{sc}({x})"
            return f"plc_str_i64((int64_t)({x}))"
        if sc == "string":
            if dcat == "bool":
                return f"((uint8_t)plc_str_to_bool({x}))"
            if dcat == "int":
                return f"(({dc})plc_str_to_i64({x}))"
            if dcat in ("uint", "bit"):
                return f"(({dc})plc_str_to_u64({x}))"
            if dcat == "real":
                return f"(({dc})plc_str_to_real({x}))"
            if dcat == "time":
                return f"plc_real_to_time(plc_str_to_real({x}))"
            return f"(({dc})0)"
        if dcat == "bool":
            return f"((uint8_t)(({x}) != 0))"
        if sc == "real":
            if dcat in ("int",):
                return f"(({dc})plc_real_to_i64((double)({x})))"
            if dcat in ("uint", "bit"):
                return f"(({dc})plc_real_to_u64((double)({x})))"
            if dcat == "real":
                return f"(({dc})({x}))"
            if dcat == "time":
                return f"plc_real_to_time((double)({x}))"
        if sc == "time" or sc in ("date", "tod", "dt"):
            if dcat in ("int", "uint", "bit"):
                return f"(({dc})plc_time_to_int({x}))"
            if dcat == "real":
                return f"(({dc})plc_time_to_real({x}))"
            if sc == "dt" and dcat == "tod":
                return f"plc_dt_to_tod({x})"
            if sc == "dt" and dcat == "date":
                return f"plc_dt_to_date({x})"
            return x
        if dcat in ("time",):
            return f"plc_int_to_time((int64_t)({x}))"
        if dcat in ("date", "tod", "dt"):
            return f"plc_int_to_time((int64_t)({x}))"
        return f"(({dc})({x}))"

    def std_call(self, c: A.Call, f: StdFunc) -> str:
        """A standard function, written by the emitter that stdfuncs keeps beside its signature."""
        if f.emit is None:
            raise InternalError(c.pos, f"standard function {f.name} has no C emitter")
        t = T.resolve_base(c.ty) if c.ty is not None else T.DINT
        if isinstance(t, T.LiteralType):
            t = T.LINT if t.cat == "int" else T.LREAL
        return f.emit(self, c, c.std_args, t)

    def suffix(self, t: T.Type) -> str:
        b = T.resolve_base(t)
        if isinstance(b, T.EnumType):
            return "i32"
        if isinstance(b, T.Elementary):
            if b.cat == "real":
                return "f32" if b.bits == 32 else "f64"
            if b.cat in ("int", "time", "date", "tod", "dt"):
                return f"i{b.bits}"
            return f"u{max(b.bits, 8)}"
        return "i64"
