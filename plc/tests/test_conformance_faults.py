"""Conformance: where MATIEC is undefined, ours stops the program with a fault record.

Integer division by zero (MATIEC: SIGFPE kills the runtime) and an array index
out of bounds (MATIEC: silent memory corruption) stop the program: run()
returns the fault kind from then on, the variables stay as they were, and the
record names the kind, the POU and the source line.  MOD 0 is not a fault (0).
Each case is its own build, since a fault stops the whole program.
"""
from __future__ import annotations

import pytest

from harness import run_st

DIV_ZERO, INDEX = 1, 2          # plc_fault_kind_t


def line_of(src: str, needle: str) -> int:
    """1-based line of the first line containing `needle` (the snippet starts the file)."""
    for n, text in enumerate(src.splitlines(), 1):
        if needle in text:
            return n
    raise AssertionError(f"{needle!r} not in the snippet")


DIV_INT = """
PROGRAM P_Div
VAR
    scan : INT;
    divisor : INT := 2;
    q : INT;
    after : INT;
END_VAR
scan := scan + 1;
IF scan = 3 THEN divisor := 0; END_IF;
q := 10 / divisor;          (* faults on scan 3 *)
after := after + 1;
END_PROGRAM
"""


def test_integer_division_by_zero_stops_the_program_with_a_fault_record():
    run = run_st(DIV_INT, scans=6)
    assert run.rcs == [0, 0, DIV_ZERO, DIV_ZERO, DIV_ZERO, DIV_ZERO]
    f = run.faults[2]
    assert (f.kind, f.pou, f.line) == (DIV_ZERO, "P_Div", line_of(DIV_INT, "q := 10 / divisor"))
    # the scan stopped at the division; later scans do not run at all
    assert run.series("after") == [1, 2, 2, 2, 2, 2]
    assert run.series("scan") == [1, 2, 3, 3, 3, 3]
    assert run.series("q") == [5, 5, 5, 5, 5, 5]


DIV_IN_FUNCTION = """
FUNCTION F_Ratio : DINT
VAR_INPUT
    a : DINT;
    b : DINT;
END_VAR
F_Ratio := a / b;
END_FUNCTION

PROGRAM P_Caller
VAR
    zero : DINT;
    r : DINT;
    m : DINT;
    u : UDINT;
    uz : UDINT;
END_VAR
m := 7 MOD zero;            (* MOD 0 is 0, no fault *)
r := F_Ratio(10, zero);
END_PROGRAM
"""


def test_division_by_zero_inside_a_function_names_the_function():
    run = run_st(DIV_IN_FUNCTION, scans=2)
    assert run.rcs == [DIV_ZERO, DIV_ZERO]
    f = run.fault
    assert (f.pou, f.line) == ("F_Ratio", line_of(DIV_IN_FUNCTION, "F_Ratio := a / b"))
    assert run.value("m") == 0


DIV_TIME = """
PROGRAM P_TimeDiv
VAR
    n : DINT;
    t : TIME;
END_VAR
t := T#1s / n;
END_PROGRAM
"""


def test_time_divided_by_zero_faults():
    run = run_st(DIV_TIME, scans=1)
    assert run.rcs == [DIV_ZERO]
    assert run.fault.line == line_of(DIV_TIME, "t := T#1s / n")


INDEX_READ = """
PROGRAM P_Index
VAR
    table : ARRAY[1..4] OF INT := [10, 20, 30, 40];
    i : INT;
    sum : INT;
END_VAR
i := i + 1;                 (* 1, 2, 3, 4, 5 *)
sum := sum + table[i];      (* reading table[5] on scan 5 *)
END_PROGRAM
"""


def test_reading_past_the_end_of_an_array_stops_the_program():
    run = run_st(INDEX_READ, scans=7)
    assert run.rcs == [0, 0, 0, 0, INDEX, INDEX, INDEX]
    f = run.faults[4]
    assert (f.kind, f.pou, f.line) == (INDEX, "P_Index", line_of(INDEX_READ, "sum := sum + table[i]"))
    assert run.series("sum") == [10, 30, 60, 100, 100, 100, 100]


INDEX_WRITE = """
FUNCTION_BLOCK FB_Store
VAR_INPUT
    slot : INT;
END_VAR
VAR
    cells : ARRAY[-1..1, 0..2] OF BOOL;
END_VAR
cells[0, slot] := TRUE;
END_FUNCTION_BLOCK

PROGRAM P_Write
VAR
    store : FB_Store;
    k : INT := 1;
END_VAR
k := k + 1;                 (* 2, then 3: out of 0..2 *)
store(slot := k);
END_PROGRAM
"""


def test_writing_out_of_bounds_in_a_function_block_names_the_block():
    run = run_st(INDEX_WRITE, scans=3)
    assert run.rcs == [0, INDEX, INDEX]
    f = run.fault
    assert (f.kind, f.pou, f.line) == (INDEX, "FB_Store", line_of(INDEX_WRITE, "cells[0, slot] := TRUE"))
    assert f.col > 0


NO_FAULT = """
PROGRAM P_Fine
VAR
    a : ARRAY[0..2] OF INT;
    i : INT;
    d : INT := 4;
END_VAR
FOR i := 0 TO 2 DO
    a[i] := i * 10 / d;
END_FOR;
END_PROGRAM
"""


def test_in_bounds_indices_and_non_zero_divisors_do_not_fault():
    run = run_st(NO_FAULT, scans=3)
    assert run.rcs == [0, 0, 0]
    assert run.fault is None
    assert run.ints("a", "h") == [0, 2, 5]


@pytest.mark.parametrize("expr", ["x / 0", "x MOD 0"])
def test_constant_zero_divisor(expr):
    """A literal 0 divisor is a compile-time error for '/', and MOD 0 is simply 0."""
    from harness import HarnessError
    src = f"""
PROGRAM P_Const
VAR
    x : INT := 5;
    y : INT := 1;
END_VAR
y := {expr};
END_PROGRAM
"""
    if "/" in expr:
        with pytest.raises(HarnessError, match="division by zero"):
            run_st(src)
    else:
        assert run_st(src).value("y") == 0
