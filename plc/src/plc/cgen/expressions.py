"""Expressions: one `x_<Kind>` method per expression kind; variable references; assignment conversions.
"""
from __future__ import annotations

from .. import ast as A
from .. import types as T
from ..diagnostics import InternalError
from ..symbols import CURRENT_TIME, EN, ENO, EnumValueSym, FuncSym, VarSym
from .base import GenBase, cid, c_string, c_compare


class ExpressionGen(GenBase):
    # -------------------------------------------------------------- expressions --
    def var_ref(self, sym: VarSym) -> str:
        """C lvalue of a variable visible in the current POU."""
        name = cid(sym.name)
        if sym.section == "VAR_EXTERNAL":
            g = sym.global_sym
            if g is None:
                return f"G_{name}"
            return f"(*G_{name})" if g.location is not None else f"G_{name}"
        if sym.section == "VAR_GLOBAL":
            return f"(*G_{name})" if sym.location is not None else f"G_{name}"
        if self.fn is not None:
            if sym.section in ("VAR_IN_OUT", "VAR_OUTPUT"):
                return f"(*{name})"
            return name
        if sym.location is not None:
            return f"(*self->{name})"
        return f"self->{name}"

    def lv(self, e: A.Expr) -> str:
        """C lvalue of `e`: a variable itself, never the literal a read of a CONSTANT may be (folded)."""
        if isinstance(e, A.Name) and isinstance(e.sym, VarSym):
            return self.var_ref(e.sym)
        return self.ex(e)

    # ------------------------------------------------------- folded constants --
    def folded(self, sym: VarSym) -> str | None:
        """The C literal a read of `sym` compiles to, or None (read the variable).  A CONSTANT scalar of an
        elementary type (VAR CONSTANT, or a VAR_EXTERNAL bound to a VAR_GLOBAL CONSTANT), not located, whose
        initial value the semantic passes folded: read as that value, so gcc can fold what it computes and drop
        the bounds checks it decides (docs/scan-cost.md).  The variable itself is still initialised and listed
        for the monitor, which never writes or forces a CONSTANT, nor does a retain file restore one.  Only
        where the generator writes a body (fold_constants): initial values read what the instance holds."""
        if not self.fold_constants:
            return None
        g = sym.global_sym if sym.section == "VAR_EXTERNAL" else sym
        if g is None or not g.constant or g.location is not None or g.decl is None or g.const_value is None \
                or not isinstance(g.type, T.Elementary) or g.type.cat == "string" or id(g) in self.folding:
            return None
        self.folding.add(id(g))
        try:
            v = self.exact_init(g.decl.init, g.type)
        finally:
            self.folding.discard(id(g))
        if v is None or v != g.const_value or isinstance(v, bool) != isinstance(g.const_value, bool):
            return None
        t = g.type
        if t.cat == "bool":
            return "((uint8_t)1)" if v else "((uint8_t)0)"
        if t.cat == "real":
            return f"(({t.ctype}){float(v)!r})"
        return self.int_const(v, t)

    def exact_init(self, e, t: T.Elementary):
        """The value C gives a variable of type `t` initialised with `e`, when it is sure to be the value the
        semantic passes folded (VarSym.const_value), else None: literals, unary minus, NOT of a BOOL, + - * of
        integers or times where no intermediate result leaves its type (C wraps it), names of CONSTANTs of the
        same kind (of the same type for a REAL: C rounds each REAL to single precision)."""
        if not isinstance(e, A.Expr):
            return None
        cat = t.cat
        if cat == "bool":
            if isinstance(e, A.BoolLit):
                return bool(e.value)
            if isinstance(e, A.Unary) and e.op == "NOT":
                v = self.exact_init(e.operand, t)
                return None if v is None else not v
            return self.exact_name(e, lambda u: u is t)
        if cat == "real":
            if isinstance(e, A.RealLit):
                return float(e.value)
            if isinstance(e, A.IntLit) and abs(e.value) < (1 << 53):
                return float(e.value)
            if isinstance(e, A.Unary) and e.op in ("-", "+"):
                v = self.exact_init(e.operand, t)
                return None if v is None else (-v if e.op == "-" else v)
            return self.exact_name(e, lambda u: u is t)
        if cat not in ("int", "uint", "bit", "time", "date", "tod", "dt"):
            return None
        v = self.exact_int(e)
        return v if v is not None and self.fits(v, t) else None

    def exact_int(self, e: A.Expr):
        """The exact value of an integer or time constant expression, each node within its own type."""
        v = None
        if isinstance(e, A.IntLit):
            v = e.value
        elif isinstance(e, A.TimeLit):
            v = e.value
        elif isinstance(e, A.Unary) and e.op in ("-", "+"):
            x = self.exact_int(e.operand)
            v = None if x is None else (-x if e.op == "-" else x)
        elif isinstance(e, A.Binary) and e.op in ("+", "-", "*"):
            a, b = self.exact_int(e.left), self.exact_int(e.right)
            if a is not None and b is not None:
                v = {"+": a + b, "-": a - b, "*": a * b}[e.op]
        elif isinstance(e, A.Name):
            return self.exact_name(e, lambda u: u.cat not in ("bool", "real", "string"))
        if v is None or isinstance(v, bool):
            return None
        t = T.resolve_base(e.ty) if e.ty is not None else None
        if isinstance(t, T.LiteralType):
            return v if -(1 << 63) <= v < (1 << 63) else None
        return v if isinstance(t, T.Elementary) and self.fits(v, t) else None

    def exact_name(self, e: A.Expr, kind):
        """The value of a name of a CONSTANT that is read as a literal (folded), if its type is of `kind`."""
        if not (isinstance(e, A.Name) and isinstance(e.sym, VarSym)):
            return None
        g = e.sym.global_sym if e.sym.section == "VAR_EXTERNAL" else e.sym
        if g is None or not isinstance(g.type, T.Elementary) or not kind(g.type) or self.folded(g) is None:
            return None
        return g.const_value

    @staticmethod
    def fits(v, t: T.Elementary) -> bool:
        if isinstance(v, bool):
            return False
        if t.cat in ("time", "date", "tod", "dt"):
            return -(1 << 63) <= v < (1 << 63)
        return t.lo <= v <= t.hi

    def ex(self, e: A.Expr) -> str:
        """The C expression of `e`, by its kind's `x_<Kind>` method; a kind without one is a compiler bug."""
        return A.handler(self, "x_", e, "the C generator", "the expression")(e)

    def x_IntLit(self, e: A.IntLit) -> str:
        return self.int_const(e.value, e.ty)

    def int_const(self, v: int, t) -> str:
        b = T.resolve_base(t) if t is not None else T.DINT
        if isinstance(b, T.Elementary) and b.cat == "real":
            return f"(({b.ctype}){float(v)!r})"
        if isinstance(b, T.Elementary) and b.cat in ("uint", "bit", "bool"):
            return f"(({b.ctype}){v & ((1 << max(b.bits, 1)) - 1)}ULL)"
        ct = b.ctype if isinstance(b, T.Elementary) else "int64_t"
        if v == -(1 << 63):
            return f"(({ct})INT64_MIN)"
        if v < -(1 << 63) or v >= (1 << 64):
            v = v & ((1 << 64) - 1)
        if v >= (1 << 63):
            return f"(({ct}){v}ULL)"
        return f"(({ct}){v}LL)"

    def x_RealLit(self, e: A.RealLit) -> str:
        b = T.resolve_base(e.ty) if e.ty is not None else T.LREAL
        ct = b.ctype if isinstance(b, T.Elementary) and b.cat == "real" else "double"
        v = repr(float(e.value))
        if v in ("inf", "-inf", "nan"):
            v = {"inf": "INFINITY", "-inf": "(-INFINITY)", "nan": "NAN"}[v]
        return f"(({ct}){v})"

    def x_BoolLit(self, e: A.BoolLit) -> str:
        return "1" if e.value else "0"

    def x_StrLit(self, e: A.StrLit) -> str:
        raw = e.value.encode("latin-1", "replace")
        return f"plc_str({c_string(e.value)}, {min(len(raw), 126)})"

    def x_TimeLit(self, e: A.TimeLit) -> str:
        return f"((int64_t){e.value}LL)"

    def x_EnumLit(self, e: A.EnumLit) -> str:
        if not isinstance(e.sym, EnumValueSym):
            raise InternalError(e.pos, f"enumerated value {e.type_name}#{e.value} reached the C generator untyped")
        return str(e.sym.index)

    def x_Name(self, e: A.Name) -> str:
        sym = e.sym
        if isinstance(sym, EnumValueSym):
            return str(sym.index)
        if sym is CURRENT_TIME:
            return "plc_clock"
        if sym is ENO:
            return "(*ENO__)" if self.fn is not None else "self->ENO"
        if sym is EN:
            return "((uint8_t)1)" if self.fn is not None else "self->EN"
        if isinstance(sym, FuncSym):
            return "RESULT__"
        if isinstance(sym, VarSym):
            return self.for_locals.get(id(sym)) or self.folded(sym) or self.var_ref(sym)
        raise InternalError(e.pos, f"name {e.name} reached the C generator unresolved")

    def x_Member(self, e: A.Member) -> str:
        if e.name == "ENO" and isinstance(T.resolve_base(e.base.ty), T.PouType):
            return f"{self.ex(e.base)}.ENO"      # the implicit field of every instance (no variable is named ENO)
        return f"{self.ex(e.base)}.{cid(e.name)}"

    def x_Index(self, e: A.Index) -> str:
        base = self.ex(e.base)
        t = T.resolve_base(e.base.ty)
        out = base
        idx = list(e.indices)
        while idx and isinstance(t, T.ArrayType):
            subs = []
            for (lo, hi), i in zip(t.dims, idx, strict=False):   # this array's indices; the rest index its elements
                cv = self.const_value(i)
                if cv is not None and lo <= cv <= hi:
                    subs.append(f"[{cv - lo}]")
                else:
                    subs.append(f"[plc_idx((int64_t)({self.ex(i)}), {lo}, {hi}, {self.site(i.pos)})]")
            out = f"{out}.e{''.join(subs)}"
            idx = idx[len(t.dims):]
            t = T.resolve_base(t.elem)
        return out

    def const_value(self, e):
        if isinstance(e, A.IntLit):
            return e.value
        if (isinstance(e, A.Name) and isinstance(e.sym, VarSym) and e.sym.constant
                and isinstance(e.sym.const_value, int)):
            return e.sym.const_value
        return None

    def x_BitAccess(self, e: A.BitAccess) -> str:
        return f"((uint8_t)((((uint64_t)({self.ex(e.base)})) >> {e.bit}) & 1u))"

    def x_Unary(self, e: A.Unary) -> str:
        t = T.resolve_base(e.ty)
        x = self.conv_to(e.operand, t) if not isinstance(t, T.LiteralType) else self.ex(e.operand)
        if e.op == "NOT":
            if isinstance(t, T.Elementary) and t.cat == "bool":
                return f"(!{x})"
            return f"(({self.ctype(t)})~{x})"
        if e.op == "+":
            return x
        if isinstance(t, T.Elementary) and t.cat in ("int", "uint", "time"):
            return f"PLC_NEG({t.ctype}, uint{t.bits}_t, {x})"
        return f"(-{x})"

    def x_Binary(self, e: A.Binary) -> str:
        op = e.op
        lt, rt = T.resolve_base(e.left.ty), T.resolve_base(e.right.ty)
        if op in ("=", "<>", "<", ">", "<=", ">="):
            cop = {"=": "==", "<>": "!="}.get(op, op)
            if T.is_elem(lt, "string") or isinstance(lt, T.StringType):
                return f"(plc_str_cmp({self.ex(e.left)}, {self.ex(e.right)}) {cop} 0)"
            return c_compare(self.ex(e.left), cop, self.ex(e.right))
        t = T.resolve_base(e.ty)
        if isinstance(t, T.LiteralType):
            t = T.LINT if t.cat == "int" else T.LREAL
        a, b = self.ex(e.left), self.ex(e.right)
        if op in ("AND", "OR") and isinstance(t, T.Elementary) and t.cat == "bool":
            # MATIEC emits && and || for BOOL: the right operand is not evaluated when the left decides
            return f"((uint8_t)({a} {'&&' if op == 'AND' else '||'} {b}))"
        if op in ("AND", "OR", "XOR"):
            cop = {"AND": "&", "OR": "|", "XOR": "^"}[op]
            return f"(({self.ctype(t)})({a} {cop} {b}))"
        if op == "**":
            return f"(({t.ctype})pow((double)({a}), (double)({b})))"
        if isinstance(t, T.Elementary) and t.cat in ("time", "tod", "dt", "date"):
            if op in ("+", "-") and isinstance(lt, T.Elementary) and isinstance(rt, T.Elementary) and \
                    lt.cat in ("time", "tod", "dt", "date") and rt.cat in ("time", "tod", "dt", "date"):
                return f"PLC_{'ADD' if op == '+' else 'SUB'}(int64_t, uint64_t, {a}, {b})"
            if op == "*":
                tv, k, kt = (a, b, rt) if T.is_elem(lt, "time") else (b, a, lt)
                if T.is_elem(kt, "real"):
                    return f"plc_time_mul({tv}, (double)({k}))"
                return f"plc_time_muli({tv}, (int64_t)({k}))"
            if op == "/":
                if T.is_elem(rt, "real"):
                    return f"plc_time_divr({a}, (double)({b}))"
                return f"plc_time_divi({a}, (int64_t)({b}), {self.site(e.pos)})"
        if isinstance(t, T.Elementary) and t.cat in ("int", "uint"):
            u = f"uint{t.bits}_t"
            if op == "+":
                return f"PLC_ADD({t.ctype}, {u}, {a}, {b})"
            if op == "-":
                return f"PLC_SUB({t.ctype}, {u}, {a}, {b})"
            if op == "*":
                return f"PLC_MUL({t.ctype}, {u}, {a}, {b})"
            suffix = ("i" if t.cat == "int" else "u") + str(t.bits)
            if op == "/":
                return f"plc_div_{suffix}({a}, {b}, {self.site(e.pos)})"
            if op == "MOD":
                return f"plc_mod_{suffix}({a}, {b})"
        if isinstance(t, T.Elementary) and t.cat == "real":
            cop = {"+": "+", "-": "-", "*": "*", "/": "/"}.get(op, "+")
            return f"(({t.ctype})({a} {cop} {b}))"
        return f"({a} {op} {b})"

    def conv_to(self, e: A.Expr, t: T.Type) -> str:
        """The C value of `e`, as type `t` (assignment context; types already checked)."""
        x = self.ex(e)
        dst, src = T.resolve_base(t), T.resolve_base(e.ty)
        if isinstance(t, T.StringType):
            return f"plc_str_limit({x}, {t.length})"
        if isinstance(dst, T.Elementary) and isinstance(src, T.Elementary) and dst is not src:
            return f"(({dst.ctype})({x}))"
        return x
