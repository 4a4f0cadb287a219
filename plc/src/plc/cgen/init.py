"""Initial values: defaults, declared initialisers of variables, arrays and structures, each POU's init function.
"""
from __future__ import annotations

from .. import ast as A
from .. import types as T
from .base import GenBase, cid


class InitGen(GenBase):
    # ------------------------------------------------------------ init code --
    def default_value(self, t: T.Type) -> str:
        b = T.resolve_base(t)
        if isinstance(t, T.SubrangeType):
            return f"(({t.of.ctype}){t.lo})"
        if isinstance(b, T.Elementary):
            if b.cat == "string":
                return "plc_str_empty()"
            return f"(({b.ctype})0)"
        if isinstance(b, T.EnumType):
            return "0"
        return f"(({self.ctype(t)}){{0}})"

    def emit_init(self, lv: str, t: T.Type, init) -> None:
        """Lines that give lvalue `lv` of type `t` its declared initial value."""
        b = T.resolve_base(t)
        type_init = self.p_type_init(t)
        if init is None and type_init is not None:
            init = type_init
        if isinstance(b, T.PouType):
            self.w(f"P_{b.name}_init(&{lv});")
            if isinstance(init, A.StructInit) and b.scope is not None:
                for name, _pos, v in init.fields:
                    m = b.scope.vars.get(name)
                    if m is not None:
                        self.emit_init(f"{lv}.{cid(name)}", m.type, v)
            return
        if isinstance(b, (T.ArrayType, T.StructType)):
            self.w(f"init_{self.ctype(b)}(&{lv});")
            if isinstance(init, A.ArrayInit) and isinstance(b, T.ArrayType):
                self.array_init_values(lv, b, init)
            elif isinstance(init, A.StructInit) and isinstance(b, T.StructType):
                for name, _pos, v in init.fields:
                    m = b.members.get(name)
                    if m is not None:
                        self.emit_init(f"{lv}.{cid(name)}", m.type, v)
            return
        if init is None:
            self.w(f"{lv} = {self.default_value(t)};")
        elif isinstance(init, A.Expr):
            self.w(f"{lv} = {self.conv_to(init, t)};")

    def p_type_init(self, t: T.Type):
        return self.p.type_inits.get(id(t))

    def array_init_values(self, lv: str, at: T.ArrayType, init: A.ArrayInit) -> None:
        flat = []
        for rep, v in init.items:
            n = 1 if rep is None else max(0, getattr(rep, "value", 1))
            flat.extend([v] * n)
        sizes = [hi - lo + 1 for lo, hi in at.dims]
        total = at.count()
        for k, v in enumerate(flat[:total]):
            if v is None:
                continue
            subs = []
            rem = k
            for s in reversed(sizes):
                subs.append(rem % s)
                rem //= s
            subs.reverse()
            self.emit_init(f"{lv}.e" + "".join(f"[{i}]" for i in subs), at.elem, v)

    def agg_init(self, t: T.Type) -> None:
        ct = self.ctype(t)
        self.w(f"{self.linkage} void init_{ct}({ct} *p) {{")
        self.ind += 1
        if isinstance(t, T.ArrayType):
            n = t.count()
            dims = [hi - lo + 1 for lo, hi in t.dims]
            self.w(f"{self.ctype(t.elem)} *e = &p->e" + "[0]" * len(dims) + ";")
            self.w(f"for (size_t i = 0; i < {n}u; i++) {{")
            self.ind += 1
            self.emit_init("e[i]", t.elem, None)
            self.ind -= 1
            self.w("}")
        else:
            for m in t.members.values():
                self.emit_init(f"p->{cid(m.name)}", m.type, m.init)
        self.ind -= 1
        self.w("}")

    def pou_init(self, pt: T.PouType) -> None:
        self.pou = pt.pou
        self.w(f"{self.linkage} void P_{pt.name}_init(P_{pt.name} *self) {{")
        self.ind += 1
        self.w("self->EN = 1;")
        self.w("self->ENO = 1;")
        for v in pt.scope.vars.values():
            if v.section == "VAR_EXTERNAL":
                continue
            if v.location is not None:
                self.w(f"self->{cid(v.name)} = &self->{cid(v.name)}__L;")
                self.emit_init(f"self->{cid(v.name)}__L", v.type, v.init)
            else:
                self.emit_init(f"self->{cid(v.name)}", v.type, v.init)
        self.ind -= 1
        self.w("}")
        self.pou = None
