"""Self-tests of `plc test`: a failing assert, a test over budget, runtime faults and a test that executed no
assert are each reported as a failure with their position, the other tests still run, and the exit code and JUnit
XML say so; a test with inputs runs once per case of its table, each case named and placed at its row."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

FIXTURES = Path(__file__).parent / "fixtures" / "plctest"
SELFTEST = FIXTURES / "selftest.st"
NO_ASSERT = FIXTURES / "noassert.st"


def plc_test(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "plc.cli", "test", "--src", str(FIXTURES / "empty"),
           "--build-dir", str(tmp_path / "build"), *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=tmp_path)


@pytest.fixture(scope="module")
def run_all(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("plctest")
    return plc_test(tmp, str(SELFTEST), "--junit-xml", str(tmp / "report.xml")), tmp


def line_in(path: Path, text: str) -> int:
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if text in line:
            return n
    raise AssertionError(text)


def line_of(text: str) -> int:
    return line_in(SELFTEST, text)


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
                    "FUNCTION_BLOCK TEST_After\nVAR_IN_OUT tc : ST_TestContext; END_VAR\n"
                    "tc.Ok := AssertEqualUDINT(tc, 1, tc.Scan, 'first scan');\ntc.Done := TRUE;\nEND_FUNCTION_BLOCK\n")
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


def test_a_test_that_executes_no_assert_fails_at_its_position(tmp_path):
    """Finishing (tc.Done) proves nothing by itself: a test that executed no assert fails, also when its asserts
    sit in a branch never taken; one executed assert is enough to pass."""
    proc = plc_test(tmp_path, str(NO_ASSERT))
    out = proc.stdout
    assert proc.returncode == 1, out + proc.stderr
    assert out.strip().splitlines()[-1] == "1 passed, 2 failed"
    assert "FAIL  TEST_ChecksNothing [no assert]  (3 scans" in out
    assert f"noassert.st:{line_in(NO_ASSERT, 'TEST_ChecksNothing')}:1: no assert was executed" in out
    assert "FAIL  TEST_AssertsOnlyInABranchNeverTaken [no assert]" in out
    assert f"noassert.st:{line_in(NO_ASSERT, 'TEST_AssertsOnlyInABranchNeverTaken')}:1: no assert was executed" in out
    assert "PASS  TEST_OneAssertIsEnough" in out


def test_a_test_that_executes_no_assert_is_a_junit_failure(tmp_path):
    report = tmp_path / "report.xml"
    plc_test(tmp_path, str(NO_ASSERT), "--junit-xml", str(report))
    cases = {c.get("name"): c for c in ET.parse(report).getroot().iter("testcase")}
    failure = cases["TEST_ChecksNothing"].find("failure")
    assert failure is not None and failure.get("type") == "NOASSERT"
    assert "no assert was executed" in failure.get("message")
    assert cases["TEST_OneAssertIsEnough"].find("failure") is None


# ------------------------------------------------------------------ parametrised tests (case tables)

POCKET_TEST = """(* a test with inputs: runs once per case of TEST_Pocket.cases.toml *)
FUNCTION_BLOCK TEST_Pocket
VAR_IN_OUT
    tc : ST_TestContext;
END_VAR
VAR_INPUT
    Side : E_Side;
    Pocket : INT;
    Limit : INT := 4;
END_VAR
tc.Ok := AssertTrue(tc, Pocket <= Limit, 'pocket within the limit');
tc.Ok := AssertTrue(tc, Side <> E_Side#Right OR Pocket > 1, 'no pocket 1 on the right');
tc.Done := TRUE;
END_FUNCTION_BLOCK
"""
SIDE_TYPE = "TYPE\n    E_Side : (Left, Right);\nEND_TYPE\n"
POCKET_CASES = """# 2 x 3 cases, then one with the limit raised
[[case]]
Side = ["Left", "E_Side#Right"]
Pocket = [1, 2, 5]

[[case]]
pocket = 6
LIMIT = 6
"""


def write_pocket_test(folder: Path, cases: str = POCKET_CASES) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "E_Side.st").write_text(SIDE_TYPE)
    (folder / "TEST_Pocket.st").write_text(POCKET_TEST)
    (folder / "TEST_Pocket.cases.toml").write_text(cases)
    return folder


def test_a_test_with_inputs_runs_once_per_case_of_its_table(tmp_path):
    folder = write_pocket_test(tmp_path / "tests")
    proc = plc_test(tmp_path, str(folder), "--junit-xml", str(tmp_path / "report.xml"))
    out = proc.stdout
    ran = re.findall(r"^(PASS|FAIL)  (\S+)", out, flags=re.M)
    assert [name for _, name in ran] == [
        "TEST_Pocket[Side=Left,Pocket=1]", "TEST_Pocket[Side=Left,Pocket=2]", "TEST_Pocket[Side=Left,Pocket=5]",
        "TEST_Pocket[Side=E_Side#Right,Pocket=1]", "TEST_Pocket[Side=E_Side#Right,Pocket=2]",
        "TEST_Pocket[Side=E_Side#Right,Pocket=5]", "TEST_Pocket[Pocket=6,Limit=6]"]
    failed = {name for verdict, name in ran if verdict == "FAIL"}
    assert failed == {"TEST_Pocket[Side=Left,Pocket=5]", "TEST_Pocket[Side=E_Side#Right,Pocket=1]",
                      "TEST_Pocket[Side=E_Side#Right,Pocket=5]"}, out
    assert out.strip().splitlines()[-1] == "4 passed, 3 failed"
    assert proc.returncode == 1
    # a failing case names the assert in the test body and the row of the table that made the case
    block = out.split("FAIL  TEST_Pocket[Side=E_Side#Right,Pocket=1]")[1].split("\n")[1:3]
    n = line_in(folder / "TEST_Pocket.st", "no pocket 1 on the right")
    assert re.search(rf"TEST_Pocket\.st:{n}:\d+: no pocket 1 on the right: expected TRUE, actual FALSE", block[0])
    assert "TEST_Pocket.cases.toml:2:1: the row of this case of TEST_Pocket" in block[1]
    cases = {c.get("name"): c for c in ET.parse(tmp_path / "report.xml").getroot().iter("testcase")}
    assert len(cases) == 7
    row = cases["TEST_Pocket[Pocket=6,Limit=6]"]
    assert row.get("file").endswith("TEST_Pocket.cases.toml") and row.get("line") == "6"


def test_k_selects_cases_by_their_name(tmp_path):
    folder = write_pocket_test(tmp_path / "tests")
    proc = plc_test(tmp_path, str(folder), "-k", "Pocket=2]")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "2 passed, 0 failed"


def test_a_case_table_is_read_beside_a_test_file_given_alone(tmp_path):
    folder = write_pocket_test(tmp_path / "tests", "[[case]]\nPocket = 3\n")
    proc = plc_test(tmp_path, str(folder / "E_Side.st"), str(folder / "TEST_Pocket.st"))
    assert "PASS  TEST_Pocket[Pocket=3]" in proc.stdout, proc.stdout + proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "1 passed, 0 failed"


def test_a_wrong_table_is_reported_at_its_rows_and_nothing_runs(tmp_path):
    folder = write_pocket_test(tmp_path / "tests", "[[case]]\nPockte = [1, 2]\n\n[[case]]\n"
                                                   "Pocket = [1, 'T#5s; x']\n")
    proc = plc_test(tmp_path, str(folder))
    err = proc.stderr
    assert proc.returncode == 1
    assert "TEST_Pocket.cases.toml:2:1: error: TEST_Pocket has no input 'Pockte'" in err, err
    assert "did you mean 'Pocket'?" in err
    assert "TEST_Pocket.cases.toml:5:14: error: Pocket: 'T#5s; x' is not one ST literal" in err
    assert proc.stdout.strip().splitlines()[-1] == "0 passed, 1 failed"


def test_a_value_of_the_wrong_type_is_reported_at_its_row(tmp_path):
    folder = write_pocket_test(tmp_path / "tests", "[[case]]\nPocket = 'T#5s'\n")
    proc = plc_test(tmp_path, str(folder))
    assert proc.returncode == 1
    assert re.search(r"TEST_Pocket\.cases\.toml:2:1: error: case TEST_Pocket\[Pocket=T#5s\]: ", proc.stderr), \
        proc.stderr


def test_a_test_with_inputs_and_no_table_does_not_compile(tmp_path):
    folder = write_pocket_test(tmp_path / "tests")
    (folder / "TEST_Pocket.cases.toml").unlink()
    proc = plc_test(tmp_path, str(folder))
    assert proc.returncode == 1
    assert "TEST_Pocket.st:2:1: error: TEST_Pocket has inputs but no case table" in proc.stderr, proc.stderr
    assert "TEST_Pocket.cases.toml" in proc.stderr


def test_a_table_without_its_test_is_an_error(tmp_path):
    folder = tmp_path / "tests"
    folder.mkdir()
    (folder / "TEST_Gone.cases.toml").write_text("[[case]]\nPocket = 1\n")
    (folder / "TEST_Other.st").write_text("FUNCTION_BLOCK TEST_Other\nVAR_IN_OUT tc : ST_TestContext; END_VAR\n"
                                          "tc.Ok := AssertTrue(tc, TRUE, 'x');\ntc.Done := TRUE;\n"
                                          "END_FUNCTION_BLOCK\n")
    proc = plc_test(tmp_path, str(folder))
    assert proc.returncode == 1
    assert "TEST_Gone.cases.toml:1:1: error: no TEST_Gone.st beside this table" in proc.stderr, proc.stderr


def test_c_that_the_c_compiler_rejects_in_the_test_build_is_an_internal_error_exit_3(tmp_path):
    """The test build's C comes from sources that checked clean: the C compiler refusing it is plc's bug (exit 3,
    as plc build), with the C and the compiler's output kept; not a user error (exit 2)."""
    fake_cc = tmp_path / "fake-cc"
    fake_cc.write_text("#!/bin/sh\necho 'tests.c:9:1: error: the fake compiler refuses this' >&2\nexit 1\n")
    fake_cc.chmod(0o755)
    cmd = [sys.executable, "-m", "plc.cli", "test", "--src", str(FIXTURES / "empty"),
           "--build-dir", str(tmp_path / "build"), str(SELFTEST)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=tmp_path,
                          env={**os.environ, "CC": str(fake_cc)})
    assert proc.returncode == 3, proc.stderr
    assert "internal compiler error: the C compiler rejected the C generated" in proc.stderr
    assert "tests.c:9:1: error: the fake compiler refuses this" in proc.stderr
    assert "bug of the compiler, not of your program" in proc.stderr and "Traceback" not in proc.stderr
    (log,) = (tmp_path / "build" / "c").glob("*.cc.log")       # the first unit refused, of one per source file
    assert log.read_text().startswith(f"$ {fake_cc} ") and log.with_suffix("").with_suffix(".c").exists()
    assert not list((tmp_path / "build").glob("*/tests"))
