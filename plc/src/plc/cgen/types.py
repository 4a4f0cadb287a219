"""C types of ST types: elementary, enumerations, arrays, structures, POU instances, in dependency order.
"""
from __future__ import annotations

from .. import types as T
from .base import GenBase


class TypeGen(GenBase):
    # ------------------------------------------------------------------- types --
    def ctype(self, t: T.Type) -> str:
        b = T.resolve_base(t)
        if isinstance(t, T.StringType):
            return "plc_string_t"
        if isinstance(b, T.Elementary):
            return b.ctype
        if isinstance(b, T.EnumType):
            return "int32_t"
        if isinstance(b, T.ArrayType):
            return b.cname
        if isinstance(b, T.StructType):
            return "S_" + b.name
        if isinstance(b, T.PouType):
            return "P_" + b.name
        if isinstance(b, T.LiteralType):
            return "int64_t" if b.cat == "int" else "double"
        return "int32_t"

    def deps(self, t: T.Type) -> list[T.Type]:
        b = T.resolve_base(t)
        if isinstance(b, T.ArrayType):
            return [b.elem]
        if isinstance(b, T.StructType):
            return [m.type for m in b.members.values()]
        if isinstance(b, T.PouType) and b.scope is not None:
            return [v.type for v in b.scope.vars.values() if v.section != "VAR_EXTERNAL"]
        return []

    def aggregates(self) -> list[T.Type]:
        """Struct, array and POU types in dependency order (members before containers)."""
        order: list[T.Type] = []
        state: dict[int, int] = {}

        def visit(t: T.Type) -> None:
            b = T.resolve_base(t)
            if not isinstance(b, (T.ArrayType, T.StructType, T.PouType)):
                return
            if state.get(id(b)) == 2:
                return
            if state.get(id(b)) == 1:
                return
            state[id(b)] = 1
            for d in self.deps(b):
                visit(d)
            state[id(b)] = 2
            order.append(b)

        for name in self.p.type_order:
            visit(self.p.types[name])
        for at in self.p.array_types:
            visit(at)
        for pt in self.p.pous.values():
            visit(pt)
        return order

    def array_decl(self, at: T.ArrayType) -> str:
        dims = "".join(f"[{hi - lo + 1}]" for lo, hi in at.dims)
        return f"typedef struct {{ {self.ctype(at.elem)} e{dims}; }} {at.cname};"
