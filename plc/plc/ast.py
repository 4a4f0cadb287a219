"""The abstract syntax tree: the only interface between the parser and later stages.

Every node carries the `Pos` where it starts.  Names are stored upper-case (the
language is case-insensitive) with the original spelling kept where messages
need it.  Semantic passes annotate expressions with `ty` (their resolved type)
and names with `sym` (what they resolve to); the parser leaves both None.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from .diagnostics import Pos


@dataclass(eq=False)
class Node:
    pos: Pos


# ----------------------------------------------------------------- type specs --
@dataclass(eq=False)
class TypeRef(Node):
    """A named type: INT, E_Mode, FB_Foo, STRING (with optional length)."""
    name: str
    text: str = ""
    length: Optional["Expr"] = None      # STRING[n] / STRING(n)


@dataclass(eq=False)
class EnumSpec(Node):
    values: list[tuple[str, Pos, Optional["Expr"]]]   # (NAME, pos, explicit value or None)
    base: Optional[TypeRef] = None
    texts: list[str] = field(default_factory=list)     # the values as spelled in the source


@dataclass(eq=False)
class SubrangeSpec(Node):
    base: TypeRef
    lo: "Expr"
    hi: "Expr"


@dataclass(eq=False)
class ArraySpec(Node):
    dims: list[tuple["Expr", "Expr"]]
    elem: "TypeSpec"


@dataclass(eq=False)
class StructMember(Node):
    name: str
    spec: "TypeSpec"
    init: Optional["Init"] = None
    text: str = ""


@dataclass(eq=False)
class StructSpec(Node):
    members: list[StructMember]


@dataclass(eq=False)
class PointerSpec(Node):
    target: "TypeSpec"
    kind: str = "POINTER"


TypeSpec = TypeRef | EnumSpec | SubrangeSpec | ArraySpec | StructSpec | PointerSpec


# ------------------------------------------------------------- initialisers --
@dataclass(eq=False)
class ArrayInit(Node):
    items: list[tuple[Optional["Expr"], "Init"]]   # (repeat count or None, value)


@dataclass(eq=False)
class StructInit(Node):
    fields: list[tuple[str, Pos, "Init"]]


Init = Any  # Expr | ArrayInit | StructInit


# ------------------------------------------------------------------ expressions --
@dataclass(eq=False)
class Expr(Node):
    def __post_init__(self) -> None:
        self.ty = None           # set by semantic analysis


@dataclass(eq=False)
class IntLit(Expr):
    value: int
    prefix: Optional[str] = None     # INT#5 -> "INT"


@dataclass(eq=False)
class RealLit(Expr):
    value: float
    prefix: Optional[str] = None


@dataclass(eq=False)
class BoolLit(Expr):
    value: bool
    prefix: Optional[str] = None


@dataclass(eq=False)
class StrLit(Expr):
    value: str
    prefix: Optional[str] = None


@dataclass(eq=False)
class TimeLit(Expr):
    kind: str          # TIME TOD DATE DT LTIME ...
    text: str
    value: int = 0     # nanoseconds (since epoch for DATE/DT)


@dataclass(eq=False)
class EnumLit(Expr):
    """E_Mode#Auto (qualified) — an unqualified enum value is a Name until resolved."""
    type_name: str
    value: str


@dataclass(eq=False)
class Name(Expr):
    name: str
    text: str = ""

    def __post_init__(self) -> None:
        super().__post_init__()
        self.sym = None


@dataclass(eq=False)
class Member(Expr):
    base: Expr
    name: str
    text: str = ""


@dataclass(eq=False)
class BitAccess(Expr):
    base: Expr
    bit: int


@dataclass(eq=False)
class Index(Expr):
    base: Expr
    indices: list[Expr]


@dataclass(eq=False)
class Deref(Expr):
    base: Expr


@dataclass(eq=False)
class Direct(Expr):
    area: str
    size: str
    parts: list[int]
    text: str = ""


@dataclass(eq=False)
class Unary(Expr):
    op: str            # "-" "+" "NOT"
    operand: Expr


@dataclass(eq=False)
class Binary(Expr):
    op: str            # OR XOR AND = <> < > <= >= + - * / MOD **
    left: Expr
    right: Expr


@dataclass(eq=False)
class Arg(Node):
    name: Optional[str]      # None for positional
    value: Optional[Expr]    # input value or output target
    output: bool = False     # `name => target`
    negated: bool = False    # `NOT name => target`
    text: str = ""


@dataclass(eq=False)
class Call(Expr):
    func: str
    args: list[Arg]
    text: str = ""

    def __post_init__(self) -> None:
        super().__post_init__()
        self.target = None       # resolved callee (function or FB instance symbol)
        self.site = -1           # assertion call site id (test builds)


# ------------------------------------------------------------------ statements --
@dataclass(eq=False)
class Stmt(Node):
    pass


@dataclass(eq=False)
class Assign(Stmt):
    target: Expr
    value: Expr


@dataclass(eq=False)
class CallStmt(Stmt):
    call: Call


@dataclass(eq=False)
class If(Stmt):
    branches: list[tuple[Expr, list[Stmt]]]
    orelse: Optional[list[Stmt]]
    end_pos: Optional[Pos] = None


@dataclass(eq=False)
class CaseLabel(Node):
    lo: Expr
    hi: Optional[Expr] = None


@dataclass(eq=False)
class Case(Stmt):
    selector: Expr
    arms: list[tuple[list[CaseLabel], list[Stmt]]]
    orelse: Optional[list[Stmt]]


@dataclass(eq=False)
class For(Stmt):
    var: Name
    start: Expr
    end: Expr
    step: Optional[Expr]
    body: list[Stmt]


@dataclass(eq=False)
class While(Stmt):
    cond: Expr
    body: list[Stmt]


@dataclass(eq=False)
class Repeat(Stmt):
    body: list[Stmt]
    cond: Expr


@dataclass(eq=False)
class Exit(Stmt):
    pass


@dataclass(eq=False)
class Continue(Stmt):
    pass


@dataclass(eq=False)
class Return(Stmt):
    pass


@dataclass(eq=False)
class Empty(Stmt):
    pass


# -------------------------------------------------------------- declarations --
@dataclass(eq=False)
class VarDecl(Node):
    name: str
    text: str
    spec: TypeSpec
    init: Optional[Init] = None
    location: Optional[Direct] = None
    section: str = "VAR"          # VAR VAR_INPUT VAR_OUTPUT VAR_IN_OUT VAR_EXTERNAL VAR_GLOBAL VAR_TEMP
    constant: bool = False
    retain: bool = False
    edge: Optional[str] = None    # R_EDGE / F_EDGE on inputs


@dataclass(eq=False)
class VarBlock(Node):
    section: str
    constant: bool
    retain: bool
    decls: list[VarDecl]


@dataclass(eq=False)
class TypeDecl(Node):
    name: str
    text: str
    spec: TypeSpec
    init: Optional[Init] = None


@dataclass(eq=False)
class TypeBlock(Node):
    decls: list[TypeDecl]


@dataclass(eq=False)
class Pou(Node):
    kind: str                 # FUNCTION FUNCTION_BLOCK PROGRAM
    name: str
    text: str
    blocks: list[VarBlock]
    body: list[Stmt]
    ret: Optional[TypeRef] = None
    end_pos: Optional[Pos] = None

    def decls(self):
        for b in self.blocks:
            yield from b.decls


@dataclass(eq=False)
class TaskDecl(Node):
    name: str
    text: str
    interval: Optional[Expr]
    priority: Optional[Expr]
    single: Optional[Expr]


@dataclass(eq=False)
class ProgInstance(Node):
    name: str
    text: str
    task: Optional[str]
    type_name: str
    type_text: str
    args: list[Arg] = field(default_factory=list)


@dataclass(eq=False)
class Resource(Node):
    name: str
    text: str
    on: Optional[str]
    globals: list[VarBlock]
    tasks: list[TaskDecl]
    programs: list[ProgInstance]


@dataclass(eq=False)
class Configuration(Node):
    name: str
    text: str
    globals: list[VarBlock]
    resources: list[Resource]


@dataclass(eq=False)
class SourceFile(Node):
    path: str
    items: list[Node]        # TypeBlock | Pou | Configuration | VarBlock (global)
