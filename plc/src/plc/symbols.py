"""What names resolve to: variables, POUs, and the scopes that hold them."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from . import ast as A
from .diagnostics import Pos
from .types import Type


@dataclass(eq=False)
class VarSym:
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
class FuncSym:
    name: str
    text: str
    pou: A.Pou
    ret: Type
    scope: Scope
    builtin: bool = False
    cname: str = ""
