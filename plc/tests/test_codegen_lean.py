"""The leaner C of issue 33 (docs/scan-cost.md): reads of CONSTANTs as literals, FOR variables in C locals.

Each optimisation is pinned twice: in the C text (what the generator emits, and what it must leave alone) and by
running the program (the values a scan leaves are those of the plain C: at the end of a loop, at EXIT, at RETURN,
after a fault).
"""
from __future__ import annotations

import re
import struct

from harness import compile_st, render, run_st, with_config

INDEX = 2           # plc_fault_kind_t


def body(c_text: str, pou: str) -> str:
    """The C of P_<pou>_body."""
    m = re.search(rf"^\S.* void P_{pou}_body\(P_{pou} \*self\) \{{\n(.*?)^\}}", c_text, re.M | re.S)
    assert m, f"no body of {pou} in the C"
    return m.group(1)


def c_of(src: str) -> str:
    res = compile_st(with_config(src)[0])
    assert res.ok and res.c_text, render(res)
    return res.c_text


CONSTANTS = """
TYPE Small : INT (1..10); END_TYPE
TYPE Colour : (Red, Green); END_TYPE

FUNCTION F_Twice : INT
VAR_INPUT x : INT; END_VAR
VAR CONSTANT Factor : INT := 2; END_VAR
F_Twice := x * Factor;
END_FUNCTION

PROGRAM P_Const
VAR CONSTANT
    KWords : INT := 406;
    KHalf : INT := KWords - 203;
    KMask : WORD := 16#00FF;
    KBig : UDINT := 4000000000;
    KOn : BOOL := TRUE;
    KOff : BOOL := NOT KOn;
    KTenth : REAL := 0.1;
    KThird : LREAL := 1.0 / 3.0;
    KWait : TIME := T#1s + T#250ms;
    KName : STRING := 'abc';
    KRow : ARRAY[1..3] OF INT := [1, 2, 3];
    KSmall : Small := 3;
    KHue : Colour := Green;
END_VAR
VAR CONSTANT
    KHere AT %MW7 : INT := 77;
END_VAR
VAR_EXTERNAL CONSTANT
    Pockets : INT;
END_VAR
VAR
    words, half, npockets, twice, part, here : INT;
    mask : WORD;
    big : UDINT;
    isOn, isOff, isGreen : BOOL;
    tenth : LREAL;
    third : LREAL;
    wait : TIME;
    name : STRING;
    row : INT;
END_VAR
words := KWords;
half := KHalf;
mask := KMask;
big := KBig;
isOn := KOn;
isOff := KOff;
tenth := REAL_TO_LREAL(KTenth);
third := KThird;
wait := KWait;
name := KName;
row := KRow[2];
part := KSmall;
isGreen := KHue = Green;
here := KHere;
npockets := Pockets;
twice := F_Twice(x := Pockets);
END_PROGRAM

CONFIGURATION Config0
    VAR_GLOBAL CONSTANT
        Pockets : INT := 24;
    END_VAR
    RESOURCE Res0 ON PLC
        TASK task0(INTERVAL := T#4ms, PRIORITY := 0);
        PROGRAM P_ConstInst WITH task0 : P_Const;
    END_RESOURCE
END_CONFIGURATION
"""


def test_a_read_of_an_elementary_constant_is_its_literal_in_the_c():
    c = c_of(CONSTANTS)
    code = body(c, "P_CONST")
    for literal in ("((int16_t)406LL)", "((int16_t)203LL)", "((uint16_t)255ULL)", "((uint32_t)4000000000ULL)",
                    "((uint8_t)1)", "((uint8_t)0)", "((float)0.1)",
                    "((int64_t)1250000000LL)", "((int16_t)24LL)"):
        assert literal in code, literal
    for name in ("WORDS", "HALF", "MASK", "BIG", "ON", "OFF", "TENTH", "WAIT"):
        assert f"self->K{name}" not in code, name
    assert "G_POCKETS" not in code                              # VAR_GLOBAL CONSTANT through VAR_EXTERNAL
    assert "RESULT__ = PLC_MUL(int16_t, uint16_t, X, ((int16_t)2LL));" in body_of_function(c, "F_TWICE")
    # the constants are still variables of the instance, initialised, for the monitor
    assert "self->KWORDS = ((int16_t)406LL);" in c


def body_of_function(c_text: str, name: str) -> str:
    m = re.search(rf"^\S.* U_{name}\(.*?\) \{{\n(.*?)^\}}", c_text, re.M | re.S)
    assert m, f"no function {name} in the C"
    return m.group(1)


def test_what_is_not_folded_is_read_from_the_instance():
    code = body(c_of(CONSTANTS), "P_CONST")
    # a STRING, an array, a subrange, an enumeration, a REAL computed (C rounds as it goes), a located constant
    for name in ("NAME", "ROW", "SMALL", "HUE", "THIRD"):
        assert f"self->K{name}" in code, name
    assert "(*self->KHERE)" in code


def test_folded_constants_give_the_values_of_the_variables():
    run = run_st(CONSTANTS, scans=1)
    names = ("words", "half", "mask", "big", "isOn", "isOff", "third", "wait", "name", "row", "part", "isGreen",
             "here", "npockets", "twice")
    v = {n: run.value(f"CONFIG0.RES0.P_CONSTINST.{n}") for n in names}
    assert v == {"words": 406, "half": 203, "mask": 255, "big": 4000000000, "isOn": True, "isOff": False,
                 "third": 1.0 / 3.0, "wait": 1_250_000_000, "name": "abc", "row": 2, "part": 3, "isGreen": True,
                 "here": 77, "npockets": 24, "twice": 48}
    # REAL 0.1 is single precision, whether read from the variable or as the literal
    assert run.value("CONFIG0.RES0.P_CONSTINST.tenth") == struct.unpack("<f", struct.pack("<f", 0.1))[0]
    assert run.info("CONFIG0.RES0.P_CONSTINST.KWords").constant


LOOPS = """
FUNCTION_BLOCK FB_Find
VAR_INPUT want : INT; END_VAR
VAR_OUTPUT pos : INT; END_VAR
VAR
    k : INT;
    cells : ARRAY[1..10] OF INT := [3, 1, 4, 1, 5, 9, 2, 6, 5, 3];
END_VAR
pos := 0;
FOR k := 1 TO 10 DO
    IF cells[k] = want THEN
        pos := k;
        RETURN;
    END_IF;
END_FOR;
END_FUNCTION_BLOCK

PROGRAM P_Loops
VAR CONSTANT
    Last : INT := 8;
END_VAR
VAR
    k, n, exitAt, sum, found, skipped : INT;
    a : ARRAY[1..8] OF INT;
    finder : FB_Find;
    j : INT := 2;
END_VAR
FOR k := 1 TO Last DO
    a[k] := k * k;
END_FOR;
n := k;                                     (* 9 *)
FOR k := 1 TO Last DO
    IF a[k] > 20 THEN EXIT; END_IF;
END_FOR;
exitAt := k;                                (* 5 *)
FOR k := Last TO 1 BY -3 DO
    sum := sum + a[k];                      (* 64 + 25 + 4 *)
END_FOR;
finder(want := 9);
found := finder.pos;                        (* 6 *)
FOR k := 1 TO 4 DO
    IF k MOD 2 = 0 THEN CONTINUE; END_IF;
    skipped := skipped + k;                 (* 1 + 3 *)
END_FOR;
FOR j := j + 1 TO 6 DO                      (* the start reads j before the loop sets it: 3 TO 6 *)
END_FOR;
END_PROGRAM
"""


def test_a_for_variable_is_read_from_a_c_local_and_written_wherever_it_changes():
    code = body(c_of(LOOPS), "P_LOOPS")
    m = re.search(r"for \((loop\d+) = \(\(int16_t\)1LL\), self->K = \1; \1 <= \(\(int16_t\)8LL\); "
                  r"\1 = PLC_ADD\(int16_t, uint16_t, \1, 1\), self->K = \1\) \{", code)
    assert m, code[:2000]
    assert f"self->A.e[plc_idx((int64_t)({m.group(1)}), 1, 8," in code


def test_for_loops_leave_their_variable_as_the_plain_c_did():
    run = run_st(LOOPS, scans=1)
    v = {n: run.value(f"P_Loops.{n}") for n in ("n", "exitAt", "sum", "found", "skipped", "k", "j", "finder.k")}
    assert v == {"n": 9, "exitAt": 5, "sum": 64 + 25 + 4, "found": 6, "skipped": 4, "k": 5, "j": 7,
                 "finder.k": 6}                                 # RETURN left the loop at k = 6


FAULT = """
PROGRAM P_Fault
VAR
    k, last : INT;
    a : ARRAY[1..3] OF INT;
END_VAR
FOR k := 1 TO 5 DO
    last := k;
    a[k] := k;                              (* k = 4 is out of bounds *)
END_FOR;
END_PROGRAM
"""


def test_a_fault_inside_a_for_loop_leaves_the_variable_of_the_failing_pass():
    run = run_st(FAULT, scans=1)
    assert run.rcs == [INDEX]
    assert run.value("k") == 4 and run.value("last") == 4


SAME_VARIABLE = """
PROGRAM P_Same
VAR
    k, n : INT;
END_VAR
FOR k := 1 TO 3 DO
    FOR k := 1 TO 2 DO
        n := n + 1;
    END_FOR;
END_FOR;
END_PROGRAM
"""


def test_a_loop_whose_variable_an_inner_loop_counts_reads_the_instance():
    code = body(c_of(SAME_VARIABLE), "P_SAME")
    assert "for (self->K = ((int16_t)1LL); self->K <= ((int16_t)3LL);" in code
    run = run_st(SAME_VARIABLE, scans=1)
    assert run.value("n") == 2 and run.value("k") == 4          # inner loop leaves 3, the outer step 4 ends it
