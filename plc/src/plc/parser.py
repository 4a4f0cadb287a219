"""Recursive-descent parser with precedence climbing for expressions.

Input: tokens from the lexer.  Output: an `ast.SourceFile`.  Parsing is
context-free: a name is never looked up here (a call `x(...)` may be a function
or an FB instance; the resolver decides), so forward references just work.

Errors are collected; after an error the parser skips to a synchronisation point
(`;` or a keyword that starts or ends a construct) and goes on, so one run
reports many problems.  Every loop consumes at least one token per turn, so the
parser always terminates.
"""
from __future__ import annotations

from . import ast as A
from . import buildcache
from .diagnostics import Diagnostics, Pos
from .facts import Fact, fact
from .lexer import Token, tokenize
from .timelit import decode

MAX_DEPTH = 120
# Operators (binary, unary, member, index, dereference) in one expression.  MAX_DEPTH bounds brackets and calls
# but not a chain `a AND a AND ...`, which is as deep a tree as it is long; every stage after the parser walks
# trees recursively (the passes take about 4 frames an operator, the C generator 2, under the 10,000 frames
# driver.deep_recursion allows), so one expression holds at most this many.  A real program never comes near
# it: the longest expression in st_src and iec_tests has 73.
MAX_OPERATORS = 500

# binary operator -> (precedence, right-associative)
BINARY = {
    "OR": 1, "XOR": 2, "AND": 3, "&": 3,
    "=": 4, "<>": 4,
    "<": 5, ">": 5, "<=": 5, ">=": 5,
    "+": 6, "-": 6,
    "*": 7, "/": 7, "MOD": 7,
    "**": 8,
}

VAR_SECTIONS = ("VAR", "VAR_INPUT", "VAR_OUTPUT", "VAR_IN_OUT", "VAR_EXTERNAL", "VAR_GLOBAL", "VAR_TEMP",
                "VAR_ACCESS", "VAR_CONFIG")

STMT_END = ("END_IF", "ELSIF", "ELSE", "END_CASE", "END_FOR", "END_WHILE", "UNTIL", "END_REPEAT",
            "END_FUNCTION", "END_FUNCTION_BLOCK", "END_PROGRAM")
TOP_KEYWORDS = ("FUNCTION", "FUNCTION_BLOCK", "PROGRAM", "CONFIGURATION", "TYPE", "VAR_GLOBAL")
POU_ENDS = ("END_FUNCTION", "END_FUNCTION_BLOCK", "END_PROGRAM")


class ParseError(Exception):
    pass


class Parser:
    def __init__(self, tokens: list[Token], filename: str, diags: Diagnostics, facts: list | None = None):
        self.toks = tokens
        self.k = 0
        self.file = filename
        self.diags = diags
        self.facts: list[Fact] = facts if facts is not None else []   # for the portability pass
        self.depth = 0
        self.operators = 0          # operators of the expression `bounded` is parsing
        self.counting = False

    # -- token helpers ------------------------------------------------------------
    @property
    def tok(self) -> Token:
        return self.toks[self.k]

    def la(self, n: int = 1) -> Token:
        return self.toks[min(self.k + n, len(self.toks) - 1)]

    def next(self) -> Token:
        t = self.toks[self.k]
        if t.kind != "EOF":
            self.k += 1
        return t

    def at_kw(self, *words: str) -> bool:
        return self.tok.is_kw(*words)

    def at_sym(self, *syms: str) -> bool:
        return self.tok.is_sym(*syms)

    def accept_kw(self, *words: str) -> Token | None:
        return self.next() if self.at_kw(*words) else None

    def accept_sym(self, *syms: str) -> Token | None:
        return self.next() if self.at_sym(*syms) else None

    def describe(self, t: Token) -> str:
        if t.kind == "EOF":
            return "end of file"
        return f"'{t.text}'"

    def fail(self, message: str, hint: str | None = None, pos: Pos | None = None) -> ParseError:
        self.diags.error(pos or self.tok.pos, message, hint, code="syntax")
        return ParseError(message)

    def expect_sym(self, sym: str, context: str = "", hint: str | None = None) -> Token:
        if self.at_sym(sym):
            return self.next()
        where = f" {context}" if context else ""
        raise self.fail(f"expected '{sym}'{where}, found {self.describe(self.tok)}", hint)

    def expect_kw(self, word: str, context: str = "", hint: str | None = None) -> Token:
        if self.at_kw(word):
            return self.next()
        where = f" {context}" if context else ""
        raise self.fail(f"expected {word}{where}, found {self.describe(self.tok)}", hint)

    def ident(self, what: str = "a name") -> Token:
        t = self.tok
        if t.kind == "IDENT":
            return self.next()
        if t.kind == "KEYWORD":
            raise self.fail(f"'{t.text}' is a keyword and cannot be used as {what}")
        raise self.fail(f"expected {what}, found {self.describe(t)}")

    def ensure_progress(self, before: int) -> None:
        """After error recovery in a loop: if nothing was consumed, skip one token (never loop forever)."""
        if self.k == before and self.tok.kind != "EOF":
            self.next()

    def sync(self, stops: tuple[str, ...] = ()) -> None:
        """Skip to just after the next ';' or to a keyword in `stops` / a top-level keyword."""
        start = self.k
        while self.tok.kind != "EOF":
            if self.at_sym(";"):
                self.next()
                return
            if self.tok.kind == "KEYWORD" and (self.tok.value in stops or self.tok.value in TOP_KEYWORDS
                                               or self.tok.value.startswith("END_")):
                if self.k == start and self.tok.value not in TOP_KEYWORDS:
                    self.next()
                return
            self.next()

    # -- file ---------------------------------------------------------------------------
    def parse_file(self) -> A.SourceFile:
        items: list[A.Node] = []
        start = self.tok.pos
        while self.tok.kind != "EOF":
            before = self.k
            try:
                item = self.top_item()
                if item is not None:
                    items.append(item)
            except ParseError:
                self.recover_top()
            if self.k == before:
                self.next()
        return A.SourceFile(start, self.file, items, self.facts)

    def recover_top(self) -> None:
        while self.tok.kind != "EOF":
            if self.tok.kind == "KEYWORD" and self.tok.value in ("END_FUNCTION", "END_FUNCTION_BLOCK", "END_PROGRAM",
                                                                  "END_TYPE", "END_CONFIGURATION"):
                self.next()
                return
            if self.tok.kind == "KEYWORD" and self.tok.value in ("FUNCTION", "FUNCTION_BLOCK", "PROGRAM",
                                                                  "CONFIGURATION", "TYPE"):
                return
            self.next()

    def top_item(self) -> A.Node | None:
        t = self.tok
        if t.is_kw("FUNCTION", "FUNCTION_BLOCK", "PROGRAM"):
            return self.pou()
        if t.is_kw("TYPE"):
            return self.type_block()
        if t.is_kw("CONFIGURATION"):
            return self.configuration()
        if t.is_kw("VAR_GLOBAL"):
            self.facts.append(fact("global", t.pos))
            return self.var_block()
        if t.is_kw("INTERFACE", "METHOD"):
            self.diags.error(t.pos, f"{t.value} is not supported (IEC 61131-3 edition 3 / not in MATIEC)",
                             code="unsupported")
            raise ParseError("unsupported")
        if t.is_sym(";"):
            self.next()
            return None
        raise self.fail(f"expected FUNCTION, FUNCTION_BLOCK, PROGRAM, TYPE or CONFIGURATION, found {self.describe(t)}")

    # -- types ----------------------------------------------------------------------------
    def type_block(self) -> A.TypeBlock:
        start = self.expect_kw("TYPE")
        decls = []
        while not self.at_kw("END_TYPE"):
            if self.tok.kind == "EOF" or self.tok.is_kw(*TOP_KEYWORDS):
                raise self.fail(f"expected END_TYPE to close TYPE opened at {start.pos.line}:{start.pos.col}",
                                pos=self.tok.pos)
            before = self.k
            try:
                name = self.ident("a type name")
                self.expect_sym(":", "after the type name")
                spec = self.type_spec()
                init = None
                if self.accept_sym(":="):
                    init = self.initializer()
                self.expect_sym(";", "after the type declaration")
                decls.append(A.TypeDecl(name.pos, name.value, name.text, spec, init))
            except ParseError:
                self.sync(("END_TYPE",))
                self.ensure_progress(before)
        self.next()
        self.accept_sym(";")
        return A.TypeBlock(start.pos, decls)

    def nested(self, what: str, parse):
        """Run `parse` one level deeper; past MAX_DEPTH report the nesting instead of exhausting the stack."""
        self.depth += 1
        try:
            if self.depth > MAX_DEPTH:
                raise self.fail(f"{what} nested too deeply")
            return parse()
        finally:
            self.depth -= 1

    def bounded(self, parse):
        """Run `parse` for an expression (or a statement's target); past MAX_OPERATORS operators in it report
        the expression at its start instead of handing every later stage a tree deeper than its stack."""
        if self.counting:
            return parse()
        start = self.tok.pos
        self.operators = 0
        self.counting = True
        try:
            e = parse()
        finally:
            self.counting = False
        if self.operators > MAX_OPERATORS:
            raise self.fail(f"expression too deeply nested: {self.operators} operators (limit {MAX_OPERATORS})",
                            "split it into several assignments through temporary variables", pos=start)
        return e

    def type_spec(self) -> A.TypeSpec:
        return self.nested("type", self._type_spec)

    def _type_spec(self) -> A.TypeSpec:
        t = self.tok
        if t.is_kw("ARRAY"):
            return self.array_spec()
        if t.is_kw("STRUCT"):
            return self.struct_spec()
        if t.is_sym("("):
            return self.enum_spec(None)
        if t.is_kw("POINTER"):
            self.next()
            self.expect_kw("TO", "after POINTER")
            return A.PointerSpec(t.pos, self.type_spec(), "POINTER")
        if t.is_kw("REF_TO"):
            self.next()
            return A.PointerSpec(t.pos, self.type_spec(), "REF_TO")
        name = self.ident("a type name")
        ref = A.TypeRef(name.pos, name.value, name.text)
        if name.value in ("STRING", "WSTRING") and self.at_sym("[", "("):
            close = "]" if self.next().value == "[" else ")"
            ref.length = self.expression()
            self.expect_sym(close, "after the string length")
            return ref
        if self.at_sym("("):
            # subrange INT (0..10) or enum with base type INT (A, B)
            if self.la().kind == "IDENT":
                return self.enum_spec(ref)
            self.next()
            lo = self.expression()
            self.expect_sym("..", "in the subrange")
            hi = self.expression()
            self.expect_sym(")", "after the subrange")
            return A.SubrangeSpec(name.pos, ref, lo, hi)
        return ref

    def enum_spec(self, base: A.TypeRef | None) -> A.EnumSpec:
        start = self.expect_sym("(")
        values = []
        texts = []
        while True:
            v = self.ident("an enumeration value")
            explicit = None
            if self.accept_sym(":="):
                explicit = self.expression()
            values.append((v.value, v.pos, explicit))
            texts.append(v.text)
            if not self.accept_sym(","):
                break
        self.expect_sym(")", "to close the enumeration")
        return A.EnumSpec(start.pos, values, base, texts)

    def array_spec(self) -> A.ArraySpec:
        start = self.expect_kw("ARRAY")
        self.expect_sym("[", "after ARRAY")
        dims = []
        while True:
            if self.at_sym("*"):
                raise self.fail("variable-length arrays ARRAY[*] are not supported")
            lo = self.expression()
            self.expect_sym("..", "in the array bounds", "bounds are written lo..hi")
            hi = self.expression()
            dims.append((lo, hi))
            if not self.accept_sym(","):
                break
        self.expect_sym("]", "after the array bounds")
        self.expect_kw("OF", "after the array bounds")
        elem = self.type_spec()
        return A.ArraySpec(start.pos, dims, elem)

    def struct_spec(self) -> A.StructSpec:
        start = self.expect_kw("STRUCT")
        members = []
        while not self.at_kw("END_STRUCT"):
            if self.tok.kind == "EOF" or self.tok.is_kw("END_TYPE", *TOP_KEYWORDS):
                raise self.fail(f"expected END_STRUCT to close STRUCT opened at {start.pos.line}:{start.pos.col}")
            before = self.k
            try:
                names = [self.ident("a member name")]
                while self.accept_sym(","):
                    names.append(self.ident("a member name"))
                self.expect_sym(":", "after the member name")
                spec = self.type_spec()
                init = self.initializer() if self.accept_sym(":=") else None
                self.expect_sym(";", "after the member declaration")
                for n in names:
                    members.append(A.StructMember(n.pos, n.value, spec, init, n.text))
            except ParseError:
                self.sync(("END_STRUCT",))
                self.ensure_progress(before)
        self.next()
        return A.StructSpec(start.pos, members)

    def initializer(self) -> A.Init:
        return self.nested("initial value", self._initializer)

    def _initializer(self) -> A.Init:
        t = self.tok
        if t.is_sym("["):
            return self.array_init()
        if t.is_sym("(") and self.la().kind == "IDENT" and self.la(2).is_sym(":="):
            return self.struct_init()
        return self.expression()

    def array_init(self) -> A.ArrayInit:
        start = self.expect_sym("[")
        items = []
        if self.at_sym("]"):
            raise self.fail("empty array initialiser")
        while True:
            if self.tok.kind == "INT" and self.la().is_sym("("):
                count = A.IntLit(self.tok.pos, self.next().value)
                self.next()
                if self.at_sym(")"):
                    self.next()
                    items.append((count, None))
                else:
                    value = self.initializer()
                    self.expect_sym(")", "after the repeated value")
                    items.append((count, value))
            else:
                items.append((None, self.initializer()))
            if not self.accept_sym(","):
                break
        self.expect_sym("]", "to close the array initialiser")
        return A.ArrayInit(start.pos, items)

    def struct_init(self) -> A.StructInit:
        start = self.expect_sym("(")
        fields = []
        while True:
            n = self.ident("a member name")
            self.expect_sym(":=", "in the structure initialiser")
            fields.append((n.value, n.pos, self.initializer()))
            if not self.accept_sym(","):
                break
        self.expect_sym(")", "to close the structure initialiser")
        return A.StructInit(start.pos, fields)

    # -- variable declarations ---------------------------------------------------------------
    def var_block(self) -> A.VarBlock:
        start = self.next()
        section = start.value
        constant = retain = False
        while self.at_kw("CONSTANT", "RETAIN", "NON_RETAIN"):
            q = self.next().value
            constant |= q == "CONSTANT"
            retain |= q == "RETAIN"
        decls: list[A.VarDecl] = []
        while not self.at_kw("END_VAR"):
            if self.tok.kind == "EOF" or (self.tok.kind == "KEYWORD" and self.tok.value not in ("AT",) and
                                          (self.tok.value in VAR_SECTIONS or self.tok.value in STMT_END
                                           or self.tok.value in TOP_KEYWORDS)):
                raise self.fail(f"expected END_VAR to close {section} opened at {start.pos.line}:{start.pos.col}",
                                pos=self.tok.pos)
            before = self.k
            try:
                decls.extend(self.var_decl(section, constant, retain))
            except ParseError:
                if self.at_kw("END_VAR"):       # e.g. `x : INT END_VAR`: the block ends here, nothing to skip
                    continue
                self.sync(("END_VAR",))
                self.ensure_progress(before)
        self.next()
        self.accept_sym(";")
        return A.VarBlock(start.pos, section, constant, retain, decls)

    def var_decl(self, section: str, constant: bool, retain: bool) -> list[A.VarDecl]:
        names = [self.ident("a variable name")]
        while self.accept_sym(","):
            names.append(self.ident("a variable name"))
        location = None
        if self.accept_kw("AT"):
            t = self.tok
            if t.kind != "DIRECT":
                raise self.fail("expected a direct address after AT", "e.g. AT %QX0.1 or AT %IW3")
            self.next()
            area, size, parts = t.value
            location = A.Direct(t.pos, area, size, parts, t.text)
            if len(names) > 1:
                self.diags.error(names[1].pos, "only one variable may be declared with AT")
        self.expect_sym(":", "after the variable name", "declarations are written `name : TYPE;`")
        spec = self.type_spec()
        edge = None
        if self.tok.kind == "IDENT" and self.tok.value in ("R_EDGE", "F_EDGE"):
            edge = self.next().value
        init = self.initializer() if self.accept_sym(":=") else None
        if self.at_kw("END_VAR"):           # `x : INT END_VAR`: reported, and x is declared (no cascade)
            self.fail(f"expected ';' after the declaration, found {self.describe(self.tok)}")
        else:
            self.expect_sym(";", "after the declaration")
        return [A.VarDecl(n.pos, n.value, n.text, spec, init, location, section, constant, retain, edge)
                for n in names]

    # -- POUs --------------------------------------------------------------------------------
    def pou(self) -> A.Pou:
        kw = self.next()
        kind = kw.value
        name = self.ident(f"the {kind} name")
        ret = None
        if kind == "FUNCTION":
            if self.accept_sym(":"):
                spec = self.type_spec()
                if not isinstance(spec, A.TypeRef):
                    self.diags.error(spec.pos, "a FUNCTION must return a named type")
                    spec = A.TypeRef(spec.pos, "INT", "INT")
                ret = spec
            else:
                self.diags.error(name.pos, f"FUNCTION {name.text} needs a return type", "FUNCTION F : INT")
                ret = A.TypeRef(name.pos, "INT", "INT")
        elif kind == "FUNCTION_BLOCK" and self.at_kw("EXTENDS", "IMPLEMENTS"):
            raise self.fail(f"{self.tok.value} is not supported (object-oriented IEC 61131-3 edition 3)")
        end_kw = "END_" + kind
        blocks: list[A.VarBlock] = []
        while self.tok.kind == "KEYWORD" and self.tok.value in VAR_SECTIONS:
            try:
                blocks.append(self.var_block())
            except ParseError:
                self.sync_to_kw(("END_VAR",) + VAR_SECTIONS, consume_end=True)
        if self.at_kw("METHOD"):
            raise self.fail("METHOD is not supported (object-oriented IEC 61131-3 edition 3)")
        body = self.stmt_list((end_kw,), kw)
        end = self.tok
        if not self.accept_kw(end_kw):
            raise self.fail(f"expected {end_kw} to close {kind} {name.text} opened at {kw.pos.line}:{kw.pos.col}",
                            pos=self.tok.pos)
        self.accept_sym(";")
        return A.Pou(kw.pos, kind, name.value, name.text, blocks, body, ret, end.pos)

    def sync_to_kw(self, words: tuple[str, ...], consume_end: bool = False) -> None:
        while self.tok.kind != "EOF" and not self.at_kw(*words) and not self.at_kw(*STMT_END, *TOP_KEYWORDS):
            self.next()
        if consume_end and self.at_kw("END_VAR"):
            self.next()

    # -- statements ----------------------------------------------------------------------------
    def stmt_list(self, ends: tuple[str, ...], opener: Token | None = None) -> list[A.Stmt]:
        out: list[A.Stmt] = []
        while True:
            t = self.tok
            if t.kind == "EOF":
                if opener is not None:
                    self.diags.error(t.pos, f"expected {' or '.join(ends)} to close {opener.value} opened at "
                                     f"{opener.pos.line}:{opener.pos.col}, found end of file", code="syntax")
                    raise ParseError("eof")
                return out
            if t.kind == "KEYWORD" and (t.value in ends or t.value in STMT_END or t.value in TOP_KEYWORDS
                                        or t.value in VAR_SECTIONS):
                return out
            before = self.k
            try:
                s = self.statement()
                if s is not None:
                    out.append(s)
            except ParseError:
                if self.at_kw(*POU_ENDS):   # a statement left open: let the POU close (one error, not two)
                    return out
                self.sync(ends)
            if self.k == before:
                self.next()

    def statement(self) -> A.Stmt | None:
        return self.nested("statements", self._statement)

    def _statement(self) -> A.Stmt | None:
        t = self.tok
        if t.is_sym(";"):
            self.next()
            return A.Empty(t.pos)
        if t.kind == "KEYWORD":
            v = t.value
            if v == "IF":
                return self.if_stmt()
            if v == "CASE":
                return self.case_stmt()
            if v == "FOR":
                return self.for_stmt()
            if v == "WHILE":
                return self.while_stmt()
            if v == "REPEAT":
                return self.repeat_stmt()
            if v == "EXIT":
                self.next()
                self.end_stmt("EXIT")
                return A.Exit(t.pos)
            if v == "CONTINUE":
                self.next()
                self.end_stmt("CONTINUE")
                return A.Continue(t.pos)
            if v == "RETURN":
                self.next()
                self.end_stmt("RETURN")
                return A.Return(t.pos)
            raise self.fail(f"unexpected {v} at the start of a statement")
        if t.kind == "IDENT":
            target = self.bounded(lambda: self.postfix(self.primary_name()))
            if isinstance(target, A.Call):
                self.end_stmt("the call")
                return A.CallStmt(t.pos, target)
            if self.at_sym(":="):
                self.next()
                value = self.expression()
                self.end_stmt("the assignment")
                return A.Assign(t.pos, target, value)
            if self.at_sym("="):
                raise self.fail("expected ':=' in the assignment, found '='", "assignment is written `x := value;`")
            raise self.fail(f"expected ':=' or a call after {t.text!r}, found {self.describe(self.tok)}")
        if t.kind == "DIRECT":
            target = self.primary()
            self.expect_sym(":=", "after the direct variable")
            value = self.expression()
            self.end_stmt("the assignment")
            return A.Assign(t.pos, target, value)
        raise self.fail(f"expected a statement, found {self.describe(t)}")

    def end_stmt(self, what: str) -> None:
        if not self.at_sym(";"):
            raise self.fail(f"expected ';' after {what}, found {self.describe(self.tok)}")
        self.next()

    def if_stmt(self) -> A.If:
        kw = self.next()
        branches = []
        cond = self.expression()
        self.expect_kw("THEN", "after the IF condition")
        branches.append((cond, self.stmt_list(("ELSIF", "ELSE", "END_IF"), kw)))
        orelse = None
        while True:
            if self.accept_kw("ELSIF"):
                c = self.expression()
                self.expect_kw("THEN", "after the ELSIF condition")
                branches.append((c, self.stmt_list(("ELSIF", "ELSE", "END_IF"), kw)))
            elif self.accept_kw("ELSE"):
                orelse = self.stmt_list(("END_IF",), kw)
            else:
                break
        end = self.tok
        if not self.accept_kw("END_IF"):
            raise self.fail(f"expected END_IF to close IF opened at {kw.pos.line}:{kw.pos.col}, "
                            f"found {self.describe(self.tok)}")
        self.end_stmt("END_IF")
        return A.If(kw.pos, branches, orelse, end.pos)

    def case_stmt(self) -> A.Case:
        kw = self.next()
        sel = self.expression()
        self.expect_kw("OF", "after the CASE selector")
        arms = []
        orelse = None
        while not self.at_kw("END_CASE"):
            if self.accept_kw("ELSE"):
                orelse = self.stmt_list(("END_CASE",), kw)
                continue
            if self.tok.kind == "EOF" or self.tok.kind == "KEYWORD" and self.tok.value in STMT_END + TOP_KEYWORDS:
                raise self.fail(f"expected END_CASE to close CASE opened at {kw.pos.line}:{kw.pos.col}, "
                                f"found {self.describe(self.tok)}")
            labels = []
            first = self.k
            while True:
                lo = self.case_value()
                hi = None
                if self.accept_sym(".."):
                    hi = self.case_value()
                labels.append(A.CaseLabel(lo.pos, lo, hi))
                if not self.accept_sym(","):
                    break
            self.strucpp_labels(first)
            self.expect_sym(":", "after the CASE label", "labels are written `1, 3..5:`")
            body = self.case_body(kw)
            arms.append((labels, body))
        self.next()
        self.end_stmt("END_CASE")
        return A.Case(kw.pos, sel, arms, orelse)

    def strucpp_labels(self, first: int) -> None:
        """STruC++ takes a CASE arm only if its first token is a number, '-' or a name and its ':' is among the
        first 8 tokens (one token for what its lexer reads as one: 16#FF, INT#5, T#1s; E_Kind#Value counts as the
        Value it must become)."""
        if not self.tok.is_sym(":"):
            return
        toks = self.toks[first:self.k]
        start = toks[0]
        # E_Kind#Value has a warning of its own (strucpp-enum-literal) and counts as the one token Value
        enum_start = start.kind == "TYPEPFX" and len(toks) > 1 and toks[1].kind == "IDENT"
        plain_start = start.kind in ("INT", "IDENT") or start.is_sym("-")
        if not (enum_start or plain_start):
            why = f"its first label starts with {start.text!r}"
        elif len([t for t in toks if t.kind != "TYPEPFX"]) > 7:
            why = "its ':' is not among its first 8 tokens"
        else:
            return
        self.facts.append(fact("strucpp-case-label", start.pos, why=why))

    def case_value(self) -> A.Expr:
        return self.bounded(self.unary)

    def case_body(self, kw: Token) -> list[A.Stmt]:
        """Statements of one CASE arm: up to the next label (`x:` or `x..y:` or `x,`) or ELSE/END_CASE."""
        out: list[A.Stmt] = []
        while True:
            t = self.tok
            if t.kind == "EOF":
                raise self.fail(f"expected END_CASE to close CASE opened at {kw.pos.line}:{kw.pos.col}, "
                                "found end of file")
            if t.is_kw("ELSE", "END_CASE") or (t.kind == "KEYWORD" and t.value in STMT_END + TOP_KEYWORDS):
                return out
            if self.looks_like_label():
                return out
            before = self.k
            try:
                s = self.statement()
                if s is not None:
                    out.append(s)
            except ParseError:
                self.sync(("END_CASE", "ELSE"))
            if self.k == before:
                self.next()

    def looks_like_label(self) -> bool:
        """A CASE label starts with a literal, a signed literal, an enum value or a name followed by ':', ','
        or '..'."""
        j = self.k
        t = self.toks[j]
        if t.is_sym("-", "+"):
            j += 1
            t = self.toks[j]
        if t.kind == "TYPEPFX":
            j += 1
            t = self.toks[j]
            if t.is_sym("-"):
                j += 1
                t = self.toks[j]
        if t.kind in ("INT", "IDENT", "REAL") or t.is_kw("TRUE", "FALSE"):
            nxt = self.toks[min(j + 1, len(self.toks) - 1)]
            return nxt.is_sym(":", ",", "..")
        return False

    def for_stmt(self) -> A.For:
        kw = self.next()
        v = self.ident("the FOR control variable")
        self.expect_sym(":=", "after the FOR variable")
        start = self.expression()
        self.expect_kw("TO", "in the FOR statement")
        end = self.expression()
        step = None
        if self.accept_kw("BY"):
            step = self.expression()
        self.expect_kw("DO", "in the FOR statement")
        body = self.stmt_list(("END_FOR",), kw)
        if not self.accept_kw("END_FOR"):
            raise self.fail(f"expected END_FOR to close FOR opened at {kw.pos.line}:{kw.pos.col}, "
                            f"found {self.describe(self.tok)}")
        self.end_stmt("END_FOR")
        return A.For(kw.pos, A.Name(v.pos, v.value, v.text), start, end, step, body)

    def while_stmt(self) -> A.While:
        kw = self.next()
        cond = self.expression()
        self.expect_kw("DO", "after the WHILE condition")
        body = self.stmt_list(("END_WHILE",), kw)
        if not self.accept_kw("END_WHILE"):
            raise self.fail(f"expected END_WHILE to close WHILE opened at {kw.pos.line}:{kw.pos.col}, "
                            f"found {self.describe(self.tok)}")
        self.end_stmt("END_WHILE")
        return A.While(kw.pos, cond, body)

    def repeat_stmt(self) -> A.Repeat:
        kw = self.next()
        body = self.stmt_list(("UNTIL",), kw)
        if not self.accept_kw("UNTIL"):
            raise self.fail(f"expected UNTIL to close REPEAT opened at {kw.pos.line}:{kw.pos.col}, "
                            f"found {self.describe(self.tok)}")
        cond = self.expression()
        if not self.accept_kw("END_REPEAT"):
            raise self.fail(f"expected END_REPEAT to close REPEAT opened at {kw.pos.line}:{kw.pos.col}, "
                            f"found {self.describe(self.tok)}")
        self.end_stmt("END_REPEAT")
        return A.Repeat(kw.pos, body, cond)

    # -- expressions -----------------------------------------------------------------------------
    def expression(self) -> A.Expr:
        return self.bounded(lambda: self.nested("expression", lambda: self.binary(1)))

    def binop(self) -> str | None:
        t = self.tok
        if t.kind == "KEYWORD" and t.value in ("OR", "XOR", "AND", "MOD"):
            return t.value
        if t.kind == "SYM" and t.value in BINARY:
            return t.value
        return None

    def binary(self, min_prec: int) -> A.Expr:
        left = self.unary()
        while True:
            op = self.binop()
            if op is None or BINARY[op] < min_prec:
                return left
            t = self.next()
            prec = BINARY[op]
            right = self.binary(prec + 1)
            if op == "&":
                op = "AND"
            self.operators += 1
            left = A.Binary(t.pos, op, left, right)

    def unary(self) -> A.Expr:
        t = self.tok
        if t.is_sym("-", "+") or t.is_kw("NOT"):
            self.next()
            call_form = self.tok.is_sym("(")
            operand = self.nested("expression", self.unary)
            op = "NOT" if t.kind == "KEYWORD" else t.value
            if op == "-" and isinstance(operand, (A.IntLit, A.RealLit)) and operand.prefix is None \
                    and not operand.negated:
                operand.value = -operand.value
                operand.pos = t.pos
                operand.negated = True
                return operand
            self.operators += 1
            self.unary_shape(t, op, operand, parenthesized=call_form)
            return A.Unary(t.pos, op, operand, call_form=call_form and op == "NOT")
        return self.power()

    def unary_shape(self, t, op: str, operand: A.Expr, parenthesized: bool) -> None:
        """MATIEC's grammar signs a number (`+5`, `- 5`) and puts `-` or NOT before a primary: `+y`, `+(5)` and an
        operator directly before another (`- -y`, `NOT NOT b`, `-+y`) are its syntax errors; `-(-y)` and `- -5`
        (the signed number -5) are not (measured with iec2c)."""
        def signed_number(e: A.Expr) -> bool:
            return isinstance(e, (A.IntLit, A.RealLit)) and e.prefix is None
        if op == "+" and (parenthesized or not signed_number(operand) or operand.negated):
            self.facts.append(fact("unary-plus", t.pos, text=t.text))
        elif op != "+" and not parenthesized and isinstance(operand, A.Unary) and not (
                operand.op == "+" and signed_number(operand.operand) and not operand.operand.negated):
            self.facts.append(fact("unary-chain", t.pos, op=op, inner=operand.op))

    def power(self) -> A.Expr:
        first = self.tok
        e = self.primary()
        if self.tok.is_sym(".", "[") and (first.is_sym("(") or isinstance(e, A.Call)):
            # MATIEC's grammar selects members and elements of variables only (measured with iec2c: F(k := 1).a,
            # (F(k := 1)).a and G(k := 1)[1] are syntax errors; v := F(k := 1); x := v.a is not)
            self.facts.append(fact("result-access", self.tok.pos, what="a parenthesized expression"
                                   if first.is_sym("(") else f"the result of {e.text or e.func}()"))
        return self.postfix(e)

    def primary(self) -> A.Expr:
        t = self.tok
        k = t.kind
        if k == "INT":
            self.next()
            return A.IntLit(t.pos, t.value)
        if k == "REAL":
            self.next()
            return A.RealLit(t.pos, t.value)
        if k == "STRING":
            self.next()
            return A.StrLit(t.pos, t.value)
        if k == "TIME":
            self.next()
            kind, text = t.value
            return A.TimeLit(t.pos, kind, text, decode(kind, text))
        if k == "TYPEPFX":
            return self.typed_literal()
        if k == "DIRECT":
            self.next()
            area, size, parts = t.value
            return A.Direct(t.pos, area, size, parts, t.text)
        if t.is_kw("TRUE", "FALSE"):
            self.next()
            return A.BoolLit(t.pos, t.value == "TRUE")
        if t.is_sym("("):
            self.next()
            e = self.expression()
            self.expect_sym(")", "to close the parenthesis")
            return e
        if k == "IDENT":
            return self.primary_name()
        raise self.fail(f"expected an expression, found {self.describe(t)}")

    def typed_literal(self) -> A.Expr:
        t = self.next()
        prefix = t.value
        v = self.tok
        neg = False
        if v.is_sym("-", "+"):
            neg = v.value == "-"
            self.next()
            v = self.tok
        if v.kind == "INT":
            self.next()
            return A.IntLit(t.pos, -v.value if neg else v.value, prefix)
        if v.kind == "REAL":
            self.next()
            return A.RealLit(t.pos, -v.value if neg else v.value, prefix)
        if v.is_kw("TRUE", "FALSE") and not neg:
            self.next()
            self.facts.append(fact("strucpp-bool-literal", t.pos, text=f"{t.text}#{v.text}", value=v.text))
            return A.BoolLit(t.pos, v.value == "TRUE", prefix)
        if v.kind == "STRING" and not neg:
            self.next()
            return A.StrLit(t.pos, v.value, prefix)
        if v.kind == "IDENT" and not neg:
            self.next()
            self.facts.append(fact("strucpp-enum-literal", t.pos, text=f"{t.text}#{v.text}", enum=t.text,
                                   value=v.text))
            return A.EnumLit(t.pos, prefix, v.value)
        raise self.fail(f"expected a literal after '{t.text}#', found {self.describe(v)}")

    def primary_name(self) -> A.Expr:
        t = self.next()
        if self.at_sym("("):
            return self.call(t)
        return A.Name(t.pos, t.value, t.text)

    def call(self, name: Token) -> A.Call:
        self.expect_sym("(")
        args: list[A.Arg] = []
        if not self.at_sym(")"):
            while True:
                args.append(self.argument())
                if not self.accept_sym(","):
                    break
        self.expect_sym(")", f"to close the call of {name.text}")
        return A.Call(name.pos, name.value, args, name.text)

    def argument(self) -> A.Arg:
        t = self.tok
        if t.is_kw("NOT") and self.la().kind == "IDENT" and self.la(2).is_sym("=>"):
            self.next()
            n = self.next()
            self.next()
            target = self.postfix(self.primary()) if not self.at_sym(",", ")") else None
            return A.Arg(t.pos, n.value, target, output=True, negated=True, text=n.text)
        if t.kind == "IDENT" and self.la().is_sym(":="):
            self.next()
            self.next()
            if self.at_sym(",", ")"):
                return A.Arg(t.pos, t.value, None, text=t.text)
            return A.Arg(t.pos, t.value, self.expression(), text=t.text)
        if t.kind == "IDENT" and self.la().is_sym("=>"):
            self.next()
            self.next()
            target = self.postfix(self.primary()) if not self.at_sym(",", ")") else None
            return A.Arg(t.pos, t.value, target, output=True, text=t.text)
        return A.Arg(t.pos, None, self.expression())

    def postfix(self, e: A.Expr) -> A.Expr:
        while True:
            t = self.tok
            if t.is_sym(".", "[", "^"):
                self.operators += 1
            if t.is_sym("."):
                self.next()
                m = self.tok
                if m.kind == "INT":
                    self.next()
                    e = A.BitAccess(m.pos, e, m.value)
                elif m.kind == "IDENT":
                    self.next()
                    if self.at_sym("("):
                        raise self.fail(f"method call {m.text}() is not supported (no methods in MATIEC)")
                    e = A.Member(m.pos, e, m.value, m.text)
                elif m.kind == "REAL":
                    raise self.fail("bit access needs a single bit number", pos=m.pos)
                else:
                    raise self.fail(f"expected a member name after '.', found {self.describe(m)}")
            elif t.is_sym("["):
                self.next()
                idx = [self.expression()]
                while self.accept_sym(","):
                    idx.append(self.expression())
                self.expect_sym("]", "to close the index")
                e = A.Index(t.pos, e, idx)
            elif t.is_sym("^"):
                self.next()
                e = A.Deref(t.pos, e)
            else:
                return e

    # -- configuration ------------------------------------------------------------------------------
    def configuration(self) -> A.Configuration:
        kw = self.next()
        name = self.ident("the CONFIGURATION name")
        globals_: list[A.VarBlock] = []
        resources: list[A.Resource] = []
        loose_tasks: list[A.TaskDecl] = []
        loose_progs: list[A.ProgInstance] = []
        while not self.at_kw("END_CONFIGURATION"):
            t = self.tok
            if t.kind == "EOF" or t.is_kw("FUNCTION", "FUNCTION_BLOCK", "PROGRAM") and not self.la().kind == "IDENT":
                raise self.fail(f"expected END_CONFIGURATION to close CONFIGURATION opened at "
                                f"{kw.pos.line}:{kw.pos.col}, found {self.describe(t)}")
            before = self.k
            try:
                if t.is_kw("VAR_GLOBAL", "VAR_ACCESS", "VAR_CONFIG"):
                    globals_.append(self.var_block())
                elif t.is_kw("RESOURCE"):
                    resources.append(self.resource())
                elif t.is_kw("TASK"):
                    loose_tasks.append(self.task())
                elif t.is_kw("PROGRAM"):
                    loose_progs.append(self.prog_instance())
                else:
                    raise self.fail(f"expected RESOURCE, TASK, PROGRAM or VAR_GLOBAL in the configuration, "
                                    f"found {self.describe(t)}")
            except ParseError:
                self.sync(("END_CONFIGURATION", "RESOURCE", "END_RESOURCE"))
                self.ensure_progress(before)
                if self.at_kw("END_RESOURCE"):
                    self.next()
                    self.accept_sym(";")
        self.next()
        self.accept_sym(";")
        if loose_tasks or loose_progs:
            resources.append(A.Resource(kw.pos, "", "", None, [], loose_tasks, loose_progs))
        return A.Configuration(kw.pos, name.value, name.text, globals_, resources)

    def resource(self) -> A.Resource:
        kw = self.next()
        name = self.ident("the RESOURCE name")
        on = None
        if self.accept_kw("ON"):
            on = self.ident("the resource type").value
        globals_, tasks, progs = [], [], []
        while not self.at_kw("END_RESOURCE"):
            t = self.tok
            if t.kind == "EOF" or t.is_kw("END_CONFIGURATION"):
                raise self.fail(f"expected END_RESOURCE to close RESOURCE opened at {kw.pos.line}:{kw.pos.col}")
            before = self.k
            try:
                if t.is_kw("VAR_GLOBAL"):
                    globals_.append(self.var_block())
                elif t.is_kw("TASK"):
                    tasks.append(self.task())
                elif t.is_kw("PROGRAM"):
                    progs.append(self.prog_instance())
                else:
                    raise self.fail(f"expected TASK, PROGRAM or VAR_GLOBAL in the resource, found {self.describe(t)}")
            except ParseError:
                self.sync(("END_RESOURCE", "TASK", "PROGRAM"))
                self.ensure_progress(before)
        self.next()
        self.accept_sym(";")
        return A.Resource(kw.pos, name.value, name.text, on, globals_, tasks, progs)

    def task(self) -> A.TaskDecl:
        kw = self.next()
        name = self.ident("the TASK name")
        interval = priority = single = None
        self.expect_sym("(", "after the task name", "TASK t(INTERVAL := T#10ms, PRIORITY := 0);")
        if not self.at_sym(")"):
            while True:
                p = self.ident("a task property")
                self.expect_sym(":=", "after the task property")
                v = self.expression()
                if p.value == "INTERVAL":
                    interval = v
                elif p.value == "PRIORITY":
                    priority = v
                elif p.value == "SINGLE":
                    single = v
                else:
                    self.diags.error(p.pos, f"unknown task property {p.text}", "INTERVAL, PRIORITY or SINGLE")
                if not self.accept_sym(","):
                    break
        self.expect_sym(")", "to close the task properties")
        self.end_stmt("the TASK declaration")
        return A.TaskDecl(kw.pos, name.value, name.text, interval, priority, single)

    def prog_instance(self) -> A.ProgInstance:
        kw = self.next()
        if self.at_kw("RETAIN", "NON_RETAIN"):
            self.next()
        name = self.ident("the program instance name")
        task = None
        if self.accept_kw("WITH"):
            task = self.ident("a task name").value
        self.expect_sym(":", "after the program instance", "PROGRAM inst WITH task : ProgramType;")
        typ = self.ident("the PROGRAM type")
        args = []
        if self.accept_sym("("):
            if not self.at_sym(")"):
                while True:
                    args.append(self.argument())
                    if not self.accept_sym(","):
                        break
            self.expect_sym(")", "to close the program arguments")
        self.end_stmt("the PROGRAM declaration")
        return A.ProgInstance(kw.pos, name.value, name.text, task, typ.value, typ.text, args)


def parse(text: str, filename: str, diags: Diagnostics) -> A.SourceFile:
    """The file's AST; the portability facts of the lexer and the parser ride on its `facts`.  With a build
    cache in use (buildcache.use), a file parsed before with the same name and text is loaded from it."""
    cache = buildcache.active()
    if cache is not None:
        return cache.parsed(text, filename, diags, parse_text)
    return parse_text(text, filename, diags)


def parse_text(text: str, filename: str, diags: Diagnostics) -> A.SourceFile:
    """The file's AST, parsed now."""
    facts: list[Fact] = []
    tokens = tokenize(text, filename, diags, facts)
    return Parser(tokens, filename, diags, facts).parse_file()
