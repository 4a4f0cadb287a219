"""The one scan core (native/runtime/scan_core.c): input latch -> forced values -> tasks due -> output publication.

ST programs run through the same core as the soft-PLC runtime and `plc test` (tests/scan_driver.c links it, with a
simulated clock and direct I/O), so these tests prove what the runtime does at the scan's edges: an input is read once
per scan, outputs reach the world only when the scan ends, each task runs on its own ticks, a stopped program's coils
go FALSE, forced values act after the latch and before the publication.  The last test checks that every host really
goes through the core.
"""
from __future__ import annotations

import pytest

from code_rules import c_assignments, c_calls, c_tokens
from harness import SCAN_CORE_C, run_st
from plc.resources import RUNTIME_SRC, STDLIB

ECHO = """
PROGRAM Main
VAR
    start AT %IX0.0 : BOOL;     (* the input under test *)
    seen : BOOL;                (* what the program read of it this scan *)
    seenLate : BOOL;            (* read again at the end of the body *)
END_VAR
seen := start;
seenLate := start;
END_PROGRAM
"""


def test_input_changed_mid_scan_is_seen_at_the_next_latch():
    run = run_st(ECHO, scans=4, mid_scan={2: {"%IX0.0": 1}})
    assert run.series("Main.seen") == [False, False, True, True]
    assert run.series("Main.seenLate") == [False, False, True, True]
    assert run.image[1]["%IX0.0"] is True, "the world did change the image during scan 2"


def test_input_changed_before_the_latch_is_seen_in_that_scan():
    run = run_st(ECHO, scans=3, before_latch={2: {"%IX0.0": 1}, 3: {"%IX0.0": 0}})
    assert run.series("Main.seen") == [False, True, False]


PUBLISH = """
PROGRAM Main
VAR
    lamp AT %QX0.0 : BOOL;      (* output switched on from scan 2 *)
    count AT %QW3 : INT;        (* scans run, published as a word *)
    total AT %MD1 : DINT;       (* a memory double word *)
END_VAR
count := count + 1;
lamp := count >= 2;
total := INT_TO_DINT(count) * 100000;
END_PROGRAM
"""


def test_outputs_are_published_only_when_the_scan_ends():
    run = run_st(PUBLISH, scans=3)
    assert run.series("Main.lamp") == [False, True, True]
    # between the tasks and the publication the image still holds the previous scan's outputs
    assert [m["%QX0.0"] for m in run.mid_image] == [False, False, True]
    assert [m["%QW3"] for m in run.mid_image] == [0, 1, 2]
    assert [m["%MD1"] for m in run.mid_image] == [0, 100000, 200000]
    assert [i["%QX0.0"] for i in run.image] == [False, True, True]
    assert [i["%QW3"] for i in run.image] == [1, 2, 3]
    assert [i["%MD1"] for i in run.image] == [100000, 200000, 300000]


def test_a_value_the_world_writes_into_an_output_reaches_the_program():
    # a host write (Modbus) lands in the image between scans; the latch hands it to the program
    run = run_st(PUBLISH, scans=3, before_latch={3: {"%QW3": 40}})
    assert run.series("Main.count") == [1, 2, 41]


TWO_TASKS = """
PROGRAM Fast
VAR
    runs AT %QW0 : INT;         (* runs of the fast task *)
END_VAR
runs := runs + 1;
END_PROGRAM

PROGRAM Slow
VAR
    runs AT %QW1 : INT;         (* runs of the slow task *)
    fastSeen : INT;             (* the fast program's output as latched at the start of the scan *)
    fastIn AT %IW1 : INT;       (* wired back from %QW0 by the test's world *)
END_VAR
runs := runs + 1;
fastSeen := fastIn;
END_PROGRAM

CONFIGURATION Config0
    RESOURCE Res0 ON PLC
        TASK FastTask(INTERVAL := T#4ms, PRIORITY := 1);
        TASK SlowTask(INTERVAL := T#12ms, PRIORITY := 2);
        PROGRAM FastInst WITH FastTask : Fast;
        PROGRAM SlowInst WITH SlowTask : Slow;
    END_RESOURCE
END_CONFIGURATION
"""


def test_a_slower_task_runs_on_its_ticks():
    run = run_st(TWO_TASKS, scans=7)
    assert run.base_tick_ns == 4_000_000
    assert [t[:3] for t in run.tasks] == [("FASTTASK", 4_000_000, 1), ("SLOWTASK", 12_000_000, 3)]
    assert run.series("CONFIG0.RES0.FASTINST.RUNS") == [1, 2, 3, 4, 5, 6, 7]
    # ticks 0, 3 and 6 of the 4 ms base tick
    assert run.series("CONFIG0.RES0.SLOWINST.RUNS") == [1, 1, 1, 2, 2, 2, 3]
    assert [i["%QW1"] for i in run.image] == [1, 1, 1, 2, 2, 2, 3]


def test_a_slow_task_sees_inputs_latched_at_the_start_of_its_scan():
    # the world feeds %IW1 before scans 3 and 4; the slow task runs on scans 1, 4 and 7 only
    run = run_st(TWO_TASKS, scans=7, before_latch={3: {"%IW1": 30}, 4: {"%IW1": 40}, 6: {"%IW1": 60}})
    assert run.series("CONFIG0.RES0.SLOWINST.FASTSEEN") == [0, 0, 0, 40, 40, 40, 60]


FAULTING = """
PROGRAM Main
VAR
    lamp AT %QX0.0 : BOOL := TRUE;   (* a coil on until the program stops *)
    word AT %QW2 : INT := 7;         (* a word: keeps its last value when the program stops *)
    divisor : INT := 2;
    n : INT;
    q : INT;
END_VAR
n := n + 1;
divisor := divisor - 1;
q := 10 / divisor;
word := word + 1;
END_PROGRAM
"""


def test_a_stopped_program_has_its_coils_cleared_at_publication():
    run = run_st(FAULTING, scans=3)
    assert run.rcs == [0, 1, 1]
    assert run.fault is not None and run.fault.kind == 1
    assert [i["%QX0.0"] for i in run.image] == [True, False, False]
    assert [i["%QW2"] for i in run.image] == [8, 8, 8]
    assert run.series("Main.n") == [1, 2, 2], "the stopped program does not run again"


SHARED_INPUT = """
PROGRAM First
VAR
    start AT %IX0.0 : BOOL;     (* the same input ... *)
    seen : BOOL;
END_VAR
seen := start;
END_PROGRAM

PROGRAM Second
VAR
    go AT %IX0.0 : BOOL;        (* ... read by a second program *)
    seen : BOOL;
END_VAR
seen := go;
END_PROGRAM
"""


def test_programs_that_locate_one_input_both_see_it():
    run = run_st(SHARED_INPUT, scans=2, before_latch={2: {"%IX0.0": 1}})
    assert run.series("First.seen") == [False, True]
    assert run.series("Second.seen") == [False, True]


FORCE = """
PROGRAM Main
VAR
    start AT %IX0.0 : BOOL;     (* an input the test forces TRUE *)
    lamp AT %QX0.0 : BOOL;      (* an output the program switches on and the test forces FALSE *)
    seen : BOOL;                (* start as the program read it *)
    lampInBody : BOOL;          (* lamp as the body left it *)
END_VAR
seen := start;
lamp := TRUE;
lampInBody := lamp;
END_PROGRAM
"""


def test_forcing_hooks_act_after_the_latch_and_before_the_publication():
    # the test driver forces through the core's hooks (after_inputs, before_outputs), as the HMI will
    run = run_st(FORCE, scans=3, forced={"%IX0.0": 1, "%QX0.0": 0})
    assert run.series("Main.seen") == [True, True, True], "a forced input is what the program reads"
    assert [i["%IX0.0"] for i in run.image] == [False, False, False], "the world's input is left as it is"
    assert run.series("Main.lampInBody") == [True, True, True], "the program still writes its output"
    assert [i["%QX0.0"] for i in run.image] == [False, False, False], "the forced value reaches the world"
    assert run.done == [1, 2, 3], "scan_done closes every scan, once"


def test_without_forcing_the_hooks_change_nothing():
    run = run_st(FORCE, scans=2)
    assert run.series("Main.seen") == [False, False]
    assert [i["%QX0.0"] for i in run.image] == [True, True]
    assert run.done == [1, 2]


# --------------------------------------------------------------- one core, every host

@pytest.mark.parametrize("host", ["runtime", "plc test", "scan driver"])
def test_every_host_runs_the_program_through_the_scan_core(host):
    """C tokens (code_rules.c_tokens: comments dropped, literals whole): one call of plc_scan_step, and the host
    never sets the program clock itself (the core writes *clock_ns)."""
    from harness import DRIVER_C
    source = {"runtime": RUNTIME_SRC / "scan.c", "plc test": STDLIB / "test_main.c", "scan driver": DRIVER_C}[host]
    assert host_breaks(source.read_text(), source.name) == []
    assert SCAN_CORE_C.exists()


def host_breaks(text: str, name: str) -> list[str]:
    """How a host's C source breaks the one-core rule: not exactly one call of plc_scan_step (the host hands run(),
    or the test body, to the core; it never latches or publishes on its own), or an assignment to clock_ns."""
    tokens = c_tokens(text, name)
    calls = c_calls(tokens, "plc_scan_step")
    breaks = [] if len(calls) == 1 else [f"{name}: {len(calls)} calls of plc_scan_step (lines {calls})"]
    return breaks + [f"{name}:{line}: sets the program clock itself" for line in c_assignments(tokens, "clock_ns")]


def test_the_one_core_rule_flags_a_host_that_scans_or_clocks_on_its_own():
    one_call = ("/* plc_scan_step(&core, 0) ... *clock_ns = 0; in a comment */\n"
                "int plc_scan_step(plc_scan_t *s, int64_t now);\n"
                'static const char *what = "plc_scan_step(";\n'
                "void loop(void) { for (;;) { int rc = plc_scan_step(&core, now); if (rc) break; } }\n")
    assert host_breaks(one_call, "ok.c") == []
    assert host_breaks(one_call.replace("if (rc) break;", "if (rc) plc_scan_step(&core, now);"), "twice.c") == \
        ["twice.c: 2 calls of plc_scan_step (lines [4, 4])"]
    assert host_breaks("void f(void) {}\n", "none.c") == ["none.c: 0 calls of plc_scan_step (lines [])"]
    clocked = one_call + "void tick(void) { *core.clock_ns = 5; }\nvoid later(void) { clock_ns++; }\n"
    assert host_breaks(clocked, "clock.c") == ["clock.c:5: sets the program clock itself",
                                               "clock.c:6: sets the program clock itself"]
