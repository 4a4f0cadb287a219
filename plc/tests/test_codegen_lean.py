"""The leaner C of issue 33 (docs/scan-cost.md): reads of CONSTANTs as literals.

Each optimisation is pinned twice: in the C text (what the generator emits, and what it must leave alone) and by
running the program (the values a scan leaves are those of the plain C).
"""
from __future__ import annotations

import re
import struct

from harness import compile_st, render, run_st, with_config

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
