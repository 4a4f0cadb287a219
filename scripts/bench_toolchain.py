"""Toolchain benchmarks (issues 2 and 3), printed as a table.

- plc check of a generated 2,000-line ST file (target <= 0.5 s)
- compiling st_src/ + iec_tests/ into the test binary, cold (target <= 10 s)
- 200 tests x 10,000 scans each through plc test's runner (target <= 5 s wall)
- plc check of a 500-rung ladder (PLCopen XML, OpenPLC Editor grid rails) against plc check of the ST it
  imports to (baseline, same run): the XML front end's cost (target <= 3x the ST check)
- the edit loop (issue 33), in a copy of the project: one declaration added to st_src/rotary/F_NextPocket.st,
  then `plc test -k TieGoes` to its verdict, median of 10 (target <= 1.5 s on a quiet machine), against the
  cold `plc test` of the same copy and, when IEC2C (and IEC2C_LIB, IEC2C_CINCLUDE: see
  plc/tests/test_matiec_optional.py) name a MATIEC build, against MATIEC + g++ of the application as OpenPLC
  builds it (`plc deploy openplc`, iec2c, g++ -std=gnu++11 of Config0.c and Res0.c), all in the same run
  (target <= 0.25x). The machine's load average is printed with the table: on a busy machine every time grows.
"""
from __future__ import annotations

import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "plc" / "src"))

sys.path.insert(0, str(ROOT / "plc" / "tests"))

from plc.diagnostics import Diagnostics  # noqa: E402
from plc.driver import compile_sources  # noqa: E402
from plc.plcopen import translate  # noqa: E402
from plc.plcopen.importer import unit_files  # noqa: E402
from plcopen_build import Body, pou, project  # noqa: E402
from plc.testrunner import build_tests, collect_tests  # noqa: E402


def big_source(lines: int) -> str:
    """Realistic ST: FBs with timers, CASE state machines, loops and arithmetic, until `lines` lines."""
    out = ["TYPE", "    E_BenchState : (Idle, Moving, Settling, Faulted);", "END_TYPE", ""]
    k = 0
    while len(out) < lines:
        k += 1
        out += f"""FUNCTION_BLOCK FB_Bench{k}
VAR_INPUT
    start : BOOL;           (* start a move *)
    target : INT;           (* target position *)
END_VAR
VAR_OUTPUT
    done : BOOL;            (* move finished *)
    position : INT;         (* current position *)
END_VAR
VAR
    state : E_BenchState;
    settle : TON;
    history : ARRAY[1..8] OF INT := [8(0)];
    i : INT;
    total : DINT;
END_VAR
CASE state OF
    Idle:
        done := FALSE;
        IF start THEN
            state := Moving;
        END_IF;
    Moving:
        IF position < target THEN
            position := position + 1;
        ELSIF position > target THEN
            position := position - 1;
        ELSE
            state := Settling;
        END_IF;
    Settling:
        settle(IN := TRUE, PT := T#20ms);
        IF settle.Q THEN
            settle(IN := FALSE);
            done := TRUE;
            state := Idle;
        END_IF;
ELSE
    state := Faulted;
END_CASE;
total := 0;
FOR i := 1 TO 8 DO
    total := total + INT_TO_DINT(history[i]);
END_FOR;
history[(position MOD 8) + 1] := position;
END_FUNCTION_BLOCK

""".splitlines()
    return "\n".join(out) + "\n"


def bench_check(tmp: Path) -> tuple[float, int]:
    src = tmp / "big.st"
    text = big_source(2000)
    src.write_text(text)
    n = text.count("\n")
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        res = compile_sources([src], generate=False)
        times.append(time.perf_counter() - t0)
        assert not res.diags.has_errors(), [d.message for d in res.diags.errors][:3]
    return statistics.median(times), n


def bench_compile_project(tmp: Path) -> float:
    t0 = time.perf_counter()
    build_tests([str(ROOT / "iec_tests")], [str(ROOT / "st_src")], tmp / "cold", quiet=True)
    return time.perf_counter() - t0


def bench_scans(tmp: Path) -> tuple[float, float, int]:
    tests = []
    for k in range(200):
        tests.append(f"""FUNCTION_BLOCK TEST_Bench{k}
VAR_IN_OUT
    tc : ST_TestContext;
END_VAR
VAR
    axis : FB_Bench1;
    pulse : TON;
    count : DINT;
END_VAR
IF tc.Scan = 1 THEN
    tc.Budget := 20000;
END_IF;
axis(start := TRUE, target := {k % 50 + 10});
pulse(IN := NOT pulse.Q, PT := T#40ms);
IF pulse.Q THEN
    count := count + 1;
END_IF;
tc.Ok := AssertTrue(tc, axis.position <= {k % 50 + 10}, 'never overshoots');
tc.Done := tc.Scan >= 10000;
END_FUNCTION_BLOCK
""")
    lib = tmp / "lib"
    lib.mkdir()
    (lib / "bench_lib.st").write_text(big_source(60))
    tfile = tmp / "bench_tests.st"
    tfile.write_text("\n".join(tests))
    t0 = time.perf_counter()
    res, exe = build_tests([str(tfile)], [str(lib)], tmp / "scan", quiet=True, optimize="-O1")
    build_s = time.perf_counter() - t0
    n = len(collect_tests(res))
    t0 = time.perf_counter()
    proc = subprocess.run([str(exe)], capture_output=True, text=True)
    run_s = time.perf_counter() - t0
    ends = [line for line in proc.stdout.splitlines() if line.startswith("END ")]
    bad = [e for e in ends if " PASS " not in e or " 10000 " not in e]
    assert len(ends) == n == 200 and not bad, (len(ends), bad[:3])
    return run_s, build_s, n


def big_ladder(rungs: int) -> str:
    """A PROGRAM of `rungs` rungs on one pair of grid rails: seal-in circuits, edges, set/reset, timers."""
    b = Body().left_rail(1, points=rungs)
    names = []
    for k in range(rungs):
        y, base = 40 * k, 100 + 10 * k
        kind = k % 4
        if kind == 0:      # start/stop seal-in
            b.contact(base, f"start{k}", 1, y=y).contact(base + 1, f"run{k}", 1, y=y + 20)
            b.contact(base + 2, f"stop{k}", [base, base + 1], x=200, y=y, negated=True)
            b.coil(base + 3, f"run{k}", base + 2, y=y)
        elif kind == 1:    # edge -> set, reset
            b.contact(base, f"start{k}", 1, y=y, edge="rising").coil(base + 1, f"run{k}", base, y=y, storage="set")
            b.coil(base + 2, f"stop{k}", base + 1, x=400, y=y, storage="reset")
        elif kind == 2:    # timer in the rung
            b.contact(base, f"start{k}", 1, y=y).in_var(base + 1, "T#50ms", y=y + 20)
            b.block(base + 2, "TON", {"IN": base, "PT": base + 1}, ["Q", "ET"], y=y, instance=f"delay{k}")
            b.coil(base + 3, f"run{k}", (base + 2, "Q"), y=y)
        else:              # series coils (the #836 shape)
            b.contact(base, f"start{k}", 1, y=y).coil(base + 1, f"run{k}", base, y=y, storage="set")
            b.coil(base + 2, f"start{k}", base + 1, x=400, y=y, storage="reset")
            b.coil(base + 3, f"stop{k}", base + 2, x=500, y=y)
        names += [(f"start{k}", "BOOL"), (f"stop{k}", "BOOL"), (f"run{k}", "BOOL")]
        if kind == 2:
            names.append((f"delay{k}", "TON"))
    return project([pou("BigLadder", "program", b, locals_=names)])


def bench_ladder(tmp: Path) -> tuple[float, float, int]:
    xml = tmp / "ladder.xml"
    text = big_ladder(500)
    xml.write_text(text)
    diags = Diagnostics()
    tr = translate(str(xml), text.encode(), diags)
    st_dir = tmp / "ladder_st"
    st_dir.mkdir()
    for name, body in unit_files(tr).items():
        (st_dir / name).write_text(body)
    times = {"xml": [], "st": []}
    for _ in range(5):
        for key, path in (("xml", xml), ("st", st_dir)):
            t0 = time.perf_counter()
            res = compile_sources([path], generate=False)
            times[key].append(time.perf_counter() - t0)
            assert not res.diags.has_errors(), [d.render() for d in res.diags.errors][:3]
    return statistics.median(times["xml"]), statistics.median(times["st"]), 500


EDITED = Path("st_src") / "rotary" / "F_NextPocket.st"
EDIT_RUNS = 10
PLC = [sys.executable, "-m", "plc.cli"]


# as a user's shell runs plc: Python keeps the compiled bytecode of the toolchain (some CI shells forbid it)
USER_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def timed(cmd: list[str], cwd: Path, expect: str | None = None) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, env=USER_ENV)
    elapsed = time.perf_counter() - t0
    if proc.returncode != 0 or (expect is not None and expect not in proc.stdout):
        raise SystemExit(f"bench: {' '.join(cmd)} failed in {cwd}:\n{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
    return elapsed


def project_copy(tmp: Path) -> Path:
    """The project as it is in the work tree, without git, the venv and build output."""
    copy = tmp / "project"
    shutil.copytree(ROOT, copy, ignore=shutil.ignore_patterns(".git", ".venv", "build", "__pycache__"))
    return copy


def add_declaration(path: Path, k: int) -> None:
    """One more local constant in the function's VAR CONSTANT block: its C changes, its interface does not."""
    text = path.read_text()
    marker = "VAR CONSTANT\n"
    assert marker in text, f"{path}: no VAR CONSTANT block to edit"
    path.write_text(text.replace(marker, f"{marker}    BenchEdit{k} : INT := {k};\n", 1))


def bench_edit_loop(tmp: Path) -> dict[str, float]:
    proj = project_copy(tmp)
    out = {"cold": timed([*PLC, "test", "-q"], proj, expect=" passed, 0 failed")}
    select = [*PLC, "test", "-k", "TieGoes"]
    out["cached"] = statistics.median(timed(select, proj, expect="2 passed, 0 failed") for _ in range(3))
    edits = []
    for k in range(EDIT_RUNS):
        add_declaration(proj / EDITED, k)
        edits.append(timed(select, proj, expect="2 passed, 0 failed"))
    out["edit"], out["edit_min"], out["edit_max"] = statistics.median(edits), min(edits), max(edits)
    matiec = matiec_build(proj, tmp / "matiec")
    if matiec is not None:
        out["matiec"] = matiec
    return out


def matiec_build(proj: Path, work: Path) -> float | None:
    """Median of 3 of iec2c + g++ of the application as OpenPLC builds it, or None (said why) without MATIEC."""
    iec2c, lib, include = (os.environ.get(v) for v in ("IEC2C", "IEC2C_LIB", "IEC2C_CINCLUDE"))
    if not (iec2c and lib and include and shutil.which("g++")):
        print("MATIEC + g++ not measured: set IEC2C, IEC2C_LIB and IEC2C_CINCLUDE (plc/tests/test_matiec_optional.py)"
              " and install g++", file=sys.stderr)
        return None
    program = work / "program.st"
    work.mkdir()
    timed([*PLC, "deploy", "openplc", "--out", str(program)], proj)
    times = []
    for k in range(3):
        run = work / f"run{k}"
        (run / "st_files").mkdir(parents=True)
        shutil.copy(program, run / "st_files" / "program.st")
        os.symlink(lib, run / "lib", target_is_directory=True)
        t0 = time.perf_counter()
        timed([iec2c, "-f", "-l", "-p", "-r", "-R", "-a", "./st_files/program.st"], run)
        core = run / "core"
        core.mkdir()
        for name in ("POUS.c", "POUS.h", "LOCATED_VARIABLES.h", "VARIABLES.csv", "Config0.c", "Config0.h", "Res0.c"):
            shutil.move(run / name, core / name)
        os.symlink(include, core / "lib", target_is_directory=True)
        (core / "c_blocks.h").write_text("")
        for unit in ("Config0.c", "Res0.c"):
            timed(["g++", "-std=gnu++11", "-I", "./lib", "-c", unit, "-w"], core)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> int:
    rows = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        check_s, lines = bench_check(tmp)
        rows.append(("plc check, generated ST file", f"{lines} lines", f"{check_s:.3f} s", "<= 0.5 s", check_s <= 0.5))
        comp_s = bench_compile_project(tmp)
        rows.append(("compile st_src/ + iec_tests/ (cold)", "ST -> C -> gcc -O1", f"{comp_s:.2f} s", "<= 10 s",
                     comp_s <= 10))
        run_s, build_s, n = bench_scans(tmp)
        rows.append(("plc test runner", f"{n} tests x 10,000 scans", f"{run_s:.2f} s", "<= 5 s", run_s <= 5))
        rows.append(("  (its build)", "ST -> C -> gcc -O1", f"{build_s:.2f} s", "", True))
        xml_s, st_s, rungs = bench_ladder(tmp)
        rows.append(("plc check, ladder as PLCopen XML", f"{rungs} rungs", f"{xml_s:.3f} s",
                     f"<= 3x baseline ({xml_s / st_s:.1f}x)", xml_s <= 3 * st_s))
        rows.append(("  baseline: the same, imported ST", f"{rungs} rungs", f"{st_s:.3f} s", "", True))
        loop = bench_edit_loop(tmp)
        ok = loop["edit"] <= 1.5 and ("matiec" not in loop or loop["edit"] <= 0.25 * loop["matiec"])
        versus = f", {loop['edit'] / loop['matiec']:.2f}x MATIEC" if "matiec" in loop else ""
        rows.append(("edit -> verdict (plc test -k TieGoes)", f"1 declaration, median of {EDIT_RUNS}",
                     f"{loop['edit']:.2f} s", f"<= 1.5 s, <= 0.25x MATIEC ({loop['edit'] / loop['cold']:.2f}x cold"
                     f"{versus})", ok))
        rows.append(("  fastest, slowest of the edits", "", f"{loop['edit_min']:.2f}, {loop['edit_max']:.2f} s", "",
                     True))
        rows.append(("  no edit (every object cached)", "median of 3", f"{loop['cached']:.2f} s", "", True))
        rows.append(("  baseline: cold plc test, whole suite", "st_src/ + iec_tests/", f"{loop['cold']:.2f} s", "",
                     True))
        if "matiec" in loop:
            rows.append(("  baseline: MATIEC + g++ (OpenPLC)", "iec2c, g++ -O0, median of 3", f"{loop['matiec']:.2f} s",
                         "", True))
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"load average (1, 5, 15 min): {load} on {os.cpu_count()} CPUs")
    w = [max(len(str(r[i])) for r in rows + [("benchmark", "size", "measured", "target", "")]) for i in range(4)]
    head = ("benchmark", "size", "measured", "target")
    print("  ".join(h.ljust(w[i]) for i, h in enumerate(head)) + "  ok")
    print("  ".join("-" * w[i] for i in range(4)) + "  --")
    for r in rows:
        print("  ".join(str(r[i]).ljust(w[i]) for i in range(4)) + ("  yes" if r[4] else "  NO"))
    return 0 if all(r[4] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
