"""Reading the project's code for its architecture rules: parsed, never grepped.

Python goes through CPython's `ast` module, Structured Text through our own front end (`plc.parser`), C through
`c_tokens`, a token scan that drops comments and keeps string and character literals whole: a name in a comment
or inside a string is not code, and text in a comment is not a literal.  pycparser would give a whole C tree, but
it wants preprocessed input (the system's and libmodbus's headers) and is not a dependency; the rules here need
tokens only.

Each checker returns what it found, with lines, so a test asserts the list and prints it when a rule breaks; the
tests that use them also run each checker on a snippet that breaks its rule, to prove it can fail.
"""
from __future__ import annotations

import ast
import re
from dataclasses import dataclass
from pathlib import Path

from plc import ast as A
from plc.diagnostics import Diagnostics
from plc.parser import parse

# ---------------------------------------------------------------------------------------------------- Python


def parents_subscripts(source: str, filename: str = "<snippet>") -> list[int]:
    """Lines where the code indexes an attribute named `parents` (`Path(__file__).parents[2]`, `p.parents[i]`):
    a path found by counting folders up from a file."""
    tree = ast.parse(source, filename)
    return sorted(node.lineno for node in ast.walk(tree)
                  if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Attribute)
                  and node.value.attr == "parents")


# -------------------------------------------------------------------------------------------- Structured Text


def parse_st(text: str, filename: str) -> A.SourceFile:
    """The AST of one ST file; a syntax error fails the calling test with its position."""
    diags = Diagnostics()
    tree = parse(text, filename, diags)
    errors = [f"{d.pos.file}:{d.pos.line}:{d.pos.col}: {d.message}" for d in diags.errors]
    assert not errors, "\n".join(errors)
    return tree


def parse_st_files(paths: list[Path], root: Path) -> list[A.SourceFile]:
    """The ASTs of ST files, each named by its path relative to root."""
    return [parse_st(p.read_text(encoding="utf-8"), p.relative_to(root).as_posix()) for p in paths]


def st_nodes(trees: list[A.SourceFile], kind: type) -> list:
    """Every node of that kind in the trees, in source order."""
    return [node for tree in trees for node in A.walk(tree) if isinstance(node, kind)]


def st_enum_values(trees: list[A.SourceFile], name: str) -> list[str]:
    """The values of the enumerated type `name`, as spelled in its declaration; no such type fails the test."""
    specs = [t.spec for t in st_nodes(trees, A.TypeDecl) if t.name.upper() == name.upper()]
    assert len(specs) == 1 and isinstance(specs[0], A.EnumSpec), f"{name}: {len(specs)} declarations, not one enum"
    return list(specs[0].texts)


def int_literal(expr: object) -> int | None:
    """The value of an integer literal, None for any other expression."""
    return expr.value if isinstance(expr, A.IntLit) else None


# ---------------------------------------------------------------------------------------------------------- C


@dataclass(frozen=True)
class CToken:
    kind: str       # "ident", "number", "string", "char", "punct"
    text: str       # a literal's text between its quotes, escapes as written
    line: int


_C_SCAN = re.compile(r"""
    (?P<comment>//[^\n]*|/\*.*?\*/)
  | (?P<open_comment>/\*)
  | (?P<string>"(?:[^"\\\n]|\\.)*")
  | (?P<char>'(?:[^'\\\n]|\\.)*')
  | (?P<ident>[A-Za-z_]\w*)
  | (?P<number>\.?\d(?:[eEpP][+-]|[\w.])*)
  | (?P<punct><<=|>>=|\.\.\.|->|\+\+|--|<<|>>|<=|>=|==|!=|&&|\|\||\#\#|[-+*/%&|^]=|[][(){}.,;:?~!<>=+\-*/%&|^\#])
  | (?P<space>\s+|\\\n)
  | (?P<other>.)
""", re.S | re.X)

C_ASSIGN = {"=", "+=", "-=", "*=", "/=", "%=", "&=", "|=", "^=", "<<=", ">>="}
# keywords that may stand before a call: after any other identifier a name followed by ( is being declared
_C_BEFORE_CALL = {"return", "case", "sizeof", "else", "do"}


def c_tokens(text: str, filename: str = "<snippet>") -> list[CToken]:
    """The C text as tokens, comments dropped.  An unterminated comment or literal is an error at its line."""
    out: list[CToken] = []
    line = 1
    for m in _C_SCAN.finditer(text):
        kind, s = m.lastgroup, m.group()
        if kind in ("open_comment", "other") and s in ("/*", '"', "'"):
            raise ValueError(f"{filename}:{line}: unterminated {'comment' if s == '/*' else 'literal'}")
        if kind in ("string", "char"):
            out.append(CToken(kind, s[1:-1], line))
        elif kind in ("ident", "number", "punct"):
            out.append(CToken(kind, s, line))
        line += s.count("\n")
    return out


def c_calls(tokens: list[CToken], name: str) -> list[int]:
    """Lines where the function `name` is called: the name, then `(`, not after a type (which declares it)."""
    return [t.line for i, t in enumerate(tokens[:-1])
            if t.kind == "ident" and t.text == name and tokens[i + 1].text == "("
            and not (i > 0 and tokens[i - 1].kind == "ident" and tokens[i - 1].text not in _C_BEFORE_CALL)]


def c_assignments(tokens: list[CToken], name: str) -> list[int]:
    """Lines where `name` (a variable, a member, what a pointer points to) is assigned, incremented or decremented."""
    found = []
    for i, t in enumerate(tokens):
        if t.kind != "ident" or t.text != name:
            continue
        after = tokens[i + 1].text if i + 1 < len(tokens) else ""
        before = tokens[i - 1].text if i > 0 else ""
        if after in C_ASSIGN or after in ("++", "--") or before in ("++", "--"):
            found.append(t.line)
    return found


def c_enum(tokens: list[CToken], tag: str) -> dict[str, int]:
    """The enumerators of `enum tag { ... }` with their values (C's rule: the previous value + 1 unless given);
    a value other than an integer literal is an error naming it."""
    for i in range(len(tokens) - 2):
        if (tokens[i].text, tokens[i + 1].text, tokens[i + 2].text) == ("enum", tag, "{"):
            break
    else:
        raise ValueError(f"no enum {tag} {{ ... }}")
    values: dict[str, int] = {}
    nxt, j = 0, i + 3
    while tokens[j].text != "}":
        name = tokens[j]
        assert name.kind == "ident", f"line {name.line}: {name.text!r} where an enumerator was expected"
        j += 1
        if tokens[j].text == "=":
            value = tokens[j + 1]
            if value.kind != "number" or tokens[j + 2].text not in (",", "}"):
                raise ValueError(f"line {value.line}: {name.text} is not given an integer literal")
            nxt = int(value.text.rstrip("uUlL"), 0)
            j += 2
        values[name.text] = nxt
        nxt += 1
        if tokens[j].text == ",":
            j += 1
    return values


def c_names(tokens: list[CToken]) -> set[str]:
    """Every identifier of the code, and every word written in one of its string literals."""
    words = {t.text for t in tokens if t.kind == "ident"}
    for t in tokens:
        if t.kind == "string":
            words |= set(re.findall(r"[A-Za-z_]\w*", t.text))
    return words
