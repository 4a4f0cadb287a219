"""Conformance: CONFIGURATION/RESOURCE/TASK/PROGRAM WITH, globals, and every VAR section.

Two tasks of 4 ms and 10 ms give a 2 ms base tick, the tasks running on every
2nd and 5th tick and both on tick 0; programs run in declaration order whatever
their PRIORITY (OpenPLC's MATIEC, measured).  VAR_GLOBAL at configuration and
resource level with VAR_EXTERNAL in programs and FBs, CONSTANT, RETAIN and
located variables, as the generated tables describe them to a host.
"""
from __future__ import annotations

import pytest

from harness import run_st

MS = 1_000_000

TASKS = r"""
PROGRAM P_Slow
VAR_EXTERNAL
    trace : DINT;
    slowRuns : INT;
END_VAR
slowRuns := slowRuns + 1;
trace := trace * 10 + 2;
END_PROGRAM

PROGRAM P_Fast
VAR_EXTERNAL
    trace : DINT;
    fastRuns : INT;
END_VAR
fastRuns := fastRuns + 1;
trace := trace * 10 + 1;
END_PROGRAM

CONFIGURATION Cell
    VAR_GLOBAL
        trace : DINT;
    END_VAR
    RESOURCE Cpu ON PLC
        VAR_GLOBAL
            slowRuns : INT;
            fastRuns : INT;
        END_VAR
        TASK fast(INTERVAL := T#4ms, PRIORITY := 0);
        TASK slow(INTERVAL := T#10ms, PRIORITY := 5);
        (* declared first, so it runs first in a tick both tasks share, despite its priority *)
        PROGRAM slowInst WITH slow : P_Slow;
        PROGRAM fastInst WITH fast : P_Fast;
    END_RESOURCE
END_CONFIGURATION
"""


def test_two_tasks_4ms_and_10ms_give_a_2ms_base_tick():
    run = run_st(TASKS, scans=11)
    assert run.base_tick_ns == 2 * MS
    assert [(t[0], t[1], t[2]) for t in run.tasks] == [("FAST", 4 * MS, 2), ("SLOW", 10 * MS, 5)]
    # counters after each tick 0..10
    fast = run.series("CELL.FASTRUNS")
    slow = run.series("CELL.SLOWRUNS")
    assert fast == [1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6]          # ticks 0, 2, 4, 6, 8, 10
    assert slow == [1, 1, 1, 1, 1, 2, 2, 2, 2, 2, 3]          # ticks 0, 5, 10


def test_programs_run_in_declaration_order_not_priority_order():
    run = run_st(TASKS, scans=11)
    trace = run.series("CELL.TRACE")
    assert trace[0] == 21                  # tick 0: slowInst (2) then fastInst (1)
    assert trace[2] == 211                 # tick 2: fast only
    assert trace[10] == 211121121          # tick 10: slow, then fast again


EVENTS = r"""
PROGRAM P_Low
VAR_EXTERNAL
    trace : DINT;
END_VAR
trace := trace * 10 + 1;
END_PROGRAM

PROGRAM P_High
VAR_EXTERNAL
    trace : DINT;
END_VAR
trace := trace * 10 + 2;
END_PROGRAM

PROGRAM P_Trigger
VAR_EXTERNAL
    trig : BOOL;
END_VAR
VAR
    n : INT;
END_VAR
n := n + 1;
trig := (n MOD 3) = 0;            (* TRUE on scans 3, 6, 9 *)
END_PROGRAM

PROGRAM P_OnEvent
VAR_EXTERNAL
    events : DINT;
END_VAR
events := events + 1;
END_PROGRAM

CONFIGURATION Config0
    VAR_GLOBAL
        trace : DINT;
        trig : BOOL;
        events : DINT;
    END_VAR
    RESOURCE Res0 ON PLC
        TASK lowPrio(INTERVAL := T#4ms, PRIORITY := 5);
        TASK highPrio(INTERVAL := T#4ms, PRIORITY := 0);
        TASK onTrig(SINGLE := trig, PRIORITY := 1);
        PROGRAM lowInst WITH lowPrio : P_Low;
        PROGRAM highInst WITH highPrio : P_High;
        PROGRAM trigInst WITH highPrio : P_Trigger;
        PROGRAM eventInst WITH onTrig : P_OnEvent;
    END_RESOURCE
END_CONFIGURATION
"""


def test_priority_does_not_change_the_order_and_single_runs_once_per_rising_edge():
    run = run_st(EVENTS, scans=10)
    assert run.base_tick_ns == 4 * MS
    assert run.value("CONFIG0.TRACE", 1) == 12           # lowInst (priority 5) still runs first
    # trig is set by a program on scans 3, 6, 9; the SINGLE task samples it at the start of the
    # next tick, before any program, so its program runs on scans 4, 7 and 10
    assert run.series("CONFIG0.EVENTS") == [0, 0, 0, 1, 1, 1, 2, 2, 2, 3]


GLOBALS = r"""
TYPE
    ST_Pair : STRUCT
        a : INT;
        b : DINT := 7;
    END_STRUCT;
END_TYPE

FUNCTION_BLOCK FB_UsesGlobals
VAR_EXTERNAL
    shared : DINT;
    pair : ST_Pair;
END_VAR
VAR_EXTERNAL CONSTANT
    limitTools : INT;
END_VAR
VAR_OUTPUT
    seenLimit : INT;
END_VAR
shared := shared + 100;
pair.a := pair.a + 1;
seenLimit := limitTools;
END_FUNCTION_BLOCK

PROGRAM P_Main
VAR_EXTERNAL
    shared : DINT;
    resourceLevel : INT;
    outWord : WORD;
END_VAR
VAR_EXTERNAL CONSTANT
    limitTools : INT;
END_VAR
VAR
    user : FB_UsesGlobals;
    limitSeen, limitSeenFb : INT;
    arr : ARRAY[1..limitTools] OF INT;
    arrLen : DINT;
END_VAR
VAR RETAIN
    kept : DINT := 5;
END_VAR
VAR CONSTANT
    k : INT := 3;
END_VAR
VAR
    motor AT %QX0.1 : BOOL;
    speed AT %QW3 : INT;
    level AT %IW2 : INT;
    setpoint AT %MD2 : DINT;
    wideMem AT %ML1 : LINT;
    inByte AT %IB4 : BYTE;
END_VAR
VAR_TEMP
    scratch : INT;
END_VAR
shared := shared + 1;
resourceLevel := resourceLevel + k;
user();
limitSeen := limitTools;
limitSeenFb := user.seenLimit;
kept := kept + 1;
scratch := scratch + 1;
motor := NOT motor;
speed := speed + scratch;
setpoint := setpoint + INT_TO_DINT(level) + 2;
wideMem := 16#1_0000_0000;
outWord := INT_TO_WORD(speed);
arrLen := UPPER_BOUND_OF_ARR(arr);
END_PROGRAM

FUNCTION UPPER_BOUND_OF_ARR : DINT
VAR_IN_OUT
    a : ARRAY[1..12] OF INT;
END_VAR
UPPER_BOUND_OF_ARR := 12;
a[12] := 12;
END_FUNCTION

CONFIGURATION Config0
    VAR_GLOBAL
        shared : DINT := 1000;
        pair : ST_Pair;
    END_VAR
    VAR_GLOBAL CONSTANT
        limitTools : INT := 12;
    END_VAR
    VAR_GLOBAL
        outWord AT %QW10 : WORD;
    END_VAR
    RESOURCE Res0 ON PLC
        VAR_GLOBAL RETAIN
            resourceLevel : INT;
        END_VAR
        TASK main(INTERVAL := T#20ms, PRIORITY := 1);
        PROGRAM mainInst WITH main : P_Main;
    END_RESOURCE
END_CONFIGURATION
"""


@pytest.fixture(scope="module")
def glob():
    return run_st(GLOBALS, scans=3)


def test_var_external_reaches_configuration_and_resource_globals(glob):
    assert glob.series("CONFIG0.SHARED") == [1101, 1202, 1303]
    assert glob.series("CONFIG0.RESOURCELEVEL") == [3, 6, 9]
    pair = glob.value("CONFIG0.PAIR")
    assert int.from_bytes(pair[:2], "little", signed=True) == 3      # a, written by the FB through VAR_EXTERNAL
    assert int.from_bytes(pair[4:8], "little", signed=True) == 7     # b keeps its TYPE initialiser


def test_global_constant_read_through_var_external_constant(glob):
    assert glob.value("CONFIG0.RES0.MAININST.LIMITSEEN") == 12
    assert glob.value("CONFIG0.RES0.MAININST.LIMITSEENFB") == 12
    assert glob.var_table["CONFIG0.LIMITTOOLS"].constant is True
    # an array bounded by the global constant has 12 elements
    assert len(glob.value("CONFIG0.RES0.MAININST.ARR")) == 12 * 2
    assert glob.value("CONFIG0.RES0.MAININST.ARRLEN") == 12


def test_retain_and_constant_flags_in_the_variable_table(glob):
    vt = glob.var_table
    assert vt["CONFIG0.RES0.MAININST.KEPT"].retain is True
    assert vt["CONFIG0.RESOURCELEVEL"].retain is True
    assert vt["CONFIG0.RES0.MAININST.K"].constant is True
    assert vt["CONFIG0.RES0.MAININST.LIMITSEEN"].retain is False
    assert glob.series("CONFIG0.RES0.MAININST.KEPT") == [6, 7, 8]


def test_var_temp_is_reinitialised_every_scan(glob):
    # speed accumulates scratch, which is 1 on every scan
    assert glob.series("CONFIG0.RES0.MAININST.SPEED") == [1, 2, 3]


def test_located_variables_are_listed_for_the_host_and_work_unbound(glob):
    loc = glob.located
    motor = loc["CONFIG0.RES0.MAININST.MOTOR"]
    assert (motor.address, motor.area, motor.size, motor.index, motor.bit) == ("%QX0.1", "Q", "X", 0, 1)
    speed = loc["CONFIG0.RES0.MAININST.SPEED"]
    assert (speed.area, speed.size, speed.index) == ("Q", "W", 3)
    assert (loc["CONFIG0.RES0.MAININST.LEVEL"].area, loc["CONFIG0.RES0.MAININST.LEVEL"].index) == ("I", 2)
    assert (loc["CONFIG0.RES0.MAININST.SETPOINT"].size, loc["CONFIG0.RES0.MAININST.SETPOINT"].index) == ("D", 2)
    assert (loc["CONFIG0.RES0.MAININST.WIDEMEM"].size, loc["CONFIG0.RES0.MAININST.WIDEMEM"].index) == ("L", 1)
    assert loc["CONFIG0.RES0.MAININST.INBYTE"].size == "B"
    assert loc["CONFIG0.OUTWORD"].index == 10
    # unbound, they live in private storage and behave like ordinary variables
    assert glob.series("CONFIG0.RES0.MAININST.MOTOR") == [True, False, True]
    assert glob.series("CONFIG0.RES0.MAININST.SETPOINT") == [2, 4, 6]
    assert glob.value("CONFIG0.RES0.MAININST.WIDEMEM") == 1 << 32
    assert glob.series("CONFIG0.OUTWORD") == [1, 2, 3]


def test_task_interval_of_one_task_is_the_base_tick(glob):
    assert glob.base_tick_ns == 20 * MS
    assert glob.tasks == [("MAIN", 20 * MS, 1, 1)]
