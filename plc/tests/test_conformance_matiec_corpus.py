"""Conformance with OpenPLC's MATIEC on programs from a corpus it accepts or rejects (docs/matiec.md):
CONTINUE runs as MATIEC runs it; PROGRAMs may each locate a variable at the same input; a direct address in a
body is an error (MATIEC rejects it; compiling it to a constant would be a wrong program); a STRUCT member named
like its type gets a portability warning (OpenPLC's g++ fails on MATIEC's C); an unqualified enumeration value
shared by two enumerations, used as a default, gets a portability warning (MATIEC: ambiguous).
"""
from __future__ import annotations

import pytest

from harness import compile_st, run_st

import rt_harness as h

CONFIG = """
CONFIGURATION Config0
    RESOURCE Res0 ON PLC
        TASK MainTask(INTERVAL := T#4ms, PRIORITY := 0);
        PROGRAM first WITH MainTask : P_First;
        PROGRAM second WITH MainTask : P_Second;
    END_RESOURCE
END_CONFIGURATION
"""


def check(text: str):
    return compile_st(text, name="t.st", generate=False).diags


def messages(diags, severity: str) -> list[tuple[int, int, str]]:
    return [(d.pos.line, d.pos.col, d.message) for d in diags.sorted() if d.severity == severity]


# ------------------------------------------------------------------------- CONTINUE --
CONTINUE_SRC = r"""
PROGRAM P_Continue
VAR
    i, j, w, r : INT;
    forSum, forEnd, whileSum, repeatSum, nestedOuter, nestedInner : INT;
END_VAR
forSum := 0;
FOR i := 1 TO 6 DO
    IF i MOD 2 = 0 THEN CONTINUE; END_IF;
    forSum := forSum + i;                      (* 1 + 3 + 5 *)
END_FOR;
forEnd := i;                                   (* the loop still counts on: 7 *)
w := 0;
whileSum := 0;
WHILE w < 6 DO
    w := w + 1;
    IF w = 3 THEN CONTINUE; END_IF;
    whileSum := whileSum + w;                  (* 1 + 2 + 4 + 5 + 6 *)
END_WHILE;
r := 0;
repeatSum := 0;
REPEAT
    r := r + 1;
    IF r = 2 THEN CONTINUE; END_IF;            (* goes on with the UNTIL test *)
    repeatSum := repeatSum + r;                (* 1 + 3 + 4 *)
UNTIL r >= 4 END_REPEAT;
nestedOuter := 0;
nestedInner := 0;
FOR i := 1 TO 3 DO
    FOR j := 1 TO 4 DO
        IF j > 1 THEN CONTINUE; END_IF;        (* the innermost loop only *)
        nestedInner := nestedInner + 1;
    END_FOR;
    nestedOuter := nestedOuter + 1;
END_FOR;
END_PROGRAM
"""


def test_continue_goes_on_with_the_next_pass_of_the_innermost_loop():
    run = run_st(CONTINUE_SRC, scans=1)
    assert run.value("P_Continue.forSum") == 9
    assert run.value("P_Continue.forEnd") == 7
    assert run.value("P_Continue.whileSum") == 18
    assert run.value("P_Continue.repeatSum") == 8
    assert (run.value("P_Continue.nestedOuter"), run.value("P_Continue.nestedInner")) == (3, 3)


def test_continue_outside_a_loop_is_an_error():
    diags = check("PROGRAM P\nVAR x : INT; END_VAR\nx := 1;\nCONTINUE;\nEND_PROGRAM\n")
    assert messages(diags, "error") == [(4, 1, "CONTINUE outside a loop")]


# ---------------------------------------------------- one input, several PROGRAMs --
SHARED_SRC = """
PROGRAM P_First
VAR
    start AT %IX50.0 : BOOL;
END_VAR
VAR
    seen AT %QX0.1 : BOOL;
END_VAR
seen := start;
END_PROGRAM

PROGRAM P_Second
VAR
    start AT %IX50.0 : BOOL;
END_VAR
VAR
    seen AT %QX0.2 : BOOL;
END_VAR
seen := start;
END_PROGRAM
""" + CONFIG


def test_programs_may_each_locate_a_variable_at_the_same_input():
    diags = check(SHARED_SRC)
    assert messages(diags, "error") == [] and messages(diags, "warning") == []


def test_the_same_input_in_two_programs_reads_the_same_value_on_the_runtime(tmp_path):
    binary = h.st_runtime_binary(tmp_path / "st", {"shared.st": SHARED_SRC})
    with h.Runtime(binary, "--no-rt") as rt, h.Client(rt.port) as c:
        c.write_coil(400, True)                                  # %QX50.0 -> %IX50.0 (sim loop-back)
        h.wait_until(lambda: c.read_coils(1, 2) == [True, True], 5, "both programs to see %IX50.0 = TRUE")
        c.write_coil(400, False)
        h.wait_until(lambda: c.read_coils(1, 2) == [False, False], 5, "both programs to see it FALSE again")


def test_two_variables_at_one_address_in_one_program_stay_an_error():
    diags = check("PROGRAM P\nVAR\n    a AT %IX0.0 : BOOL;\n    b AT %IX0.0 : BOOL;\nEND_VAR\n"
                  "VAR\n    q : BOOL;\nEND_VAR\nq := a AND b;\nEND_PROGRAM\n")
    assert messages(diags, "error") == [(4, 10, "%IX0.0 is already the location of 'a'")]


def test_one_output_written_by_two_programs_is_a_warning_naming_both():
    src = SHARED_SRC.replace("seen AT %QX0.2", "seen AT %QX0.1")
    diags = check(src)
    assert messages(diags, "error") == []
    (warning,) = messages(diags, "warning")
    assert warning[2].startswith("%QX0.1 is also the location of 'seen' (PROGRAM P_First): both write this output")


# ------------------------------------------------------------- direct addresses --
@pytest.mark.parametrize("stmt, col", [("a := %IX0.0;", 6), ("w := %IW3;", 6),
                                       ("IF %IX0.1 THEN a := TRUE; END_IF;", 4)])
def test_a_direct_address_in_a_body_is_an_error_not_a_constant(stmt, col):
    diags = check(f"PROGRAM P\nVAR a : BOOL; w : WORD; END_VAR\n{stmt}\nEND_PROGRAM\n")
    errs = messages(diags, "error")
    assert len(errs) == 1 and errs[0][:2] == (3, col), errs
    assert "a direct address in code" in errs[0][2] and "not supported" in errs[0][2]


# ---------------------------------------------------- names MATIEC's C trips over --
def test_a_struct_member_named_like_its_type_gets_a_portability_warning():
    diags = check("TYPE St : STRUCT a : INT; END_STRUCT; END_TYPE\n"
                  "TYPE Outer : STRUCT st : St; other : St; END_STRUCT; END_TYPE\n")
    assert messages(diags, "error") == []
    (warning,) = messages(diags, "warning")
    assert warning[:2] == (2, 21) and "member 'st' is named like its type" in warning[2]


def test_a_shared_enum_value_as_a_default_gets_a_portability_warning():
    diags = check("TYPE E_A : (Red, Green); E_B : (Green, Blue); END_TYPE\n"
                  "FUNCTION_BLOCK FB_X\nVAR_INPUT c : E_A := Green; END_VAR\nVAR n : INT; END_VAR\nn := 1;\n"
                  "END_FUNCTION_BLOCK\n")
    assert messages(diags, "error") == []
    (warning,) = messages(diags, "warning")
    assert warning[:2] == (3, 22) and "'Green' is a value of several enumerations" in warning[2]
