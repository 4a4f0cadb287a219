"""Optional cross-check: does STruC++, the compiler of OpenPLC v4, take our ST, and do our scan tests pass on it?

Since runtime 4.1.0 OpenPLC v4 compiles only STruC++ output (C++).  These tests hand the project's ST to a
STruC++ the user has built (docs/openplc-v4.md says how; nothing of it is stored here):

    STRUCPP=/path/to/STruCpp     a checkout built with `npm install && npm run build` (dist/node/cli.js,
                                 src/runtime/include), or a release's `strucpp` executable (runtime/ beside it)

Without STRUCPP the tests are skipped and say why (`pytest -rs`); without node (for a checkout) or g++ likewise.

- The deploy file (`plc deploy openplc`, one self-contained ST file) compiles with STruC++, and its C++ with
  g++ -std=c++17 against STruC++'s runtime headers, as the v4 runtime builds it.
- Every scan test of iec_tests/ (the TEST_ function blocks without a case table) runs on STruC++'s output through
  its own test runner (`strucpp ... --test`): one TEST per scan test calls a generated function block that loops
  scans as `plc test` does (Scan, Now, CycleTime + Advance, Budget) and sets STruC++'s scan clock
  (`__CURRENT_TIME_NS`, through an `{external}` block) before each scan; the TEST asserts that the scan test
  finished with assertions and none failed.  STruC++'s runner runs its binary under a 30 s limit, which our ~140
  tests exceed on a busy machine: the g++ it is given builds the runner as asked, keeps it, and leaves a no-op in
  its place; the kept runner then runs here with --json.
"""

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
TIMEOUT_S = 3600

# The scan loop of `plc test` (stdlib/test_main.c) in ST, around one scan test.
RUNNER = """FUNCTION_BLOCK RUN_{name}
VAR_OUTPUT
    Done : BOOL;
    Asserts : UDINT;
    Failures : UDINT;
END_VAR
VAR
    uut : {name};
    tc : ST_TestContext;
    clock : FB_StrucppClock;
    step : TIME;
END_VAR
WHILE NOT tc.Done AND tc.Scan < tc.Budget DO
    tc.Scan := tc.Scan + 1;
    clock(Now := tc.Now);
    uut(tc := tc);
    step := tc.CycleTime + tc.Advance;
    tc.Advance := T#0s;
    tc.Now := tc.Now + step;
END_WHILE;
Done := tc.Done;
Asserts := tc.Asserts;
Failures := tc.Failures;
END_FUNCTION_BLOCK
"""

TEST = """TEST '{name}'
VAR
    run : RUN_{name};
END_VAR
run();
ASSERT_TRUE(run.Done, 'finished within its budget');
ASSERT_EQ(run.Failures, 0, 'no failed assertion');
ASSERT_GT(run.Asserts, 0, 'checked something');
END_TEST
"""

CLOCK = """FUNCTION_BLOCK FB_StrucppClock
VAR_INPUT
    Now : TIME;
END_VAR
{external strucpp::__CURRENT_TIME_NS = static_cast<int64_t>(iec_unwrap(NOW)); }
END_FUNCTION_BLOCK
"""

# g++ for `strucpp --test`: builds the runner as asked, keeps it as $STRUCPP_KEEP and leaves a no-op in its place.
KEEPING_GPP = """#!/bin/sh
out=""; prev=""
for a in "$@"; do [ "$prev" = "-o" ] && out="$a"; prev="$a"; done
[ -n "$out" ] || exec g++ "$@"
g++ "$@" || exit $?
cp "$out" "$STRUCPP_KEEP" && printf '#!/bin/sh\\nexit 0\\n' > "$out"
"""


def _strucpp():
    """(command prefix, runtime include directory) of the STruC++ that STRUCPP names, or skip with the reason."""
    where = os.environ.get("STRUCPP")
    if not where:
        pytest.skip("STRUCPP not set: point it at a built Autonomy-Logic/STruCpp checkout (npm install && npm run "
                    "build) or a release's strucpp executable to compile our ST for OpenPLC v4")
    path = Path(where)
    if path.is_dir():
        cli = path / "dist" / "node" / "cli.js"
        if not cli.is_file():
            pytest.fail(f"STRUCPP={where} has no dist/node/cli.js: run `npm install && npm run build` there")
        if shutil.which("node") is None:
            pytest.skip("node not found: STruC++'s compiler is a Node.js program")
        return ["node", str(cli)], path / "src" / "runtime" / "include"
    if not (path.is_file() and os.access(path, os.X_OK)):
        pytest.fail(f"STRUCPP={where} is neither a STruC++ checkout nor an executable")
    return [str(path)], path.parent / "runtime" / "include"


def _gpp():
    if shutil.which("g++") is None:
        pytest.skip("g++ not found: STruC++'s output is C++17")


def test_the_deploy_file_compiles_with_strucpp_and_its_cpp_with_gpp(tmp_path):
    strucpp, include = _strucpp()
    bundle = tmp_path / "atc.st"
    deployed = subprocess.run([sys.executable, "-m", "plc.cli", "deploy", "openplc", "-q", "--out", str(bundle)],
                              cwd=REPO, capture_output=True, text=True, timeout=600)
    assert deployed.returncode == 0, deployed.stderr
    compiled = subprocess.run([*strucpp, str(bundle), "-o", str(tmp_path / "atc.cpp")], capture_output=True,
                              text=True, timeout=TIMEOUT_S)
    assert compiled.returncode == 0, compiled.stdout + compiled.stderr
    header = (tmp_path / "atc.hpp").read_text()
    assert "class Program_ATCMAIN" in header       # the PROGRAM the v4 runtime runs
    _gpp()
    built = subprocess.run(["g++", "-std=c++17", "-Wno-invalid-offsetof", "-I", str(include), "-c",
                            str(tmp_path / "atc.cpp"), "-o", str(tmp_path / "atc.o")], capture_output=True, text=True,
                           timeout=TIMEOUT_S)
    assert built.returncode == 0, built.stderr[-4000:]


def _sources(tmp_path):
    """st_src/, the testing library, its enumeration asserts and iec_tests/ as ST files STruC++ reads (PLCopen XML
    translated, E_Kind#Value labels of the generated asserts written bare), and the scan tests' names."""
    from plc import driver
    from plc.diagnostics import Diagnostics, SourceSet
    folder = tmp_path / "st"
    folder.mkdir()
    written, parsed, names = [], [], []
    for part in ("st_src", "iec_tests"):
        for path in driver.collect_files([REPO / part]):
            diags = Diagnostics()
            name, text, _translation = driver.load_user_file(path, diags, SourceSet())
            assert text is not None and not diags.has_errors(), [d.render() for d in diags.sorted()]
            target = folder / f"{part}-{len(written):03d}-{Path(name).stem}.st"
            target.write_text(text)
            written.append(target)
            parsed.append(driver.parse(text, str(target), diags))
            if part == "iec_tests":
                for m in re.finditer(r"FUNCTION_BLOCK\s+(TEST_\w+)(.*?)END_FUNCTION_BLOCK", text, re.S | re.I):
                    if not re.search(r"\bVAR_INPUT\b", m.group(2), re.I):     # a case table's test: plc test only
                        names.append(m.group(1))
    asserts = re.sub(r"^(\s+)\w+#(\w+):", r"\1\2:", driver.enum_asserts(parsed), flags=re.M)
    library = sorted(driver.TESTLIB.glob("*.st"))
    extra = folder / "zz-runners.st"
    extra.write_text(asserts + "\n" + CLOCK + "\n" + "\n".join(RUNNER.format(name=n) for n in names))
    sources_end = sum(1 for p in written if p.name.startswith("st_src-"))
    return [*written[:sources_end], *library, *written[sources_end:], extra], names


def test_the_scan_tests_pass_on_strucpp_output(tmp_path):
    strucpp, _include = _strucpp()
    _gpp()
    files, names = _sources(tmp_path)
    assert len(names) > 100
    tests = tmp_path / "scan_tests.st"
    tests.write_text("\n".join(TEST.format(name=n) for n in names))
    gpp = tmp_path / "g++-keep"
    gpp.write_text(KEEPING_GPP)
    gpp.chmod(0o755)
    runner = tmp_path / "runner"
    built = subprocess.run([*strucpp, *map(str, files), "--test", str(tests), "--gpp", str(gpp),
                            "--cxx-flags", "-O1"], capture_output=True, text=True, timeout=TIMEOUT_S,
                           env={**os.environ, "STRUCPP_KEEP": str(runner)})
    assert built.returncode == 0 and runner.is_file(), (built.stdout + built.stderr)[-6000:]
    ran = subprocess.run([str(runner), "--json"], capture_output=True, text=True, timeout=TIMEOUT_S)
    report = json.loads(ran.stdout)
    failed = [(r["name"], r.get("failure")) for r in report["results"] if not r["passed"]]
    assert failed == []
    assert sorted(r["name"] for r in report["results"]) == sorted(names)
    assert ran.returncode == 0


# Statements whose C++ from STruC++ g++ may refuse: NOT over AND / OR / XOR (`NOT (x)` is a call of its runtime's NOT,
# which takes bit types only; `NOT x` is C++ '!x') and the string functions (its runtime has overloads for some
# literal arguments only).  The rules strucpp-not-int and strucpp-string-call must warn exactly where g++ refuses.
REFUSABLE = [
    "k := NOT (p <> 0 AND p = r)",
    "k := NOT (NOT b AND p = r)",
    "k := NOT (NOT (b) AND p = r)",
    "k := NOT (b AND p = r)",
    "k := NOT (NOT b OR NOT c)",
    "k := NOT (NOT (b) OR NOT (c))",
    "k := NOT (NOT b AND c)",
    "k := NOT (b XOR TRUE)",
    "k := NOT (b AND c)",
    "k := NOT b AND NOT (c)",
    "s := CONCAT('ab', 'cd')",
    "s := CONCAT(s, 'a')",
    "s := CONCAT('a', s)",
    "s := CONCAT(s, s, s)",
    "s := CONCAT(CONCAT(s, s), s)",
    "s := LEFT('abc', 2)",
    "s := LEFT(s, 2)",
    "p := LEN('abc')",
    "p := LEN(s)",
    "s := MID('abc', 1, 1)",
    "s := DELETE('abc', 1, 1)",
    "s := INSERT(s, 'a', 1)",
    "s := INSERT('abc', s, 1)",
    "s := REPLACE(s, 'a', 1, 1)",
    "s := REPLACE('abc', s, 1, 1)",
    "p := FIND('abc', s)",
    "k := s = 'abc'",
]
WARNED = ("under this NOT", "has no C++ for")


@pytest.mark.parametrize("statement", REFUSABLE)
def test_the_v4_target_warns_exactly_where_gpp_refuses_strucpps_cpp(tmp_path, statement):
    strucpp, include = _strucpp()
    _gpp()
    source = tmp_path / "a.st"
    source.write_text("PROGRAM Main\nVAR b : BOOL; c : BOOL; p : INT; r : INT; k : BOOL; s : STRING; END_VAR\n"
                      f"{statement};\nEND_PROGRAM\nCONFIGURATION Config0\nRESOURCE Res0 ON PLC\n"
                      "TASK t0(INTERVAL := T#4ms, PRIORITY := 0);\nPROGRAM i0 WITH t0 : Main;\nEND_RESOURCE\n"
                      "END_CONFIGURATION\n")
    compiled = subprocess.run([*strucpp, str(source), "-o", str(tmp_path / "a.cpp")], capture_output=True,
                              text=True, timeout=600)
    assert compiled.returncode == 0, compiled.stdout + compiled.stderr
    gpp = subprocess.run(["g++", "-std=c++17", "-fsyntax-only", "-I", str(include), str(tmp_path / "a.cpp")],
                         capture_output=True, text=True, timeout=600)
    checked = subprocess.run([sys.executable, "-m", "plc.cli", "check", "--target", "openplc-v4", str(source)],
                             capture_output=True, text=True, timeout=600)
    said = checked.stdout + checked.stderr
    warned = any(w in said for w in WARNED)
    assert warned == (gpp.returncode != 0), (statement, gpp.stderr[-1500:], said)


# What STruC++ and plc (and MATIEC, whose C does the same: docs/openplc-v4.md) compute alike and apart: a function
# block's VAR_IN_OUT copied in and back (given twice; a global the block also writes), and a STRING longer than
# 126 characters, which only CONCAT, INSERT and REPLACE make (rule strucpp-string-length).
PROBE = """FUNCTION_BLOCK FB_Two
VAR_IN_OUT a : INT; b : INT; END_VAR
a := a + 1;
b := b + 10;
END_FUNCTION_BLOCK
FUNCTION_BLOCK FB_Ext
VAR_IN_OUT a : INT; END_VAR
VAR_EXTERNAL g : INT; END_VAR
a := a + 1;
g := g + 10;
END_FUNCTION_BLOCK
FUNCTION_BLOCK FB_Probe
VAR_OUTPUT Twice : INT; Ext : INT; Chars : INT; END_VAR
VAR x : INT; f : FB_Two; e : FB_Ext; s : STRING; END_VAR
VAR_EXTERNAL g : INT; END_VAR
x := 0;
g := 0;
f(a := x, b := x);
e(a := g);
Twice := x;
Ext := g;
s := '{hundred}';
s := CONCAT(s, s);
Chars := LEN(s);
END_FUNCTION_BLOCK
PROGRAM Main
VAR p : FB_Probe; Twice : INT; Ext : INT; Chars : INT; END_VAR
p();
Twice := p.Twice;
Ext := p.Ext;
Chars := p.Chars;
END_PROGRAM
CONFIGURATION Config0
VAR_GLOBAL g : INT; END_VAR
RESOURCE Res0 ON PLC
TASK t0(INTERVAL := T#4ms, PRIORITY := 0);
PROGRAM MainInst WITH t0 : Main;
END_RESOURCE
END_CONFIGURATION
""".replace("{hundred}", "x" * 100)
PROBE_TEST = """TEST 'probe'
VAR p : FB_Probe; END_VAR
p();
ASSERT_EQ(p.Twice, {twice}, 'twice');
ASSERT_EQ(p.Ext, {ext}, 'ext');
ASSERT_EQ(p.Chars, {chars}, 'chars');
END_TEST
"""


def test_in_out_copies_agree_with_plc_and_a_long_string_differs_where_the_v4_target_warns(tmp_path):
    strucpp, _include = _strucpp()
    _gpp()
    from harness import run_st
    run = run_st(PROBE, scans=1)
    ours = {k: run.value(f"CONFIG0.RES0.MAININST.{k.upper()}") for k in ("twice", "ext", "chars")}
    assert ours == {"twice": 10, "ext": 1, "chars": 126}     # copied in and back; a STRING keeps 126 characters
    source, test = tmp_path / "probe.st", tmp_path / "probe_test.st"
    source.write_text(PROBE)
    test.write_text(PROBE_TEST.format(**{**ours, "chars": 200}))
    ran = subprocess.run([*strucpp, str(source), "--test", str(test)], capture_output=True, text=True,
                         timeout=TIMEOUT_S)
    assert ran.returncode == 0 and "1 passed" in ran.stdout, (ran.stdout + ran.stderr)[-3000:]
    checked = subprocess.run([sys.executable, "-m", "plc.cli", "check", "--target", "openplc-v4", str(source)],
                             capture_output=True, text=True, timeout=600)
    said = checked.stdout + checked.stderr
    assert said.count("warning: portability:") == 1 and "the result of CONCAT can be longer than 126" in said, said
