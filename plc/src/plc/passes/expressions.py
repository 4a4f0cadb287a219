"""Expression typing for the bodies pass: literals, names, members, indices, operators; fills each
expression's `ty` and each name's `sym` annotation with MATIEC's strictness.
"""
from __future__ import annotations

from .. import ast as A
from .. import types as T
from ..symbols import CURRENT_TIME, EN, ENO, EnumValueSym, Scope
from .context import Pass, TIME_KIND_TYPE


class ExpressionTyping(Pass):
    """Asked by the bodies, scopes and configuration passes; no pass of its own."""
    pass_name = "expressions"

    def expr(self, e: A.Expr, scope: Scope | None, expected: T.Type | None, lvalue: bool = False,
             for_init: bool = False) -> T.Type:
        t = self._expr(e, scope, expected, lvalue)
        e.ty = t
        if expected is not None and isinstance(t, T.LiteralType):
            self.fix_literal(e, expected)
        return e.ty

    def fix_literal(self, e: A.Expr, target: T.Type) -> None:
        """Give an untyped literal (sub)expression the concrete type the context needs."""
        b = T.resolve_base(target)
        if not isinstance(b, T.Elementary) or not isinstance(e.ty, T.LiteralType):
            return
        lit = e.ty
        if lit.cat == "int" and b.cat in ("int", "uint", "bit"):
            v = self.const_eval.const_int(e)
            if v is not None and not (b.lo <= v <= b.hi):
                self.err(e.pos, f"literal {v} is out of range for {b.name} ({b.lo}..{b.hi})")
            self.set_type(e, b)
        elif lit.cat == "real" and b.cat == "real":
            self.set_type(e, b)
        elif lit.cat == "int" and b.cat == "real":
            self.set_type(e, b)   # an integer literal as a REAL: allowed, value converted
        elif lit.cat == "int" and b.cat == "bool":
            v = self.const_eval.const_int(e)
            if v in (0, 1):
                self.set_type(e, b)

    def set_type(self, e: A.Expr, t: T.Type) -> None:
        if isinstance(e.ty, T.LiteralType) or e.ty is None:
            e.ty = t
            if isinstance(e, A.Binary):
                self.set_type(e.left, t)
                self.set_type(e.right, t)
            elif isinstance(e, A.Unary):
                self.set_type(e.operand, t)

    def _expr(self, e: A.Expr, scope: Scope | None, expected: T.Type | None, lvalue: bool) -> T.Type:
        """The type of `e`, by its kind's `t_<Kind>` method; a kind without one is a compiler bug."""
        return A.handler(self, "t_", e, "semantic analysis", "the expression")(e, scope, expected)

    def t_IntLit(self, e: A.IntLit, scope, expected) -> T.Type:
        return self.int_lit(e)

    def t_RealLit(self, e: A.RealLit, scope, expected) -> T.Type:
        if e.prefix:
            t = T.ELEMENTARY.get(e.prefix)
            if t is None or not t.is_real:
                self.err(e.pos, f"{e.prefix}# cannot prefix a real literal")
                return T.ERROR
            return t
        return T.ANY_REAL_LIT

    def t_BoolLit(self, e: A.BoolLit, scope, expected) -> T.Type:
        if e.prefix and e.prefix != "BOOL":
            self.err(e.pos, f"{e.prefix}#{'TRUE' if e.value else 'FALSE'} is not a valid literal")
        return T.BOOL

    def t_StrLit(self, e: A.StrLit, scope, expected) -> T.Type:
        if e.prefix and e.prefix not in ("STRING",):
            self.err(e.pos, f"{e.prefix}# cannot prefix a string literal")
        n = len(e.value.encode("latin-1", "replace"))
        if n > 126:
            self.err(e.pos, f"string literal of {n} characters is longer than 126")
        elif n == 126:
            self.port(e.pos, "string-literal")
        return T.STRING

    def t_TimeLit(self, e: A.TimeLit, scope, expected) -> T.Type:
        if e.kind not in TIME_KIND_TYPE:
            self.err(e.pos, f"{e.kind} literals are not supported by MATIEC")
            return T.ERROR
        if e.value is None:          # the parser decoded the text (timelit.decode)
            self.err(e.pos, f"invalid {e.kind} literal '{e.text}'",
                     {"TIME": "e.g. T#1s500ms, T#2.5s, T#-5s", "TOD": "e.g. TOD#12:30:00",
                      "DATE": "e.g. D#2024-01-31", "DT": "e.g. DT#2024-01-31-12:30:00"}[e.kind])
            return T.ERROR
        low = e.text.lower()
        if e.kind == "TIME" and ("us" in low or "ns" in low):
            self.port(e.pos, "time-unit")
        return TIME_KIND_TYPE[e.kind]

    def t_EnumLit(self, e: A.EnumLit, scope, expected) -> T.Type:
        return self.enum_lit(e)

    def t_Name(self, e: A.Name, scope, expected) -> T.Type:
        return self.name(e, scope, expected)

    def t_Member(self, e: A.Member, scope, expected) -> T.Type:
        return self.member(e, scope)

    def t_Index(self, e: A.Index, scope, expected) -> T.Type:
        return self.index(e, scope)

    def t_BitAccess(self, e: A.BitAccess, scope, expected) -> T.Type:
        self.port(e.pos, "bit-access")
        bt = self.expr(e.base, scope, None)
        b = T.resolve_base(bt)
        if not (isinstance(b, T.Elementary) and b.cat in ("bit", "int", "uint") and b.bits > 1):
            if not isinstance(b, T.ErrorType):
                self.err(e.pos, f"bit access needs a bit-string or integer variable, not {bt}")
            return T.ERROR
        if not (0 <= e.bit < b.bits):
            self.err(e.pos, f"bit {e.bit} does not exist in {b.name} (0..{b.bits - 1})")
        return T.BOOL

    def t_Direct(self, e: A.Direct, scope, expected) -> T.Type:
        return self.direct(e)

    def t_Deref(self, e: A.Deref, scope, expected) -> T.Type:
        self.err(e.pos, "pointer dereference '^' is not supported")
        return T.ERROR

    def t_Unary(self, e: A.Unary, scope, expected) -> T.Type:
        return self.unary(e, scope, expected)

    def t_Binary(self, e: A.Binary, scope, expected) -> T.Type:
        return self.binary(e, scope, expected)

    def t_Call(self, e: A.Call, scope, expected) -> T.Type:
        return self.call_typing.call_expr(e, scope, expected)

    def int_lit(self, e: A.IntLit) -> T.Type:
        if e.prefix is None:
            return T.ANY_INT_LIT
        t = T.ELEMENTARY.get(e.prefix)
        if t is None:
            if e.prefix in self.st.type_decls:
                tt = self.type_pass.named_type(e.prefix, e.pos)
                b = T.resolve_base(tt)
                if isinstance(b, T.Elementary) and b.is_int:
                    t = b
            if t is None:
                self.err(e.pos, f"'{e.prefix}#' cannot prefix an integer literal")
                return T.ERROR
        if t.cat == "real":
            return t
        if t.cat == "bool":
            if e.value not in (0, 1):
                self.err(e.pos, f"BOOL#{e.value} is not a BOOL value")
            return T.BOOL
        if t.cat not in ("int", "uint", "bit"):
            self.err(e.pos, f"'{e.prefix}#' cannot prefix an integer literal")
            return T.ERROR
        if not (t.lo <= e.value <= t.hi):
            self.err(e.pos, f"literal {e.value} is out of range for {t.name} ({t.lo}..{t.hi})")
        return t

    def enum_lit(self, e: A.EnumLit) -> T.Type:
        t = self.type_pass.named_type(e.type_name, e.pos) if e.type_name in self.st.type_decls else None
        if t is None:
            self.err(e.pos, f"unknown type '{e.type_name}' in '{e.type_name}#{e.value}'")
            return T.ERROR
        if not isinstance(t, T.EnumType):
            self.err(e.pos, f"'{e.type_name}' is not an enumeration")
            return T.ERROR
        if e.value not in t.values:
            self.err(e.pos, f"'{e.value}' is not a value of {t.name}",
                     f"values: {', '.join(t.values)}")
            return T.ERROR
        e.sym = EnumValueSym(t, e.value)
        return t

    def name(self, e: A.Name, scope: Scope | None, expected: T.Type | None) -> T.Type:
        sym = scope.lookup(e.name) if scope else None
        if sym is None and self.st.func is not None and scope is self.st.func.scope and e.name == self.st.func.name:
            e.sym = self.st.func
            return self.st.func.ret
        if sym is None and e.name == "CURRENT_TIME" and self.in_builtin():
            e.sym = CURRENT_TIME
            return T.TIME
        if sym is None and e.name in ("EN", "ENO") and self.st.current_pou is not None:
            e.sym = EN if e.name == "EN" else ENO       # the POU's implicit EN input / ENO output
            return T.BOOL
        if sym is not None:
            e.sym = sym
            return sym.type
        enums = self.st.prog.enum_values.get(e.name)
        if enums:
            exp = T.resolve_base(expected) if expected is not None else None
            if len(enums) == 1:
                et = enums[0]
            elif isinstance(exp, T.EnumType) and exp in enums:
                et = exp
                self.port(e.pos, "enum-qualify", value=e.text, enums=', '.join(x.name for x in enums), enum=et.name)
            else:
                self.err(e.pos, f"enumeration value '{e.text}' is ambiguous ({', '.join(x.name for x in enums)})",
                         f"qualify it: {enums[0].name}#{e.text}")
                return T.ERROR
            e.sym = EnumValueSym(et, e.name)
            return et
        if e.name in self.st.pou_decls:
            self.err(e.pos, f"'{e.text}' is a POU, not a variable")
            return T.ERROR
        cands = list(scope.vars) if scope else []
        self.err(e.pos, f"undeclared variable '{e.text}'", self.type_pass.suggest(e.name, cands))
        return T.ERROR

    def member(self, e: A.Member, scope: Scope | None) -> T.Type:
        bt = self.expr(e.base, scope, None)
        b = T.resolve_base(bt)
        if isinstance(b, T.ErrorType):
            return T.ERROR
        if isinstance(b, T.StructType):
            m = b.members.get(e.name)
            if m is None:
                self.err(e.pos, f"'{b.name}' has no member '{e.text}'", self.type_pass.suggest(e.name, b.members))
                return T.ERROR
            return m.type
        if isinstance(b, T.PouType):
            v = b.scope.lookup(e.name) if b.scope else None
            if e.name == "ENO" and v is None:
                return T.BOOL                               # the instance's implicit ENO, read as MATIEC reads it
            if e.name == "EN" and v is None:
                # MATIEC refuses it (a syntax error) and a call without EN := runs the body whatever it holds
                self.err(e.pos, f"EN of an instance cannot be read or written from outside ('{e.text}')",
                         "EN belongs to a call (EN := ...); keep the value you pass in a variable of your own")
                return T.BOOL
            if v is None:
                self.err(e.pos, f"{b.name} has no member '{e.text}'",
                         self.type_pass.suggest(e.name, b.scope.vars if b.scope else []))
                return T.ERROR
            if v.section in ("VAR", "VAR_TEMP", "VAR_EXTERNAL") and not self.in_builtin():
                self.err(e.pos, f"'{e.text}' is internal to {b.name}; only inputs and outputs can be read from outside")
                return v.type
            e.sym = v
            return v.type
        self.err(e.pos, f"{bt} has no members ('.{e.text}')")
        return T.ERROR

    def index(self, e: A.Index, scope: Scope | None) -> T.Type:
        bt = self.expr(e.base, scope, None)
        b = T.resolve_base(bt)
        for i in e.indices:
            literal = isinstance(T.resolve_base(self.peek_type(i, scope)), T.LiteralType)
            it = self.expr(i, scope, T.DINT if literal else None)
            if not isinstance(it, T.ErrorType) and not T.is_elem(it, "int", "uint"):
                self.err(i.pos, f"array index must be an integer, not {it}")
        if isinstance(b, T.ErrorType):
            return T.ERROR
        if not isinstance(b, T.ArrayType):
            self.err(e.pos, f"{bt} is not an array")
            return T.ERROR
        t: T.Type = b
        idx = list(e.indices)
        while idx:
            tb = T.resolve_base(t)
            if not isinstance(tb, T.ArrayType):
                self.err(idx[0].pos, "too many indices for the array")
                return T.ERROR
            n = min(len(idx), len(tb.dims))
            if len(idx) < len(tb.dims):
                self.err(e.pos, f"array needs {len(tb.dims)} indices, got {len(idx)}")
                return T.ERROR
            for k in range(n):
                v = self.const_eval.const_int(idx[k])
                lo, hi = tb.dims[k]
                if v is not None and not (lo <= v <= hi):
                    self.err(idx[k].pos, f"index {v} is out of bounds {lo}..{hi}")
            idx = idx[n:]
            t = tb.elem
        return t

    def peek_type(self, e: A.Expr, scope) -> T.Type:
        if isinstance(e, A.IntLit) and e.prefix is None:
            return T.ANY_INT_LIT
        return T.ERROR

    def direct(self, e: A.Direct) -> T.Type:
        self.err(e.pos, f"a direct address in code ({e.text}) is not supported (MATIEC rejects it too)",
                 f"declare a located variable: name AT {e.text} : type;", code="direct-in-code")
        return T.ERROR

    def unary(self, e: A.Unary, scope, expected) -> T.Type:
        t = self.expr(e.operand, scope, expected if e.op != "NOT" else None)
        b = T.resolve_base(t)
        if isinstance(b, T.ErrorType):
            return T.ERROR
        if e.op == "NOT":
            if isinstance(b, T.LiteralType):
                if expected is not None and T.is_elem(expected, "bit"):
                    self.fix_literal(e.operand, expected)
                    return e.operand.ty
                self.err(e.pos, "NOT needs a BOOL or bit-string operand; give the literal a type (WORD#...)")
                return T.ERROR
            if not (isinstance(b, T.Elementary) and b.is_bit):
                self.err(e.pos, f"NOT needs a BOOL or bit-string operand, not {t}")
                return T.ERROR
            return b
        if isinstance(b, T.LiteralType):
            return b
        if not (isinstance(b, T.Elementary) and (b.is_num or b.cat == "time")):
            self.err(e.pos, f"unary '{e.op}' needs a number, not {t}")
            return T.ERROR
        if e.op == "-" and b.cat == "uint":
            self.err(e.pos, f"unary '-' on unsigned {b.name}")
        if e.op == "-" and b.cat == "time":
            self.port(e.pos, "openplc-time-negate", type=b.name)
        return b

    ARITH = ("+", "-", "*", "/", "MOD", "**")
    COMPARE = ("=", "<>", "<", ">", "<=", ">=")
    LOGIC = ("AND", "OR", "XOR")

    def binary(self, e: A.Binary, scope, expected) -> T.Type:
        op = e.op
        lt = self.expr(e.left, scope, None)
        rt = self.expr(e.right, scope, None)
        lb, rb = T.resolve_base(lt), T.resolve_base(rt)
        if isinstance(lb, T.ErrorType) or isinstance(rb, T.ErrorType):
            return T.ERROR
        if op == "**":
            self.port(e.pos, "power")
            if not (T.is_elem(lb, "real") or isinstance(lb, T.LiteralType)):
                self.err(e.pos, f"'**' needs a REAL or LREAL base, not {lt}")
                return T.ERROR
            if isinstance(lb, T.LiteralType):
                self.fix_literal(e.left, expected if T.is_elem(expected or T.ERROR, "real") else T.LREAL)
                lb = T.resolve_base(e.left.ty)
            if isinstance(rb, T.LiteralType):
                self.fix_literal(e.right, T.DINT if rb.cat == "int" else lb)
            return lb
        # time arithmetic
        if op in ("+", "-", "*", "/") and (T.is_elem(lb, "time", "date", "tod", "dt")
                                           or T.is_elem(rb, "time", "date", "tod", "dt")):
            return self.time_arith(e, lb, rb)
        # settle literals against the other side
        if isinstance(lb, T.LiteralType) and not isinstance(rb, T.LiteralType):
            self.fix_literal(e.left, rb)
            lb = T.resolve_base(e.left.ty)
        elif isinstance(rb, T.LiteralType) and not isinstance(lb, T.LiteralType):
            self.fix_literal(e.right, lb)
            rb = T.resolve_base(e.right.ty)
        elif isinstance(lb, T.LiteralType) and isinstance(rb, T.LiteralType):
            if op in self.COMPARE:
                lit = T.ANY_REAL_LIT if "real" in (lb.cat, rb.cat) else T.ANY_INT_LIT
                tgt = T.LREAL if lit.cat == "real" else T.LINT
                self.fix_literal(e.left, tgt)
                self.fix_literal(e.right, tgt)
                return T.BOOL
            if op in self.LOGIC:
                if expected is not None and T.is_elem(expected, "bit", "bool"):
                    self.fix_literal(e.left, expected)
                    self.fix_literal(e.right, expected)
                    return T.resolve_base(expected)
                self.err(e.pos, f"{op} of two untyped literals: give one a type (WORD#...)")
                return T.ERROR
            if "real" in (lb.cat, rb.cat):
                return T.ANY_REAL_LIT
            if op == "/" and self.const_eval.const_int(e.right) == 0:
                self.err(e.right.pos, "division by zero")
            return T.ANY_INT_LIT
        if isinstance(lb, T.LiteralType) or isinstance(rb, T.LiteralType):
            # fix_literal could not give the literal the other side's type (2.5 + i, 1.0 MOD d)
            lit, other = (lb, rt) if isinstance(lb, T.LiteralType) else (rb, lt)
            self.err(e.pos, f"'{op}' of {'a REAL' if lit.cat == 'real' else 'an integer'} literal and {other}: "
                     f"the literal is not a {other}", self.conv_hint(lt, rt) if lit.cat != "real" else None)
            return T.ERROR
        if op in self.COMPARE:
            if not self.same_for_op(lb, rb):
                self.err(e.pos, f"cannot compare {lt} with {rt}", self.conv_hint(lt, rt))
                return T.ERROR
            if isinstance(lb, (T.StructType, T.ArrayType, T.PouType)):
                self.err(e.pos, f"cannot compare values of type {lt}")
                return T.ERROR
            if isinstance(lb, T.EnumType) and op not in ("=", "<>"):
                self.port(e.pos, "enum-order", op=op)
            return T.BOOL
        if op in self.LOGIC:
            if not (isinstance(lb, T.Elementary) and lb.is_bit):
                self.err(e.pos, f"{op} needs BOOL or bit-string operands, not {lt}",
                         "integers are not bit strings in IEC: convert with INT_TO_WORD"
                         if T.is_elem(lb, "int", "uint") else None)
                return T.ERROR
            if not self.same_for_op(lb, rb):
                self.err(e.pos, f"{op} of {lt} and {rt}: both sides must have the same type", self.conv_hint(lt, rt))
                return T.ERROR
            return lb
        # arithmetic
        if isinstance(lb, T.Elementary) and lb.cat in ("bit", "bool"):
            self.err(e.pos, f"arithmetic '{op}' on {lt} (a bit string) is not allowed",
                     f"convert first, e.g. {lb.name}_TO_UINT" if lb.cat == "bit" else None)
            return T.ERROR
        if not (isinstance(lb, T.Elementary) and lb.is_num):
            self.err(e.pos, f"arithmetic '{op}' needs numbers, not {lt}")
            return T.ERROR
        if not self.same_for_op(lb, rb):
            self.err(e.pos, f"'{op}' of {lt} and {rt}: both sides must have the same type (no implicit conversion)",
                     self.conv_hint(lt, rt))
            return T.ERROR
        if op == "MOD" and lb.is_real:
            self.err(e.pos, "MOD needs integers")
            return T.ERROR
        if op in ("/", "MOD") and self.const_eval.const_int(e.right) == 0 and lb.is_int:
            if op == "/":
                self.err(e.right.pos, "integer division by zero")
        return lb

    def same_for_op(self, a: T.Type, b: T.Type) -> bool:
        return T.same_type(a, b)

    def conv_hint(self, a: T.Type, b: T.Type) -> str | None:
        a, b = T.resolve_base(a), T.resolve_base(b)
        if isinstance(a, T.Elementary) and isinstance(b, T.Elementary) and a.name != b.name:
            small, big = (a, b) if a.size <= b.size else (b, a)
            return f"convert explicitly, e.g. {small.name}_TO_{big.name}(...)"
        return None

    def time_arith(self, e: A.Binary, lb: T.Type, rb: T.Type) -> T.Type:
        op = e.op
        lc = lb.cat if isinstance(lb, T.Elementary) else ("lit" + lb.cat if isinstance(lb, T.LiteralType) else "?")
        rc = rb.cat if isinstance(rb, T.Elementary) else ("lit" + rb.cat if isinstance(rb, T.LiteralType) else "?")
        table = {
            ("+", "time", "time"): T.TIME, ("-", "time", "time"): T.TIME,
            ("+", "tod", "time"): T.TOD, ("-", "tod", "time"): T.TOD, ("-", "tod", "tod"): T.TIME,
            ("+", "dt", "time"): T.DT, ("-", "dt", "time"): T.DT, ("-", "dt", "dt"): T.TIME,
            ("-", "date", "date"): T.TIME,
        }
        if (op, lc, rc) in table:
            return table[(op, lc, rc)]
        if op in ("*", "/") and lc == "time" and (rc in ("int", "uint", "real", "litint", "litreal")):
            if rc.startswith("lit"):
                self.fix_literal(e.right, T.LREAL if rc == "litreal" else T.DINT)
            if op == "/" and self.const_eval.const_value(e.right) == 0:
                self.err(e.right.pos, "division of a TIME by zero")
            return T.TIME
        if op == "*" and rc == "time" and lc in ("int", "uint", "real", "litint", "litreal"):
            if lc.startswith("lit"):
                self.fix_literal(e.left, T.LREAL if lc == "litreal" else T.DINT)
            return T.TIME
        self.err(e.pos, f"'{op}' is not defined for {lb} and {rb}")
        return T.ERROR
