"""Constant expressions: the value of an expression known at compile time (array bounds, subranges, CASE
labels, initial values), used by the other passes.
"""
from __future__ import annotations

import math

from .. import ast as A
from ..symbols import VarSym
from .context import Pass


class ConstantEval(Pass):
    """Asked by the other passes; no pass of its own."""
    pass_name = "constants"

    def const_value(self, e: A.Expr):
        """Fold a constant expression: int, float, bool, or None if not constant."""
        if isinstance(e, A.IntLit):
            return e.value
        if isinstance(e, A.RealLit):
            return e.value
        if isinstance(e, A.BoolLit):
            return e.value
        if isinstance(e, A.TimeLit):
            return e.value
        if isinstance(e, A.Name):
            sym = e.sym or self.lookup_const(e.name)
            if isinstance(sym, VarSym) and sym.constant and sym.const_value is not None:
                return sym.const_value
            if isinstance(sym, VarSym) and sym.constant and sym.section == "VAR_EXTERNAL":
                return self.global_constant(e.name)
            return None
        if isinstance(e, A.Unary):
            v = self.const_value(e.operand)
            if v is None:
                return None
            if e.op == "-" and not isinstance(v, bool):
                return -v
            if e.op == "+":
                return v
            if e.op == "NOT" and isinstance(v, bool):
                return not v
            return None
        if isinstance(e, A.Binary):
            a, b = self.const_value(e.left), self.const_value(e.right)
            if a is None or b is None or isinstance(a, bool) or isinstance(b, bool):
                return None
            try:
                if e.op == "+":
                    return a + b
                if e.op == "-":
                    return a - b
                if e.op == "*":
                    return a * b
                if e.op == "/" and b != 0:
                    return int(a / b) if isinstance(a, int) and isinstance(b, int) else a / b
                if e.op == "MOD" and isinstance(a, int) and isinstance(b, int):
                    return 0 if b == 0 else int(math.fmod(a, b))
            except (OverflowError, ValueError):
                return None
        return None

    def const_int(self, e: A.Expr) -> int | None:
        v = self.const_value(e)
        return v if isinstance(v, int) and not isinstance(v, bool) else None

    def is_external_constant(self, name: str) -> bool:
        sym = self.lookup_const(name)
        return isinstance(sym, VarSym) and sym.constant and sym.section == "VAR_EXTERNAL"

    def global_constant(self, name: str):
        """Value of the VAR_GLOBAL CONSTANT `name`, read from its declaration: a VAR_EXTERNAL CONSTANT
        may bound an array before the configuration itself has been analysed."""
        busy = self.__dict__.setdefault("_globals_in_progress", set())
        if name in busy:
            return None
        busy.add(name)
        try:
            for f in self.st.files:
                for cfg in (i for i in f.items if isinstance(i, A.Configuration)):
                    for b in [*cfg.globals, *(b for r in cfg.resources for b in r.globals)]:
                        for d in b.decls if b.constant else []:
                            if d.name == name and isinstance(d.init, A.Expr):
                                return self.const_value(d.init)
            return None
        finally:
            busy.discard(name)

    def lookup_const(self, name: str):
        scope = self.st.scope
        if scope is not None:
            s = scope.lookup(name)
            if s is not None:
                return s
        return None
