"""The abstract syntax tree: the only interface between the parser and later stages.

Every node carries the `Pos` where it starts.  Names are stored upper-case (the
language is case-insensitive) with the original spelling kept where messages
need it.

Two kinds of fields, as MATIEC's symbol_c has them:
- syntax fields, set by the parser and never written after it; the child nodes
  among them are what `iter_child_nodes`, `walk` and `NodeVisitor` walk.  The
  one exception: the PLCopen front end moves the positions (`Pos` fields) of a
  project's translated ST into its XML once the checks are done
  (plcopen.Translation.remap_tree), so that the C reports XML lines;
- annotations, declared with `annotation()`: None until the semantic passes
  fill them (`ty` the resolved type of an expression, `sym` what a name
  resolves to, `target` a call's callee, `param` the parameter an argument
  binds, ...: the symbols of symbols.py).  They are not in the constructor and
  never walked.

Each pass dispatches on the node kind with `handler(pass, prefix, node, ...)`:
the pass's method `<prefix><Kind>`, one prefix per family of nodes it takes
(`d_` a file's items, `s_` statements, `t_` expression typing, `x_` C
expressions), each family's methods with the arguments its context needs.  A
kind without its method is an `InternalError` at the node's position, never
silently skipped (MATIEC stops with ERROR there).  `NodeVisitor` is the
generic walk over the declared children (pycparser's and CPython's `ast`
pattern) for tools and tests that look at a whole tree; no pass is one.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Optional

from .diagnostics import InternalError, Pos
from .types import Type


def annotation(doc: str) -> Any:
    """A field a semantic pass fills in (None until then): out of the constructor, never walked."""
    return field(default=None, init=False, repr=False, compare=False, metadata={"annotation": doc})


class Symbol:
    """What a name or a call resolves to: the base of the symbols of symbols.py (VarSym, FuncSym, EnumValueSym,
    BuiltinSym, ConversionSym) and of stdfuncs.StdFunc, which build on this module."""
    __slots__ = ()


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
    ty: Type | None = annotation("types.Type of the value (sema: bodies/expressions)")
    sym: Symbol | None = annotation("what a Name / EnumLit / Member resolves to: a VarSym, FuncSym, EnumValueSym "
                                    "or BuiltinSym of symbols.py (sema: expressions)")


@dataclass(eq=False)
class IntLit(Expr):
    value: int
    prefix: Optional[str] = None     # INT#5 -> "INT"
    negated: bool = False            # written `-5`: the parser folded the sign into value


@dataclass(eq=False)
class RealLit(Expr):
    value: float
    prefix: Optional[str] = None
    negated: bool = False            # written `-2.5`: the parser folded the sign into value


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
    kind: str                     # TIME TOD DATE DT LTIME ...
    text: str
    value: Optional[int] = None   # nanoseconds (since epoch for DATE/DT); None: not a valid literal of its kind


@dataclass(eq=False)
class EnumLit(Expr):
    """E_Mode#Auto (qualified) — an unqualified enum value is a Name until resolved."""
    type_name: str
    value: str


@dataclass(eq=False)
class Name(Expr):
    name: str
    text: str = ""


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
    call_form: bool = False   # written `NOT (x)`: STruC++ reads that as a call of the function NOT, `NOT x` as '!x'


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
    param: Symbol | None = annotation("the callee's parameter this argument binds, by name or by position: a "
                                      "VarSym (sema: calls)")


@dataclass(eq=False)
class Call(Expr):
    func: str
    args: list[Arg]
    text: str = ""
    target: Symbol | None = annotation("the callee: a FuncSym, StdFunc, ConversionSym or the FB instance's "
                                       "VarSym (sema: calls)")
    site: int = field(default=-1, init=False, repr=False, compare=False,
                      metadata={"annotation": "assertion call site id, -1 if none (sema: test builds)"})
    std_args: list[Expr] = field(default_factory=list, init=False, repr=False, compare=False,
                                 metadata={"annotation": "a standard function's or a conversion's input values "
                                                         "in parameter order (stdfuncs, sema: calls)"})
    time_arith: bool = field(default=False, init=False, repr=False, compare=False,
                             metadata={"annotation": "ADD/SUB/MUL/DIV on TIME operands (stdfuncs)"})


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
    # portability.Fact records of the lexer and the parser (constructs MATIEC rejects), for the portability pass
    facts: list = field(default_factory=list)


# -------------------------------------------------------------------- walking --
def is_annotation(f: dataclasses.Field) -> bool:
    return "annotation" in f.metadata


def child_fields(node: Node) -> Iterator[tuple[str, Any]]:
    """(name, value) of the node's syntax fields, annotations left out."""
    for f in dataclasses.fields(node):
        if not is_annotation(f):
            yield f.name, getattr(node, f.name)


def _nodes_in(value: Any) -> Iterator[Node]:
    if isinstance(value, Node):
        yield value
    elif isinstance(value, (list, tuple)):
        for item in value:
            yield from _nodes_in(item)


def iter_child_nodes(node: Node) -> Iterator[Node]:
    """The nodes directly under `node`, in field order (lists and tuples such as If.branches are looked into)."""
    for _name, value in child_fields(node):
        yield from _nodes_in(value)


def walk(node: Node) -> Iterator[Node]:
    """`node` and every node below it, parents before children."""
    todo = [node]
    while todo:
        n = todo.pop()
        yield n
        todo.extend(reversed(list(iter_child_nodes(n))))


def handler(owner: Any, prefix: str, node: Node, who: str, what: str = "") -> Callable:
    """`owner`'s method `<prefix><Kind>` for `node`'s kind.  A kind without one is an InternalError at the node:
    the language grew a node this pass was not taught (MATIEC's ERROR), never a silent skip."""
    method = getattr(owner, prefix + type(node).__name__, None)
    if method is None:
        raise InternalError(node.pos, f"{who} does not handle {what + ' ' if what else ''}{type(node).__name__}")
    return method


class NodeVisitor:
    """`visit(node)` calls `visit_<Kind>(node)`; a kind without a method has its children visited."""

    def visit(self, node: Node) -> Any:
        method = getattr(self, "visit_" + type(node).__name__, None)
        if method is None:
            return self.generic_visit(node)
        return method(node)

    def generic_visit(self, node: Node) -> Any:
        for child in iter_child_nodes(node):
            self.visit(child)
        return None
