"""The conformance harness itself: sanitizers really armed, builds cached, output parsed.

A conformance test can only be trusted if undefined behaviour in the generated C
would fail it; these tests feed the driver hand-written programs with UB.
"""
from __future__ import annotations

import pytest

import harness
from harness import HarnessError, run_c, run_st

# A minimal program written against plc_abi.h by hand; BODY is spliced into run().
C_PROGRAM = r"""
#include <stdlib.h>
#include <string.h>
#include <limits.h>
#include "plc_abi.h"
static int64_t clock_ns;
static int32_t counter;
static volatile int32_t big = INT_MAX;
static plc_fault_t fault;
static const plc_task_t tasks[] = {{"T", 4000000u, 1u, 0}};
static const plc_var_t vars[] = {{"CONFIG0.COUNTER", PLC_T_DINT, 0, 0, &counter, 4, "DINT"}};
static void init(void) { counter = 0; }
static int run(uint64_t tick) { (void)tick; BODY; return 0; }
const plc_program_t plc_program = {PLC_ABI_VERSION, "CONFIG0", 4000000u, tasks, 1u, NULL, 0u, vars, 1u, 0u,
                                   init, run, &clock_ns, &fault};
"""


def test_a_clean_program_runs_and_prints_its_variables():
    run = run_c(C_PROGRAM.replace("BODY", "counter += 2"), scans=3)
    assert run.series("CONFIG0.COUNTER") == [2, 4, 6]
    assert run.base_tick_ns == 4_000_000 and run.tasks == [("T", 4_000_000, 1, 0)]


def test_signed_overflow_in_generated_code_fails_the_run():
    with pytest.raises(HarnessError, match="runtime error"):
        run_c(C_PROGRAM.replace("BODY", "counter = big + 1"), scans=1)


def test_out_of_bounds_heap_access_fails_the_run():
    body = "char *p = malloc(16); volatile size_t n = 17; if (p) { memset(p, 1, n); counter = p[0]; } free(p)"
    with pytest.raises(HarnessError, match="heap-buffer-overflow"):
        run_c(C_PROGRAM.replace("BODY", body), scans=1)


def test_builds_are_cached_by_content(monkeypatch, tmp_path):
    monkeypatch.setenv("PLC_HARNESS_CACHE", str(tmp_path))
    src = "PROGRAM Main\nVAR n : INT; END_VAR\nn := n + 1;\nEND_PROGRAM\n"
    assert run_st(src, scans=2).series("n") == [1, 2]
    built = sorted(p.name for p in tmp_path.glob("prog-*"))
    assert len(built) == 1
    assert run_st(src, scans=3).series("n") == [1, 2, 3]
    assert sorted(p.name for p in tmp_path.glob("prog-*")) == built          # reused, not rebuilt
    run_st(src.replace("+ 1", "+ 2"), scans=1)
    assert len(list(tmp_path.glob("prog-*"))) == 2


def test_a_snippet_that_does_not_compile_reports_its_diagnostics():
    with pytest.raises(HarnessError, match="undeclared variable 'y'"):
        run_st("PROGRAM Main\nVAR x : INT; END_VAR\nx := y;\nEND_PROGRAM\n")


def test_generated_configuration_names_one_instance_per_program():
    full, inst = harness.with_config("PROGRAM A_One\nVAR x : INT; END_VAR\nx := 1;\nEND_PROGRAM\n"
                                     "program b_two\nVAR y : INT; END_VAR\ny := 2;\nEND_PROGRAM\n")
    assert inst == {"A_ONE": "A_ONEINST", "B_TWO": "B_TWOINST"}
    assert "TASK task0(INTERVAL := T#4ms" in full
