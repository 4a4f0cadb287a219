"""Diagnostics: one test per semantic check, syntax error and portability warning; exit codes of plc.

Every check asserts the file:line:col the diagnostic points at and its message.
Semantic checks follow MATIEC's strictness (issue 2, item 4); portability
warnings flag what OpenPLC's iec2c rejects or runs differently (item 5).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from harness import compile_st
from plc.cli import main as plc_main

PLC = Path(sys.executable).with_name("plc")


def diags(src: str, name: str = "t.st", portability: bool = True, target: str | None = None):
    res = compile_st(src, name=name, generate=False, portability=portability, target=target)
    return res, [(d.severity, d.pos.file, d.pos.line, d.pos.col, d.message, d.code) for d in res.diags.sorted()]


def errors(src: str, **kw):
    return [(ln, col, msg) for sev, _f, ln, col, msg, _c in diags(src, portability=False, **kw)[1] if sev == "error"]


def one_error(src: str) -> tuple[int, int, str]:
    errs = errors(src)
    assert len(errs) == 1, errs
    return errs[0]


def warnings(src: str, **kw):
    return [(ln, col, msg, code) for sev, _f, ln, col, msg, code in diags(src, **kw)[1] if sev == "warning"]


def prog(decls: str, body: str, name: str = "Main") -> str:
    """A PROGRAM with the given declarations (line 2 on) and body."""
    return f"PROGRAM {name}\n{decls}\n{body}\nEND_PROGRAM\n"


# =================================================================== semantic errors

def test_undeclared_variable():
    assert one_error(prog("VAR a : INT; END_VAR", "a := missing + 1;")) == (3, 6, "undeclared variable 'missing'")


def test_duplicate_variable_differing_only_in_case():
    ln, col, msg = one_error(prog("VAR speed : INT; Speed : INT; END_VAR", "speed := 1;"))
    assert (ln, col, msg) == (2, 18, "duplicate variable 'Speed'")


def test_duplicate_pou_name_differing_only_in_case():
    src = ("FUNCTION_BLOCK FB_Axis\nVAR x : INT; END_VAR\nx := 1;\nEND_FUNCTION_BLOCK\n"
           "FUNCTION_BLOCK fb_axis\nVAR y : INT; END_VAR\ny := 1;\nEND_FUNCTION_BLOCK\n")
    assert one_error(src) == (5, 1, "duplicate POU name 'fb_axis'")


def test_int_into_dint_needs_an_explicit_conversion():
    ln, col, msg = one_error(prog("VAR i : INT; d : DINT; END_VAR", "d := i;"))
    assert (ln, col) == (3, 6)
    assert "implicit conversion from INT to DINT" in msg
    res, _ = diags(prog("VAR i : INT; d : DINT; END_VAR", "d := i;"))
    assert "INT_TO_DINT" in res.diags.errors[0].hint
    assert errors(prog("VAR i : INT; d : DINT; END_VAR", "d := INT_TO_DINT(i);")) == []


def test_arithmetic_on_a_bit_string_is_rejected():
    assert one_error(prog("VAR w : WORD; END_VAR", "w := w + 1;")) == \
        (3, 8, "arithmetic '+' on WORD (a bit string) is not allowed")
    assert errors(prog("VAR w : WORD; END_VAR", "w := w AND 16#FF;")) == []


def test_real_literal_mixed_with_an_integer_variable():
    assert one_error(prog("VAR d : DINT; END_VAR", "d := d + 2.5;")) == \
        (3, 8, "'+' of a REAL literal and DINT: the literal is not a DINT")
    assert one_error(prog("VAR i : INT; END_VAR", "i := 2.5;"))[:2] == (3, 6)


def test_literal_out_of_range_for_int():
    assert one_error(prog("VAR i : INT; END_VAR", "i := 40000;")) == \
        (3, 6, "literal 40000 is out of range for INT (-32768..32767)")
    assert errors(prog("VAR i : INT; END_VAR", "i := 32767;")) == []


def test_assignment_to_an_input_inside_its_function_block():
    src = "FUNCTION_BLOCK FB_A\nVAR_INPUT go : BOOL; END_VAR\ngo := FALSE;\nEND_FUNCTION_BLOCK\n"
    assert one_error(src) == (3, 1, "cannot assign to input 'go' inside its own function block")


def test_assignment_to_a_constant():
    assert one_error(prog("VAR CONSTANT k : INT := 3; END_VAR", "k := 4;")) == (3, 1, "cannot assign to CONSTANT 'k'")


def test_assignment_to_an_fb_output_from_outside():
    src = ("FUNCTION_BLOCK FB_A\nVAR_OUTPUT done : BOOL; END_VAR\ndone := TRUE;\nEND_FUNCTION_BLOCK\n"
           + prog("VAR a : FB_A; END_VAR", "a.done := FALSE;", "P_Main"))
    assert one_error(src) == (7, 3, "cannot assign to output 'done' of an instance from outside")


EN_DECL = "'{}' cannot be declared: EN and ENO are the implicit enable input and output of every POU"


def test_a_variable_named_en_or_eno_cannot_be_declared():
    # the issue: VAR_INPUT en was accepted, then fb(en := x) bound the implicit EN and the body never ran.
    # MATIEC (iec2c) refuses these too; it takes only IEC's spelled-out EN : BOOL := 1 and ENO : BOOL, refused here
    src = ("FUNCTION_BLOCK FB_A\nVAR_INPUT en : BOOL; END_VAR\nVAR_OUTPUT done : BOOL; END_VAR\ndone := en;\n"
           "END_FUNCTION_BLOCK\n" + prog("VAR a : FB_A; x : BOOL; END_VAR", "a(en := x);", "P_Main"))
    assert one_error(src) == (2, 11, EN_DECL.format("en"))
    src = ("FUNCTION F_A : BOOL\nVAR_INPUT EN : BOOL := TRUE; END_VAR\nVAR_OUTPUT Eno : BOOL; END_VAR\n"
           "F_A := TRUE;\nEND_FUNCTION\n" + prog("VAR eNo : INT; END_VAR", "", "P_Main"))
    assert errors(src) == [(2, 11, EN_DECL.format("EN")), (3, 12, EN_DECL.format("Eno")),
                           (7, 5, EN_DECL.format("eNo"))]
    cfg = ("CONFIGURATION C\nVAR_GLOBAL En : BOOL; END_VAR\nRESOURCE R ON PLC\n"
           "TASK t(INTERVAL := T#10ms, PRIORITY := 0);\nPROGRAM i WITH t : P_Main;\nEND_RESOURCE\nEND_CONFIGURATION\n")
    assert errors(prog("VAR x : INT; END_VAR", "x := 1;", "P_Main") + cfg) == [(6, 12, EN_DECL.format("En"))]
    # the error stands alone: no portability warning about the same name on top
    assert [w for w in warnings(src) if "keyword" in w[2]] == []


def test_eno_of_an_instance_is_read_not_written_from_outside():
    fb = "FUNCTION_BLOCK FB_A\nVAR_OUTPUT done : BOOL; END_VAR\ndone := TRUE;\nEND_FUNCTION_BLOCK\n"
    assert errors(fb + prog("VAR a : FB_A; ok : BOOL; END_VAR", "a(EN := ok);\nok := a.ENO AND a.done;", "P_Main")) \
        == []
    # as MATIEC ("Assignment to FB output variable is not allowed")
    assert one_error(fb + prog("VAR a : FB_A; END_VAR", "a.eno := FALSE;", "P_Main")) == \
        (7, 3, "cannot assign to output 'eno' of an instance from outside")


def test_en_of_an_instance_is_neither_read_nor_written_from_outside():
    # MATIEC refuses both (a syntax error); and a call without EN := runs the body whatever EN holds
    fb = "FUNCTION_BLOCK FB_A\nVAR_OUTPUT done : BOOL; END_VAR\ndone := TRUE;\nEND_FUNCTION_BLOCK\n"
    msg = "EN of an instance cannot be read or written from outside ('{}')"
    assert errors(fb + prog("VAR a : FB_A; ok : BOOL; END_VAR", "ok := a.En;\na.EN := TRUE;", "P_Main")) == \
        [(7, 9, msg.format("En")), (8, 3, msg.format("EN"))]


def test_assignment_to_the_for_variable_inside_its_loop():
    src = prog("VAR i : INT; END_VAR", "FOR i := 1 TO 3 DO\n    i := 5;\nEND_FOR;")
    assert one_error(src) == (4, 5, "cannot assign to the FOR control variable 'i' inside its loop")


F_ADD = "FUNCTION F_Add : INT\nVAR_INPUT a : INT; b : INT; END_VAR\nF_Add := a + b;\nEND_FUNCTION\n"


def test_unknown_parameter_name():
    assert one_error(F_ADD + prog("VAR x : INT; END_VAR", "x := F_Add(a := 1, c := 2);")) == \
        (7, 20, "F_Add has no parameter 'c'")


def test_too_many_positional_arguments():
    assert one_error(F_ADD + prog("VAR x : INT; END_VAR", "x := F_Add(1, 2, 3);")) == \
        (7, 18, "too many arguments for F_Add (it has 2 inputs)")


def test_function_block_call_must_connect_its_var_in_out():
    src = ("FUNCTION_BLOCK FB_A\nVAR_IN_OUT v : INT; END_VAR\nv := v + 1;\nEND_FUNCTION_BLOCK\n"
           + prog("VAR a : FB_A; END_VAR", "a();"))
    assert one_error(src) == (7, 1, "call of a must connect VAR_IN_OUT 'v'")


def test_output_passed_like_an_input():
    src = ("FUNCTION_BLOCK FB_A\nVAR_OUTPUT q : BOOL; END_VAR\nq := TRUE;\nEND_FUNCTION_BLOCK\n"
           + prog("VAR a : FB_A; END_VAR", "a(q := TRUE);"))
    assert one_error(src) == (7, 3, "'q' is an output: write `q => variable`")


def test_constant_array_index_out_of_bounds():
    errs = errors(prog("VAR a : ARRAY[1..4] OF INT; END_VAR", "a[5] := 1;\na[0] := 2;\na[4] := 3;"))
    assert errs == [(3, 3, "index 5 is out of bounds 1..4"), (4, 3, "index 0 is out of bounds 1..4")]


def test_case_label_of_the_wrong_type():
    src = prog("VAR i : INT; END_VAR", "CASE i OF\n    1: i := 2;\n    2.5: i := 3;\nEND_CASE;")
    assert one_error(src) == (5, 5, "CASE label must be an integer constant")


def test_case_label_of_another_enumeration():
    src = ("TYPE E_A : (One, Two); E_B : (Red, Green); END_TYPE\n"
           + prog("VAR a : E_A; i : INT; END_VAR", "CASE a OF\n    E_B#Red: i := 1;\nEND_CASE;"))
    assert one_error(src) == (5, 5, "CASE label must be a value of E_A")


def test_located_variable_size_must_match_its_type():
    src = prog("VAR\n    x AT %IW0 : BOOL;\nEND_VAR", "")
    assert one_error(src) == (3, 10, "%IW0 is a 16-bit location but 'x' is BOOL")


def test_one_output_located_in_two_scopes_is_a_warning_one_scope_an_error():
    # as in MATIEC: one address, one variable within a scope; PROGRAMs and the globals may share an address
    # (test_conformance_matiec_corpus.py), and an output written from two scopes is worth a warning
    src = (prog("VAR\n    a AT %QW3 : INT;\nEND_VAR", "a := 1;", "P_One")
           + prog("VAR\n    b AT %QW3 : WORD;\n    c AT %QX0.1 : BOOL;\n    d AT %QX0.1 : BOOL;\nEND_VAR",
                  "b := 16#1;", "P_Two")
           + "CONFIGURATION Config0\nVAR_GLOBAL\n    g AT %QX0.1 : BOOL;\n    h AT %QX0.2 : BOOL;\nEND_VAR\n"
           "RESOURCE Res0 ON PLC\nTASK t(INTERVAL := T#4ms, PRIORITY := 0);\nPROGRAM p1 WITH t : P_One;\n"
           "PROGRAM p2 WITH t : P_Two;\nEND_RESOURCE\nEND_CONFIGURATION\n")
    assert errors(src) == [(11, 10, "%QX0.1 is already the location of 'c'")]
    shared = [(ln, col, msg.split(":")[0]) for ln, col, msg, code in warnings(src) if code == "located-shared-output"]
    assert shared == [(9, 10, "%QW3 is also the location of 'a' (PROGRAM P_One)"),
                      (17, 10, "%QX0.1 is also the location of 'c' (PROGRAM P_Two)")]


def test_located_variable_inside_a_function_block():
    src = "FUNCTION_BLOCK FB_A\nVAR\n    x AT %QX0.0 : BOOL;\nEND_VAR\nx := TRUE;\nEND_FUNCTION_BLOCK\n"
    ln, col, msg = one_error(src)
    assert (ln, col) == (3, 10)
    assert msg.startswith("located variables are not allowed inside a FUNCTION_BLOCK")


def test_array_of_function_block_instances():
    errs = errors(prog("VAR t : ARRAY[1..2] OF TON; x : INT; END_VAR", "x := 1;"))
    assert errs == [(2, 9, "arrays of function block instances are not supported")]


def test_function_block_instance_inside_a_struct():
    src = "TYPE ST_A : STRUCT t : TON; n : INT; END_STRUCT; END_TYPE\n"
    assert one_error(src) == (1, 20, "function block instances inside a STRUCT are not supported by MATIEC")


def test_every_error_of_a_file_is_reported_in_one_run():
    src = prog("VAR i : INT; d : DINT; w : WORD; END_VAR",
               "d := i;\nw := w + 1;\ni := 40000;\nq := 1;\nCASE i OF 1.5: i := 0; END_CASE;")
    errs = errors(src)
    assert [(ln, col) for ln, col, _m in errs] == [(3, 6), (4, 8), (5, 6), (6, 1), (7, 11)]
    assert len({m for _l, _c, m in errs}) == 5


def test_single_task_needs_a_bool_global():
    src = (prog("VAR x : INT; END_VAR", "x := 1;") +
           "CONFIGURATION Config0\nVAR_GLOBAL n : INT; END_VAR\nRESOURCE Res0 ON PLC\n"
           "TASK t0(INTERVAL := T#4ms, PRIORITY := 0);\nTASK ev(SINGLE := n, PRIORITY := 1);\n"
           "PROGRAM i0 WITH t0 : Main;\nEND_RESOURCE\nEND_CONFIGURATION\n")
    assert one_error(src) == (9, 19, "SINGLE needs a BOOL global variable")


def test_nesting_is_limited_instead_of_exhausting_the_stack():
    deep = "x := " + "(" * 500 + "1" + ")" * 500 + ";"
    errs = errors(prog("VAR x : INT; END_VAR", deep))
    assert errs and errs[0][2] == "expression nested too deeply"
    ok = "x := " + "(" * 50 + "1" + ")" * 50 + ";"
    assert errors(prog("VAR x : INT; END_VAR", ok)) == []



def chain(n: int, op: str, term: str) -> str:
    return f" {op} ".join([term] * n)


def test_a_long_operator_chain_is_an_error_before_any_pass_recurses(tmp_path, capsys):
    """Brackets count towards MAX_DEPTH, an operator chain does not: `a AND a AND ...` is as deep a tree as it
    is long, and every stage after the parser recurses over it.  Past parser.MAX_OPERATORS the parser reports
    the expression at its start (2,500 terms ended in a RecursionError in the passes)."""
    from plc.parser import MAX_OPERATORS
    decls = "VAR a : BOOL; q : BOOL; n : INT; END_VAR"
    too_deep = f"expression too deeply nested: {{}} operators (limit {MAX_OPERATORS})"
    assert errors(prog(decls, f"q := {chain(2500, 'AND', 'a')};")) == [(3, 6, too_deep.format(2499))]
    # the first error of the rest of the file is what the parser's recovery makes of it
    assert errors(prog(decls, f"IF n > {chain(MAX_OPERATORS + 1, '+', '1')} THEN n := 0; END_IF;"))[0] == \
        (3, 4, too_deep.format(MAX_OPERATORS + 1))
    # a statement's target: members count too (s.s.s... would be wrong later, but no later stage sees it)
    assert (3, 1, too_deep.format(1001)) in errors(prog(decls, f"s{'.s' * 1000}.n := 1;"))
    const = ("VAR CONSTANT k : INT := " + chain(3000, "+", "1") + "; END_VAR\n"
             "VAR x : INT; END_VAR")
    assert errors(prog(const, "x := k;"))[0] == (2, 25, f"expression too deeply nested: 2999 operators "
                                                          f"(limit {MAX_OPERATORS})")
    f = tmp_path / "chain.st"
    f.write_text(prog("VAR a : BOOL; q : BOOL; END_VAR", f"q := {chain(2500, 'AND', 'a')};"))
    rc, text = run_plc("check", str(f), capsys=capsys)
    assert rc == 1 and "Traceback" not in text
    assert f"chain.st:3:6: error: expression too deeply nested: 2499 operators (limit {MAX_OPERATORS})" in text


def test_an_operator_chain_at_the_limit_compiles_to_c_and_scans(tmp_path, capsys):
    """MAX_OPERATORS operators in one expression go through every stage (passes, constant folding, the portability
    pass, the C generator); chains of 200 terms give their values in a scan."""
    from harness import run_st, with_config
    from plc.parser import MAX_OPERATORS
    deepest = "(" * 100 + chain(MAX_OPERATORS, "+", "1") + ")" * 100     # MAX_OPERATORS with the '-'

    limit = prog("VAR CONSTANT k : DINT := " + chain(MAX_OPERATORS + 1, "+", "1") + "; END_VAR\n"
                 "VAR n : DINT; END_VAR", f"n := k - {deepest};")
    res = compile_st(with_config(limit)[0], target="openplc")
    assert res.ok and res.c_text, render_errors(res)
    src = prog("VAR a : BOOL := TRUE; b : BOOL; q_and : BOOL; q_low : BOOL; q_or : BOOL; n : INT; END_VAR",
               f"q_and := {chain(200, 'AND', 'a')};\n"
               f"q_low := {chain(199, 'AND', 'a')} AND b;\n"
               f"q_or := {chain(199, 'OR', 'b')} OR a;\n"
               f"n := {chain(200, '+', '1')} - {chain(50, '*', '1')};", name="P_Chain")
    run = run_st(src)
    assert [run.value(f"P_Chain.{v}") for v in ("q_and", "q_low", "q_or", "n")] == [1, 0, 1, 199]
    f = tmp_path / "limit.st"
    f.write_text(limit)
    assert run_plc("check", "--target", "openplc", str(f), capsys=capsys)[0] == 0


def render_errors(res) -> str:
    return "\n".join(str(d) for d in res.diags.errors)

def test_huge_literals_are_diagnosed():
    errs = errors(prog("VAR x : LINT; r : LREAL; t : TIME; END_VAR",
                       "x := " + "9" * 100 + ";\nr := 1.0E999;\nt := T#" + "9" * 30 + "d;"))
    assert [e[:2] for e in errs] == [(3, 6), (4, 6), (5, 6)]
    assert errs[0][2] == "integer literal of 100 digits is too long"
    assert errs[1][2] == "real literal is too large"


# ====================================================================== syntax errors

def test_missing_end_if_names_the_opening_if():
    src = prog("VAR x : INT; END_VAR", "IF x > 0 THEN\n    x := 1;")
    assert errors(src) == [(5, 1, "expected END_IF to close IF opened at 3:1, found 'END_PROGRAM'")]


def test_wrong_end_keyword_names_the_opening_loop():
    src = prog("VAR x : INT; END_VAR", "FOR x := 1 TO 3 DO\n    x := 1;\nEND_WHILE;")
    assert errors(src) == [(5, 1, "expected END_FOR to close FOR opened at 3:1, found 'END_WHILE'")]


def test_missing_semicolon():
    assert errors(prog("VAR x : INT; END_VAR", "x := 1\nx := 2;")) == [
        (4, 1, "expected ';' after the assignment, found 'x'")]


def test_end_of_file_inside_a_loop():
    src = "PROGRAM Main\nVAR x : INT; END_VAR\nWHILE x < 3 DO\n    x := x + 1;\n"
    errs = errors(src)
    assert errs[0] == (5, 1, "expected END_WHILE to close WHILE opened at 3:1, found end of file")


def test_unterminated_comment_and_string():
    res, ds = diags(prog("VAR x : INT; END_VAR", "(* never closed\nx := 1;"), portability=False)
    assert ds[0][2:5] == (3, 1, "unterminated comment")
    assert res.diags.errors[0].hint == "a '(*' comment needs a closing '*)'"
    errs = errors(prog("VAR s : STRING; END_VAR", "s := 'abc;"))
    assert errs[0] == (3, 6, "unterminated string literal")


def test_missing_end_var():
    errs = errors("PROGRAM Main\nVAR x : INT;\nx := 1;\nEND_PROGRAM\n")
    assert (4, 1, "expected END_VAR to close VAR opened at 2:1") in errs


def test_on_as_an_enumeration_value_is_an_error():
    # ON is reserved in MATIEC, and a keyword of ours too (RESOURCE r ON PLC): never a value
    assert errors("TYPE E_Power : (Off, On); END_TYPE\n")[0] == \
        (1, 22, "'On' is a keyword and cannot be used as an enumeration value")


def test_a_syntax_error_is_reported_once_and_the_other_pous_are_still_checked():
    # issue 27: after one syntax error a cascade error, and the semantic errors elsewhere were the question
    src = ("FUNCTION_BLOCK FB_A\nVAR x : INT END_VAR\nx := 1;\nEND_FUNCTION_BLOCK\n\n"
           "FUNCTION_BLOCK FB_B\nVAR y : INT; END_VAR\ny := undefined_thing;\nEND_FUNCTION_BLOCK\n\n"
           "PROGRAM Main\nVAR z : INT; END_VAR\nz := (1 + 2;\nz := nosuch;\nEND_PROGRAM\n")
    assert errors(src) == [(2, 13, "expected ';' after the declaration, found 'END_VAR'"),
                           (8, 6, "undeclared variable 'undefined_thing'"),
                           (13, 12, "expected ')' to close the parenthesis, found ';'"),
                           (14, 6, "undeclared variable 'nosuch'")]


# ================================================================ portability warnings

def pw(src: str, **kw):
    """Portability warnings (code, line, col) of `src`, which must have no error."""
    res, ds = diags(src, **kw)
    assert not res.diags.errors, [d.message for d in res.diags.errors]
    quiet = diags(src, portability=False, **kw)[1]
    assert not any(c and c.startswith("portability") for *_x, c in quiet), "--no-portability must silence them"
    return [(code, ln, col) for sev, _f, ln, col, msg, code in ds if code and code.startswith("portability")]


OK_DECLS = "VAR x : INT; w : WORD; b : BOOL; t : TIME; d : DINT; END_VAR"


def test_clean_program_has_no_warning():
    assert pw(prog(OK_DECLS, "x := 1;")) == []


def test_pou_named_like_an_openplc_library_identifier():
    assert pw("FUNCTION_BLOCK Busy\nVAR x : INT; END_VAR\nx := 1;\nEND_FUNCTION_BLOCK\n") == \
        [("portability.library-name", 1, 1)]


def test_type_named_like_an_openplc_library_identifier():
    assert pw("TYPE State : (Idle, Running); END_TYPE\n") == [("portability.library-name", 1, 6)]


def test_line_comment():
    assert pw(prog(OK_DECLS, "x := 1; // set x")) == [("portability.comment-line", 3, 9)]


def test_block_comment():
    assert pw(prog(OK_DECLS, "/* set x */ x := 1;")) == [("portability.comment-block", 3, 1)]


def test_enum_with_explicit_values():
    assert pw("TYPE E_A : (One := 1, Two := 5); END_TYPE\n") == \
        [("portability.enum-value", 1, 13), ("portability.enum-value", 1, 23)]


def test_enum_value_named_like_a_standard_function_or_type():
    assert pw("TYPE E_A : (Low, Mid, High, Ton); END_TYPE\n") == \
        [("portability.enum-value-name", 1, 18), ("portability.enum-value-name", 1, 29)]


def test_string_with_a_length():
    assert pw(prog("VAR s : STRING[20]; END_VAR", "s := 'a';")) == [("portability.string-length", 2, 9)]


def test_wstring():
    res, ds = diags(prog("VAR s : STRING; END_VAR", 's := "a";'))
    assert ("warning", 3, 6, "portability.wstring") in [(sev, ln, col, code) for sev, _f, ln, col, _m, code in ds]
    assert one_error(prog("VAR s : WSTRING; END_VAR", "s := 'a';")) == (2, 9, "WSTRING is not supported by OpenPLC")


def test_power_operator():
    assert pw(prog("VAR r : REAL; END_VAR", "r := 2.0 ** 3.0;")) == [("portability.power", 3, 10)]


def test_bit_access():
    assert pw(prog(OK_DECLS, "b := w.3;")) == [("portability.bit-access", 3, 8)]


def test_zero_argument_function_call():
    src = "FUNCTION F_One : INT\nVAR k : INT; END_VAR\nF_One := 1;\nEND_FUNCTION\n" + prog(OK_DECLS, "x := F_One();")
    assert pw(src) == [("portability.empty-call", 7, 6)]


def test_time_to_dint_and_dint_to_time_count_seconds():
    assert pw(prog(OK_DECLS, "d := TIME_TO_DINT(t);\nt := DINT_TO_TIME(d);")) == \
        [("portability.time-conversion", 3, 6), ("portability.time-conversion", 4, 6)]


CELL = ("CONFIGURATION Cell\nRESOURCE Cpu ON PLC\nTASK t0(INTERVAL := T#4ms, PRIORITY := 0);\n"
        "PROGRAM i0 WITH t0 : Main;\nEND_RESOURCE\nEND_CONFIGURATION\n")


def test_configuration_and_resource_names_for_openplc():
    src = prog(OK_DECLS, "x := 1;") + CELL
    assert pw(src, target="openplc") == \
        [("portability.openplc-configuration", 5, 1), ("portability.openplc-resource", 6, 1)]
    assert pw(src) == []                                    # only with --target openplc
    assert pw(src.replace("Cell", "Config0").replace("Cpu", "Res0"), target="openplc") == []


def test_configuration_names_are_checked_after_a_type_declaration_too():
    # regression: a TYPE before the CONFIGURATION used to switch the openplc check off
    src = "TYPE\n    Count : INT;\nEND_TYPE\n" + prog(OK_DECLS, "x := 1;") + CELL
    assert [c for c, _l, _col in pw(src, target="openplc")] == \
        ["portability.openplc-configuration", "portability.openplc-resource"]


def test_var_block_mixing_located_and_unlocated_variables():
    assert pw(prog("VAR\n    out AT %QW0 : INT;\n    x : INT;\nEND_VAR", "x := 1;")) == \
        [("portability.mixed-located", 2, 1)]


def test_function_call_as_a_statement():
    src = "FUNCTION F_One : INT\nVAR_INPUT k : INT; END_VAR\nF_One := k;\nEND_FUNCTION\n" + prog(OK_DECLS, "F_One(1);")
    assert pw(src) == [("portability.call-statement", 7, 1)]


def test_variable_named_like_a_type():
    src = "TYPE E_Mode : (Idle, Moving); END_TYPE\n" + \
        prog("VAR e_mode : INT; tOn : TON; timer1 : TON; END_VAR", "e_mode := 1;")
    assert pw(src) == [("portability.var-type-name", 3, 5), ("portability.var-own-type-name", 3, 19)]


def test_variable_named_like_a_keyword():
    assert pw(prog("VAR en2 : INT; r_edge : INT; END_VAR", "en2 := 1;")) == [("portability.var-keyword", 2, 16)]


def test_variable_named_like_a_standard_function():
    assert pw(prog("VAR limit : INT; max : INT; END_VAR", "limit := 1;")) == \
        [("portability.var-std-name", 2, 5), ("portability.var-std-name", 2, 18)]


def test_identifier_with_double_or_trailing_underscore():
    assert pw(prog("VAR a__b : INT; ab_ : INT; END_VAR", "a__b := 1;")) == \
        [("portability.identifier-double-underscore", 2, 5), ("portability.identifier-trailing-underscore", 2, 17)]


def test_empty_statement_lists_and_stray_semicolons():
    assert pw(prog(OK_DECLS, "IF x > 0 THEN END_IF;\nx := 1;;")) == \
        [("portability.empty-body", 3, 1), ("portability.empty-statement", 4, 8)]


def test_function_without_any_variable():
    src = "FUNCTION F_Seven : INT\nF_Seven := 7;\nEND_FUNCTION\n"
    assert pw(src) == [("portability.function-without-vars", 1, 1)]


def test_type_renaming_an_enumeration():
    assert pw("TYPE E_A : (One, Two); T_B : E_A; END_TYPE\n") == [("portability.type-alias", 1, 24)]


def test_a_struct_member_of_a_type_declared_later_in_the_file():
    # iec2c (OpenPLC's MATIEC) reads a file in order: "invalid specification in structure element declaration"
    src = ("TYPE\n ST_Outer : STRUCT\n  inner : ST_Inner;\n  more : ARRAY[1..2] OF ST_Inner;\n END_STRUCT;\n"
           " ST_Inner : STRUCT\n  a : INT;\n END_STRUCT;\n"
           " ST_After : STRUCT\n  b : ST_Inner;\n END_STRUCT;\nEND_TYPE\n")
    assert pw(src) == [("portability.type-order", 3, 3), ("portability.type-order", 4, 3)]


def test_a_types_initial_value_that_two_enumerations_declare():
    # iec2c: "Ambiguous enumerate value"; qualified (E_St#IDLE) or unique it is fine
    src = "TYPE E_St : (IDLE, RUN) := IDLE; E_Mode : (IDLE, AUTO); E_Ok : (STOPPED) := STOPPED; END_TYPE\n"
    assert pw(src) == [("portability.enum-qualify", 1, 28)]
    assert pw("TYPE E_St : (IDLE, RUN) := E_St#IDLE; E_Mode : (IDLE, AUTO); END_TYPE\n") == []


def test_sel_and_mux_of_enumeration_values():
    # iec2c: "Unable to resolve which overloaded function 'SEL' is being invoked"; SEL of numbers is fine
    src = ("TYPE E_A : (One, Two); END_TYPE\n" + prog("VAR a, b : E_A; g : BOOL; k : INT; n : INT; END_VAR",
           "a := SEL(g, a, b);\nb := MUX(k, a, b);\nn := SEL(g, 1, 2);"))
    found = pw(src)
    assert [c for c, *_ in found] == ["portability.enum-select", "portability.enum-select"], found


def test_inline_subrange_starts_at_0_in_matiec():
    assert pw(prog("VAR p : INT (3..10); q : INT (0..10); END_VAR", "p := 4;")) == \
        [("portability.subrange-default", 2, 5)]


# ========================================================================= commands

def write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


GOOD = prog("VAR x : INT; END_VAR", "x := x + 1;") + \
    ("CONFIGURATION Config0\nRESOURCE Res0 ON PLC\nTASK t0(INTERVAL := T#4ms, PRIORITY := 0);\n"
     "PROGRAM i0 WITH t0 : Main;\nEND_RESOURCE\nEND_CONFIGURATION\n")
WARN = prog("VAR x : INT; END_VAR", "x := 1; // comment")
BAD = prog("VAR x : INT; END_VAR", "x := y;")


def run_plc(*args, capsys) -> tuple[int, str]:
    try:
        rc = plc_main(list(args))
    except SystemExit as e:           # argparse usage errors
        rc = e.code
    out = capsys.readouterr()
    return rc, out.out + out.err


def test_check_exit_codes_and_rendering(tmp_path, capsys):
    good, warn, bad = write(tmp_path, "good.st", GOOD), write(tmp_path, "warn.st", WARN), write(tmp_path, "bad.st", BAD)
    assert run_plc("check", str(good), capsys=capsys)[0] == 0
    rc, text = run_plc("check", str(warn), capsys=capsys)
    assert rc == 0 and "warning: portability: '//' comments" in text
    rc, text = run_plc("check", "--no-portability", str(warn), capsys=capsys)
    assert rc == 0 and "warning" not in text.split("checked")[0]
    rc, text = run_plc("check", str(bad), capsys=capsys)
    assert rc == 1
    lines = text.splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.endswith("3:6: error: undeclared variable 'y'"))
    assert lines[k + 1] == "    x := y;"
    assert lines[k + 2] == "         ^"
    assert "Traceback" not in text


def test_usage_errors_exit_2(tmp_path, capsys):
    assert run_plc("check", str(tmp_path / "missing.st"), capsys=capsys)[0] == 2
    assert run_plc("check", capsys=capsys)[0] == 2
    assert run_plc("build", str(write(tmp_path, "g.st", GOOD)), capsys=capsys)[0] == 2      # --out missing
    assert run_plc("frobnicate", capsys=capsys)[0] == 2


def test_build_writes_c_and_object(tmp_path, capsys):
    src = write(tmp_path, "good.st", GOOD)
    out = tmp_path / "out"
    rc, text = run_plc("build", str(src), "--out", str(out), capsys=capsys)
    assert rc == 0, text
    assert (out / "program.c").read_text().count("plc_program") >= 1
    assert (out / "program.o").stat().st_size > 0
    rc, text = run_plc("build", str(write(tmp_path, "bad.st", BAD)), "--out", str(tmp_path / "o2"), capsys=capsys)
    assert rc == 1 and not (tmp_path / "o2" / "program.c").exists()


def test_installed_command_help_and_no_traceback_on_garbage(tmp_path):
    garbage = write(tmp_path, "garbage.st", "\x00\xff PROGRAM (* END_IF ;;; := := 16#ZZ 'unterminated")
    for args in (["check", "--help"], ["build", "--help"], ["check", str(garbage)]):
        proc = subprocess.run([str(PLC), *args], capture_output=True, text=True, timeout=60)
        assert "Traceback" not in proc.stderr
        assert proc.returncode == (0 if "--help" in args else 1), proc.stderr
