"""The C unit tests of the runtime (tests/c_unit/): the retain store, variable paths and the I/O image, each test
linking the runtime's translation units it tests directly, with no Modbus server and no program process.

Every case of a C test (its `cases[]` table, check.h) is a pytest case here. The binaries are built with the
system compiler by tests/c_unit/Makefile, plain, or with AddressSanitizer + UndefinedBehaviorSanitizer when
PLC_RUNTIME_SANITIZE=1 (scripts/test runs the runtime suites both ways), and each runs once, all its cases in
one process; a sanitizer report, a crash or a case the binary never ran fails here with the binary's output.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import pytest

import rt_harness as h

C_UNIT = Path(__file__).resolve().parent / "c_unit"
SUFFIX = "-asan" if h.SANITIZE else ""


def declared_cases(test_c: Path) -> list[str]:
    """The cases a C test lists in its table (`CASE(name)` entries); the binary's --list is checked against it."""
    return re.findall(r"^\s*CASE\((\w+)\),?\s*$", test_c.read_text(), re.MULTILINE)


SUITES = {p.stem.removeprefix("test_"): declared_cases(p) for p in sorted(C_UNIT.glob("test_*.c"))}


@dataclass
class Result:
    """One C case as its binary reported it: 'ok', 'FAIL' or None (it started and never ended), and the
    lines it printed (its failed checks)."""
    status: str | None = None
    lines: list[str] = field(default_factory=list)


@dataclass
class Run:
    returncode: int
    stdout: str
    stderr: str
    cases: dict[str, Result]
    listed: list[str]


def parse(stdout: str) -> dict[str, Result]:
    """check.h's output: `case NAME`, the messages of its failed checks, then `ok NAME (...)` or `FAIL NAME (...)`."""
    cases: dict[str, Result] = {}
    current: Result | None = None
    for line in stdout.splitlines():
        if m := re.fullmatch(r"case (\w+)", line):
            current = cases.setdefault(m.group(1), Result())
        elif (m := re.fullmatch(r"(ok|FAIL) (\w+)( .*)?", line)) and m.group(2) in cases:
            cases[m.group(2)].status = m.group(1)
            current = None
        elif current is not None:
            current.lines.append(line)
    return cases


def scratch_root(fallback: Path) -> Path:
    """Where the retain cases write their files: memory (/dev/shm) when the machine has it, else `fallback`.
    ext4 flushes a file renamed over another at once (auto_da_alloc), about 17 ms a save on the loaded test VM
    against 0.5 ms in memory, and the torn-file case saves 228 times; what the cases check (the calls, their
    order, the bytes) is the same on either."""
    shm = Path("/dev/shm")
    if shm.is_dir() and os.access(shm, os.W_OK):
        return Path(tempfile.mkdtemp(prefix="atc-c-unit-", dir=shm))
    return fallback


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Run]:
    """Every C test built (one make for all) and run once."""
    build = tmp_path_factory.mktemp("c_unit_build")
    targets = [str(build / f"test_{name}{SUFFIX}") for name in SUITES]
    made = subprocess.run(["make", "-s", "-C", str(C_UNIT), f"BUILD={build}", "-j2", *targets],
                          capture_output=True, text=True, timeout=600 * h.SLOW)
    assert made.returncode == 0, f"building the C unit tests failed:\n{made.stdout}{made.stderr}"
    scratch = scratch_root(tmp_path_factory.mktemp("c_unit_files"))
    env = {**os.environ, **h.SANITIZER_ENV, "TMPDIR": str(scratch)}
    out: dict[str, Run] = {}
    try:
        for name in SUITES:
            binary = build / f"test_{name}{SUFFIX}"
            listed = subprocess.run([str(binary), "--list"], capture_output=True, text=True, env=env,
                                    timeout=60 * h.SLOW).stdout.split()
            # the time-out only bounds a hang: the slowest suite takes about 4 s on a loaded machine, ASan included
            done = subprocess.run([str(binary)], capture_output=True, text=True, env=env, timeout=300 * h.SLOW)
            out[name] = Run(done.returncode, done.stdout, done.stderr, parse(done.stdout), listed)
    finally:
        if scratch.parent == Path("/dev/shm"):
            shutil.rmtree(scratch, ignore_errors=True)
    return out


def tail(text: str, lines: int = 40) -> str:
    return "\n".join(text.splitlines()[-lines:])


CASES = [(suite, case) for suite, names in SUITES.items() for case in names]


@pytest.mark.parametrize("suite, case", CASES, ids=[f"{s}.{c}" for s, c in CASES])
def test_c_case(runs, suite, case):
    run = runs[suite]
    result = run.cases.get(case)
    assert result is not None, (f"test_{suite} never started {case} (exit status {run.returncode}):\n"
                                f"{tail(run.stdout)}\n{tail(run.stderr)}")
    assert result.status is not None, (f"test_{suite} stopped inside {case} (exit status {run.returncode}):\n"
                                       + "\n".join(result.lines) + f"\n{tail(run.stderr)}")
    assert result.status == "ok", f"{case}:\n" + "\n".join(result.lines)


@pytest.mark.parametrize("suite", list(SUITES))
def test_c_binary_ran_every_declared_case_and_exited_cleanly(runs, suite):
    """Nothing is left out (the cases pytest collected are those the binary runs) and nothing is reported after
    the last case (a leak found at exit, a sanitizer report that did not stop the run)."""
    run = runs[suite]
    assert SUITES[suite], f"test_{suite}.c declares no case"
    assert run.listed == SUITES[suite], "the binary's --list differs from the CASE(...) table read here"
    assert list(run.cases) == SUITES[suite]
    assert run.returncode == 0, f"exit status {run.returncode}:\n{tail(run.stdout, 5)}\n{tail(run.stderr)}"
    assert re.search(r"ERROR: \w+Sanitizer|runtime error:", run.stderr) is None, tail(run.stderr)
    assert run.stdout.rstrip().endswith(f"{len(SUITES[suite])} cases, 0 failed")
