"""What the semantic passes share: the `Program` they build (the tables the C generator reads), the
records of a configuration, `SemanticState` (the one state object every pass is handed) and `Pass`, the base
of every pass with its diagnostic helpers and its accessors to the other passes.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from .. import ast as A
from .. import portability
from .. import types as T
from ..diagnostics import Diagnostics, Pos
from ..symbols import FuncSym, Scope, VarSym

LOCATION_SIZES = {"X": 1, "B": 8, "W": 16, "D": 32, "L": 64}
LOCATED_OK = {
    "X": ("BOOL",),
    "B": ("BYTE", "SINT", "USINT"),
    "W": ("WORD", "INT", "UINT"),
    "D": ("DWORD", "DINT", "UDINT", "REAL"),
    "L": ("LWORD", "LINT", "ULINT", "LREAL"),
}
TIME_KIND_TYPE = {"TIME": T.TIME, "TOD": T.TOD, "DATE": T.DATE, "DT": T.DT}


@dataclass(eq=False)
class TaskInfo:
    name: str
    interval_ns: int
    priority: int
    pos: Pos
    every: int = 1
    single: object = None      # VarSym of the BOOL global whose rising edge runs the task (SINGLE)


@dataclass(eq=False)
class InstanceInfo:
    name: str
    type: T.PouType
    task: TaskInfo | None
    resource: str
    pos: Pos
    cname: str = ""


@dataclass(eq=False)
class ConfigInfo:
    name: str
    decl: A.Configuration
    globals: dict[str, VarSym] = field(default_factory=dict)
    tasks: list[TaskInfo] = field(default_factory=list)
    instances: list[InstanceInfo] = field(default_factory=list)
    base_tick_ns: int = 0
    resources: list[str] = field(default_factory=list)


@dataclass(eq=False)
class Site:
    pos: Pos
    pou: str


@dataclass(eq=False)
class Program:
    files: list[A.SourceFile]
    types: dict[str, T.Type] = field(default_factory=dict)
    type_order: list[str] = field(default_factory=list)
    pous: dict[str, T.PouType] = field(default_factory=dict)      # FBs and PROGRAMs
    funcs: dict[str, FuncSym] = field(default_factory=dict)
    enum_values: dict[str, list[T.EnumType]] = field(default_factory=dict)
    type_inits: dict[int, object] = field(default_factory=dict)   # id(type) -> TYPE-level initial value
    configs: list[ConfigInfo] = field(default_factory=list)
    sites: list[Site] = field(default_factory=list)
    array_types: list[T.ArrayType] = field(default_factory=list)
    builtin_files: set[str] = field(default_factory=set)
    facts: list[portability.Fact] = field(default_factory=list)   # the passes' portability facts

    def site(self, pos: Pos, pou: str) -> int:
        self.sites.append(Site(pos, pou))
        return len(self.sites) - 1


class LoopCtx:
    def __init__(self) -> None:
        self.loop_depth = 0
        self.for_vars: list[VarSym] = []


class SemanticState:
    """What the semantic passes share, and nothing else: the files, the diagnostics, the `Program` being
    built, the declarations found by pass 1, the global variables, and where the bodies pass stands (POU,
    FUNCTION, scope).  One object, handed to every pass; each pass keeps its own working state itself."""

    def __init__(self, files: list[A.SourceFile], diags: Diagnostics, builtin_files: set[str] | None = None,
                 test_build: bool = False):
        self.files = files
        self.d = diags
        self.prog = Program(files)
        self.prog.builtin_files = builtin_files or set()
        self.test_build = test_build
        self.type_decls: dict[str, A.TypeDecl] = {}       # pass 1
        self.pou_decls: dict[str, A.Pou] = {}             # pass 1
        self.global_scope: dict[str, VarSym] = {}         # pass 4 (names reserved by pass 1)
        # where the passes stand: the POU, the FUNCTION's FuncSym, the scope names are looked up in
        self.current_pou: A.Pou | None = None
        self.func: FuncSym | None = None
        self.scope: Scope | None = None
        # the passes of this build by name (driver.analyze fills it); a pass reaches another through
        # the accessors of Pass below, so who asks whom is visible in the code
        self.passes: dict[str, "Pass"] = {}
        # POUs whose bodies the bodies pass leaves out (their C is the build cache's: codegen.PieceMemo)
        self.skip_bodies = None

    def err(self, pos: Pos, msg: str, hint: str | None = None, code: str = "semantic") -> None:
        self.d.error(pos, msg, hint, code)

    def warn(self, pos: Pos, msg: str, hint: str | None = None, code: str = "semantic") -> None:
        self.d.warning(pos, msg, hint, code)

    def port(self, pos: Pos, rule: str, **details: str) -> None:
        """Record a portability fact (a rule of portability.RULES) where it was found, for the portability pass;
        built-in files are exempt."""
        if pos.file in self.prog.builtin_files:
            return
        self.prog.facts.append(portability.fact(rule, pos, **details))

    def in_builtin(self) -> bool:
        return self.current_pou is not None and self.current_pou.pos.file in self.prog.builtin_files


class Pass:
    """A semantic pass (or the helper of one) over the shared state `st`.  The passes that others ask for
    types, constants, initial values and expressions are reached by name through the accessors below."""

    pass_name = ""

    def __init__(self, st: SemanticState) -> None:
        self.st = st

    def run(self) -> None:
        """The pass over the whole build (helpers that only answer the other passes have none)."""
        raise NotImplementedError(f"{type(self).__name__} is not a pass of its own")

    # diagnostics
    def err(self, pos: Pos, msg: str, hint: str | None = None, code: str = "semantic") -> None:
        self.st.err(pos, msg, hint, code)

    def warn(self, pos: Pos, msg: str, hint: str | None = None, code: str = "semantic") -> None:
        self.st.warn(pos, msg, hint, code)

    def port(self, pos: Pos, rule: str, **details: str) -> None:
        self.st.port(pos, rule, **details)

    def in_builtin(self) -> bool:
        return self.st.in_builtin()

    # the other passes
    @property
    def type_pass(self):
        return self.st.passes["types"]

    @property
    def const_eval(self):
        return self.st.passes["constants"]

    @property
    def scope_pass(self):
        return self.st.passes["scopes"]

    @property
    def stmt_pass(self):
        return self.st.passes["bodies"]

    @property
    def expr_typing(self):
        return self.st.passes["expressions"]

    @property
    def call_typing(self):
        return self.st.passes["calls"]
