"""Pass 2, types: TYPE declarations and every type spec resolved to a `types.Type` (forward references are
fine; a cycle is an error).
"""
from __future__ import annotations

from .. import ast as A
from .. import types as T
from ..diagnostics import InternalError, Pos
from .context import Pass


class TypePass(Pass):
    pass_name = "types"

    def __init__(self, st) -> None:
        super().__init__(st)
        self.resolving: set[str] = set()          # named types being resolved (a cycle is an error)

    def run(self) -> None:
        for name in self.st.type_decls:
            self.named_type(name, self.st.type_decls[name].pos)

    def named_type(self, name: str, pos: Pos) -> T.Type:
        if name in self.st.prog.types:
            return self.st.prog.types[name]
        td = self.st.type_decls.get(name)
        if td is None:
            return T.ERROR
        if name in self.resolving:
            self.err(td.pos, f"type '{td.text}' is defined in terms of itself")
            return T.ERROR
        self.resolving.add(name)
        try:
            t = self.type_spec(td.spec, name_for=td)
        finally:
            self.resolving.discard(name)
        # known before its initial value is checked: `TYPE E : (A, B) := E#A;` names the type being declared
        self.st.prog.types[name] = t
        if td.init is not None and not isinstance(t, T.ErrorType):
            if isinstance(t, T.StructType):
                self.err(td.pos, "a STRUCT type takes initial values per member, not for the whole type")
            else:
                self.scope_pass.check_init(td.init, t)
                if not isinstance(td.spec, A.TypeRef):
                    t = self.with_default(t, td.init)
                # an alias (TYPE Speed : INT := 5) shares its type object: the initial
                # value belongs to the name and is applied where the name is used (alias_init)
        self.st.prog.types[name] = t
        self.st.prog.type_order.append(name)
        return t

    def alias_init(self, spec):
        """Initial value a declaration of type `spec` inherits from a TYPE alias chain, if any."""
        seen = set()
        while isinstance(spec, A.TypeRef) and spec.name in self.st.type_decls and spec.name not in seen:
            seen.add(spec.name)
            td = self.st.type_decls[spec.name]
            if td.init is not None:
                return td.init if isinstance(td.spec, A.TypeRef) else None
            spec = td.spec
        return None

    def with_default(self, t: T.Type, init) -> T.Type:
        """Types declared with an initial value keep it (TYPE Speed : INT := 5; END_TYPE)."""
        self.st.prog.type_inits[id(t)] = init
        return t

    def type_ref(self, ref: A.TypeRef) -> T.Type:
        name = ref.name
        if name in T.ELEMENTARY:
            if name == "STRING" and ref.length is not None:
                n = self.const_eval.const_int(ref.length)
                self.port(ref.pos, "string-length")
                if n is None or not 1 <= n <= 126:
                    self.err(ref.length.pos, "string length must be a constant between 1 and 126")
                    return T.STRING
                return T.StringType(n)
            return T.ELEMENTARY[name]
        if name in T.UNSUPPORTED:
            self.err(ref.pos, T.UNSUPPORTED[name])
            return T.ERROR
        if name in self.st.type_decls:
            return self.named_type(name, ref.pos)
        if name in self.st.prog.pous:
            return self.st.prog.pous[name]
        if name in self.st.pou_decls:
            self.err(ref.pos, f"'{ref.text}' is a FUNCTION, not a type")
            return T.ERROR
        self.err(ref.pos, f"unknown type '{ref.text}'", self.suggest(name, list(self.st.type_decls) +
                                                                     list(self.st.prog.pous) + list(T.ELEMENTARY)))
        return T.ERROR

    def suggest(self, name: str, candidates) -> str | None:
        import difflib
        close = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.75)
        return f"did you mean '{close[0]}'?" if close else None

    def type_spec(self, spec, name_for: A.TypeDecl | None = None) -> T.Type:
        if isinstance(spec, A.TypeRef):
            return self.type_ref(spec)
        if isinstance(spec, A.EnumSpec):
            if name_for is None:
                self.port(spec.pos, "anon-enum")
            name = name_for.name if name_for else f"ENUM_{spec.pos.line}_{spec.pos.col}"
            vals = []
            for v, pos, explicit in spec.values:
                if explicit is not None:
                    self.port(pos, "enum-value")
                if v in vals:
                    self.err(pos, f"duplicate enumeration value '{v}'")
                    continue
                vals.append(v)
            if spec.base is not None:
                self.port(spec.pos, "enum-base")
            et = T.EnumType(name, vals)
            for v in vals:
                self.st.prog.enum_values.setdefault(v, []).append(et)
            return et
        if isinstance(spec, A.SubrangeSpec):
            base = self.type_ref(spec.base)
            b = T.resolve_base(base)
            lo, hi = self.const_eval.const_int(spec.lo), self.const_eval.const_int(spec.hi)
            if not (isinstance(b, T.Elementary) and b.is_int):
                if not isinstance(b, T.ErrorType):
                    self.err(spec.pos, f"a subrange needs an integer base type, not {base}")
                return T.ERROR
            if lo is None or hi is None:
                self.err(spec.pos, "subrange bounds must be constant integers")
                return b
            if lo > hi or lo < b.lo or hi > b.hi:
                self.err(spec.pos, f"subrange {lo}..{hi} does not fit {b.name}")
                return b
            return T.SubrangeType(name_for.name if name_for else f"{b.name}({lo}..{hi})", b, lo, hi)
        if isinstance(spec, A.ArraySpec):
            dims = []
            for lo_e, hi_e in spec.dims:
                for e in (lo_e, hi_e):
                    n = e if isinstance(e, A.Name) else e.operand if isinstance(e, A.Unary) else None
                    if isinstance(n, A.Name) and not self.const_eval.is_external_constant(n.name):
                        # (a VAR_GLOBAL CONSTANT reached through VAR_EXTERNAL CONSTANT is fine with iec2c -a)
                        self.port(e.pos, "array-bound")
                lo, hi = self.const_eval.const_int(lo_e), self.const_eval.const_int(hi_e)
                if lo is None or hi is None:
                    self.err(lo_e.pos, "array bounds must be constant integers")
                    return T.ERROR
                if lo > hi:
                    self.err(lo_e.pos, f"array bounds {lo}..{hi} are reversed")
                    return T.ERROR
                dims.append((lo, hi))
            elem = self.type_spec(spec.elem)
            if isinstance(elem, T.PouType):
                self.port(spec.pos, "fb-array")
                self.err(spec.pos, "arrays of function block instances are not supported")
                return T.ERROR
            if isinstance(elem, T.ErrorType):
                return T.ERROR
            at = T.ArrayType(dims, elem)
            for existing in self.st.prog.array_types:
                if existing.dims == at.dims and existing.elem is at.elem:
                    return existing
            at.cname = f"ARR{len(self.st.prog.array_types)}"
            self.st.prog.array_types.append(at)
            if isinstance(T.resolve_base(elem), T.ArrayType):
                self.port(spec.pos, "array-of-array")
            if at.count() > 1_000_000:
                self.err(spec.pos, f"array of {at.count()} elements is too large")
            return at
        if isinstance(spec, A.StructSpec):
            if name_for is None:
                self.port(spec.pos, "anon-struct")
            st = T.StructType(name_for.name if name_for else f"STRUCT_{spec.pos.line}_{spec.pos.col}",
                              decl=name_for)
            for m in spec.members:
                if m.name in st.members:
                    self.err(m.pos, f"duplicate member '{m.text}' in STRUCT")
                    continue
                mt = self.type_spec(m.spec)
                if getattr(mt, "name", "").upper() == m.name.upper():
                    self.port(m.pos, "member-named-like-type", member=m.text)
                if isinstance(mt, T.PouType):
                    self.err(m.pos, "function block instances inside a STRUCT are not supported by MATIEC")
                    mt = T.ERROR
                if m.init is not None and not isinstance(mt, T.ErrorType):
                    self.scope_pass.check_init(m.init, mt)
                st.members[m.name] = T.StructMemberT(m.name, mt, m.init if m.init is not None
                                                     else self.alias_init(m.spec), m.pos)
            return st
        if isinstance(spec, A.PointerSpec):
            self.err(spec.pos, f"{spec.kind} is not supported (MATIEC has no usable pointers)",
                     code="portability.pointer")
            return T.ERROR
        raise InternalError(spec.pos, f"the types pass does not handle the type spec {type(spec).__name__}")
