"""Conformance: TYPE blocks, enums, subranges, STRUCT and ARRAY initialisers, typed literals.

Expected values are OpenPLC's MATIEC results (MATIEC findings sections e, f,
k, l, q): repeat counts `3(5)`, row-major multi-dimensional arrays, partial
struct initialisers, the lower bound as a subrange's default, enum defaults.
One build for the module.
"""
from __future__ import annotations

import pytest

from harness import run_st

NS = 1
MS = 1_000_000 * NS
S = 1_000 * MS

SRC = r"""
TYPE
    E_Mode : (Idle, Moving, Fault);
    E_Level : (Low, Medium, High) := Medium;
    E_Gear : (Neutral, Forward) := E_Gear#Forward;   (* the initial value names the type being declared *)
    T_Pocket : INT (1..12);
    T_Percent : USINT (0..100);
    T_Tools : ARRAY[1..8] OF INT := [8(3)];
    T_Count : DINT;
    T_Speed : INT := 5;
    T_LevelHigh : E_Level := High;   (* an extension: MATIEC's C does not compile a renamed enum *)
    ST_Inner : STRUCT
        x : INT := 1;
        y : INT := 2;
    END_STRUCT;
    ST_Outer : STRUCT
        inner : ST_Inner;
        z : INT := 3;
        mode : E_Mode := E_Mode#Moving;
        tools : T_Tools;
        flags : ARRAY[0..2] OF BOOL := [FALSE, TRUE];
        name : STRING := 'outer';
        t : TIME := T#2s;
    END_STRUCT;
END_TYPE

PROGRAM P_Enums
VAR
    mode : E_Mode;
    level : E_Level;
    explicit : E_Mode := E_Mode#Fault;
    gear : E_Gear;
    isIdle, isNotFault, caseHit : BOOL;
    code : INT;
    next : E_Mode;
END_VAR
isIdle := mode = Idle;
isNotFault := explicit <> E_Mode#Fault;
CASE mode OF
    Idle: code := 10;
    Moving, Fault: code := 20;
END_CASE;
CASE explicit OF
    E_Mode#Fault: caseHit := TRUE;
END_CASE;
next := F_Next(mode);
mode := next;
END_PROGRAM

FUNCTION F_Next : E_Mode
VAR_INPUT
    m : E_Mode;
END_VAR
CASE m OF
    Idle: F_Next := Moving;
    Moving: F_Next := Fault;
ELSE
    F_Next := Idle;
END_CASE;
END_FUNCTION

PROGRAM P_Subrange
VAR
    pocket : T_Pocket;
    percent : T_Percent;
    inline : INT (-5..5);
    bumped : T_Pocket := 3;
    count : T_Count := 70000;
    speed : T_Speed;
    plainInt : INT;
    levelHigh : T_LevelHigh;
    plainLevel : E_Level;
    scans : INT;
END_VAR
scans := scans + 1;
END_PROGRAM

PROGRAM P_Struct
VAR
    plain : ST_Outer;
    partial : ST_Inner := (y := 20);
    nested : ST_Outer := (inner := (x := 100), z := 30);
    copy : ST_Outer;
    ix, iy, z, px, py, nx, ny, nz, cz, toolSum : INT;
    modeOk, flag1, flag0 : BOOL;
    nameLen : INT;
    t : TIME;
END_VAR
VAR_TEMP
    i : INT;
END_VAR
ix := plain.inner.x;
iy := plain.inner.y;
z := plain.z;
modeOk := plain.mode = E_Mode#Moving;
px := partial.x;
py := partial.y;
nx := nested.inner.x;
ny := nested.inner.y;
nz := nested.z;
copy := nested;
copy.z := copy.z + 1;
cz := copy.z;
toolSum := 0;
FOR i := 1 TO 8 DO toolSum := toolSum + plain.tools[i]; END_FOR;
flag0 := plain.flags[0];
flag1 := plain.flags[1];
nameLen := LEN(plain.name);
t := plain.t;
END_PROGRAM

PROGRAM P_Arrays
VAR
    rep : ARRAY[1..8] OF INT := [1, 2, 3(5)];
    m : ARRAY[1..2, 1..3] OF INT := [1, 2, 3, 4, 5, 6];
    m21, m13 : INT;
    a : ARRAY[0..3] OF DINT := [10, 20, 30, 40];
    b : ARRAY[0..3] OF DINT;
    typed : T_Tools;
    pockets : ARRAY[1..2] OF ST_Inner;
    neg : ARRAY[-2..2] OF SINT := [-2, -1, 0, 1, 2];
    sumNeg : SINT;
    reals : ARRAY[1..3] OF REAL := [1.5, 2(0.25)];
    words : ARRAY[1..2] OF WORD := [16#BEEF, 16#0001];
    bools : ARRAY[1..4] OF BOOL := [2(TRUE), FALSE];
    i, j, total : INT;
END_VAR
m21 := m[2, 1];
m13 := m[1, 3];
b := a;
b[0] := 99;
pockets[2].y := 7;
sumNeg := neg[-2] + neg[2] + neg[1];
total := 0;
FOR i := 1 TO 2 DO
    FOR j := 1 TO 3 DO
        total := total + m[i, j] * i;
    END_FOR;
END_FOR;
END_PROGRAM

PROGRAM P_Literals
VAR
    i5 : INT;
    uHex : UINT;
    w : WORD;
    b : BOOL;
    t1, t2, t3, t4, t5, t6, t7 : TIME;
    tod1 : TOD;
    d1 : DATE;
    dt1 : DT;
    bin, oct, hex, under : DINT;
    r : REAL;
    lr : LREAL;
    s : STRING;
    n : INT;
    bigHex : DINT;
    lw : LWORD;
    ul : ULINT;
    lmin : LINT;
    sNeg : SINT;
    oneByte : BYTE;
    dw : DWORD;
    quote : STRING;
    dq : STRING;
    longTod : TOD;
    longDate : DATE;
    longDt : DT;
    typedReal : REAL;
    typedLreal : LREAL;
    subMs : TIME;
    typedBin : USINT;
END_VAR
i5 := INT#5;
uHex := UINT#16#FFFF;
w := WORD#16#8000;
b := BOOL#TRUE;
t1 := T#1s500ms;
t2 := TIME#1.5s;
t3 := TIME#-5s;
t4 := T#1d2h3m4s5ms;
t5 := t#250MS;
t6 := T#1m;
t7 := T#100ms;
tod1 := TOD#12:00:00;
d1 := D#2024-01-02;
dt1 := DT#2024-01-02-12:00:00;
bin := 2#1010_1010;
oct := 8#17;
hex := 16#7FFF_FFFF;
under := 1_000;
r := 1.5E3;
lr := -2.5e-3;
s := '$N$T$'$$';
n := LEN(s);
bigHex := DINT#16#7FFFFFFF;
lw := 16#FFFF_FFFF_FFFF_FFFF;
ul := 18446744073709551615;
lmin := LINT#-9223372036854775808;
sNeg := SINT#-128;
oneByte := BYTE#255;
dw := DWORD#2#1111;
quote := 'it$'s';
dq := '$22$41';
longTod := TIME_OF_DAY#12:00:00;
longDate := DATE#2024-01-02;
longDt := DATE_AND_TIME#2024-01-02-12:00:00;
typedReal := REAL#1.5;
typedLreal := LREAL#-2.25E2;
subMs := T#1.5ms;
typedBin := USINT#2#1111_0000;
END_PROGRAM
"""


@pytest.fixture(scope="module")
def run():
    return run_st(SRC, scans=3)


def v(run, name, scan=None):
    return run.value(name, scan)


def test_enum_values_count_from_0_and_default_to_the_first(run):
    assert v(run, "P_Enums.mode", 1) == 1           # Idle (0) -> F_Next -> Moving
    assert v(run, "P_Enums.isIdle", 1) is True
    assert v(run, "P_Enums.code", 1) == 10
    assert run.series("P_Enums.mode") == [1, 2, 0]


def test_enum_type_default_and_explicit_initial_value(run):
    assert v(run, "P_Enums.level") == 1             # E_Level := Medium
    assert v(run, "P_Enums.gear") == 1              # E_Gear := E_Gear#Forward (the compiler recursed on it)
    assert v(run, "P_Enums.explicit") == 2
    assert v(run, "P_Enums.isNotFault") is False
    assert v(run, "P_Enums.caseHit") is True


def test_enum_case_with_lists_and_function_result(run):
    assert run.series("P_Enums.code") == [10, 20, 20]


def test_subrange_defaults_to_its_lower_bound(run):
    assert v(run, "P_Subrange.pocket") == 1
    assert v(run, "P_Subrange.percent") == 0
    # IEC: the lower bound.  OpenPLC's MATIEC starts an *inline* subrange at 0 (measured);
    # plc warns about it (portability.subrange-default).
    assert v(run, "P_Subrange.inline") == -5
    assert v(run, "P_Subrange.bumped") == 3
    assert v(run, "P_Subrange.count") == 70000      # a plain alias type


def test_alias_type_initial_values_stay_with_the_alias(run):
    assert v(run, "P_Subrange.speed") == 5
    assert v(run, "P_Subrange.plainInt") == 0       # INT itself keeps 0
    assert v(run, "P_Subrange.levelHigh") == 2
    assert v(run, "P_Subrange.plainLevel") == 1     # E_Level keeps its own default Medium


def test_struct_member_initialisers_from_the_type(run):
    assert (v(run, "P_Struct.ix"), v(run, "P_Struct.iy"), v(run, "P_Struct.z")) == (1, 2, 3)
    assert v(run, "P_Struct.modeOk") is True
    assert v(run, "P_Struct.toolSum") == 8 * 3      # member of an array type with [8(3)]
    assert (v(run, "P_Struct.flag0"), v(run, "P_Struct.flag1")) == (False, True)
    assert v(run, "P_Struct.nameLen") == 5
    assert v(run, "P_Struct.t") == 2 * S


def test_struct_variable_initialiser_replaces_only_the_members_it_names(run):
    assert (v(run, "P_Struct.px"), v(run, "P_Struct.py")) == (1, 20)
    assert v(run, "P_Struct.nz") == 30
    # a nested initialiser starts from the inner type's defaults (MATIEC: p.inner = (100, 2))
    assert (v(run, "P_Struct.nx"), v(run, "P_Struct.ny")) == (100, 2)


def test_struct_assignment_copies(run):
    assert v(run, "P_Struct.cz") == 31
    assert v(run, "P_Struct.nz") == 30


def test_array_initialiser_with_repeat_count_and_missing_elements_zero(run):
    assert run.ints("P_Arrays.rep", "h") == [1, 2, 5, 5, 5, 0, 0, 0]
    assert run.ints("P_Arrays.reals", "f") == [1.5, 0.25, 0.25]
    assert run.ints("P_Arrays.words", "H") == [0xBEEF, 1]
    assert run.ints("P_Arrays.bools", "B") == [1, 1, 0, 0]
    assert run.ints("P_Arrays.typed", "h") == [3] * 8


def test_two_dimensional_arrays_are_row_major(run):
    assert v(run, "P_Arrays.m21") == 4
    assert v(run, "P_Arrays.m13") == 3
    assert v(run, "P_Arrays.total") == (1 + 2 + 3) + 2 * (4 + 5 + 6)


def test_whole_array_assignment_copies_and_negative_bounds_work(run):
    assert run.ints("P_Arrays.b", "i") == [99, 20, 30, 40]
    assert run.ints("P_Arrays.a", "i") == [10, 20, 30, 40]
    assert v(run, "P_Arrays.sumNeg") == 1
    assert run.ints("P_Arrays.pockets", "h") == [1, 2, 1, 7]


def test_integer_and_bit_string_literals(run):
    assert v(run, "P_Literals.i5") == 5
    assert v(run, "P_Literals.uHex") == 65535
    assert v(run, "P_Literals.w") == 0x8000
    assert v(run, "P_Literals.b") is True
    assert (v(run, "P_Literals.bin"), v(run, "P_Literals.oct")) == (170, 15)
    assert (v(run, "P_Literals.hex"), v(run, "P_Literals.under")) == (0x7FFFFFFF, 1000)
    assert v(run, "P_Literals.bigHex") == 0x7FFFFFFF
    assert v(run, "P_Literals.lw") == 2**64 - 1
    assert v(run, "P_Literals.ul") == 2**64 - 1
    assert v(run, "P_Literals.lmin") == -2**63
    assert v(run, "P_Literals.sNeg") == -128
    assert v(run, "P_Literals.oneByte") == 255
    assert v(run, "P_Literals.dw") == 15
    assert v(run, "P_Literals.typedBin") == 0xF0
    assert (v(run, "P_Literals.typedReal"), v(run, "P_Literals.typedLreal")) == (1.5, -225.0)


def test_time_and_date_literals(run):
    assert v(run, "P_Literals.t1") == 1500 * MS
    assert v(run, "P_Literals.t2") == 1500 * MS
    assert v(run, "P_Literals.t3") == -5 * S
    assert v(run, "P_Literals.t4") == 93784005 * MS
    assert v(run, "P_Literals.t5") == 250 * MS
    assert v(run, "P_Literals.t6") == 60 * S
    assert v(run, "P_Literals.t7") == 100 * MS
    assert v(run, "P_Literals.tod1") == 43200 * S
    assert v(run, "P_Literals.d1") == 1704153600 * S
    assert v(run, "P_Literals.dt1") == 1704196800 * S
    assert v(run, "P_Literals.longTod") == v(run, "P_Literals.tod1")
    assert v(run, "P_Literals.longDate") == v(run, "P_Literals.d1")
    assert v(run, "P_Literals.longDt") == v(run, "P_Literals.dt1")
    assert v(run, "P_Literals.subMs") == 1_500_000


def test_real_and_string_literals(run):
    assert v(run, "P_Literals.r") == 1500.0
    assert v(run, "P_Literals.lr") == -2.5e-3
    assert v(run, "P_Literals.s") == "\n\t'$"
    assert v(run, "P_Literals.n") == 4
    assert v(run, "P_Literals.quote") == "it's"
    assert v(run, "P_Literals.dq") == '"A'
