"""Parametrised scan tests for `plc test`: one test body, its cases as rows of a table.

A test FUNCTION_BLOCK TEST_X that declares VAR_INPUTs is a template, not a test by itself: `plc test` runs it
once per case of the table TEST_X.cases.toml beside TEST_X.st, each case on a fresh instance and reported under
its own name, TEST_X[Input=value,...], at the row of the table that made it.  The table is an array of tables
`case`; a row gives inputs by name (case-insensitive, as in ST).  A list of values makes one case per value,
several lists every combination (in the order TEST_X declares its inputs, the first varying slowest, which is
also the order of the name); an input a row leaves out keeps its declared initial value:

    [[case]]
    Kind = ["OperatorAbort", "EStopOpened"]
    AtStep = [1, 2, 3]                   # 2 x 3 = 6 cases

Values are TOML booleans, integers and floats, or a string holding one ST literal: an enumeration value
(`EStopOpened`, `E_InterruptKind#EStopOpened`), a time (`T#5s`), a typed literal (`INT#5`), a string (`'text'`).

Each case becomes a small test FB, TEST_X__<n> (a name portable ST cannot declare), that calls TEST_X with the
row's values on every scan.  It is compiled with the tests from memory and never written into the project: the
sources stay portable ST that MATIEC compiles like any other (TEST_X is an ordinary function block there).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path

from . import ast as A
from . import tomlconf
from .diagnostics import Diagnostics, Pos, SourceSet
from .driver import display_name, read_source
from .lexer import tokenize
from .parser import parse

SUFFIX = ".cases.toml"
GENERATED = "<plc>/testing/cases.st"     # the name the generated case FBs are compiled under
ROWS = "case"                            # the table's one key: its rows
CONTEXT_TYPE = "ST_TESTCONTEXT"
LITERAL_KINDS = {"INT", "REAL", "STRING", "TIME", "IDENT"}


@dataclass
class Case:
    """One case of a parametrised test: its reported name, the generated FB that runs it, its row."""
    name: str          # TEST_X[Kind=EStopOpened,AtStep=3]
    template: str      # TEST_X, as declared
    pou: str           # TEST_X__3, the generated test FB
    pos: Pos           # the row of the table
    context: str       # TEST_X's VAR_IN_OUT of type ST_TestContext
    args: list[tuple[Pos, str, str]] = field(default_factory=list)   # (the key in the table, input, ST text)


@dataclass
class CaseSet:
    """The case tables of a test build: their cases, the ST that runs them, and where each generated line came
    from (to point a compiler diagnostic on the generated text at the table)."""
    diags: Diagnostics = field(default_factory=Diagnostics)
    sources: SourceSet = field(default_factory=SourceSet)
    cases: list[Case] = field(default_factory=list)
    templates: set[str] = field(default_factory=set)        # upper-case names of the tests that have a table
    tables: dict[str, str] = field(default_factory=dict)    # display name -> text
    lines: list[tuple[Pos, str]] = field(default_factory=list)   # generated line n + 1 -> (table position, case)
    text: str = ""

    def by_pou(self) -> dict[str, Case]:
        return {c.pou.upper(): c for c in self.cases}

    def extra_texts(self) -> list[tuple[str, str]]:
        return [(GENERATED, self.text)] if self.cases else []

    def remap(self, diags: Diagnostics, sources: SourceSet) -> None:
        """Diagnostics on the generated ST moved to the table row (or key) they come from, naming the case."""
        for d in diags.items:
            if d.pos.file == GENERATED and 1 <= d.pos.line <= len(self.lines):
                pos, case = self.lines[d.pos.line - 1]
                d.pos = pos
                d.message = f"case {case}: {d.message}"
        for name, text in self.tables.items():
            sources.add(name, text)


def find_tables(paths: list[str]) -> list[Path]:
    """The case tables of the test paths: every *.cases.toml under a directory, the one beside a file given."""
    found: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found.extend(sorted(q for q in p.rglob("*" + SUFFIX) if q.is_file()))
        elif p.suffix.lower() == ".st":
            table = p.with_name(p.stem + SUFFIX)
            if table.is_file():
                found.append(table)
    unique: dict[Path, Path] = {}
    for t in found:
        unique.setdefault(t.resolve(), t)
    return list(unique.values())


def load(paths: list[str]) -> CaseSet:
    """Read and check every case table of the test paths; generate the ST of their cases."""
    cs = CaseSet()
    for table in find_tables(paths):
        _load_table(cs, table)
    cs.text = _generate(cs)
    return cs


class _Table:
    """One table file being read: its document (values and positions) and where its problems go."""

    def __init__(self, cs: CaseSet, doc: tomlconf.Document) -> None:
        self.cs = cs
        self.doc = doc
        self.name = doc.file

    def at(self, *path) -> Pos:
        """Where the entry of a key path is written (or its nearest written ancestor)."""
        return self.doc.pos(tuple(path))

    def error(self, pos: Pos, message: str, hint: str | None = None) -> None:
        self.cs.diags.error(pos, message, hint, code="test.cases")


def _load_table(cs: CaseSet, path: Path) -> None:
    name = display_name(path)
    text = read_source(path)
    cs.tables[name] = text
    cs.sources.add(name, text)
    test = path.name[:-len(SUFFIX)]
    try:
        doc = tomlconf.parse(text, name)
    except tomlconf.TomlError as e:
        cs.diags.items.append(e.diagnostic)
        return
    t = _Table(cs, doc)
    pou = _template(t, path.with_name(test + ".st"), test)
    for key in doc.data:
        if key != ROWS:
            t.error(t.at(key), f"unknown key '{key}'", f"a case table has one key, its rows: [[{ROWS}]]")
    rows = doc.data.get(ROWS)
    if not isinstance(rows, list) or not rows or not all(isinstance(r, dict) for r in rows):
        t.error(t.at(ROWS), f"no rows: write each case (or set of cases) as a [[{ROWS}]] table",
                f"e.g. [[{ROWS}]] then Pocket = [1, 2, 3]")
        return
    cs.templates.add(test.upper())
    if pou is None:
        return
    inputs = [d for d in pou.decls() if d.section == "VAR_INPUT"]
    by_name = {d.name: d for d in inputs}
    context = next(d.text for d in pou.decls() if _is_context(d))
    seen: dict[str, Pos] = {}
    for n, row in enumerate(rows):
        row_pos = t.at(ROWS, n)
        for case_name, args in _row_cases(t, n, row, by_name, pou.text):
            if case_name in seen:
                t.error(row_pos, f"case {case_name} twice (first at line {seen[case_name].line})")
                continue
            seen[case_name] = row_pos
            number = sum(1 for c in cs.cases if c.template == pou.text) + 1
            cs.cases.append(Case(case_name, pou.text, f"{pou.text}__{number}", row_pos, context,
                                 [(t.at(ROWS, n, key), decl, st) for key, decl, st in args]))


def _is_context(d: A.VarDecl) -> bool:
    return d.section == "VAR_IN_OUT" and isinstance(d.spec, A.TypeRef) and d.spec.name == CONTEXT_TYPE


def _template(t: _Table, st: Path, test: str) -> A.Pou | None:
    """The parametrised test the table belongs to: FUNCTION_BLOCK `test` with inputs, in `st` beside it."""
    where = Pos(t.name, 1, 1)
    hint = f"the cases of a test with inputs, TEST_X in TEST_X.st, are in TEST_X{SUFFIX} beside it"
    if not test.upper().startswith("TEST_"):
        t.error(where, f"a case table is named after its test, TEST_...{SUFFIX}", hint)
        return None
    if not st.is_file():
        t.error(where, f"no {st.name} beside this table for its test {test}", hint)
        return None
    parsed = Diagnostics()
    tree = parse(read_source(st), display_name(st), parsed)
    if parsed.has_errors():
        return None         # the compiler reports the file's errors; its inputs are not known before they are mended
    pou = next((p for p in tree.items if isinstance(p, A.Pou) and p.kind == "FUNCTION_BLOCK"
                and p.name == test.upper()), None)
    if pou is None:
        t.error(where, f"{st.name} declares no FUNCTION_BLOCK {test}", hint)
        return None
    if not any(_is_context(d) for d in pou.decls()):
        t.error(where, f"{pou.text} is not a test: it has no VAR_IN_OUT of type ST_TestContext", hint)
        return None
    if not any(d.section == "VAR_INPUT" for d in pou.decls()):
        t.error(where, f"{pou.text} has no VAR_INPUT for the table's values", hint)
        return None
    return pou


def _row_cases(t: _Table, n: int, row: dict, by_name: dict[str, A.VarDecl], test: str):
    """(case name, [(key, input, ST text)]) for every case row n makes; nothing when the row is wrong."""
    given: dict[str, tuple[str, list[str]]] = {}
    ok = True
    if not row:
        t.error(t.at(ROWS, n), "a row with no input", f"name inputs of {test}: " + ", ".join(
            d.text for d in by_name.values()))
        return []
    for key, value in row.items():
        decl = by_name.get(key.upper())
        if decl is None:
            t.error(t.at(ROWS, n, key), f"{test} has no input '{key}'",
                    tomlconf.suggestion(key, [d.text for d in by_name.values()]))
            ok = False
            continue
        if decl.name in given:
            t.error(t.at(ROWS, n, key), f"input {decl.text} given twice in one row")
            ok = False
            continue
        values = value if isinstance(value, list) else [value]
        if not values:
            t.error(t.at(ROWS, n, key), f"{key}: an empty list makes no case")
            ok = False
            continue
        texts = []
        for k, v in enumerate(values):
            text, problem = st_literal(v)
            if problem:
                where = t.at(ROWS, n, key, k) if isinstance(value, list) else t.at(ROWS, n, key)
                t.error(where, f"{key}: {problem}",
                        "a boolean, an integer, a float, or a string holding one ST literal ('T#5s', 'E_Kind#A')")
                ok = False
            texts.append(text)
        given[decl.name] = (key, texts)
    if not ok:
        return []
    order = [d for d in by_name.values() if d.name in given]      # the declaration's order
    out = []
    for combo in itertools.product(*(given[d.name][1] for d in order)):
        name = f"{test}[" + ",".join(f"{d.text}={v}" for d, v in zip(order, combo, strict=True)) + "]"
        out.append((name, [(given[d.name][0], d.text, v) for d, v in zip(order, combo, strict=True)]))
    return out


def st_literal(value) -> tuple[str, str | None]:
    """(ST text, problem) of one table value."""
    if isinstance(value, bool):
        return ("TRUE" if value else "FALSE"), None
    if isinstance(value, int):
        return str(value), None
    if isinstance(value, float):
        if not math.isfinite(value):
            return "", f"{value} has no ST literal"
        mantissa, _, exponent = repr(value).partition("e")
        if "." not in mantissa:
            mantissa += ".0"
        return mantissa + (f"E{exponent}" if exponent else ""), None
    if isinstance(value, str):
        text = value.strip()
        return text, (None if _one_literal(text) else f"'{value}' is not one ST literal")
    return "", f"a {type(value).__name__} is not a value for an input"


def _one_literal(text: str) -> bool:
    """Whether `text` is one ST literal: [TYPE#] [sign] value, the value a number, string, time, name or
    TRUE/FALSE (an enumeration value is a name, qualified or not)."""
    diags = Diagnostics()
    tokens = [tok for tok in tokenize(text, "<case>", diags) if tok.kind != "EOF"]
    if diags.has_errors() or not tokens:
        return False
    if tokens[0].kind == "TYPEPFX":
        tokens = tokens[1:]
    if len(tokens) == 2 and tokens[0].is_sym("-", "+") and tokens[1].kind in ("INT", "REAL"):
        tokens = tokens[1:]
    return len(tokens) == 1 and (tokens[0].kind in LITERAL_KINDS or tokens[0].is_kw("TRUE", "FALSE"))


def _generate(cs: CaseSet) -> str:
    """The ST of every case: a test FB calling its template with the row's values, each line remembering the
    table position it stands for."""
    out: list[str] = ["(* Generated by plc test from the case tables (*.cases.toml): one test FB per case. *)"]
    cs.lines = [(Pos(GENERATED, 1, 1), "")]

    def emit(text: str, pos: Pos, case: str) -> None:
        out.append(text)
        cs.lines.append((pos, case))

    for c in cs.cases:
        for line in (f"FUNCTION_BLOCK {c.pou}", "VAR_IN_OUT", "    tc : ST_TestContext;", "END_VAR", "VAR",
                     f"    body : {c.template};", "END_VAR"):
            emit(line, c.pos, c.name)
        emit(f"body({c.context} := tc" + ("," if c.args else ");"), c.pos, c.name)
        for k, (pos, name, text) in enumerate(c.args):
            emit(f"    {name} := {text}" + ("," if k + 1 < len(c.args) else ");"), pos, c.name)
        emit("END_FUNCTION_BLOCK", c.pos, c.name)
    return "\n".join(out) + "\n"
