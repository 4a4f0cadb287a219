"""Conformance: arithmetic, conversions and the standard functions, compiled and run.

Expected values are OpenPLC's MATIEC results (docs/matiec.md):
wrap-around, truncating division, MOD 0 = 0, REAL_TO_INT half to even,
TIME_TO_DINT in seconds, shifts on the type's width.  One build for the module.
"""
from __future__ import annotations

import math

import pytest

from harness import run_st

SRC = r"""
PROGRAM P_Int
VAR
    big : INT := 32767;
    wrapInt : INT;
    sMax : SINT := 127;
    wrapSint : SINT;
    uZero : UINT;
    wrapUint : UINT;
    usMax : USINT := 255;
    wrapUsint : USINT;
    dMax : DINT := 2147483647;
    wrapDint : DINT;
    lMin : LINT := -9223372036854775807;
    wrapLint : LINT;
    negInt : INT;
    minusSeven : INT := -7;
    seven : INT := 7;
    two : INT := 2;
    minusTwo : INT := -2;
    zero : INT := 0;
    divNeg, modNeg, modByNeg, modZero, prod : INT;
    dDiv, dMod, dModZero : DINT;
    dSeven : DINT := -7;
    dZero : DINT;
    uDiv, uMod : UINT;
    u17 : UINT := 17;
    u5 : UINT := 5;
    mulWrap : INT;
    pri : INT;
END_VAR
wrapInt := big + 1;
wrapSint := sMax + 1;
wrapUint := uZero - 1;
wrapUsint := usMax + 1;
wrapDint := dMax + 1;
wrapLint := lMin - 2;
negInt := -big - 1;
divNeg := minusSeven / two;
modNeg := minusSeven MOD two;
modByNeg := seven MOD minusTwo;
modZero := seven MOD zero;
dDiv := dSeven / 2;
dMod := dSeven MOD 2;
dModZero := dSeven MOD dZero;
uDiv := u17 / u5;
uMod := u17 MOD u5;
mulWrap := big * two;
prod := 2 + 3 * 4 - 10 / 5;        (* precedence: 12 *)
pri := -2 + 3;                     (* unary minus binds tighter than + *)
END_PROGRAM

PROGRAM P_Conv
VAR
    r25, rm25, r35, r37, r05, r15, rm27 : INT;
    x25 : REAL := 2.5;
    xm25 : REAL := -2.5;
    x35 : REAL := 3.5;
    x37 : REAL := 3.7;
    x05 : REAL := 0.5;
    x15 : REAL := 1.5;
    xm27 : REAL := -2.7;
    lr25 : LREAL := 2.5;
    ld25 : DINT;
    tr : DINT;
    minusOne : INT := -1;
    u65535 : UINT := 65535;
    i200 : INT := 200;
    d100000 : DINT := 100000;
    intToUint, uintToInt : INT;
    intToUintU : UINT;
    intToWord : WORD;
    intToSint : SINT;
    intToUsint : USINT;
    dintToInt : INT;
    intToDint : DINT;
    intToReal : REAL;
    boolToInt : INT;
    intToBool, zeroToBool : BOOL;
    wordToInt : INT;
    w8000 : WORD := 16#8000;
    realToDint : DINT;
    timeToDint : DINT;
    dintToTime : TIME;
    timeToReal : REAL;
    lrealToReal : REAL;
    realToLreal : LREAL;
    bigReal : REAL := 1.0E10;
    udintFromDint : UDINT;
END_VAR
r25 := REAL_TO_INT(x25);
rm25 := REAL_TO_INT(xm25);
r35 := REAL_TO_INT(x35);
r37 := REAL_TO_INT(x37);
r05 := REAL_TO_INT(x05);
r15 := REAL_TO_INT(x15);
rm27 := REAL_TO_INT(xm27);
ld25 := LREAL_TO_DINT(lr25);
tr := TRUNC(xm27);
intToUintU := INT_TO_UINT(minusOne);
uintToInt := UINT_TO_INT(u65535);
intToWord := INT_TO_WORD(-2);
intToSint := INT_TO_SINT(i200);
intToUsint := INT_TO_USINT(minusOne);
dintToInt := DINT_TO_INT(d100000);
intToDint := INT_TO_DINT(minusOne);
intToReal := INT_TO_REAL(i200);
boolToInt := BOOL_TO_INT(TRUE);
intToBool := INT_TO_BOOL(i200);
zeroToBool := INT_TO_BOOL(0);
wordToInt := WORD_TO_INT(w8000);
realToDint := REAL_TO_DINT(x37);
timeToDint := TIME_TO_DINT(T#1500ms);
dintToTime := DINT_TO_TIME(1500);
timeToReal := TIME_TO_REAL(T#2s);
lrealToReal := LREAL_TO_REAL(lr25);
realToLreal := REAL_TO_LREAL(x25);
udintFromDint := DINT_TO_UDINT(-1);
END_PROGRAM

PROGRAM P_Bits
VAR
    w : WORD := 16#8001;
    b : BYTE := 16#81;
    shlW, rolW, shrW, rorW, shl16 : WORD;
    shlB, rolB, shrB, rorB : BYTE;
    andW, orW, xorW, notW : WORD;
    lw : LWORD := 16#FFFF_FFFF_FFFF_FFFF;
    shlL : LWORD;
    bt, bf : BOOL := TRUE;
    andB, orB, xorB, notB : BOOL;
    dw : DWORD := 16#F0F0_F0F0;
    notDw : DWORD;
END_VAR
bf := FALSE;
shlW := SHL(w, 1);
rolW := ROL(w, 1);
shrW := SHR(w, 15);
rorW := ROR(w, 1);
shl16 := SHL(w, 16);
shlB := SHL(b, 1);
rolB := ROL(b, 1);
shrB := SHR(b, 7);
rorB := ROR(b, 1);
andW := w AND 16#00FF;
orW := w OR 16#0F00;
xorW := w XOR 16#FFFF;
notW := NOT w;
shlL := SHL(lw, 4);
andB := bt AND bf;
orB := bt OR bf;
xorB := bt XOR bt;
notB := NOT bf;
notDw := NOT dw;
END_PROGRAM

PROGRAM P_Select
VAR
    i : INT := 5;
    j : INT := -3;
    k : INT := 9;
    mn, mx, mn3, mx3, lim, limLow, limHigh, sel0, sel1, mux1, muxOut, mv : INT;
    mxD : DINT;
    d : DINT := 70000;
    absI : INT;
    absR : REAL;
    sq : REAL;
    ex : REAL;
    exr : REAL;
    add3, mul3 : INT;
    lnE, sinZero, cosZero : LREAL;
    x : LREAL := 1.0;
    gtF, geF, eqF, neF, ltF, leF : BOOL;
END_VAR
mn := MIN(i, j);
mx := MAX(i, j);
mn3 := MIN(i, j, k);
mx3 := MAX(IN1 := i, IN2 := j, IN3 := k);
lim := LIMIT(0, i, 10);
limLow := LIMIT(MN := 0, IN := j, MX := 10);
limHigh := LIMIT(0, k, 6);
sel0 := SEL(FALSE, i, j);
sel1 := SEL(G := TRUE, IN0 := i, IN1 := j);
mux1 := MUX(1, i, j, k);
muxOut := MUX(5, i, j, k);
mv := MOVE(k);
mxD := MAX(1, d);
absI := ABS(j);
absR := ABS(-2.5);
sq := SQRT(16.0);
ex := EXPT(2.0, 3);
exr := EXPT(2.0, 0.5);
add3 := ADD(i, j, k);
mul3 := MUL(i, j, 2);
lnE := LN(EXP(x));
sinZero := SIN(0.0);
cosZero := COS(0.0);
gtF := GT(i, j);
geF := GE(i, i);
eqF := EQ(i, j);
neF := NE(i, j);
ltF := LT(i, j);
leF := LE(j, i);
END_PROGRAM

PROGRAM P_Time
VAR
    t : TIME := T#1s;
    twice, quarter, sum, diff, scaled : TIME;
    later, equal : BOOL;
    four : INT := 4;
END_VAR
twice := t * 2;
quarter := t / four;
sum := T#1s500ms + T#250ms;
diff := T#1s - T#1500ms;
later := T#1m > T#59s;
equal := T#1s500ms = T#1.5s;
scaled := t * 2.5;
END_PROGRAM

PROGRAM P_Strings
VAR
    s : STRING := 'hello';
    t : STRING;
    u : STRING;
    three, esc, leftS, rightS, midS, ins, del, rep : STRING;
    n, f, nEsc, nEmpty, nFindNone : INT;
    long, cat126 : STRING;
    lenCat : INT;
    eqS, gtS, ltS : BOOL;
    i42 : INT := -42;
    fromInt, fromDint, fromBool, fromUint, fromLreal, fromReal, fromSint : STRING;
    toInt : INT;
    toReal : REAL;
    toDint : DINT;
END_VAR
t := CONCAT(s, ' world');
n := LEN(t);
three := CONCAT('a', 'b', 'c');
esc := '$N$T$'$$';
nEsc := LEN(esc);
nEmpty := LEN('');
leftS := LEFT(t, 5);
rightS := RIGHT(t, 5);
midS := MID(t, 3, 2);
f := FIND(t, 'wor');
nFindNone := FIND(t, 'xyz');
ins := INSERT(s, 'XY', 2);
del := DELETE(t, 6, 6);
rep := REPLACE(t, 'W', 1, 7);
long := '{LONG}';
cat126 := CONCAT(long, 'ABCDEF');
lenCat := LEN(cat126);
eqS := s = 'hello';
gtS := 'b' > 'abc';
ltS := s < t;
fromInt := INT_TO_STRING(i42);
fromDint := DINT_TO_STRING(123456);
fromBool := BOOL_TO_STRING(TRUE);
fromUint := UINT_TO_STRING(65535);
fromSint := SINT_TO_STRING(-5);
fromLreal := LREAL_TO_STRING(0.1);
fromReal := REAL_TO_STRING(2.5);
toInt := STRING_TO_INT('123');
toDint := STRING_TO_DINT('-70000');
toReal := STRING_TO_REAL('1.5');
END_PROGRAM

PROGRAM P_ToString
VAR
    t1, t2, t3, t4, t5, t6, t7, t8 : STRING;
    w1, w2, b1, d1 : STRING;
    r1, r2, r3, lr1 : STRING;
    date1, tod1, tod2, dt1 : STRING;
END_VAR
t1 := TIME_TO_STRING(T#1s500ms);
t2 := TIME_TO_STRING(T#0s);
t3 := TIME_TO_STRING(T#2s);
t4 := TIME_TO_STRING(T#1h);
t5 := TIME_TO_STRING(T#1d2h3m4s5ms);
t6 := TIME_TO_STRING(T#1.5ms);
t7 := TIME_TO_STRING(T#3m);
t8 := TIME_TO_STRING(T#25h);
w1 := WORD_TO_STRING(16#BEEF);
w2 := WORD_TO_STRING(16#0001);
b1 := BYTE_TO_STRING(16#0F);
d1 := DWORD_TO_STRING(16#DEADBEEF);
r1 := REAL_TO_STRING(1.0E10);
r2 := REAL_TO_STRING(0.1);
r3 := REAL_TO_STRING(-3.0);
lr1 := LREAL_TO_STRING(1.0 / 3.0);
date1 := DATE_TO_STRING(D#2024-01-02);
tod1 := TOD_TO_STRING(TOD#12:34:56.5);
tod2 := TOD_TO_STRING(TOD#01:02:03);
dt1 := DT_TO_STRING(DT#2024-01-02-12:00:00);
END_PROGRAM
"""
# P_Strings.long: a literal of 125 characters, longer than a source line here may be
SRC = SRC.replace("{LONG}", "abcdefghijklmnopqrstuvwxyz" * 4 + "abcdefghijklmnopqrstu")


@pytest.fixture(scope="module")
def run():
    return run_st(SRC, scans=1)


def v(run, name):
    return run.value(name)


# ---------------------------------------------------------------- integers

def test_int_32767_plus_1_wraps_to_minus_32768(run):
    assert v(run, "P_Int.wrapInt") == -32768
    assert v(run, "P_Int.negInt") == -32768
    assert v(run, "P_Int.mulWrap") == -2


def test_every_integer_width_wraps(run):
    assert v(run, "P_Int.wrapSint") == -128
    assert v(run, "P_Int.wrapUint") == 65535
    assert v(run, "P_Int.wrapUsint") == 0
    assert v(run, "P_Int.wrapDint") == -2147483648
    assert v(run, "P_Int.wrapLint") == 9223372036854775807


def test_division_truncates_towards_zero(run):
    assert v(run, "P_Int.divNeg") == -3
    assert v(run, "P_Int.dDiv") == -3
    assert v(run, "P_Int.uDiv") == 3


def test_mod_takes_the_sign_of_the_dividend_and_mod_0_is_0(run):
    assert v(run, "P_Int.modNeg") == -1
    assert v(run, "P_Int.modByNeg") == 1
    assert v(run, "P_Int.modZero") == 0
    assert v(run, "P_Int.dMod") == -1
    assert v(run, "P_Int.dModZero") == 0
    assert v(run, "P_Int.uMod") == 2


def test_operator_precedence(run):
    assert v(run, "P_Int.prod") == 12
    assert v(run, "P_Int.pri") == 1


# ------------------------------------------------------------- conversions

def test_real_to_int_rounds_half_to_even(run):
    got = [v(run, f"P_Conv.{n}") for n in ("r25", "rm25", "r35", "r37", "r05", "r15", "rm27")]
    assert got == [2, -2, 4, 4, 0, 2, -3]
    assert v(run, "P_Conv.ld25") == 2
    assert v(run, "P_Conv.realToDint") == 4


def test_trunc_cuts_towards_zero(run):
    assert v(run, "P_Conv.tr") == -2


def test_integer_conversions_wrap_like_matiec(run):
    assert v(run, "P_Conv.intToUintU") == 65535
    assert v(run, "P_Conv.uintToInt") == -1
    assert v(run, "P_Conv.intToWord") == 0xFFFE
    assert v(run, "P_Conv.intToSint") == -56
    assert v(run, "P_Conv.intToUsint") == 255
    assert v(run, "P_Conv.dintToInt") == -31072
    assert v(run, "P_Conv.intToDint") == -1
    assert v(run, "P_Conv.wordToInt") == -32768
    assert v(run, "P_Conv.udintFromDint") == 4294967295


def test_bool_and_real_conversions(run):
    assert v(run, "P_Conv.intToReal") == 200.0
    assert v(run, "P_Conv.boolToInt") == 1
    assert v(run, "P_Conv.intToBool") is True
    assert v(run, "P_Conv.zeroToBool") is False
    assert v(run, "P_Conv.lrealToReal") == 2.5
    assert v(run, "P_Conv.realToLreal") == 2.5


def test_time_to_dint_and_dint_to_time_count_seconds(run):
    assert v(run, "P_Conv.timeToDint") == 1
    assert v(run, "P_Conv.dintToTime") == 1500 * 10**9
    assert v(run, "P_Conv.timeToReal") == 2.0


# ----------------------------------------------------------- bit strings

def test_shifts_and_rotations_on_word(run):
    assert v(run, "P_Bits.shlW") == 0x0002
    assert v(run, "P_Bits.rolW") == 0x0003
    assert v(run, "P_Bits.shrW") == 1
    assert v(run, "P_Bits.rorW") == 0xC000
    assert v(run, "P_Bits.shl16") == 0


def test_shifts_and_rotations_on_byte_and_lword(run):
    assert [v(run, f"P_Bits.{n}") for n in ("shlB", "rolB", "shrB", "rorB")] == [0x02, 0x03, 1, 0xC0]
    assert v(run, "P_Bits.shlL") == 0xFFFF_FFFF_FFFF_FFF0


def test_bitwise_operators_on_bit_strings_and_bool(run):
    assert v(run, "P_Bits.andW") == 0x0001
    assert v(run, "P_Bits.orW") == 0x8F01
    assert v(run, "P_Bits.xorW") == 0x7FFE
    assert v(run, "P_Bits.notW") == 0x7FFE
    assert v(run, "P_Bits.notDw") == 0x0F0F0F0F
    assert [v(run, f"P_Bits.{n}") for n in ("andB", "orB", "xorB", "notB")] == [False, True, False, True]


# ------------------------------------------------------ selection, numeric

def test_min_max_limit_with_two_and_three_inputs(run):
    assert v(run, "P_Select.mn") == -3 and v(run, "P_Select.mx") == 5
    assert v(run, "P_Select.mn3") == -3 and v(run, "P_Select.mx3") == 9
    assert v(run, "P_Select.lim") == 5
    assert v(run, "P_Select.limLow") == 0
    assert v(run, "P_Select.limHigh") == 6
    assert v(run, "P_Select.mxD") == 70000


def test_sel_mux_move(run):
    assert v(run, "P_Select.sel0") == 5
    assert v(run, "P_Select.sel1") == -3
    assert v(run, "P_Select.mux1") == -3
    assert v(run, "P_Select.muxOut") == 0          # selector out of range gives 0, as MATIEC
    assert v(run, "P_Select.mv") == 9


def test_abs_sqrt_expt_and_extensible_add_mul(run):
    assert v(run, "P_Select.absI") == 3
    assert v(run, "P_Select.absR") == 2.5
    assert v(run, "P_Select.sq") == 4.0
    assert v(run, "P_Select.ex") == 8.0
    assert math.isclose(v(run, "P_Select.exr"), math.sqrt(2), rel_tol=1e-6)
    assert v(run, "P_Select.add3") == 11
    assert v(run, "P_Select.mul3") == -30
    assert math.isclose(v(run, "P_Select.lnE"), 1.0, rel_tol=1e-12)
    assert v(run, "P_Select.sinZero") == 0.0 and v(run, "P_Select.cosZero") == 1.0


def test_comparison_functions(run):
    got = [v(run, f"P_Select.{n}") for n in ("gtF", "geF", "eqF", "neF", "ltF", "leF")]
    assert got == [True, True, False, True, False, True]


def test_time_arithmetic(run):
    assert v(run, "P_Time.twice") == 2 * 10**9
    assert v(run, "P_Time.quarter") == 250 * 10**6
    assert v(run, "P_Time.sum") == 1750 * 10**6
    assert v(run, "P_Time.diff") == -500 * 10**6
    assert v(run, "P_Time.later") is True
    assert v(run, "P_Time.equal") is True
    assert v(run, "P_Time.scaled") == 2500 * 10**6


# ----------------------------------------------------------------- strings

def test_concat_len_and_escapes(run):
    assert v(run, "P_Strings.t") == "hello world"
    assert v(run, "P_Strings.n") == 11
    assert v(run, "P_Strings.three") == "abc"
    assert v(run, "P_Strings.esc") == "\n\t'$"
    assert v(run, "P_Strings.nEsc") == 4
    assert v(run, "P_Strings.nEmpty") == 0


def test_left_right_mid_find(run):
    assert v(run, "P_Strings.leftS") == "hello"
    assert v(run, "P_Strings.rightS") == "world"
    assert v(run, "P_Strings.midS") == "ell"          # MID(IN, L, P): 3 characters from position 2
    assert v(run, "P_Strings.f") == 7
    # IEC: 0 when not found.  OpenPLC's MATIEC returns a length-dependent value here
    # (12 for this 11-character string, measured); portable code must not rely on it.
    assert v(run, "P_Strings.nFindNone") == 0


def test_insert_delete_replace(run):
    assert v(run, "P_Strings.ins") == "heXYllo"
    assert v(run, "P_Strings.del") == "hello"
    assert v(run, "P_Strings.rep") == "hello World"


def test_concat_truncates_at_126_characters(run):
    assert len(v(run, "P_Strings.long")) == 125
    assert v(run, "P_Strings.lenCat") == 126
    assert v(run, "P_Strings.cat126").endswith("uA")


def test_string_comparisons(run):
    # We compare whole strings.  OpenPLC's MATIEC compares only the common prefix
    # ('ab' = 'abc' is TRUE there, 'hello' < 'hello world' FALSE; measured), so
    # portable code must not compare strings that are prefixes of each other.
    assert [v(run, f"P_Strings.{n}") for n in ("eqS", "gtS", "ltS")] == [True, True, True]


def test_numbers_to_string_and_back(run):
    assert v(run, "P_Strings.fromInt") == "-42"
    assert v(run, "P_Strings.fromDint") == "123456"
    assert v(run, "P_Strings.fromBool") == "TRUE"
    assert v(run, "P_Strings.fromUint") == "65535"
    assert v(run, "P_Strings.fromSint") == "-5"
    assert v(run, "P_Strings.fromLreal") == "0.1"
    assert v(run, "P_Strings.fromReal") == "2.5"
    assert v(run, "P_Strings.toInt") == 123
    assert v(run, "P_Strings.toDint") == -70000
    assert v(run, "P_Strings.toReal") == 1.5


def test_time_to_string_uses_matiec_format(run):
    got = [v(run, f"P_ToString.t{k}") for k in range(1, 9)]
    assert got == ["T#0d0h0m1s500ms", "T#0d", "T#0d0h0m2s", "T#0d1h", "T#1d2h3m4s5ms",
                   "T#0d0h0m0s1.5ms", "T#0d0h3m", "T#1d1h"]


def test_bit_strings_to_string_are_lower_case_hex_without_padding(run):
    got = [v(run, f"P_ToString.{n}") for n in ("w1", "w2", "b1", "d1")]
    assert got == ["16#beef", "16#1", "16#f", "16#deadbeef"]


def test_reals_to_string_use_ten_significant_digits(run):
    got = [v(run, f"P_ToString.{n}") for n in ("r1", "r2", "r3", "lr1")]
    assert got == ["1e+10", "0.1000000015", "-3", "0.3333333333"]


def test_dates_and_times_of_day_to_string(run):
    got = [v(run, f"P_ToString.{n}") for n in ("date1", "tod1", "tod2", "dt1")]
    assert got == ["D#2024-01-02", "TOD#12:34:56.500000", "TOD#01:02:03", "DT#2024-01-02-12:00:00"]
