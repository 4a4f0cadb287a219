"""The abstract syntax tree: the only interface between the parser and later stages.

Every node carries the `Pos` where it starts.  Names are stored upper-case (the
language is case-insensitive) with the original spelling kept where messages
need it.

Two kinds of fields, as MATIEC's symbol_c has them:
- syntax fields, set by the parser; the child nodes among them are what
  `iter_child_nodes` and the visitors walk;
- annotations, declared with `annotation()`: None until the semantic passes
  fill them (`ty` the resolved type of an expression, `sym` what a name
  resolves to, `target` a call's callee, `param` the parameter an argument
  binds, ...).  They are not in the constructor and never walked.

`NodeVisitor` / `NodeTransformer` walk the declared child fields (pycparser's
and CPython's `ast` pattern); `StrictVisitor` is for passes that must handle
every node kind they meet: any other kind is an `InternalError` at the node's
position, never silently skipped.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Optional

from .diagnostics import InternalError, Pos


def annotation(doc: str) -> Any:
    """A field a semantic pass fills in (None until then): out of the constructor, never walked."""
    return field(default=None, init=False, repr=False, compare=False, metadata={"annotation": doc})


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
    ty: Any = annotation("types.Type of the value (sema: bodies/expressions)")
    sym: Any = annotation("what a Name / EnumLit / Member resolves to: VarSym, FuncSym, (EnumType, value), "
                          "'CURRENT_TIME', 'EN', 'ENO' (sema: expressions)")


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
    param: Any = annotation("the callee's VarSym this argument binds (sema: calls)")


@dataclass(eq=False)
class Call(Expr):
    func: str
    args: list[Arg]
    text: str = ""
    target: Any = annotation("the callee: FuncSym, StdFunc, FB instance VarSym or ('CONV', src, dst) "
                             "(sema: calls)")
    site: int = field(default=-1, init=False, repr=False, compare=False,
                      metadata={"annotation": "assertion call site id, -1 if none (sema: test builds)"})
    std_args: list = field(default_factory=list, init=False, repr=False, compare=False,
                           metadata={"annotation": "a standard function's input values in parameter order "
                                                   "(stdfuncs)"})
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


class StrictVisitor(NodeVisitor):
    """A visitor that must know every node kind it is given: an unknown kind is an internal compiler error
    with the node's position (MATIEC stops with ERROR there), never silently ignored."""

    def visit(self, node: Node) -> Any:
        return handler(self, "visit_", node, type(self).__name__)(node)


class NodeTransformer(NodeVisitor):
    """A visitor whose `visit_<Kind>` returns the node that replaces the one visited (None drops it from a
    list); `generic_visit` rebuilds the children in place."""

    def generic_visit(self, node: Node) -> Any:
        for name, value in child_fields(node):
            if isinstance(value, Node):
                setattr(node, name, self.visit(value))
            elif isinstance(value, list):
                setattr(node, name, self._list(value))
        return node

    def _list(self, items: list) -> list:
        out = []
        for item in items:
            if isinstance(item, Node):
                new = self.visit(item)
                if new is not None:
                    out.append(new)
            elif isinstance(item, tuple):
                out.append(tuple(self.visit(x) if isinstance(x, Node) else
                                 self._list(x) if isinstance(x, list) else x for x in item))
            elif isinstance(item, list):
                out.append(self._list(item))
            else:
                out.append(item)
        return out
