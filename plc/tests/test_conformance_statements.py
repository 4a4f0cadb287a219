"""Conformance: statements (IF/ELSIF, CASE, FOR, WHILE, REPEAT, EXIT, RETURN) compiled and run.

Every expected value is OpenPLC's MATIEC behaviour as measured scan by scan
(docs/matiec.md).  All programs share one build.
"""
from __future__ import annotations

import pytest

from harness import run_st

SRC = r"""
PROGRAM P_If
VAR
    x : INT;
    a, b, c, d : INT;
END_VAR
x := x + 1;                       (* 1, 2, 3, 4 on scans 1..4 *)
IF x = 1 THEN
    a := 10;
ELSIF x = 2 THEN
    a := 20;
ELSIF x = 3 THEN
    a := 30;
ELSE
    a := 99;
END_IF;
IF x > 100 THEN b := 1; END_IF;                 (* never *)
IF x >= 2 THEN c := c + 1; ELSE c := c - 1; END_IF;
IF x = 1 THEN d := 1; ELSIF x = 1 THEN d := 2; END_IF;   (* first true branch only *)
END_PROGRAM

PROGRAM P_Case
VAR
    choice : INT;
    r0, r1, r2, r5, r9, rneg, r100 : INT;
    hits : INT;
END_VAR
VAR_TEMP
    k : INT;
END_VAR
FOR k := -1 TO 100 DO
    choice := k;
    CASE choice OF
        0: hits := 1;
        1, 2: hits := 12;
        3..5, 7: hits := 357;
        8..9: hits := 89;
        -1: hits := -1;
    ELSE
        hits := 0;
    END_CASE;
    CASE k OF
        -1: rneg := hits;
        0: r0 := hits;
        1: r1 := hits;
        2: r2 := hits;
        5: r5 := hits;
        9: r9 := hits;
        100: r100 := hits;
    END_CASE;
END_FOR;
END_PROGRAM

PROGRAM P_CaseNoElse
VAR
    v : INT := 6;
    touched : BOOL;
    before : INT := 42;
END_VAR
CASE v OF
    1..5: touched := TRUE; before := 0;
    7: touched := TRUE; before := 0;
END_CASE;
END_PROGRAM

PROGRAM P_For
VAR
    i : INT;
    once, onceEnd, upEnd, sumDown, downEnd, zeroRuns, zeroEnd : INT;
    byThree, byThreeEnd : INT;
    reevalRuns, reevalEnd, hi : INT;
    stepVar, stepRuns : INT;
END_VAR
once := 0;
FOR i := 5 TO 5 DO once := once + 1; END_FOR;
onceEnd := i;
FOR i := 1 TO 3 DO upEnd := upEnd; END_FOR;
upEnd := i;
sumDown := 0;
FOR i := 10 TO 1 BY -2 DO sumDown := sumDown + i; END_FOR;
downEnd := i;
zeroRuns := 0;
FOR i := 3 TO 1 DO zeroRuns := zeroRuns + 1; END_FOR;
zeroEnd := i;
byThree := 0;
FOR i := 1 TO 10 BY 3 DO byThree := byThree + i; END_FOR;       (* 1 + 4 + 7 + 10 *)
byThreeEnd := i;
hi := 3;
reevalRuns := 0;
FOR i := 1 TO hi DO hi := 10; reevalRuns := reevalRuns + 1; END_FOR;   (* end re-read every iteration *)
reevalEnd := i;
stepVar := 1;
stepRuns := 0;
FOR i := 1 TO 20 BY stepVar DO stepVar := stepVar * 2; stepRuns := stepRuns + 1; END_FOR;  (* 1, 3, 7, 15 *)
END_PROGRAM

PROGRAM P_Loops
VAR
    n, w, r, rOnce : INT;
    outer, inner, innerBody, i, j : INT;
    whileExit : INT;
    repeatExit : INT;
END_VAR
n := 0;
w := 0;
WHILE w < 5 DO w := w + 1; n := n + 2; END_WHILE;
WHILE FALSE DO n := 1000; END_WHILE;
r := 0;
REPEAT r := r + 3; UNTIL r >= 10 END_REPEAT;
rOnce := 0;
REPEAT rOnce := rOnce + 1; UNTIL TRUE END_REPEAT;
outer := 0;
innerBody := 0;
FOR i := 1 TO 3 DO
    outer := outer + 1;
    FOR j := 1 TO 5 DO
        innerBody := innerBody + 1;
        IF j = 2 THEN EXIT; END_IF;
    END_FOR;
END_FOR;
inner := j;
whileExit := 0;
WHILE TRUE DO
    whileExit := whileExit + 1;
    IF whileExit = 7 THEN EXIT; END_IF;
END_WHILE;
repeatExit := 0;
REPEAT
    repeatExit := repeatExit + 1;
    IF repeatExit = 4 THEN EXIT; END_IF;
UNTIL FALSE END_REPEAT;
END_PROGRAM

FUNCTION F_Ret : INT
VAR_INPUT
    flag : BOOL;
END_VAR
F_Ret := 1;
IF flag THEN RETURN; END_IF;
F_Ret := 2;
END_FUNCTION

FUNCTION_BLOCK FB_Ret
VAR_INPUT
    stop : BOOL;
END_VAR
VAR_OUTPUT
    first, second : INT;
END_VAR
first := first + 1;
IF stop THEN RETURN; END_IF;
second := second + 1;
END_FUNCTION_BLOCK

PROGRAM P_Return
VAR
    early, late : INT;
    fb : FB_Ret;
    fbFirst, fbSecond : INT;
    z, after : INT;
END_VAR
early := F_Ret(flag := TRUE);
late := F_Ret(flag := FALSE);
fb(stop := TRUE);
fb(stop := FALSE);
fb(stop := TRUE, first => fbFirst, second => fbSecond);
z := z + 1;
IF z > 0 THEN RETURN; END_IF;
after := 1;
END_PROGRAM
"""


@pytest.fixture(scope="module")
def run():
    return run_st(SRC, scans=4)


def test_if_elsif_else_takes_the_first_true_branch(run):
    assert run.series("P_If.a") == [10, 20, 30, 99]
    assert run.value("P_If.b") == 0
    assert run.series("P_If.c") == [-1, 0, 1, 2]
    assert run.value("P_If.d") == 1


def test_case_with_lists_ranges_negative_labels_and_else(run):
    v = {n: run.value(f"P_Case.{n}") for n in ("rneg", "r0", "r1", "r2", "r5", "r9", "r100")}
    assert v == {"rneg": -1, "r0": 1, "r1": 12, "r2": 12, "r5": 357, "r9": 89, "r100": 0}


def test_case_without_match_and_without_else_does_nothing(run):
    assert run.value("P_CaseNoElse.touched") is False
    assert run.value("P_CaseNoElse.before") == 42


def test_for_5_to_5_runs_once_and_leaves_6(run):
    assert run.value("P_For.once") == 1
    assert run.value("P_For.onceEnd") == 6


def test_for_1_to_3_leaves_4(run):
    assert run.value("P_For.upEnd") == 4


def test_for_10_to_1_by_minus_2_sums_30_and_leaves_0(run):
    assert run.value("P_For.sumDown") == 30
    assert run.value("P_For.downEnd") == 0


def test_for_3_to_1_runs_zero_times_and_leaves_the_start_value(run):
    assert run.value("P_For.zeroRuns") == 0
    assert run.value("P_For.zeroEnd") == 3


def test_for_by_3_stops_at_the_last_value_not_past_the_end(run):
    assert run.value("P_For.byThree") == 1 + 4 + 7 + 10
    assert run.value("P_For.byThreeEnd") == 13


def test_for_end_and_step_are_re_evaluated_every_iteration(run):
    assert run.value("P_For.reevalRuns") == 10
    assert run.value("P_For.reevalEnd") == 11
    assert run.value("P_For.stepRuns") == 4            # i = 1, 3, 7, 15, then 31 > 20


def test_while_and_repeat(run):
    assert run.value("P_Loops.n") == 10
    assert run.value("P_Loops.w") == 5
    assert run.value("P_Loops.r") == 12
    assert run.value("P_Loops.rOnce") == 1               # REPEAT body runs at least once


def test_exit_leaves_only_the_innermost_loop(run):
    assert run.value("P_Loops.outer") == 3
    assert run.value("P_Loops.innerBody") == 6
    assert run.value("P_Loops.inner") == 2
    assert run.value("P_Loops.whileExit") == 7
    assert run.value("P_Loops.repeatExit") == 4


def test_return_in_function_keeps_the_result_set_so_far(run):
    assert run.value("P_Return.early") == 1
    assert run.value("P_Return.late") == 2


def test_return_in_function_block_skips_the_rest_and_keeps_outputs(run):
    # three calls per scan, two of them with stop = TRUE
    assert run.series("P_Return.fbFirst") == [3, 6, 9, 12]
    assert run.series("P_Return.fbSecond") == [1, 2, 3, 4]


def test_return_in_program_skips_the_rest_of_the_scan(run):
    assert run.series("P_Return.z") == [1, 2, 3, 4]
    assert run.value("P_Return.after") == 0
