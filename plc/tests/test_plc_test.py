"""Self-tests of `plc test`: a failing assert, a test over budget and runtime faults are each reported as a
failure with their position, the other tests still run, and the exit code and JUnit XML say so."""
from __future__ import annotations

import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

FIXTURES = Path(__file__).parent / "fixtures" / "plctest"
SELFTEST = FIXTURES / "selftest.st"


def plc_test(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "plc.cli", "test", "--src", str(FIXTURES / "empty"),
           "--build-dir", str(tmp_path / "build"), *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=tmp_path)


@pytest.fixture(scope="module")
def run_all(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("plctest")
    return plc_test(tmp, str(SELFTEST), "--junit-xml", str(tmp / "report.xml")), tmp


def line_of(text: str) -> int:
    for n, line in enumerate(SELFTEST.read_text().splitlines(), 1):
        if text in line:
            return n
    raise AssertionError(text)


def test_exit_code_is_nonzero_when_a_test_fails(run_all):
    proc, _ = run_all
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "3 passed, 4 failed"


def test_failing_assert_names_file_line_expected_and_actual(run_all):
    proc, _ = run_all
    out = proc.stdout
    assert "FAIL  TEST_FailingAssert" in out
    n = line_of("AssertEqualINT(tc, 3, pocket")
    assert re.search(rf"selftest\.st:{n}:\d+: pocket after the move: expected 3, actual 2", out), out


def test_over_budget_names_the_test_and_how_far_it_got(run_all):
    out = run_all[0].stdout
    assert "FAIL  TEST_OverBudget [budget]  (25 scans, 96ms simulated)" in out
    assert "over budget: still running after 25 scans" in out


def test_division_by_zero_is_a_fault_with_position(run_all):
    out = run_all[0].stdout
    n = line_of("quotient := 100 / divisor")
    assert "FAIL  TEST_DivisionByZero [fault]  (2 scans" in out
    assert re.search(rf"selftest\.st:{n}:\d+: runtime fault in TEST_DivisionByZero: integer division by zero", out)


def test_index_out_of_bounds_is_a_fault_with_position(run_all):
    out = run_all[0].stdout
    n = line_of("table[i] := 1")
    # scan 1 writes table[3], scan 2 table[4], scan 3 table[5]: out of bounds
    assert "FAIL  TEST_IndexOutOfBounds [fault]  (3 scans" in out
    assert re.search(rf"selftest\.st:{n}:\d+: runtime fault in TEST_IndexOutOfBounds: array index out of bounds", out)


def test_other_tests_still_run_and_pass(run_all):
    out = run_all[0].stdout
    assert "PASS  TEST_PassesBeforeFailures  (3 scans, 8ms simulated)" in out
    assert "PASS  TEST_PassesAfterFailures  (6 scans, 50ms simulated)" in out
    assert "PASS  TEST_ClockJump  (2 scans, 3600004ms simulated)" in out


def test_junit_xml_has_suites_cases_and_failures(run_all):
    _, tmp = run_all
    root = ET.parse(tmp / "report.xml").getroot()
    assert root.tag == "testsuites"
    cases = root.findall("./testsuite/testcase")
    assert len(cases) == 7
    failed = {c.get("name"): c.find("failure") for c in cases if c.find("failure") is not None}
    assert set(failed) == {"TEST_FailingAssert", "TEST_OverBudget", "TEST_DivisionByZero", "TEST_IndexOutOfBounds"}
    assert "expected 3, actual 2" in failed["TEST_FailingAssert"].get("message")
    assert failed["TEST_OverBudget"].get("type") == "BUDGET"


def test_k_selects_and_x_stops_at_first_failure(tmp_path):
    proc = plc_test(tmp_path, str(SELFTEST), "-k", "passes")
    assert proc.returncode == 0, proc.stdout
    assert proc.stdout.strip().splitlines()[-1] == "2 passed, 0 failed"
    proc = plc_test(tmp_path, str(SELFTEST), "-x")
    assert proc.returncode == 1
    assert proc.stdout.strip().splitlines()[-1] == "1 passed, 1 failed, 5 skipped"


def test_a_test_that_does_not_compile_fails_loudly(tmp_path):
    bad = tmp_path / "bad.st"
    bad.write_text("FUNCTION_BLOCK TEST_Bad\nVAR_IN_OUT tc : ST_TestContext; END_VAR\nx := 1;\nEND_FUNCTION_BLOCK\n")
    proc = plc_test(tmp_path, str(bad))
    assert proc.returncode == 1
    assert "bad.st:3:1: error: undeclared variable 'x'" in proc.stderr
    assert "0 passed, 1 failed" in proc.stdout


def test_an_endless_loop_inside_a_scan_is_reported_as_a_hang(tmp_path):
    hang = tmp_path / "hang.st"
    hang.write_text("FUNCTION_BLOCK TEST_Spins\nVAR_IN_OUT tc : ST_TestContext; END_VAR\nVAR n : DINT; END_VAR\n"
                    "WHILE TRUE DO n := n + 1; END_WHILE;\nEND_FUNCTION_BLOCK\n"
                    "FUNCTION_BLOCK TEST_After\nVAR_IN_OUT tc : ST_TestContext; END_VAR\ntc.Done := TRUE;\n"
                    "END_FUNCTION_BLOCK\n")
    proc = plc_test(tmp_path, str(hang), "--timeout", "1")
    assert "FAIL  TEST_Spins [hang]" in proc.stdout
    assert "PASS  TEST_After" in proc.stdout
    assert proc.returncode == 1


def test_enum_asserts_name_the_values_and_array_helper_names_the_index(tmp_path):
    proc = plc_test(tmp_path, str(FIXTURES / "enum_array.st"))
    assert proc.returncode == 1
    out = proc.stdout
    assert "light fails: expected Green, actual Amber" in out
    assert "light passes" not in out
    assert "levels[3]: expected 3, actual 4" in out
    assert "levels[1]" not in out and "levels[2]" not in out


def test_bool_and_or_skip_the_right_operand_as_in_matiec(tmp_path):
    proc = plc_test(tmp_path, str(FIXTURES / "short_circuit.st"))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "PASS  TEST_ShortCircuit" in proc.stdout
