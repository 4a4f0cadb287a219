"""Portability: what our compiler accepts but OpenPLC's MATIEC does not, all in one place.

RULES holds every language-level portability warning (its code, message and
hint).  The lexer, parser and semantic passes meet these constructs while they
check them, so they record a `Fact` there (`fact(rule, pos, **details)`: the
lexer's and the parser's ride on the file's `SourceFile.facts`, the semantic
passes' on `Program.facts`, built-in files left out), and `lint`, the
portability pass, turns every fact into the rule's warning (`--no-portability`
silences them all).  Only this module writes portability warnings, and
each is a rule of RULES: what the pass finds itself goes through `report`.

`lint`, run after the semantic passes, also looks at names:
POU and TYPE names that collide with OpenPLC's library, identifiers MATIEC's
lexer or code generator cannot take, and the CONFIGURATION/RESOURCE names
OpenPLC needs; at statement lists MATIEC rejects; and at TIME literals OpenPLC
converts inexactly.
"""
from __future__ import annotations

from functools import lru_cache

from . import ast as A
from . import lexer
from .diagnostics import Diagnostics
from .facts import RULES, Fact, Rule, fact, rule_code  # noqa: F401 (the rules are part of this pass's interface)
from .resources import DATA
from .stdfuncs import STD_FUNCS, conversion
from .timelit import exact_openplc_spelling, matiec_takes_duration, openplc_duration_ns, portable_spelling
from .types import ELEMENTARY, GENERIC, EnumType, StructType


def warn(facts: list[Fact], diags: Diagnostics, target: str | None = None) -> None:
    """Each recorded fact as its rule's warning, in the order the stages found them (a rule of a deploy target
    only when checking for that target)."""
    for f in facts:
        r = RULES[f.rule]
        if r.target is not None and r.target != target:
            continue
        details = dict(f.details)
        diags.portable(f.pos, r.message.format(**details), r.hint.format(**details) if r.hint else None,
                       code=rule_code(f.rule))


def report(diags: Diagnostics, rule: str, pos, target: str | None = None, **details) -> None:
    """The warning of `rule` at `pos`, for what the portability pass finds itself."""
    warn([fact(rule, pos, **{k: str(v) for k, v in details.items()})], diags, target)


# Identifiers MATIEC's parser refuses as variable names besides our keywords (measured with iec2c -p).
MATIEC_RESERVED = {
    "STEP", "END_STEP", "TRANSITION", "END_TRANSITION", "ACTION", "END_ACTION", "INITIAL_STEP",
    "EN", "ENO", "BY", "DT", "TOD", "R_EDGE", "F_EDGE",
}


@lru_cache(maxsize=1)
def library_identifiers() -> frozenset[str]:
    """OpenPLC's library identifiers (shared data) plus the names our MATIEC probes found fatal too."""
    names: set[str] = set()
    for f in ("openplc_library_identifiers.txt", "openplc_extra_identifiers.txt"):
        p = DATA / f
        if p.is_file():
            for line in p.read_text().splitlines():
                line = line.strip()
                if line and not line.startswith("#"):
                    names.add(line.upper())
    return frozenset(names)


def lint(files: list[A.SourceFile], prog, diags: Diagnostics, builtin: set[str], target: str | None = None) -> None:
    """The portability pass: the facts the lexer, parser and semantic passes recorded become warnings (file by
    file, then the passes'), then the names and statement lists of the user's files are checked."""
    for f in files:
        if f.path not in builtin:
            warn(f.facts, diags, target)
    warn(prog.facts, diags, target)
    lib = library_identifiers()
    v4 = target == "openplc-v4"
    enum_owners = enumeration_owners(files)
    for f in files:
        if f.path in builtin:
            continue
        if not f.path.lower().endswith(".xml#st"):    # a PLCopen project's types (plcopen.st_name) are
            type_order(f, prog, diags)                   # ordered by the tool that writes its ST, not the XML
        durations(f, diags)
        for item in f.items:
            if isinstance(item, A.Pou):
                pou_name(item.name, item.text, item.pos, "POU", lib, diags)
                if v4:
                    strucpp_names(item, prog, diags)
                    strucpp_and_guards(item, diags)
                    strucpp_not_ints(item, diags)
                    strucpp_string_lengths(item, diags)
                    strucpp_string_calls(item, diags)
                if not errors_inside(item, diags):   # a syntax error may have emptied a statement list
                    statement_lists(item.body, item.pos, f"{item.kind} {item.text}", diags)
                if item.kind == "FUNCTION" and not item.blocks:
                    report(diags, "function-without-vars", item.pos, function=item.text)
                for d in item.decls():
                    var_name(d, prog, diags, lib)
            elif isinstance(item, A.TypeBlock):
                for td in item.decls:
                    pou_name(td.name, td.text, td.pos, "TYPE", lib, diags)
                    if v4:
                        strucpp_type_names(td, diags)
                    aliased = prog.types.get(td.spec.name) if isinstance(td.spec, A.TypeRef) else None
                    if isinstance(aliased, (EnumType, StructType)):
                        kind = "an enumeration" if isinstance(aliased, EnumType) else "a STRUCT"
                        report(diags, "type-alias", td.pos, type=td.text, kind=kind,
                               aliased=td.spec.text or td.spec.name)
                    if isinstance(td.spec, A.EnumSpec):
                        ambiguous_initial_value(td, enum_owners, diags)
                        for k, (v, pos, _x) in enumerate(td.spec.values):
                            text = td.spec.texts[k] if k < len(td.spec.texts) else v
                            clash = name_clash(v, prog, lib)
                            if ident_shape(v, text, pos, diags) and clash:
                                report(diags, "enum-value-name", pos, value=text, clash=clash)
                    if isinstance(td.spec, A.StructSpec):
                        for m in td.spec.members:
                            ident_shape(m.name, m.text, m.pos, diags)
            elif isinstance(item, A.Configuration):
                config_names(item, diags, target)
                for b in item.globals:
                    for d in b.decls:
                        var_name(d, prog, diags, lib)
                        if v4:
                            strucpp_keyword(d.name, d.text, d.pos, diags)
                for r in item.resources:
                    for b in r.globals:
                        for d in b.decls:
                            var_name(d, prog, diags, lib)
                            if v4:
                                strucpp_keyword(d.name, d.text, d.pos, diags)


def enumeration_owners(files: list[A.SourceFile]) -> dict[str, list[str]]:
    """Enumeration value (upper case) -> the TYPEs of the program that declare it, in source order."""
    owners: dict[str, list[str]] = {}
    for f in files:
        for item in f.items:
            if isinstance(item, A.TypeBlock):
                for td in item.decls:
                    if isinstance(td.spec, A.EnumSpec):
                        for v, _pos, _x in td.spec.values:
                            owners.setdefault(v.upper(), []).append(td.text or td.name)
    return owners


def ambiguous_initial_value(td: A.TypeDecl, owners: dict[str, list[str]], diags: Diagnostics) -> None:
    """An enumeration TYPE whose initial value is an unqualified value that another enumeration declares too:
    iec2c rejects it ("Ambiguous enumerate value") where our compiler takes the TYPE's own."""
    if not isinstance(td.init, A.Name):
        return
    others = [t for t in owners.get(td.init.name.upper(), []) if t.upper() != td.name.upper()]
    if others:      # the expression pass cannot see it when the other enumeration is declared after this TYPE
        report(diags, "enum-qualify", td.init.pos, value=td.init.text or td.init.name,
               enums=", ".join([td.text, *others]), enum=td.text)


def type_order(f: A.SourceFile, prog, diags: Diagnostics) -> None:
    """A STRUCT member (or an array's element) of a TYPE declared further down the same file: iec2c reads a file
    in order and rejects it ("invalid specification in structure element declaration"). Files are ordered by
    `plc deploy openplc` (types before their users); inside one file the order is the author's."""
    declared = {td.name.upper(): td for item in f.items if isinstance(item, A.TypeBlock) for td in item.decls}
    seen: set[str] = set()
    for item in f.items:
        if not isinstance(item, A.TypeBlock):
            continue
        for td in item.decls:
            specs = [(m.spec, m.pos) for m in td.spec.members] if isinstance(td.spec, A.StructSpec) else \
                [(td.spec.elem, td.pos)] if isinstance(td.spec, A.ArraySpec) else []
            for spec, pos in specs:
                while isinstance(spec, A.ArraySpec):
                    spec = spec.elem
                if isinstance(spec, A.TypeRef) and spec.name.upper() in declared and spec.name.upper() not in seen \
                        and spec.name.upper() != td.name.upper():
                    later = declared[spec.name.upper()]
                    report(diags, "type-order", pos, type=td.text, used=later.text, line=later.pos.line)
            seen.add(td.name.upper())


def durations(f: A.SourceFile, diags: Diagnostics) -> None:
    """TIME literals MATIEC's lexer rejects (timelit.matiec_takes_duration), and those OpenPLC v3 converts a
    nanosecond short (timelit.openplc_duration_ns). A TASK's INTERVAL is exempt from the second: iec2c computes
    the tick from it in integers (T#4ms: common_ticktime__ = 4000000ULL)."""
    intervals = {id(n.interval) for item in f.items for n in A.walk(item) if isinstance(n, A.TaskDecl)}
    for item in f.items:
        for n in A.walk(item):
            if not isinstance(n, A.TimeLit) or n.kind != "TIME" or n.value is None:
                continue
            low = n.text.lower()
            if "us" in low or "ns" in low:         # the `time-unit` rule's
                continue
            if not matiec_takes_duration(n.text):
                report(diags, "time-syntax", n.pos, text=n.text, spelling=portable_spelling(n.value))
                continue
            if id(n) in intervals:
                continue
            openplc = openplc_duration_ns(n.text)
            if openplc is None or openplc == n.value:
                continue
            spelling = exact_openplc_spelling(n.value)
            hint = f"write {spelling}, which OpenPLC converts exactly" if spelling else \
                "no usual spelling of it is exact there: do not add it up scan after scan"
            report(diags, "time-inexact", n.pos, text=n.text, openplc=f"{openplc:,}", exact=f"{n.value:,}",
                   hint=hint)


def errors_inside(pou: A.Pou, diags: Diagnostics) -> bool:
    last = pou.end_pos.line if pou.end_pos is not None else 1 << 30
    return any(d.severity == "error" and d.pos.file == pou.pos.file and pou.pos.line <= d.pos.line <= last
               for d in diags.items)


def statement_lists(body: list[A.Stmt], pos, where: str, diags: Diagnostics) -> None:
    """MATIEC rejects an empty statement list (a POU body, THEN, ELSE, DO, a CASE arm) and a stray ';'."""
    if not any(not isinstance(s, A.Empty) for s in body):
        report(diags, "empty-body", pos, where=where)
    for s in body:
        if isinstance(s, A.Empty):
            report(diags, "empty-statement", s.pos)
        elif isinstance(s, A.If):
            for k, (_c, b) in enumerate(s.branches):
                statement_lists(b, s.pos, "the IF branch" if k == 0 else "an ELSIF branch", diags)
            if s.orelse is not None:
                statement_lists(s.orelse, s.pos, "the ELSE of this IF", diags)
        elif isinstance(s, A.Case):
            for labels, b in s.arms:
                statement_lists(b, labels[0].pos if labels else s.pos, "this CASE branch", diags)
            if s.orelse is not None:
                statement_lists(s.orelse, s.pos, "the ELSE of this CASE", diags)
        elif isinstance(s, (A.For, A.While, A.Repeat)):
            statement_lists(s.body, s.pos, f"this {type(s).__name__.upper()} loop", diags)


def ident_shape(name: str, text: str, pos, diags: Diagnostics) -> bool:
    if "__" in name:
        report(diags, "identifier-double-underscore", pos, name=text)
        return False
    if name.endswith("_"):
        report(diags, "identifier-trailing-underscore", pos, name=text)
        return False
    return True


def pou_name(name: str, text: str, pos, what: str, lib, diags: Diagnostics) -> None:
    if not ident_shape(name, text, pos, diags):
        return
    if name in lib:
        report(diags, "library-name", pos, what=what, name=text)


def name_clash(name: str, prog, lib) -> str | None:
    """Why MATIEC refuses `name` for a variable or an enumeration value (None: it takes it)."""
    if name in set(prog.types) | set(prog.pous) | set(ELEMENTARY):
        return "named like a type"
    if name in lexer.KEYWORDS or name in MATIEC_RESERVED or name in GENERIC:
        return "a keyword to MATIEC"
    if name in STD_FUNCS or conversion(name) is not None:
        return "named like a standard function"
    if name in lib and name in LIBRARY_BLOCKS:
        return "named like a function block of OpenPLC's library"
    return None


def var_name(d: A.VarDecl, prog, diags: Diagnostics, lib) -> None:
    name = d.name
    if name in ("EN", "ENO"):
        return          # the scopes pass refuses the declaration (an error): no warning on top
    if not ident_shape(name, d.text, d.pos, diags):
        return
    clash = name_clash(name, prog, lib)
    if clash is None:
        return
    if clash == "named like a type":
        rule = "var-own-type-name" if name == getattr(d.spec, "name", None) else "var-type-name"
    else:
        rule = VAR_CLASH_RULES[clash]
    report(diags, rule, d.pos, name=d.text)


# name_clash's other answers for a variable -> the rule of its warning
VAR_CLASH_RULES = {
    "a keyword to MATIEC": "var-keyword",
    "named like a standard function": "var-std-name",
    "named like a function block of OpenPLC's library": "var-library-block",
}


# Library function blocks whose names also break variables (measured with iec2c -p).
LIBRARY_BLOCKS = frozenset({"RAMP", "PID", "HYSTERESIS", "INTEGRAL", "DERIVATIVE", "SEMA", "RTC", "BLINK"})


def config_names(cfg: A.Configuration, diags: Diagnostics, target: str | None) -> None:
    if target != "openplc":
        return
    if cfg.text != "Config0":
        report(diags, "openplc-configuration", cfg.pos, name=cfg.text)
    for r in cfg.resources:
        if r.text and r.text != "Res0":
            report(diags, "openplc-resource", r.pos, name=r.text)


# Words STruC++ 0.6.1's lexer reserves that MATIEC and plc take as names (each tried as a variable name with
# STruC++; ABSTRACT, FINAL, OVERRIDE, GET, SET and its test words stay names there).
STRUCPP_KEYWORDS = frozenset({
    "THIS", "SUPER", "REF", "DREF", "NULL", "POINTER", "REF_TO", "REFERENCE_TO", "METHOD", "END_METHOD",
    "PROPERTY", "END_PROPERTY", "END_GET", "END_SET", "INTERFACE", "END_INTERFACE", "EXTENDS", "IMPLEMENTS",
    "PUBLIC", "PRIVATE", "PROTECTED", "VAR_INST",
})


@lru_cache(maxsize=1)
def strucpp_library_functions() -> frozenset[str]:
    """The functions of the libraries STruC++ loads unless told not to (its IEC functions, OSCAT Basic,
    PLCopen motion): names only, listed in data/strucpp_library_functions.txt."""
    p = DATA / "strucpp_library_functions.txt"
    return frozenset(line.strip().upper() for line in p.read_text().splitlines()
                     if line.strip() and not line.startswith("#"))


def strucpp_keyword(name: str, text: str, pos, diags: Diagnostics) -> None:
    if name.upper() in STRUCPP_KEYWORDS:
        report(diags, "strucpp-keyword", pos, "openplc-v4", name=text or name)


def strucpp_names(pou: A.Pou, prog, diags: Diagnostics) -> None:
    """A POU's name and variables against STruC++'s keywords; a function block instance against the functions
    of its libraries (STruC++ resolves `rnd(...)` to OSCAT's RND before the instance rnd)."""
    strucpp_keyword(pou.name, pou.text, pou.pos, diags)
    functions = strucpp_library_functions()
    for d in pou.decls():
        strucpp_keyword(d.name, d.text, d.pos, diags)
        spec = d.spec.name.upper() if isinstance(d.spec, A.TypeRef) else None
        block = prog.pous.get(spec) if spec else None
        if d.name.upper() in functions and getattr(block, "kind", None) == "FUNCTION_BLOCK":
            report(diags, "strucpp-library-call", d.pos, "openplc-v4", name=d.text or d.name,
                   function=d.name.upper())


ORDERING = ("<", "<=", ">", ">=")


def strucpp_and_guards(pou: A.Pou, diags: Diagnostics) -> None:
    """`k > 0 AND a[k] = 0`: STruC++ writes AND and OR as C++ '&' and '|' and reads arrays with a bounds-checked
    at(), so an element whose index the left operand compares to a bound is read anyway, and throws when out of
    bounds (plc and MATIEC write '&&' and '||')."""
    seen: set[int] = set()
    for node in (n for stmt in pou.body for n in A.walk(stmt)):
        if not (isinstance(node, A.Binary) and node.op in ("AND", "&", "OR")):
            continue
        guarded = {side.name for c in A.walk(node.left) if isinstance(c, A.Binary) and c.op in ORDERING
                   for side in (c.left, c.right) if isinstance(side, A.Name)}       # k > 0, i <= n
        for index in (n for n in A.walk(node.right) if isinstance(n, A.Index) and id(n) not in seen):
            names = {n.name for i in index.indices for n in A.walk(i) if isinstance(n, A.Name)}
            if names & guarded:
                seen.add(id(index))
                base = index.base
                array = (base.text or base.name) if isinstance(base, (A.Name, A.Member)) else "the array"
                report(diags, "strucpp-and-guard", index.pos, "openplc-v4", op="AND" if node.op == "&" else node.op,
                       array=array, index=", ".join(sorted(names & guarded)))


COMPARISONS = ("=", "<>", *ORDERING)
BITWISE = {"AND": "&", "&": "&", "OR": "|", "XOR": "^"}


def strucpp_cpp_kind(e: A.Expr) -> str | None:
    """What C++ type STruC++'s code gives `e`, as far as NOT cares: "int" (C++ '&', '|', '^' of two plain bools, of
    an int, or of IECVar<T> and IECVar<U> of different T and U: none of the runtime's operator templates matches),
    "bool" (a comparison, TRUE or FALSE, a NOT it writes as '!'), the name of the elementary type of an IECVar
    (a variable, an element, a member, a function's result, a typed literal) or None where not known."""
    if isinstance(e, A.Binary) and e.op in COMPARISONS:
        return "bool"
    if isinstance(e, A.BoolLit) and not e.prefix:
        return "bool"
    if isinstance(e, A.IntLit):
        return e.prefix.upper() if e.prefix else "int"
    if isinstance(e, A.Unary) and e.op == "NOT":
        # NOT (x) is a call of the runtime's function NOT, of x's type; NOT x is C++ '!x' (a bool) when x is a BOOL
        # ('~x' for the other bit types, left unknown here)
        if e.call_form:
            return strucpp_cpp_kind(e.operand)
        return "bool" if getattr(e.operand.ty, "name", None) == "BOOL" else None
    if isinstance(e, A.Binary) and e.op in BITWISE:
        left, right = strucpp_cpp_kind(e.left), strucpp_cpp_kind(e.right)
        if "int" in (left, right) or left == right == "bool":
            return "int"
        if left is None or right is None:
            return None
        if "bool" in (left, right):                 # IECVar<bool> & bool is IECVar<bool>; IECVar<uint16_t> & bool
            other = right if left == "bool" else left   # is C++'s own '&': an int
            return other if other == "BOOL" else "int"
        return left if left == right else "int"
    if isinstance(e, (A.Name, A.Member, A.Index, A.Call)):
        name = getattr(e.ty, "name", None)
        return name.upper() if isinstance(name, str) and name.upper() in ELEMENTARY else None
    return None


def strucpp_not_ints(pou: A.Pou, diags: Diagnostics) -> None:
    """`NOT (a <> 0 AND b = c)`: STruC++ writes AND, OR and XOR as C++ '&', '|' and '^', which give an int from two
    comparisons (bools), and its NOT takes bit types only, so g++ refuses NOT of that int.  With a BOOL variable
    (an IECVar) on one side and a bool or a BOOL on the other the runtime's operator gives an IECVar, and NOT
    takes it."""
    for node in (n for stmt in pou.body for n in A.walk(stmt)):
        if not (isinstance(node, A.Unary) and node.op == "NOT" and isinstance(node.operand, A.Binary)
                and node.operand.op in BITWISE):
            continue
        inner = node.operand
        left, right = strucpp_cpp_kind(inner.left), strucpp_cpp_kind(inner.right)
        if strucpp_cpp_kind(inner) != "int":
            continue
        if "int" in (left, right):
            operands = "an int (an AND, OR or XOR of comparisons, or an untyped integer literal)"
        elif left == right == "bool":
            operands = "two bools (comparisons, TRUE or FALSE)"
        else:
            operands = f"{left} and {right}"
        report(diags, "strucpp-not-int", node.pos, "openplc-v4", op="AND" if inner.op == "&" else inner.op,
               cpp=BITWISE[inner.op], operands=operands)


GROWING = ("CONCAT", "INSERT", "REPLACE")


def call_inputs(call: A.Call) -> list:
    """A standard function call's input values in parameter order (sema's std_args), else as written."""
    return call.std_args or [a.value for a in call.args if not a.output]


def strucpp_string_lengths(pou: A.Pou, diags: Diagnostics) -> None:
    """A plain STRING holds 126 characters in OpenPLC v3 (MATIEC) and 254 in STruC++ (OpenPLC v4): only CONCAT,
    INSERT and REPLACE make a string longer than the literals (at most 125 characters, rule string-literal), and
    their result is the same on both when LEFT(..., n) with n <= 126 takes it."""
    cut: set[int] = set()
    nodes = [n for stmt in pou.body for n in A.walk(stmt)]
    for node in nodes:
        values = call_inputs(node) if isinstance(node, A.Call) and node.func.upper() == "LEFT" else []
        if len(values) == 2 and isinstance(values[1], A.IntLit) and values[1].value <= 126 and values[0] is not None:
            cut.add(id(values[0]))
    for node in nodes:
        if isinstance(node, A.Call) and node.func.upper() in GROWING and id(node) not in cut \
                and getattr(node.ty, "name", None) == "STRING":
            report(diags, "strucpp-string-length", node.pos, "openplc-v4", call=node.text or node.func.upper())


# the standard string functions whose first STRING input STruC++'s runtime takes only as a variable or a function's
# result (no overload for a literal, a C++ const char*)
STRING_FIRST_NOT_LITERAL = ("LEFT", "RIGHT", "MID", "LEN", "DELETE", "INSERT", "REPLACE")


def strucpp_string_calls(pou: A.Pou, diags: Diagnostics) -> None:
    """String function calls STruC++'s C++ runtime has no overload for (g++ refuses them): CONCAT of more than
    two strings, CONCAT of two literals, and a literal as the first input of LEFT, RIGHT, MID, LEN, DELETE,
    INSERT and REPLACE."""
    for node in (n for stmt in pou.body for n in A.walk(stmt)):
        if not isinstance(node, A.Call):
            continue
        func = node.func.upper()
        values = call_inputs(node)
        name = node.text or func
        if func == "CONCAT" and len(values) > 2:
            report(diags, "strucpp-string-call", node.pos, "openplc-v4", call=name,
                   why=f"{len(values)} strings (it takes two)", hint="nest the calls: CONCAT(CONCAT(a, b), c)")
        elif func == "CONCAT" and len(values) == 2 and all(isinstance(v, A.StrLit) for v in values):
            report(diags, "strucpp-string-call", node.pos, "openplc-v4", call=name, why="two literals",
                   hint="write the joined literal")
        elif func in STRING_FIRST_NOT_LITERAL and values and isinstance(values[0], A.StrLit):
            report(diags, "strucpp-string-call", node.pos, "openplc-v4", call=name, why="a literal as its first input",
                   hint="give the literal to a STRING variable first")


def strucpp_type_names(td: A.TypeDecl, diags: Diagnostics) -> None:
    strucpp_keyword(td.name, td.text, td.pos, diags)
    if isinstance(td.spec, A.EnumSpec):
        for k, (v, pos, _x) in enumerate(td.spec.values):
            strucpp_keyword(v, td.spec.texts[k] if k < len(td.spec.texts) else v, pos, diags)
    if isinstance(td.spec, A.StructSpec):
        for m in td.spec.members:
            strucpp_keyword(m.name, m.text, m.pos, diags)
