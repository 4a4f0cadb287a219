"""Conformance: the standard function blocks scan by scan (4 ms task, clock 0 on scan 1).

The expected series are OpenPLC's MATIEC results measured scan by scan
(docs/matiec.md, "Results our code must reproduce"): TON with PT = 20 ms
sets Q on scan 6, R_TRIG fires on the first scan, F_TRIG does not, CTU counts a
held input once, and so on.  One build for the module.
"""
from __future__ import annotations

import pytest

from harness import run_st

MS = 1_000_000
SCANS = 10

SRC = r"""
PROGRAM P_Ton
VAR
    timer : TON;
    q : BOOL;
    et : TIME;
    scan : INT;
    resetQ : BOOL;
    resetEt : TIME;
    again : TON;
END_VAR
scan := scan + 1;
timer(IN := TRUE, PT := T#20ms, Q => q, ET => et);
(* a second timer: IN TRUE on scans 1..7, FALSE on scan 8, TRUE again from scan 9 *)
again(IN := scan < 8 OR scan > 8, PT := T#8ms);
resetQ := again.Q;
resetEt := again.ET;
END_PROGRAM

PROGRAM P_Tof
VAR
    timer : TOF;
    scan : INT;
    q : BOOL;
    et : TIME;
END_VAR
scan := scan + 1;
timer(IN := scan <= 2, PT := T#8ms);     (* IN falls at scan 3, when the clock reads 8 ms *)
q := timer.Q;
et := timer.ET;
END_PROGRAM

PROGRAM P_Tp
VAR
    pulse : TP;
    scan : INT;
    q : BOOL;
    et : TIME;
END_VAR
scan := scan + 1;
pulse(IN := TRUE, PT := T#8ms);
q := pulse.Q;
et := pulse.ET;
END_PROGRAM

PROGRAM P_Edges
VAR
    rise : R_TRIG;
    fall : F_TRIG;
    fallLow : F_TRIG;
    scan : INT;
    riseQ, fallQ, fallLowQ : BOOL;
END_VAR
scan := scan + 1;
rise(CLK := TRUE);
riseQ := rise.Q;
fall(CLK := scan <= 2);           (* TRUE on scans 1-2, falls on scan 3 *)
fallQ := fall.Q;
fallLow(CLK := FALSE);             (* FALSE from the first scan *)
fallLowQ := fallLow.Q;
END_PROGRAM

PROGRAM P_Counters
VAR
    held : CTU;
    heldCv : INT;
    up : CTU;
    upCv : INT;
    upQ : BOOL;
    scan : INT;
    down : CTD;
    downCv : INT;
    downQ : BOOL;
    both : CTUD;
    bothCv : INT;
    bothQu, bothQd : BOOL;
    zero : CTD;
    zeroCv : INT;
    clamp : CTUD;
    clampCv : INT;
END_VAR
scan := scan + 1;
held(CU := TRUE, PV := 100);
heldCv := held.CV;
(* pulses on odd scans; RESET on scan 9 *)
up(CU := (scan MOD 2) = 1, R := scan = 9, PV := 3, Q => upQ, CV => upCv);
(* LD on scan 1 loads PV = 2; CD pulses on scans 3, 5, 7, 9 *)
down(CD := scan > 1 AND (scan MOD 2) = 1, LD := scan = 1, PV := 2, Q => downQ, CV => downCv);
(* count up on scans 1, 3, 5; down on scans 7, 9 *)
both(CU := scan <= 5 AND (scan MOD 2) = 1, CD := scan > 5 AND (scan MOD 2) = 1, R := FALSE, LD := FALSE,
     PV := 3, QU => bothQu, QD => bothQd, CV => bothCv);
(* CTD never loaded: stays at 0 *)
zero(CD := (scan MOD 2) = 1, LD := FALSE, PV := 5, CV => zeroCv);
(* up on scans 1, 3, 5 with PV 2 (stops at 2), down on 7, 9, 11 (stops at 0) *)
clamp(CU := scan <= 5 AND (scan MOD 2) = 1, CD := scan > 5 AND (scan MOD 2) = 1, R := FALSE, LD := FALSE,
      PV := 2, CV => clampCv);
END_PROGRAM

PROGRAM P_Bistable
VAR
    setDominant : SR;
    resetDominant : RS;
    latch : SR;
    scan : INT;
    srQ, rsQ, latchQ : BOOL;
END_VAR
scan := scan + 1;
setDominant(S1 := TRUE, R := TRUE);
srQ := setDominant.Q1;
resetDominant(S := TRUE, R1 := TRUE);
rsQ := resetDominant.Q1;
latch(S1 := scan = 2, R := scan = 5);    (* set on scan 2, holds, reset on scan 5 *)
latchQ := latch.Q1;
END_PROGRAM

PROGRAM P_Preset
VAR
    timer : TON := (PT := T#12ms);
    q : BOOL;
END_VAR
timer(IN := TRUE);
q := timer.Q;
END_PROGRAM
"""


@pytest.fixture(scope="module")
def run():
    return run_st(SRC, scans=SCANS)


def test_ton_20ms_sets_q_on_scan_6_when_the_clock_reads_20ms(run):
    assert run.series("P_Ton.q") == [False] * 5 + [True] * 5
    assert run.series("P_Ton.et") == [0, 4 * MS, 8 * MS, 12 * MS, 16 * MS] + [20 * MS] * 5


def test_ton_resets_when_in_falls_and_restarts_on_the_next_rise(run):
    q = run.series("P_Ton.resetQ")
    et = run.series("P_Ton.resetEt")
    assert q == [False, False, True, True, True, True, True, False, False, False]
    assert et[7] == 0                              # IN FALSE on scan 8
    assert et[8] == 0 and et[9] == 4 * MS          # restarted on scan 9


def test_tof_holds_q_for_pt_after_in_falls(run):
    assert run.series("P_Tof.q") == [True] * 4 + [False] * 6
    assert run.series("P_Tof.et")[2:5] == [0, 4 * MS, 8 * MS]


def test_tp_gives_one_pulse_of_pt(run):
    assert run.series("P_Tp.q") == [True, True] + [False] * 8


def test_r_trig_fires_on_the_first_scan_when_clk_is_already_true(run):
    assert run.series("P_Edges.riseQ") == [True] + [False] * 9


def test_f_trig_is_false_on_the_first_scan_and_fires_on_the_falling_edge(run):
    assert run.series("P_Edges.fallLowQ") == [False] * 10
    assert run.series("P_Edges.fallQ") == [False, False, True] + [False] * 7


def test_ctu_counts_a_held_input_once(run):
    assert run.series("P_Counters.heldCv") == [1] * 10


def test_ctu_counts_rising_edges_up_to_pv_sets_q_and_resets(run):
    # OpenPLC's library counts only while CV < PV: CV stops at 3
    assert run.series("P_Counters.upCv") == [1, 1, 2, 2, 3, 3, 3, 3, 0, 0]
    assert run.series("P_Counters.upQ") == [False] * 4 + [True] * 4 + [False] * 2


def test_ctd_loads_pv_and_counts_down_to_0(run):
    # OpenPLC's library counts down only while CV > 0
    assert run.series("P_Counters.downCv") == [2, 2, 1, 1, 0, 0, 0, 0, 0, 0]
    assert run.series("P_Counters.downQ") == [False] * 4 + [True] * 6
    assert run.series("P_Counters.zeroCv") == [0] * 10


def test_ctud_counts_both_ways_within_0_and_pv(run):
    assert run.series("P_Counters.bothCv") == [1, 1, 2, 2, 3, 3, 2, 2, 1, 1]
    assert run.series("P_Counters.bothQu") == [False] * 4 + [True] * 2 + [False] * 4
    assert run.series("P_Counters.bothQd") == [False] * 10
    assert run.series("P_Counters.clampCv") == [1, 1, 2, 2, 2, 2, 1, 1, 0, 0]


def test_sr_is_set_dominant_and_rs_reset_dominant(run):
    assert run.series("P_Bistable.srQ") == [True] * 10
    assert run.series("P_Bistable.rsQ") == [False] * 10
    assert run.series("P_Bistable.latchQ") == [False, True, True, True, False, False, False, False, False, False]


def test_fb_instance_initialiser_presets_an_input(run):
    # PT = 12 ms preset by the declaration: Q on scan 4 (clock 12 ms)
    assert run.series("P_Preset.q") == [False] * 3 + [True] * 7
