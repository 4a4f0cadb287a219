"""`plc test`: scan-cycle unit tests written in ST.

A test is a FUNCTION_BLOCK whose name starts with TEST_ and that has a
VAR_IN_OUT of type ST_TestContext.  `plc test` compiles st_src/ and the test
files once into one native binary (the generated C plus stdlib/test_main.c and
the runtime's scan core), runs each test on a fresh instance with a simulated
clock, and reports.  A test passes when it finishes (tc.Done) with at least one
assert executed and none failed.  A test with VAR_INPUTs runs once per case of
its table (testcases.py).
"""
from __future__ import annotations

import argparse
import fnmatch
import os
import shlex
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from . import buildcache, testcases
from .codegen import generate_units
from .driver import (INCLUDE, STDLIB, CompileResult, UserError, cc, compile_sources, compile_units, content_hash,
                     deep_recursion, print_diagnostics)
from .project import Preflight, add_view_options, beside_preflight, project_root
from .resources import RUNTIME_SRC

# The scan core the runtime uses: `plc test` runs every scan through it.
SCAN_CORE = (RUNTIME_SRC / "scan_core.c", RUNTIME_SRC / "scan_core.h")

DEFAULT_TIMEOUT_S = 20

# How a status other than PASS/FAIL is tagged after the test's name.
STATUS_TAGS = {"NOASSERT": "no assert", "BUDGET": "budget", "HANG": "hang", "FAULT": "fault"}


@dataclass
class TestResult:
    name: str
    file: str
    line: int
    col: int = 1
    template: str | None = None     # a case: the parametrised test it runs (its position is the table row)
    runnable: bool = True           # False for a parametrised test itself: only its cases run
    status: str = "NOTRUN"          # PASS FAIL NOASSERT BUDGET HANG FAULT
    scans: int = 0
    clock_ns: int = 0
    asserts: int = 0
    failures: int = 0
    messages: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def passed(self) -> bool:
        return self.status == "PASS"


def fmt_time(ns: int) -> str:
    if ns % 1_000_000_000 == 0:
        return f"{ns // 1_000_000_000}s"
    if ns % 1_000_000 == 0:
        return f"{ns // 1_000_000}ms"
    return f"{ns / 1e6:.3f}ms"


def build_tests(paths: list[str], src: list[str], build_dir: Path, quiet: bool, optimize: str = "-O1",
                cases: testcases.CaseSet | None = None, cache: buildcache.Cache | None = None):
    """Compile the sources, the tests and the cases of their tables into one runner binary.  The program's C is
    one translation unit per source file (codegen.generate_units), each compiled only when its text is not in
    the build cache (`cache`, default the one in use, else build_dir/cache); the runner is linked only when
    an object changed."""
    cases = cases if cases is not None else testcases.load(paths)
    if cases.diags.has_errors():
        print_diagnostics(CompileResult(cases.diags, cases.sources), quiet=True)
        raise TestBuildError(len(cases.diags.errors))
    # errors only (warnings are plc check's business): no portability pass
    cache = cache or buildcache.active() or buildcache.Cache(build_dir / "cache")
    # the POUs of the files an edit leaves alone: their C from the cache, their bodies not checked again
    # (codegen.PieceMemo); only errors are reported here, which such a body had none of
    res = compile_sources([*src, *paths], test_build=True, extra_texts=cases.extra_texts(), generate=False,
                          portability=False, memo_cache=cache)
    cases.remap(res.diags, res.sources)
    untabled(res, cases)
    print_diagnostics(res, quiet=True)   # errors only: warnings are `plc check`'s business
    if not res.ok:
        raise TestBuildError(len(res.diags.errors))
    # the C generator recurses over expressions like the passes: the same stack allowance (parser.MAX_OPERATORS)
    memo = res.memo
    units = [buildcache.Unit(name, text)
             for name, text in deep_recursion(generate_units)(res.program, test_build=True, memo=memo)]
    cache.written = (len(memo.written), len(memo.written) + memo.replayed)
    units += [buildcache.Unit(f.stem, f.read_text()) for f in (STDLIB / "test_main.c", SCAN_CORE[0])]
    flags = ["-std=c99", "-Wall", "-Wextra", "-Werror", optimize, f"-I{INCLUDE}", f"-I{RUNTIME_SRC}"]
    # a unit the C compiler refuses is the compiler's bug: exit 3, the C and the output kept in build_dir/c
    objects = compile_units(cache, units, flags, [SCAN_CORE[1]], build_dir / "c")
    exe = build_dir / content_hash(*(o.name for o in objects)) / "tests"
    if not exe.exists():
        exe.parent.mkdir(parents=True, exist_ok=True)
        link = [cc(), *map(str, objects), "-o", str(exe) + ".tmp", "-lm"]
        proc = subprocess.run(link, capture_output=True, text=True)
        if proc.returncode != 0:
            raise UserError(f"linking the test runner failed ({shlex.join(link)}):\n{proc.stderr}{proc.stdout}")
        os.replace(str(exe) + ".tmp", exe)
    return res, exe


class TestBuildError(Exception):
    pass


def scan_tests(res):
    """The TEST_ function blocks in generation order (the order of plc_tests[])."""
    ctx_t = res.program.types.get("ST_TESTCONTEXT")
    for pt in res.program.pous.values():
        if pt.kind != "FUNCTION_BLOCK" or not pt.name.startswith("TEST_"):
            continue
        if any(v.section == "VAR_IN_OUT" and v.type is ctx_t for v in pt.scope.vars.values()):
            yield pt


def inputs_of(pt) -> list[str]:
    return [v.name for v in pt.scope.vars.values() if v.section == "VAR_INPUT"]


def untabled(res, cases: testcases.CaseSet) -> None:
    """A test with inputs runs only through its case table: without one, it is an error (its checks would
    silently never run)."""
    for pt in scan_tests(res):
        if inputs_of(pt) and pt.name not in cases.templates:
            res.diags.error(pt.pou.pos, f"{pt.pou.text} has inputs but no case table",
                            f"write its cases in {pt.pou.text}{testcases.SUFFIX} beside {pt.pou.text}.st "
                            "(plc test --help), or make the inputs local variables", code="test.cases")


def collect_tests(res, cases: testcases.CaseSet | None = None) -> list[TestResult]:
    """The tests in the order of plc_tests[]: a case carries its name and the row of its table, a parametrised
    test itself is listed but not runnable."""
    by_pou = cases.by_pou() if cases is not None else {}
    out = []
    for pt in scan_tests(res):
        case = by_pou.get(pt.name)
        if case is not None:
            out.append(TestResult(case.name, case.pos.file, case.pos.line, case.pos.col, template=case.template))
        else:
            pos = pt.pou.pos
            out.append(TestResult(pt.pou.text, pos.file, pos.line, pos.col, runnable=not inputs_of(pt)))
    return out


def unescape(s: str) -> str:
    return s.replace("\\t", "\t").replace("\\n", "\n").replace("\\r", "\r").replace("\\\\", "\\")


def run_binary(exe: Path, indices: list[int], tests: list[TestResult], sites, timeout: int, stop_first: bool,
               on_result) -> None:
    cmd = [str(exe), "--timeout", str(timeout), *map(str, indices)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, errors="replace")
    current: TestResult | None = None
    t0 = time.perf_counter()
    try:
        for line in proc.stdout:
            line = line.rstrip("\n")
            if line.startswith("BEGIN "):
                current = tests[int(line.split()[1])]
                t0 = time.perf_counter()
            elif line.startswith("ASSERT ") and current is not None:
                head, _, rest = line.partition(" ")[2].partition(" ")
                site = int(head)
                parts = rest.split("\t")
                msg, exp, act = (unescape(p) for p in (parts + ["", "", ""])[:3])
                where = f"{sites[site].pos}" if 0 <= site < len(sites) else current.file
                detail = f"expected {exp}, actual {act}" if (exp or act) else "failed"
                current.messages.append(f"{where}: {msg}: {detail}")
            elif line.startswith("FAULT ") and current is not None:
                kind_s, _, rest = line[6:].partition(" ")
                f, ln, col, pou = (rest.split("\t") + ["?", "0", "0", "?"])[:4]
                kind = {"1": "integer division by zero", "2": "array index out of bounds",
                        "3": "subrange violation"}.get(kind_s, f"fault {kind_s}")
                current.messages.append(f"{f}:{ln}:{col}: runtime fault in {pou}: {kind}")
            elif line.startswith("END ") and current is not None:
                _, _idx, status, scans, clock, asserts, failures = line.split()[:7]
                current.status = status
                current.scans, current.clock_ns = int(scans), int(clock)
                current.asserts, current.failures = int(asserts), int(failures)
                current.seconds = time.perf_counter() - t0
                on_result(current)
                if stop_first and not current.passed:
                    proc.kill()
                    break
                current = None
    finally:
        proc.wait()
    if proc.returncode not in (0, -9) and current is not None:
        current.status = "FAULT"
        current.messages.append(f"the test process died (signal {-proc.returncode})"
                                if proc.returncode < 0 else f"the test process exited with {proc.returncode}")
        on_result(current)


def explain(r: TestResult) -> list[str]:
    out = list(r.messages)
    where = f"{r.file}:{r.line}:{r.col}"
    if r.status == "NOASSERT":
        out.append(f"{where}: no assert was executed (an assert in a branch never taken does not count)")
    elif r.status == "BUDGET":
        out.append(f"{r.file}:{r.line}: over budget: still running after {r.scans} scans "
                   f"({fmt_time(r.clock_ns)} simulated) without setting tc.Done")
    elif r.status == "HANG":
        out.append(f"{r.file}:{r.line}: hung inside a scan (no return within the wall-clock timeout; "
                   f"an endless loop?) at scan {r.scans}")
    elif r.status == "FAIL" and not r.messages:
        out.append(f"{r.file}:{r.line}: {r.failures} assertion(s) failed")
    if r.status == "FAIL" and r.failures > len(r.messages):
        out.append(f"... {r.failures - len(r.messages)} more failed assertion(s)")
    if r.template is not None and r.status in ("FAIL", "FAULT"):
        out.append(f"{where}: the row of this case of {r.template}")
    return out


def write_junit(path: str, results: list[TestResult], total_s: float) -> None:
    suites = ET.Element("testsuites", name="plc test", tests=str(len(results)),
                        failures=str(sum(not r.passed for r in results)), time=f"{total_s:.3f}")
    by_file: dict[str, list[TestResult]] = {}
    for r in results:
        by_file.setdefault(r.file, []).append(r)
    for f, rs in by_file.items():
        suite = ET.SubElement(suites, "testsuite", name=f, tests=str(len(rs)),
                              failures=str(sum(not r.passed for r in rs)),
                              time=f"{sum(r.seconds for r in rs):.3f}")
        for r in rs:
            case = ET.SubElement(suite, "testcase", classname=f, name=r.name, time=f"{r.seconds:.3f}",
                                 file=f, line=str(r.line))
            if not r.passed:
                fail = ET.SubElement(case, "failure", type=r.status,
                                     message=(explain(r) or [r.status])[0])
                fail.text = "\n".join(explain(r))
            ET.SubElement(case, "system-out").text = f"{r.scans} scans, {fmt_time(r.clock_ns)} simulated"
    ET.ElementTree(suites).write(path, encoding="utf-8", xml_declaration=True)


def cmd_test(args) -> int:
    # the collector stays off to the end: after the build, a collection would walk the million objects of the
    # front end (a tenth of a second) to free nothing, and the command ends soon after
    with buildcache.paused_gc():
        return _test(args)


def _test(args) -> int:
    root = project_root()
    if not args.paths and root is not None and not (root / "iec_tests").is_dir():
        raise UserError(f"no test paths given and the project at {root} has no iec_tests/")
    paths = args.paths or ([str(root / "iec_tests")] if root else [])
    if not paths:
        raise UserError("no test paths given and no project (st_src/ and iec_tests/) found from here")
    src = args.src if args.src is not None else ([str(root / "st_src")] if root else [])
    build_dir = Path(args.build_dir) if args.build_dir else (root or Path.cwd()) / "build" / "plc-test"
    # the project's build cache (parse results, objects), shared with plc build and plc run; else the build dir's
    buildcache.use(buildcache.project_cache(root) if root is not None else build_dir / "cache")
    # the project's checks (stale generated files) run beside the build, on the other CPU
    preflight = Preflight(root, "plc test") if root is not None and args.src is None else None
    t0 = time.perf_counter()

    def build():
        cases = testcases.load(paths)
        return cases, *build_tests(paths, src, build_dir, args.quiet, cases=cases)
    try:
        refused, built = beside_preflight(preflight, build)
    except TestBuildError as e:
        print(f"plc test: the tests do not compile ({e.args[0]} error(s))", file=sys.stderr)
        print("0 passed, 1 failed")
        return 1
    if refused:
        return 2        # the project is not ready (stale generated files): no test ran, so no test count
    cases, res, exe = built
    t_build = time.perf_counter() - t0
    tests = collect_tests(res, cases)
    selected = [i for i, t in enumerate(tests) if t.runnable]
    if args.k:
        pat = args.k.lower()
        selected = [i for i in selected if pat in tests[i].name.lower() or fnmatch.fnmatch(tests[i].name.lower(), pat)]
    if args.verbose:
        cache = buildcache.active()
        written, pous = cache.written
        print(f"built {sum(t.runnable for t in tests)} test(s) in {t_build:.2f}s ({len(cache.compiled)} C unit(s) "
              f"compiled, the others from the cache; the C of {written} of {pous} POU(s) written) -> {exe}")
    sites = res.program.sites

    def on_result(r: TestResult) -> None:
        tag = "PASS" if r.passed else "FAIL"
        extra = f" [{STATUS_TAGS[r.status]}]" if r.status in STATUS_TAGS else ""
        info = f"{r.scans} scans, {fmt_time(r.clock_ns)} simulated"
        if args.verbose:
            info += f", {r.asserts} asserts, {r.seconds * 1000:.1f} ms"
        if not r.passed or not args.quiet:
            print(f"{tag}  {r.name}{extra}  ({info})")
        if not r.passed:
            for m in explain(r):
                print(f"      {m}")
        sys.stdout.flush()

    t1 = time.perf_counter()
    if selected:
        run_binary(exe, selected, tests, sites, args.timeout, args.x, on_result)
    ran = [tests[i] for i in selected if tests[i].status != "NOTRUN"]
    skipped = len(selected) - len(ran)
    passed = sum(r.passed for r in ran)
    failed = len(ran) - passed
    if args.junit_xml:
        write_junit(args.junit_xml, ran, time.perf_counter() - t1)
    line = f"{passed} passed, {failed} failed"
    if skipped:
        line += f", {skipped} skipped"
    print(line)
    if not selected:
        print("plc test: no test matched", file=sys.stderr)
        return 1 if args.k else 0
    return 0 if failed == 0 and skipped == 0 else 1


DESCRIPTION = """\
Compile st_src/ and the tests into one binary and run every TEST_ function block on a fresh
instance with a simulated clock. Exit status: 0 all passed, 1 a test failed or did not compile,
2 usage or the project is not ready (stale generated files: nothing run, no test count)."""

EPILOG = f"""\
A test passes when it sets tc.Done having executed at least one assert and failed none; a test that
executed no assert fails ("no assert was executed"), also when its asserts sit in branches never taken.

Parametrised tests: a TEST_X with VAR_INPUTs runs once per case of the table TEST_X{testcases.SUFFIX}
beside TEST_X.st, each case on a fresh instance, named TEST_X[Input=value,...] and placed at its row:

    [[case]]                                 # one row; a list makes a case per value,
    Kind = ["OperatorAbort", "EStopOpened"]  # several lists every combination
    AtStep = [1, 2, 3]                       # -> 6 cases, TEST_X[Kind=OperatorAbort,AtStep=1] ...

Each case calls TEST_X with its row's values on every scan. Inputs are named case-insensitively;
one a row leaves out keeps its initial value. Values: booleans,
integers, floats, or a string holding one ST literal ("T#5s", "E_Kind#A" or "A", "'text'"). The
cases are compiled from memory and never written into the project, so TEST_X stays portable ST."""


def add_parser(sub) -> None:
    p = sub.add_parser("test", help="run the scan-cycle tests written in ST", description=DESCRIPTION, epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("paths", nargs="*", metavar="PATH",
                   help=f"test files or directories (default: iec_tests/); a file's case table TEST_X"
                        f"{testcases.SUFFIX} is read beside it")
    p.add_argument("-k", metavar="PATTERN", help="run only tests whose name contains PATTERN (or matches the glob); "
                   "a case is named TEST_X[Input=value,...]")
    p.add_argument("-x", action="store_true", help="stop at the first failing test")
    p.add_argument("-v", "--verbose", action="store_true", help="more detail per test")
    p.add_argument("-q", "--quiet", action="store_true", help="print failing tests and the summary only")
    p.add_argument("--junit-xml", metavar="FILE", help="also write a JUnit XML report")
    p.add_argument("--src", action="append", metavar="DIR",
                   help="library sources to compile with the tests (default: the project's st_src/)")
    p.add_argument("--timeout", type=int, default=DEFAULT_TIMEOUT_S, metavar="S",
                   help=f"wall-clock limit per test in seconds (default {DEFAULT_TIMEOUT_S})")
    p.add_argument("--build-dir", metavar="DIR", help="where to link the test binary (default: build/plc-test); "
                   "parse results and C objects are cached in the project's build/plc-cache/ (outside a "
                   "project: DIR/cache)")
    add_view_options(p)
    p.set_defaults(func=cmd_test)
