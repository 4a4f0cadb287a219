"""Conformance: POU kinds, calls and parameter passing, EN/ENO, case-insensitive names.

FUNCTION / FUNCTION_BLOCK / PROGRAM; formal (`:=`, `=>`) and positional calls;
VAR_INPUT/VAR_OUTPUT/VAR_IN_OUT (copy-in/copy-out)/VAR/VAR_TEMP; implicit
EN/ENO as OpenPLC's MATIEC runs them (EN = FALSE: the function still returns
its result's initial value, an FB still copies inputs in and `=>` outputs out).
One build for the module.
"""
from __future__ import annotations

import pytest

from harness import run_st

SRC = r"""
TYPE
    ST_Ctx : STRUCT
        count : UDINT;
        note : STRING;
        flag : BOOL;
    END_STRUCT;
END_TYPE

(* PROGRAM before the blocks it uses: names are resolved after parsing *)
PROGRAM P_Calls
VAR
    sumFormal, sumPositional, nested : INT;
    hi, lo : INT;
    split : BOOL;
    ctx : ST_Ctx;
    touched : BOOL;
    acc : FB_Accumulate;
    accTotal, accCalls : DINT;
    keepInput : DINT;
    fromOutside : DINT;
    inner : ST_Ctx;
    relay : FB_Relay;
    positional : FB_Accumulate;
    posTotal : DINT;
    fresh1, fresh2 : INT;
    tempFb : FB_Temp;
    tempA, tempB : INT;
    arr : ARRAY[1..4] OF INT;
    fillOk : BOOL;
    made : ST_Ctx;
END_VAR
sumFormal := F_Add(a := 2, b := 3);
sumPositional := F_Add(10, 20);
nested := F_Add(F_Add(1, 2), MAX(F_Add(3, 4), 5));
split := F_Split(v := 16#1234, hi => hi, lo => lo);
touched := F_Touch(ctx, 'hello');
touched := F_Touch(tc := ctx, msg := 'again');
(* inputs set, body run, outputs copied with => ; an omitted input keeps its value *)
acc(increment := 5, total => accTotal);
acc(total => accTotal, calls => accCalls);
keepInput := acc.increment;
acc.increment := 100;                     (* writing an input from outside *)
acc();
fromOutside := acc.total;
relay(tc := inner);                   (* FB VAR_IN_OUT passed on to a FUNCTION and an inner FB *)
positional(1);
posTotal := positional.total;
fresh1 := F_Fresh(1);
fresh2 := F_Fresh(1);
tempFb();
tempA := tempFb.seen;
tempFb();
tempB := tempFb.seen;
fillOk := F_Fill(arr, 7);
made := F_Make(3);
END_PROGRAM

FUNCTION F_Add : INT
VAR_INPUT
    a : INT;
    b : INT;
END_VAR
F_Add := a + b;
END_FUNCTION

FUNCTION F_Split : BOOL
VAR_INPUT
    v : WORD;
END_VAR
VAR_OUTPUT
    hi : INT;
    lo : INT;
END_VAR
hi := WORD_TO_INT(SHR(v, 8));
lo := WORD_TO_INT(v AND 16#00FF);
F_Split := TRUE;
END_FUNCTION

FUNCTION F_Touch : BOOL
VAR_IN_OUT
    tc : ST_Ctx;
END_VAR
VAR_INPUT
    msg : STRING;
END_VAR
tc.count := tc.count + 1;
tc.note := msg;
F_Touch := TRUE;
END_FUNCTION

FUNCTION F_Fresh : INT
VAR_INPUT
    k : INT;
END_VAR
VAR
    local : INT;            (* a FUNCTION has no memory: starts at 0 on every call *)
END_VAR
local := local + k;
F_Fresh := local;
END_FUNCTION

FUNCTION F_Fill : BOOL
VAR_IN_OUT
    v : ARRAY[1..4] OF INT;
END_VAR
VAR_INPUT
    x : INT;
END_VAR
VAR
    i : INT;
END_VAR
FOR i := 1 TO 4 DO
    v[i] := x;
END_FOR;
F_Fill := TRUE;
END_FUNCTION

FUNCTION F_Make : ST_Ctx
VAR_INPUT
    n : UDINT;
END_VAR
F_Make.count := n;
F_Make.note := 'made';
END_FUNCTION

FUNCTION_BLOCK FB_Accumulate
VAR_INPUT
    increment : DINT;
END_VAR
VAR_OUTPUT
    total : DINT;
    calls : DINT;
END_VAR
total := total + increment;
calls := calls + 1;
END_FUNCTION_BLOCK

FUNCTION_BLOCK FB_Inner
VAR_IN_OUT
    tc : ST_Ctx;
END_VAR
tc.count := tc.count + 100;
END_FUNCTION_BLOCK

FUNCTION_BLOCK FB_Relay
VAR_IN_OUT
    tc : ST_Ctx;
END_VAR
VAR
    inner : FB_Inner;
    ok : BOOL;
END_VAR
inner(tc := tc);
ok := F_Touch(tc, 'relay');
END_FUNCTION_BLOCK

FUNCTION_BLOCK FB_Temp
VAR_OUTPUT
    seen : INT;
END_VAR
VAR_TEMP
    t : INT;
END_VAR
t := t + 1;
seen := t;
END_FUNCTION_BLOCK

PROGRAM P_EnEno
VAR
    x, y, z : INT;
    ok, ok2, ok3, ok4 : BOOL;
    r : REAL := 2.7;
    c : FB_Counter;
    e : BOOL;
    eo : BOOL;
    cOut : INT;
    onlyEn : INT;
    okFlag : BOOL;
END_VAR
x := 55;
x := F_Add(EN := FALSE, a := 1, b := 2, ENO => ok);
y := F_Add(EN := TRUE, a := 1, b := 2, ENO => ok2);
z := 55;
z := REAL_TO_INT(EN := FALSE, IN := r, ENO => ok3);
e := FALSE;
c(EN := e, k := 7, ENO => eo, n => cOut);
onlyEn := F_Seven(EN := TRUE);
okFlag := TRUE;
okFlag := F_NoEno(EN := TRUE, ENO => ok4);
END_PROGRAM

(* an instance's ENO read after its call, as MATIEC reads it (the C struct's own field) *)
PROGRAM P_InstEno
VAR
    gate : FB_Gate;
    ran : BOOL;
    skipped : BOOL := TRUE;
    cleared : BOOL := TRUE;
    ranAndPassed : BOOL;
END_VAR
gate(EN := TRUE, pass := TRUE);
ran := gate.ENO;
ranAndPassed := gate.eno AND gate.q;
gate(EN := FALSE, pass := TRUE);
skipped := gate.Eno;
gate(pass := FALSE);                  (* no EN: the body runs and clears ENO itself *)
cleared := gate.ENO;
END_PROGRAM

FUNCTION_BLOCK FB_Gate
VAR_INPUT
    pass : BOOL;
END_VAR
VAR_OUTPUT
    q : BOOL;
END_VAR
q := pass;
IF NOT pass THEN
    ENO := FALSE;
END_IF;
END_FUNCTION_BLOCK

FUNCTION_BLOCK FB_Counter
VAR_INPUT
    k : INT;
END_VAR
VAR_OUTPUT
    n : INT := 9;
END_VAR
n := n + k;
END_FUNCTION_BLOCK

FUNCTION F_Seven : INT
VAR
    seven : INT := 7;
END_VAR
F_Seven := seven;
END_FUNCTION

FUNCTION F_NoEno : BOOL
VAR_INPUT
    unused : BOOL;
END_VAR
ENO := FALSE;
F_NoEno := TRUE;
END_FUNCTION

program p_Case
var
    MyVar : Int;
    other : iNT;
end_var
myvar := MYVAR + 1;
Other := MyVar * 2;
end_program
"""


@pytest.fixture(scope="module")
def run():
    return run_st(SRC, scans=2)


def v(run, name, scan=None):
    return run.value(name, scan)


def test_function_formal_positional_and_nested_calls(run):
    assert v(run, "P_Calls.sumFormal") == 5
    assert v(run, "P_Calls.sumPositional") == 30
    assert v(run, "P_Calls.nested") == 10


def test_function_var_output_bound_with_arrow(run):
    assert v(run, "P_Calls.split") is True
    assert (v(run, "P_Calls.hi"), v(run, "P_Calls.lo")) == (0x12, 0x34)


def test_function_var_in_out_writes_reach_the_caller(run):
    raw = run.value("P_Calls.ctx")
    assert isinstance(raw, bytes)
    assert int.from_bytes(raw[:4], "little") == 4                  # two calls per scan, two scans
    assert b"again" in raw


def test_function_block_inputs_outputs_and_omitted_inputs_keep_their_value(run):
    # scan 1: increment 5 -> total 5; second call, increment kept -> 10; acc.increment := 100 -> 110
    assert v(run, "P_Calls.accTotal", 1) == 10
    assert v(run, "P_Calls.accCalls", 1) == 2
    assert v(run, "P_Calls.keepInput", 1) == 5
    assert v(run, "P_Calls.fromOutside", 1) == 110
    assert v(run, "P_Calls.fromOutside", 2) == 110 + 5 + 5 + 100


def test_fb_var_in_out_passed_on_to_an_inner_fb_and_a_function(run):
    raw = run.value("P_Calls.inner", 2)
    assert int.from_bytes(raw[:4], "little") == 2 * 101
    assert b"relay" in raw


def test_positional_fb_call(run):
    assert v(run, "P_Calls.posTotal", 1) == 1
    assert v(run, "P_Calls.posTotal", 2) == 2


def test_function_locals_and_var_temp_are_fresh_on_every_call(run):
    assert (v(run, "P_Calls.fresh1"), v(run, "P_Calls.fresh2")) == (1, 1)
    assert (v(run, "P_Calls.tempA"), v(run, "P_Calls.tempB")) == (1, 1)


def test_array_var_in_out_and_struct_result(run):
    assert run.ints("P_Calls.arr", "h") == [7, 7, 7, 7]
    assert v(run, "P_Calls.fillOk") is True
    made = run.value("P_Calls.made")
    assert int.from_bytes(made[:4], "little") == 3 and b"made" in made


def test_function_with_en_false_returns_0_and_clears_eno(run):
    assert v(run, "P_EnEno.x") == 0
    assert v(run, "P_EnEno.ok") is False
    assert v(run, "P_EnEno.y") == 3
    assert v(run, "P_EnEno.ok2") is True


def test_standard_function_with_en_false(run):
    assert v(run, "P_EnEno.z") == 0
    assert v(run, "P_EnEno.ok3") is False


def test_fb_with_en_false_copies_inputs_skips_body_and_copies_outputs(run):
    assert v(run, "P_EnEno.c.k") == 7
    assert v(run, "P_EnEno.eo") is False
    assert v(run, "P_EnEno.c.n") == 9          # body skipped: initial value kept
    assert v(run, "P_EnEno.cOut") == 9         # outputs still copied out


def test_eno_of_an_fb_instance_read_after_its_call(run):
    # issue: `ok := ctr.ENO;` passed the checker but the C named a field ENO_V that no struct has
    assert v(run, "P_InstEno.ran") is True
    assert v(run, "P_InstEno.ranAndPassed") is True
    assert v(run, "P_InstEno.skipped") is False          # EN := FALSE: body skipped, ENO cleared
    assert v(run, "P_InstEno.cleared") is False          # the body's own ENO := FALSE
    assert v(run, "P_InstEno.gate.q") is False


def test_function_without_inputs_called_with_en_and_eno_set_in_body(run):
    assert v(run, "P_EnEno.onlyEn") == 7
    assert v(run, "P_EnEno.ok4") is False
    assert v(run, "P_EnEno.okFlag") is True


def test_identifiers_are_case_insensitive(run):
    assert run.series("p_case.myvar") == [1, 2]
    assert run.series("P_CASE.OTHER") == [2, 4]
