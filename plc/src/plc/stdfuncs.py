"""The IEC standard functions: signature, type check and C emitter of each, side by side.

Each entry knows its parameter names (for formal calls), how to type-check a
call (`kind`, as MATIEC checks it) and how to write it in C (`emit`, called by
the C generator with the call's resolved arguments and result type).
Conversions (`INT_TO_DINT`, …) are recognised by name in `conversion()`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from . import ast as A
from . import types as T

CONV_TYPES = {
    "BOOL": T.BOOL, "SINT": T.SINT, "INT": T.INT, "DINT": T.DINT, "LINT": T.LINT,
    "USINT": T.USINT, "UINT": T.UINT, "UDINT": T.UDINT, "ULINT": T.ULINT,
    "BYTE": T.BYTE, "WORD": T.WORD, "DWORD": T.DWORD, "LWORD": T.LWORD,
    "REAL": T.REAL, "LREAL": T.LREAL, "TIME": T.TIME, "DATE": T.DATE, "TOD": T.TOD,
    "TIME_OF_DAY": T.TOD, "DT": T.DT, "DATE_AND_TIME": T.DT, "STRING": T.STRING,
}

# conversions between date/time kinds that make sense
_TIME_KINDS = ("time", "date", "tod", "dt")


def conversion(name: str):
    """(source type, destination type, generic?) for a conversion function name, else None."""
    if name.startswith("TO_") and name[3:] in CONV_TYPES:
        return (None, CONV_TYPES[name[3:]], True)
    if "_TO_" not in name:
        return None
    for i in range(len(name)):
        if name.startswith("_TO_", i):
            src, dst = name[:i], name[i + 4:]
            if src in CONV_TYPES and dst in CONV_TYPES:
                s, d = CONV_TYPES[src], CONV_TYPES[dst]
                if s is d:
                    return (s, d, False)
                if s.cat in _TIME_KINDS and d.cat in _TIME_KINDS:
                    ok = {("dt", "tod"), ("dt", "date")}
                    if (s.cat, d.cat) not in ok:
                        return None
                if s.cat == "string" and d.cat in ("date", "tod", "dt"):
                    return None
                return (s, d, False)
    return None


# An emitter: (C generator, call, input values in parameter order, result type) -> C expression.
Emitter = Callable[..., str]


@dataclass
class StdFunc(A.Symbol):
    name: str
    kind: str                  # see check()
    params: tuple[str, ...] = ()
    extensible: bool = False
    emit: Emitter | None = None

    # ----------------------------------------------------------------------------------
    def bind(self, an, c: A.Call) -> list[A.Expr] | None:
        """Order the arguments of a call positionally; report bad parameter names."""
        outs = [a for a in c.args if a.output]
        for a in outs:
            if a.name != "ENO":
                an.err(a.pos, f"{self.name} has no output '{a.text or a.name}'")
        args = [a for a in c.args if not a.output and a.name != "EN"]
        for a in args:
            if a.value is None:                 # `IN := ,`
                an.err(a.pos, f"argument '{a.text or a.name}' of {self.name} has no value")
                return None
        if any(a.name is not None for a in args):
            if any(a.name is None for a in args):
                an.err(c.pos, f"call of {self.name} mixes positional and formal arguments")
                return None
            by_name = {a.name: a.value for a in args}
            names = list(self.params)
            if self.extensible:
                n = len(args)
                names = [p for p in names if not p.startswith("IN")] + [f"IN{i}" for i in range(1, n + 1)]
                if self.kind == "mux":
                    names = ["K"] + [f"IN{i}" for i in range(0, n - 1)]
            out = []
            for p in names:
                if p in by_name:
                    out.append(by_name.pop(p))
                elif not self.extensible or p in self.params:
                    an.err(c.pos, f"call of {self.name} is missing '{p}'")
                    return None
            for extra in by_name:
                an.err(c.pos, f"{self.name} has no parameter '{extra}'", f"its parameters are {', '.join(names)}")
                return None
            return out
        return [a.value for a in args]

    def check(self, an, c: A.Call, scope, expected) -> T.Type:
        for a in c.args:
            if a.name == "EN" and not a.output:
                if a.value is None:
                    an.err(a.pos, "EN := needs a value")
                    continue
                an.expr_typing.expr(a.value, scope, T.BOOL)
            if a.name == "ENO" and a.output and a.value is not None:
                tt = an.stmt_pass.lvalue(a.value, "write ENO into")
                an.assign_compat(a.value, T.BOOL, tt, a.pos, "ENO")
        args = self.bind(an, c)
        if args is None:
            return T.ERROR
        n = len(args)
        fixed = len(self.params)
        if self.extensible:
            if n < 2 and self.kind != "mux":
                an.err(c.pos, f"{self.name} needs at least 2 inputs")
                return T.ERROR
            if self.kind == "mux" and n < 2:
                an.err(c.pos, "MUX needs K and at least one input")
                return T.ERROR
        elif n != fixed:
            an.err(c.pos, f"{self.name} takes {fixed} input{'s' if fixed != 1 else ''} "
                          f"({', '.join(self.params)}), got {n}")
            for v in args:
                an.expr_typing.expr(v, scope, None)
            return T.ERROR
        c.std_args = args
        return getattr(self, "k_" + self.kind)(an, c, args, scope, expected)

    # -- helpers -----------------------------------------------------------------------
    def same(self, an, c, args, scope, expected, generic: str) -> T.Type:
        """All arguments share one type (literals adapt); return it."""
        tys = [an.expr_typing.expr(v, scope, None) for v in args]
        concrete = [T.resolve_base(t) for t in tys if not isinstance(T.resolve_base(t), T.LiteralType)]
        if any(isinstance(t, T.ErrorType) for t in concrete):
            return T.ERROR
        if concrete:
            target = concrete[0]
        elif expected is not None and not isinstance(T.resolve_base(expected), T.LiteralType):
            target = T.resolve_base(expected)
        else:
            lits = [T.resolve_base(t) for t in tys]
            target = T.LREAL if any(getattr(t, "cat", "") == "real" for t in lits) else T.DINT
        for v, t in zip(args, tys, strict=True):
            if isinstance(T.resolve_base(t), T.LiteralType):
                an.expr_typing.fix_literal(v, target)
                if isinstance(v.ty, T.LiteralType):
                    an.err(v.pos, f"{self.name}: this literal does not fit {target}")
                    return T.ERROR
            elif not T.same_type(t, target):
                an.err(v.pos, f"{self.name}: all inputs must have the same type ({target} and {t})",
                       an.expr_typing.conv_hint(t, target))
                return T.ERROR
        if not T.is_generic_ok(generic, target):
            an.err(c.pos, f"{self.name} needs {generic} inputs, not {target}")
            return T.ERROR
        return target

    def one(self, an, v, scope, want: T.Type) -> None:
        t = an.expr_typing.expr(v, scope, want)
        an.assign_compat(v, t, want, v.pos, f"{self.name} input")

    # -- kinds -------------------------------------------------------------------------
    def k_num1(self, an, c, args, scope, expected):
        return self.same(an, c, args, scope, expected, "ANY_NUM")

    def k_real1(self, an, c, args, scope, expected):
        return self.same(an, c, args, scope, expected, "ANY_REAL")

    def k_arith(self, an, c, args, scope, expected):
        tys = [T.resolve_base(an.expr_typing.expr(v, scope, None)) for v in args]
        if any(isinstance(t, T.Elementary) and t.cat == "time" for t in tys):
            c.time_arith = True
            for v, t in zip(args[1:], tys[1:], strict=True):
                if isinstance(t, T.LiteralType):
                    an.expr_typing.fix_literal(v, T.DINT if t.cat == "int" else T.LREAL)
            return T.TIME
        return self.same(an, c, args, scope, expected, "ANY_NUM")

    def k_expt(self, an, c, args, scope, expected):
        b = an.expr_typing.expr(args[0], scope, expected if T.is_elem(expected or T.ERROR, "real") else T.LREAL)
        e = an.expr_typing.expr(args[1], scope, None)
        bb = T.resolve_base(b)
        if isinstance(T.resolve_base(e), T.LiteralType):
            an.expr_typing.fix_literal(args[1], T.LREAL if T.resolve_base(e).cat == "real" else T.DINT)
        if not T.is_elem(bb, "real"):
            if not isinstance(bb, T.ErrorType):
                an.err(args[0].pos, f"EXPT needs a REAL or LREAL base, not {b}")
            return T.ERROR
        if not T.is_elem(args[1].ty or T.ERROR, "int", "uint", "real"):
            an.err(args[1].pos, "EXPT exponent must be a number")
        return bb

    def k_move(self, an, c, args, scope, expected):
        t = an.expr_typing.expr(args[0], scope, expected)
        return t

    def k_minmax(self, an, c, args, scope, expected):
        t = self.same(an, c, args, scope, expected, "ANY_ELEMENTARY")
        if isinstance(t, (T.StructType, T.ArrayType)):
            an.err(c.pos, f"{self.name} needs elementary inputs")
            return T.ERROR
        return t

    def k_limit(self, an, c, args, scope, expected):
        return self.same(an, c, args, scope, expected, "ANY_ELEMENTARY")

    def k_sel(self, an, c, args, scope, expected):
        self.one(an, args[0], scope, T.BOOL)
        return self.no_enum(an, c, self.same(an, c, args[1:], scope, expected, "ANY"))

    def no_enum(self, an, c, t: T.Type) -> T.Type:
        """SEL and MUX of enumeration values: ours takes them, MATIEC has no overload for them."""
        if isinstance(T.resolve_base(t), T.EnumType):
            an.port(c.pos, "enum-select", call=self.name)
        return t

    def k_mux(self, an, c, args, scope, expected):
        kt = an.expr_typing.expr(args[0], scope, T.DINT)
        if isinstance(T.resolve_base(kt), T.LiteralType):
            an.expr_typing.fix_literal(args[0], T.DINT)
        elif not T.is_elem(kt, "int", "uint"):
            an.err(args[0].pos, f"MUX selector K must be an integer, not {kt}")
        return self.no_enum(an, c, self.same(an, c, args[1:], scope, expected, "ANY"))

    def k_shift(self, an, c, args, scope, expected):
        t = an.expr_typing.expr(args[0], scope, expected)
        b = T.resolve_base(t)
        if isinstance(b, T.LiteralType):
            an.err(args[0].pos, f"{self.name} needs a typed bit string; write WORD#16#...")
            return T.ERROR
        if not (isinstance(b, T.Elementary) and b.cat == "bit"):
            if not isinstance(b, T.ErrorType):
                an.err(args[0].pos, f"{self.name} needs a bit string (BYTE, WORD, DWORD, LWORD), not {t}")
            return T.ERROR
        nt = an.expr_typing.expr(args[1], scope, T.DINT)
        if isinstance(T.resolve_base(nt), T.LiteralType):
            an.expr_typing.fix_literal(args[1], T.DINT)
        elif not T.is_elem(nt, "int", "uint"):
            an.err(args[1].pos, f"{self.name} count N must be an integer, not {nt}")
        return b

    def k_logic(self, an, c, args, scope, expected):
        return self.same(an, c, args, scope, expected, "ANY_BIT")

    def k_not(self, an, c, args, scope, expected):
        return self.same(an, c, args, scope, expected, "ANY_BIT")

    def k_compare(self, an, c, args, scope, expected):
        self.same(an, c, args, scope, None, "ANY_ELEMENTARY")
        return T.BOOL

    def k_len(self, an, c, args, scope, expected):
        self.one(an, args[0], scope, T.STRING)
        return T.INT

    def k_strint(self, an, c, args, scope, expected):
        """LEFT(IN, L), RIGHT(IN, L)."""
        self.one(an, args[0], scope, T.STRING)
        self.int_arg(an, args[1], scope)
        return T.STRING

    def int_arg(self, an, v, scope):
        t = an.expr_typing.expr(v, scope, T.INT)
        if isinstance(T.resolve_base(t), T.LiteralType):
            an.expr_typing.fix_literal(v, T.INT)
        elif not T.is_elem(t, "int", "uint"):
            an.err(v.pos, f"{self.name}: expected an integer, not {t}")

    def k_mid(self, an, c, args, scope, expected):
        self.one(an, args[0], scope, T.STRING)
        self.int_arg(an, args[1], scope)
        self.int_arg(an, args[2], scope)
        return T.STRING

    def k_concat(self, an, c, args, scope, expected):
        for v in args:
            self.one(an, v, scope, T.STRING)
        return T.STRING

    def k_insert(self, an, c, args, scope, expected):
        self.one(an, args[0], scope, T.STRING)
        self.one(an, args[1], scope, T.STRING)
        self.int_arg(an, args[2], scope)
        return T.STRING

    def k_delete(self, an, c, args, scope, expected):
        self.one(an, args[0], scope, T.STRING)
        self.int_arg(an, args[1], scope)
        self.int_arg(an, args[2], scope)
        return T.STRING

    def k_replace(self, an, c, args, scope, expected):
        self.one(an, args[0], scope, T.STRING)
        self.one(an, args[1], scope, T.STRING)
        self.int_arg(an, args[2], scope)
        self.int_arg(an, args[3], scope)
        return T.STRING

    def k_find(self, an, c, args, scope, expected):
        self.one(an, args[0], scope, T.STRING)
        self.one(an, args[1], scope, T.STRING)
        return T.INT

    def k_trunc(self, an, c, args, scope, expected):
        t = an.expr_typing.expr(args[0], scope, T.LREAL)
        if isinstance(T.resolve_base(t), T.LiteralType):
            an.expr_typing.fix_literal(args[0], T.LREAL)
        elif not T.is_elem(t, "real"):
            an.err(args[0].pos, f"TRUNC needs a REAL or LREAL, not {t}")
        return T.DINT


# ------------------------------------------------------------------------------ C emitters --
# Each takes the C generator `g` (for g.ex, g.conv_to, g.ctype, ...), the call, its inputs in parameter
# order and the call's resolved result type `t`.

def e_abs(g, c, args, t) -> str:
    x, ct = g.conv_to(args[0], t), g.ctype(t)
    if isinstance(t, T.Elementary) and t.cat == "int":
        return f"(({x}) < 0 ? PLC_NEG({ct}, uint{t.bits}_t, {x}) : ({x}))"
    if isinstance(t, T.Elementary) and t.cat == "real":
        return f"(({ct})fabs({x}))"
    return x


def e_libm(g, c, args, t) -> str:
    fn = {"LN": "log", "LOG": "log10"}.get(c.target.name, c.target.name.lower())
    return f"(({g.ctype(t)}){fn}((double)({g.conv_to(args[0], t)})))"


def e_expt(g, c, args, t) -> str:
    return f"(({g.ctype(t)})pow((double)({g.ex(args[0])}), (double)({g.ex(args[1])})))"


ARITH_OPS = {"ADD": "+", "SUB": "-", "MUL": "*", "DIV": "/", "MOD": "MOD"}


def e_arith(g, c, args, t) -> str:
    """The arithmetic functions are the operators: ADD(a, b, c) is written as (a + b) + c."""
    n = c.target.name
    if c.time_arith:
        expr = A.Binary(c.pos, ARITH_OPS[n] if n != "MOD" else "+", args[0], args[1])
        expr.ty = T.TIME
        return g.x_Binary(expr)
    acc = args[0]
    for nxt in args[1:]:
        b = A.Binary(c.pos, ARITH_OPS[n], acc, nxt)
        b.ty = t
        acc = b
    return g.x_Binary(acc)


def e_move(g, c, args, t) -> str:
    return g.ex(args[0])


def e_minmax(g, c, args, t) -> str:
    n = c.target.name
    g.tmp += 1
    cmp = "<" if n == "MIN" else ">"
    xs = [g.conv_to(a, t) for a in args]
    acc = xs[0]
    for x in xs[1:]:
        if T.is_elem(t, "string"):
            acc = f"(plc_str_cmp({x}, {acc}) {cmp} 0 ? {x} : {acc})"
        else:
            acc = f"plc_{n.lower()}_{g.suffix(t)}({acc}, {x})"
    return acc


def e_limit(g, c, args, t) -> str:
    mn, x, mx = (g.conv_to(a, t) for a in args)
    if T.is_elem(t, "string"):
        return f"(plc_str_cmp({x}, {mn}) < 0 ? {mn} : (plc_str_cmp({x}, {mx}) > 0 ? {mx} : {x}))"
    return f"plc_max_{g.suffix(t)}({mn}, plc_min_{g.suffix(t)}({x}, {mx}))"


def e_sel(g, c, args, t) -> str:
    return f"(({g.ex(args[0])}) ? ({g.conv_to(args[2], t)}) : ({g.conv_to(args[1], t)}))"


def e_mux(g, c, args, t) -> str:
    k = g.ex(args[0])
    ins = [g.conv_to(a, t) for a in args[1:]]
    expr = g.default_value(t)          # selector out of range: 0, as MATIEC
    for i in range(len(ins) - 1, -1, -1):
        expr = f"(({k}) == {i} ? ({ins[i]}) : {expr})"
    return expr


def e_shift(g, c, args, t) -> str:
    fn = c.target.name.lower()
    return f"(({g.ctype(t)})plc_{fn}((uint64_t)({g.ex(args[0])}), (int64_t)({g.ex(args[1])}), {t.bits}))"


def e_logic(g, c, args, t) -> str:
    cop = {"AND": "&", "OR": "|", "XOR": "^"}[c.target.name]
    return f"(({g.ctype(t)})({f' {cop} '.join(g.conv_to(a, t) for a in args)}))"


def e_not(g, c, args, t) -> str:
    x = g.conv_to(args[0], t)
    return f"(!{x})" if T.is_elem(t, "bool") else f"(({g.ctype(t)})~{x})"


def e_compare(g, c, args, t) -> str:
    """The comparison functions are the comparison operators."""
    op = {"GT": ">", "GE": ">=", "EQ": "=", "LE": "<=", "LT": "<", "NE": "<>"}[c.target.name]
    cmp = A.Binary(c.pos, op, args[0], args[1])
    cmp.ty = T.BOOL
    return g.x_Binary(cmp)


def e_len(g, c, args, t) -> str:
    return f"plc_len({g.ex(args[0])})"


def e_leftright(g, c, args, t) -> str:
    return f"plc_{c.target.name.lower()}({g.ex(args[0])}, (int64_t)({g.ex(args[1])}))"


def e_mid(g, c, args, t) -> str:
    return f"plc_mid({g.ex(args[0])}, (int64_t)({g.ex(args[1])}), (int64_t)({g.ex(args[2])}))"


def e_concat(g, c, args, t) -> str:
    acc = g.ex(args[0])
    for a in args[1:]:
        acc = f"plc_concat({acc}, {g.ex(a)})"
    return acc


def e_insert(g, c, args, t) -> str:
    return f"plc_insert({g.ex(args[0])}, {g.ex(args[1])}, (int64_t)({g.ex(args[2])}))"


def e_delete(g, c, args, t) -> str:
    return f"plc_delete({g.ex(args[0])}, (int64_t)({g.ex(args[1])}), (int64_t)({g.ex(args[2])}))"


def e_replace(g, c, args, t) -> str:
    return (f"plc_replace({g.ex(args[0])}, {g.ex(args[1])}, (int64_t)({g.ex(args[2])}), "
            f"(int64_t)({g.ex(args[3])}))")


def e_find(g, c, args, t) -> str:
    return f"plc_find({g.ex(args[0])}, {g.ex(args[1])})"


def e_trunc(g, c, args, t) -> str:
    return f"((int32_t)plc_trunc((double)({g.ex(args[0])})))"


# ---------------------------------------------------------------------------------- table --
def _table() -> dict[str, StdFunc]:
    t: dict[str, StdFunc] = {}
    for n in ("ABS",):
        t[n] = StdFunc(n, "num1", ("IN",), emit=e_abs)
    for n in ("SQRT", "LN", "LOG", "EXP", "SIN", "COS", "TAN", "ASIN", "ACOS", "ATAN"):
        t[n] = StdFunc(n, "real1", ("IN",), emit=e_libm)
    t["ADD"] = StdFunc("ADD", "arith", ("IN1", "IN2"), extensible=True, emit=e_arith)
    t["MUL"] = StdFunc("MUL", "arith", ("IN1", "IN2"), extensible=True, emit=e_arith)
    t["SUB"] = StdFunc("SUB", "arith", ("IN1", "IN2"), emit=e_arith)
    t["DIV"] = StdFunc("DIV", "arith", ("IN1", "IN2"), emit=e_arith)
    t["MOD"] = StdFunc("MOD", "arith", ("IN1", "IN2"), emit=e_arith)
    t["EXPT"] = StdFunc("EXPT", "expt", ("IN1", "IN2"), emit=e_expt)
    t["MOVE"] = StdFunc("MOVE", "move", ("IN",), emit=e_move)
    t["MIN"] = StdFunc("MIN", "minmax", ("IN1", "IN2"), extensible=True, emit=e_minmax)
    t["MAX"] = StdFunc("MAX", "minmax", ("IN1", "IN2"), extensible=True, emit=e_minmax)
    t["LIMIT"] = StdFunc("LIMIT", "limit", ("MN", "IN", "MX"), emit=e_limit)
    t["SEL"] = StdFunc("SEL", "sel", ("G", "IN0", "IN1"), emit=e_sel)
    t["MUX"] = StdFunc("MUX", "mux", ("K", "IN0", "IN1"), extensible=True, emit=e_mux)
    for n in ("SHL", "SHR", "ROL", "ROR"):
        t[n] = StdFunc(n, "shift", ("IN", "N"), emit=e_shift)
    for n in ("AND", "OR", "XOR"):
        t[n] = StdFunc(n, "logic", ("IN1", "IN2"), extensible=True, emit=e_logic)
    t["NOT"] = StdFunc("NOT", "not", ("IN",), emit=e_not)
    for n in ("GT", "GE", "EQ", "LE", "LT", "NE"):
        t[n] = StdFunc(n, "compare", ("IN1", "IN2"), emit=e_compare)
    t["LEN"] = StdFunc("LEN", "len", ("IN",), emit=e_len)
    t["LEFT"] = StdFunc("LEFT", "strint", ("IN", "L"), emit=e_leftright)
    t["RIGHT"] = StdFunc("RIGHT", "strint", ("IN", "L"), emit=e_leftright)
    t["MID"] = StdFunc("MID", "mid", ("IN", "L", "P"), emit=e_mid)
    t["CONCAT"] = StdFunc("CONCAT", "concat", ("IN1", "IN2"), extensible=True, emit=e_concat)
    t["INSERT"] = StdFunc("INSERT", "insert", ("IN1", "IN2", "P"), emit=e_insert)
    t["DELETE"] = StdFunc("DELETE", "delete", ("IN", "L", "P"), emit=e_delete)
    t["REPLACE"] = StdFunc("REPLACE", "replace", ("IN1", "IN2", "L", "P"), emit=e_replace)
    t["FIND"] = StdFunc("FIND", "find", ("IN1", "IN2"), emit=e_find)
    t["TRUNC"] = StdFunc("TRUNC", "trunc", ("IN",), emit=e_trunc)
    return t


STD_FUNCS = _table()
