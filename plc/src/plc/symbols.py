"""What names and calls resolve to (the `sym` and `target` annotations of ast.py), and the scopes that hold
variables.

A name resolves to a VarSym (a variable), a FuncSym (inside a FUNCTION, its result), an EnumValueSym (an
enumeration value) or a BuiltinSym (EN, ENO, CURRENT_TIME); a call to a FuncSym, a stdfuncs.StdFunc, a
ConversionSym or, for a function block call, the instance's VarSym.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from . import ast as A
from .diagnostics import Pos
from .types import EnumType, Type


@dataclass(eq=False)
class VarSym(A.Symbol):
    name: str
    text: str
    type: Type
    section: str                 # VAR VAR_INPUT VAR_OUTPUT VAR_IN_OUT VAR_EXTERNAL VAR_GLOBAL VAR_TEMP RESULT
    pos: Pos
    decl: Optional[A.VarDecl] = None
    constant: bool = False
    retain: bool = False
    location: Optional[A.Direct] = None
    init: object = None          # ast initialiser
    owner: str = ""              # POU name or "" for configuration globals
    cname: str = ""              # C spelling of the storage
    global_sym: Optional["VarSym"] = None   # for VAR_EXTERNAL: the VAR_GLOBAL it binds to
    const_value: object = None   # folded value of a CONSTANT with a literal initialiser


@dataclass(eq=False)
class Scope:
    owner: str
    kind: str                                         # FUNCTION FUNCTION_BLOCK PROGRAM CONFIGURATION
    vars: dict[str, VarSym] = field(default_factory=dict)

    def lookup(self, name: str) -> VarSym | None:
        return self.vars.get(name)

    def inputs(self) -> list[VarSym]:
        return [v for v in self.vars.values() if v.section == "VAR_INPUT"]

    def params(self) -> list[VarSym]:
        """Parameters in declaration order, as a positional call sees them."""
        return [v for v in self.vars.values() if v.section in ("VAR_INPUT", "VAR_IN_OUT", "VAR_OUTPUT")]


@dataclass(eq=False)
class FuncSym(A.Symbol):
    name: str
    text: str
    pou: A.Pou
    ret: Type
    scope: Scope
    builtin: bool = False
    cname: str = ""


@dataclass(frozen=True, eq=False)
class EnumValueSym(A.Symbol):
    """An enumeration value (`Idle`, `E_Mode#Idle`): its enumeration and the value, upper case."""
    type: EnumType
    value: str

    @property
    def index(self) -> int:
        """The value's number in the C code: its place in the enumeration's declaration."""
        return self.type.values.index(self.value)


@dataclass(frozen=True, eq=False)
class BuiltinSym(A.Symbol):
    """A name a POU has without declaring it: one of EN, ENO, CURRENT_TIME below (compared by identity)."""
    name: str


EN = BuiltinSym("EN")                        # the POU's enable input (TRUE inside a FUNCTION)
ENO = BuiltinSym("ENO")                      # the POU's enable output
CURRENT_TIME = BuiltinSym("CURRENT_TIME")    # the PLC clock, for the built-in library only


@dataclass(frozen=True, eq=False)
class ConversionSym(A.Symbol):
    """The callee of a type conversion (INT_TO_DINT(x), TO_DINT(x)): from the input's type to `dst`."""
    src: Type
    dst: Type
