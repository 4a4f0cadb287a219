"""Every portability warning is a rule of portability.RULES, documented in docs/matiec.md.

One example per rule proves that no rule is dead: compiling it gives that rule's warning and no other.  Over a
corpus (the project's ST, the standard and testing libraries, the ST snippets of the compiler tests, the examples
below), every portability warning the compiler writes carries the code of a rule.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from fuzz_compiler import corpus
from harness import compile_st
import plc
from plc import portability

ROOT = Path(__file__).resolve().parents[2]
CFG = ("CONFIGURATION Config0\nRESOURCE Res0 ON PLC\nTASK t0(INTERVAL := T#4ms, PRIORITY := 0);\n"
       "PROGRAM i0 WITH t0 : Main;\nEND_RESOURCE\nEND_CONFIGURATION\n")
FN = "FUNCTION F_Twice : INT\nVAR_INPUT k : INT; END_VAR\nF_Twice := k * 2;\nEND_FUNCTION\n"


def prog(decls: str, body: str) -> str:
    return f"PROGRAM Main\n{decls}\n{body}\nEND_PROGRAM\n"


OK = "VAR x : INT; w : WORD; b : BOOL; t : TIME; d : DINT; END_VAR"
# functions whose results are a structure and an array (result-access)
RESULTS = ("TYPE T_Pair : STRUCT a : INT; b : INT; END_STRUCT; END_TYPE\n"
           "TYPE T_Row : ARRAY[1..3] OF INT; END_TYPE\n"
           "FUNCTION F_Pair : T_Pair\nVAR_INPUT k : INT; END_VAR\nF_Pair.a := k;\nEND_FUNCTION\n"
           "FUNCTION F_Row : T_Row\nVAR_INPUT k : INT; END_VAR\nF_Row[1] := k;\nEND_FUNCTION\n")

# rule -> (ST that breaks it, --target)
EXAMPLES: dict[str, tuple[str, str | None]] = {
    "anon-enum": (prog("VAR m : (Stopped, Moving); END_VAR", "m := Moving;"), None),
    "anon-struct": (prog("VAR s : STRUCT a : INT; END_STRUCT; END_VAR", "s.a := 1;"), None),
    "array-bound": (prog("VAR CONSTANT n : INT := 3; END_VAR\nVAR a : ARRAY[0..n] OF INT; END_VAR", "a[0] := 1;"),
                    None),
    "array-of-array": ("TYPE T_Row : ARRAY[0..1] OF INT; END_TYPE\n" +
                       prog("VAR a : ARRAY[0..1] OF T_Row; END_VAR", "a[0][1] := 1;"), None),
    "bit-access": (prog(OK, "b := w.3;"), None),
    "call-statement": (FN + prog(OK, "F_Twice(1);"), None),
    "case-constant": (prog("VAR CONSTANT k : INT := 2; END_VAR\n" + OK, "CASE x OF k: x := 1; END_CASE;"), None),
    "comment-block": (prog(OK, "/* set x */ x := 1;"), None),
    "comment-line": (prog(OK, "x := 1; // set x"), None),
    "empty-call": ("FUNCTION F_One : INT\nVAR k : INT; END_VAR\nF_One := 1;\nEND_FUNCTION\n" +
                   prog(OK, "x := F_One();"), None),
    "enum-base": ("TYPE E_Mode : INT (Idle, Moving); END_TYPE\n" + prog("VAR m : E_Mode; END_VAR", "m := Idle;"),
                  None),
    "enum-order": ("TYPE E_Mode : (Idle, Moving); END_TYPE\n" +
                   prog("VAR m : E_Mode; b : BOOL; END_VAR", "b := m < Moving;"), None),
    "enum-qualify": ("TYPE E_A : (Idle, Run1); E_B : (Idle, Run2); END_TYPE\n" +
                     prog("VAR a : E_A; END_VAR", "a := Idle;"), None),
    "enum-select": ("TYPE E_Mode : (Idle, Moving); END_TYPE\n" +
                    prog("VAR m : E_Mode; b : BOOL; END_VAR", "m := SEL(b, Idle, Moving);"), None),
    "enum-value": ("TYPE E_Mode : (Idle := 0, Moving := 1); END_TYPE\n" + prog("VAR m : E_Mode; END_VAR", "m := Idle;"),
                   None),
    "fb-array": (prog("VAR timers : ARRAY[0..1] OF TON; END_VAR", ";"), None),
    "fb-inout": ("FUNCTION_BLOCK FB_Use\nVAR_IN_OUT tmr : TON; END_VAR\ntmr(IN := TRUE, PT := T#1s);\n"
                 "END_FUNCTION_BLOCK\n", None),
    "generic-conversion": (prog(OK, "d := TO_DINT(x);"), None),
    "global": ("VAR_GLOBAL g : INT; END_VAR\n" + prog(OK, "x := 1;"), None),
    "global-fb": (prog(OK, "x := 1;") + CFG.replace("RESOURCE Res0", "VAR_GLOBAL tmr : TON; END_VAR\nRESOURCE Res0"),
                  None),
    "inout-element": ("FUNCTION F_Bump : INT\nVAR_IN_OUT v : INT; END_VAR\nv := v + 1;\nF_Bump := v;\nEND_FUNCTION\n" +
                      prog("VAR a : ARRAY[0..1] OF INT; x : INT; END_VAR", "x := F_Bump(v := a[0]);"), None),
    "member-named-like-type": ("TYPE ST_Pos : STRUCT a : INT; END_STRUCT; END_TYPE\n"
                               "TYPE ST_Cell : STRUCT st_pos : ST_Pos; END_STRUCT; END_TYPE\n", None),
    "mixed-located": (prog("VAR\n    out AT %QW0 : INT;\n    x : INT;\nEND_VAR", "x := 1;"), None),
    "no-resource": (prog(OK, "x := 1;") + "CONFIGURATION Config0\nTASK t0(INTERVAL := T#4ms, PRIORITY := 0);\n"
                    "PROGRAM i0 WITH t0 : Main;\nEND_CONFIGURATION\n", None),
    "no-task": (prog(OK, "x := 1;") + CFG.replace("WITH t0 ", ""), None),
    "openplc-time-negate": (prog(OK, "t := -T#20ms;\nt := -(t - T#1s);"), "openplc"),
    "power": (prog("VAR r : REAL; END_VAR", "r := 2.0 ** 3.0;"), None),
    "pragma": (prog(OK, "{attribute 'x'}\nx := 1;"), None),
    "string-length": (prog("VAR s : STRING[20]; END_VAR", "s := 'a';"), None),
    "string-literal": (prog("VAR s : STRING; END_VAR", "s := '" + "a" * 126 + "';"), None),
    "struct-array-init": ("TYPE ST_P : STRUCT a : INT; END_STRUCT; END_TYPE\n" +
                          prog("VAR ps : ARRAY[0..1] OF ST_P := [(a := 1), (a := 2)]; END_VAR", "ps[0].a := 3;"),
                          None),
    "subrange-default": (prog("VAR k : INT(1..5); END_VAR", "k := 2;"), None),
    "time-conversion": (prog(OK, "d := TIME_TO_DINT(t);"), None),
    "time-inexact": (prog(OK, "t := t + T#4ms;"), None),
    "time-syntax": (prog(OK, "t := T#30m500ms;"), None),
    "result-access": (RESULTS + prog(OK, "x := F_Pair(k := 1).a;"), None),
    "time-unit": (prog(OK, "t := T#5us;"), None),
    "unary-chain": (prog(OK, "x := - -x;"), None),
    "unary-plus": (prog(OK, "x := 2 * +x;"), None),
    "wstring": (prog("VAR s : STRING; END_VAR", 's := "wide";'), None),
    "empty-body": (prog(OK, "IF b THEN\nEND_IF;"), None),
    "empty-statement": (prog(OK, "x := 1;;"), None),
    "enum-value-name": ("TYPE E_Op : (Idle, Limit); END_TYPE\n", None),
    "function-without-vars": ("FUNCTION F_Seven : INT\nF_Seven := 7;\nEND_FUNCTION\n", None),
    "identifier-double-underscore": (prog("VAR a__b : INT; END_VAR", "a__b := 1;"), None),
    "identifier-trailing-underscore": (prog("VAR ab_ : INT; END_VAR", "ab_ := 1;"), None),
    "library-name": ("TYPE State : (Idle, Running); END_TYPE\n", None),
    "openplc-configuration": (prog(OK, "x := 1;") + CFG.replace("Config0", "Cell"), "openplc"),
    "openplc-resource": (prog(OK, "x := 1;") + CFG.replace("Res0", "Cpu"), "openplc"),
    "type-alias": ("TYPE E_A : (One, Two); T_B : E_A; END_TYPE\n", None),
    "type-order": ("TYPE ST_Outer : STRUCT inner : ST_Inner; END_STRUCT; END_TYPE\n"
                   "TYPE ST_Inner : STRUCT a : INT; END_STRUCT; END_TYPE\n", None),
    "var-keyword": (prog("VAR r_edge : INT; END_VAR", "r_edge := 1;"), None),
    "var-library-block": (prog("VAR ramp : INT; END_VAR", "ramp := 1;"), None),
    "var-own-type-name": (prog("VAR tOn : TON; END_VAR", "tOn(IN := TRUE, PT := T#1s);"), None),
    "var-std-name": (prog("VAR limit : INT; END_VAR", "limit := 1;"), None),
    "var-type-name": ("TYPE E_Mode : (Idle, Moving); END_TYPE\n" + prog("VAR e_mode : INT; END_VAR", "e_mode := 1;"),
                      None),
    "strucpp-enum-literal": ("TYPE E_Mode : (Idle, Moving); END_TYPE\n" +
                             prog("VAR m : E_Mode; END_VAR", "m := E_Mode#Moving;"), "openplc-v4"),
    "strucpp-bool-literal": (prog(OK, "b := BOOL#TRUE;"), "openplc-v4"),
    "strucpp-negative-time": (prog(OK, "t := T#-20ms;"), "openplc-v4"),
    "strucpp-nested-comment": (prog(OK, "(* a (* b *)\nx := 1;"), "openplc-v4"),
    "strucpp-case-label": (prog(OK, "CASE x OF\n1, 2, 3, 4, 5: x := 0;\nEND_CASE;"), "openplc-v4"),
    "strucpp-keyword": (prog("VAR this : INT; END_VAR", "this := 1;"), "openplc-v4"),
    "strucpp-library-call": ("FUNCTION_BLOCK FB_Die\nVAR_INPUT faces : INT; END_VAR\nVAR_OUTPUT v : INT; END_VAR\n"
                             "v := faces;\nEND_FUNCTION_BLOCK\n" +
                             prog("VAR rnd : FB_Die; x : INT; END_VAR", "rnd(faces := 6);\nx := rnd.v;"), "openplc-v4"),
    "strucpp-and-guard": (prog("VAR a : ARRAY[1..3] OF INT; k : INT; b : BOOL; END_VAR", "b := k > 0 AND a[k] = 0;"),
                          "openplc-v4"),
    "strucpp-string-call": (prog("VAR s : STRING; x : INT; END_VAR", "x := LEN('abc');"), "openplc-v4"),
    "strucpp-string-length": (prog("VAR s : STRING; END_VAR", "s := CONCAT(s, 'ab');"), "openplc-v4"),
    "strucpp-not-int": (prog("VAR tool : INT; pocket : INT; keep : BOOL; END_VAR",
                             "keep := NOT (tool <> 0 AND pocket = 3);"), "openplc-v4"),
}


def portability_warnings(text: str, target: str | None = None) -> list:
    res = compile_st(text, name="t.st", generate=False, target=target)
    return [d for d in res.diags.sorted() if d.severity == "warning" and d.message.startswith("portability:")]


def test_every_rule_has_an_example_and_every_example_a_rule():
    assert sorted(EXAMPLES) == sorted(portability.RULES)


@pytest.mark.parametrize("rule", sorted(EXAMPLES))
def test_the_example_of_a_rule_gives_its_warning_and_no_other(rule):
    text, target = EXAMPLES[rule]
    found = portability_warnings(text, target)
    assert found, f"no warning for {rule}"
    assert {d.code for d in found} == {portability.rule_code(rule)}, [(d.code, d.message) for d in found]
    r = portability.RULES[rule]
    assert all(d.message.startswith("portability: ") for d in found)
    if r.hint is not None:
        assert all(d.hint for d in found)


def test_every_portability_warning_over_the_corpus_is_a_rule():
    """The warnings of the project's ST, the libraries, the compiler tests' snippets and the examples."""
    codes = {portability.rule_code(r) for r in portability.RULES}
    items = [*corpus(), *((f"example {r}", t) for r, (t, _target) in EXAMPLES.items())]
    seen: dict[str, int] = {}
    strays = []
    for name, text in items:
        for target in (None, "openplc", "openplc-v4"):
            for d in portability_warnings(text, target):
                seen[d.code] = seen.get(d.code, 0) + 1
                if d.code not in codes:
                    strays.append((name, d.code, d.message))
    assert strays == []
    assert set(seen) == codes      # the examples alone reach every rule; the corpus must not write another


def test_only_the_portability_pass_writes_a_portability_warning():
    """Parsed code: Diagnostics.portable is called by portability.warn only, and every rule a stage names is in
    RULES (a stage records a fact with `fact(rule, ...)` or `self.port(pos, rule, ...)`, the portability pass
    reports with `report(diags, rule, ...)`)."""
    pkg = Path(plc.__file__).parent
    callers, named = set(), set()
    for path in sorted(pkg.rglob("*.py")):
        tree = ast.parse(path.read_text())
        owner: dict[ast.Call, str] = {}
        for fn in ast.walk(tree):            # outer functions first: an inner one overwrites its calls
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                owner.update((c, fn.name) for c in ast.walk(fn) if isinstance(c, ast.Call))
        for call in (c for c in ast.walk(tree) if isinstance(c, ast.Call)):
            f = call.func
            name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            if name == "portable":
                callers.add((str(path.relative_to(pkg)), owner.get(call, "<module>")))
            k = {"fact": 0, "port": 1, "report": 1}.get(name)
            if k is not None and len(call.args) > k and isinstance(call.args[k], ast.Constant):
                named.add(call.args[k].value)
    assert callers == {("portability.py", "warn")}
    assert named <= set(portability.RULES), named - set(portability.RULES)
    assert len(named) > 40           # the walk found the stages' calls


def test_every_rule_is_documented_in_matiec_md_and_nothing_else_is():
    text = (ROOT / "docs" / "matiec.md").read_text()
    section = text.split("### Every portability warning", 1)[1].split("\n## ", 1)[0]
    documented = re.findall(r"^\| `([a-z-]+)` \|", section, flags=re.M)
    assert len(documented) == len(set(documented)), "a rule documented twice"
    assert sorted(documented) == sorted(portability.RULES)


@pytest.mark.parametrize("target", [None, "openplc", "openplc-v4"])
def test_a_negative_time_written_as_a_subtraction_from_zero_is_portable_everywhere(target):
    """The spelling the hints of strucpp-negative-time and openplc-time-negate give: MATIEC, OpenPLC's g++ and
    STruC++ all take it, so no target warns."""
    assert portability_warnings(prog(OK, "t := T#0s - T#20ms;\nb := t >= T#0s - (t - T#1s);"), target) == []
    hints = {d.hint for d in portability_warnings(prog(OK, "t := T#-20ms;"), "openplc-v4")}
    assert hints == {"write T#0s - T#20ms: MATIEC, OpenPLC's C and STruC++ all take it (-T#20ms does not compile "
                     "in OpenPLC v3)"}


@pytest.mark.parametrize("expr, rules", [
    ("+x", {"unary-plus"}), ("+(5)", {"unary-plus"}), ("+ -5", {"unary-plus"}), ("+-x", {"unary-plus"}),
    ("-+x", {"unary-chain", "unary-plus"}), ("- -x", {"unary-chain"}),
    ("+5", set()), ("+ 5", set()), ("- +5", set()), ("- -5", set()), ("-(-x)", set()), ("-(+5)", set()),
    ("x - -x", set()), ("x * -5", set()), ("-x * 2", set()),
])
def test_unary_operators_warn_exactly_where_iec2c_refuses_them(expr, rules):
    """Each expression was given to iec2c (OpenPLC_v3's MATIEC) in `x := <expr>;`: it refuses the ones with a
    rule, and compiles the others."""
    found = portability_warnings(prog(OK, f"x := {expr};"))
    assert {d.code for d in found} == {portability.rule_code(r) for r in rules}, [d.message for d in found]


def test_not_directly_before_not_warns_and_in_parentheses_does_not():
    assert [d.code for d in portability_warnings(prog(OK, "b := NOT NOT b;"))] == [portability.rule_code("unary-chain")]
    assert portability_warnings(prog(OK, "b := NOT (NOT b);")) == []


@pytest.mark.parametrize("body, warns", [
    ("x := F_Pair(k := 1).a;", True), ("x := (F_Pair(k := 1)).a;", True), ("x := F_Row(k := 1)[1];", True),
    ("x := 2 * F_Pair(k := x).b + 1;", True),
    ("p := F_Pair(k := 1); x := p.a;", False), ("r := F_Row(k := 1); x := r[1];", False),
    ("x := ABS(x) + (x);", False), ("x := (p).a;", True),
])
def test_selecting_from_a_result_warns_exactly_where_iec2c_refuses_it(body, warns):
    """Each body was given to iec2c (OpenPLC_v3's MATIEC): it refuses the ones that warn as syntax errors (a member
    or element of a function's result or of a parenthesized expression, a parenthesized variable too) and compiles
    the others (the same values taken from a variable)."""
    found = portability_warnings(RESULTS + prog("VAR x : INT; b : BOOL; p : T_Pair; r : T_Row; END_VAR", body))
    assert [d.code for d in found] == ([portability.rule_code("result-access")] if warns else []), \
        [d.message for d in found]
    if warns:
        assert "assign it to a variable first" in found[0].message + str(found[0].hint)
