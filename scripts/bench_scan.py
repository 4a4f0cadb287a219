"""Scan code benchmark (issue 33 point 3): instructions per scan of the application, ours against MATIEC's.

The application (st_src/, AtcMain through Config0, as `plc deploy openplc` writes it) is built three ways and each
build is driven by the same deterministic host script: the host of the MATIEC differential
(plc/tests/test_openplc_differential.py: the simulated plant, prepares, changes, aborts, E-stops, soft faults and
recoveries), its plan once (about 19,500 scans), played against our build and recorded, then replayed to every
build's driver (--quiet) under valgrind's callgrind. A native replay first checks that each build answers every
scan as ours does.

- ours: `plc build`, gcc -O2 (as the runtime builds it), stepped by plc/tests/differential/abi_driver.c;
- with --baseline REV, ours as the compiler of git revision REV (an earlier release, or the last one before a
  change of the code generator) builds the same deploy file: REV's plc package and plc_abi.h, exported from this
  repository's history into the work directory, stepped by today's abi_driver.c (the bench's own harness);
- MATIEC -O2 and MATIEC as OpenPLC builds it (g++ without -O, i.e. -O0): iec2c, then g++ with OpenPLC's headers,
  stepped by plc/tests/differential/matiec_driver.cpp; only when IEC2C, IEC2C_LIB and IEC2C_CINCLUDE name a
  MATIEC build (see plc/tests/test_matiec_optional.py).

Only the scans are counted: callgrind starts with collection off and --toggle-collect turns it on inside the scan
function alone (our plc_run, MATIEC's config_run__), so start-up, the driver's parsing and printing are left out.
Ir/scan is the instructions counted divided by the scans the script ran. Instruction counts do not depend on the
machine's speed or load; the same script gives the same count every run.

The breakdown attributes every counted instruction to the function whose source line it comes from (callgrind's
per-line costs with the builds' debug information), so code gcc inlined into a caller still counts for the POU it
was written in. Names are matched across the builds: our P_<FB>_body and U_<FUNCTION> against MATIEC's
<FB>_body__ and <FUNCTION>.

    scripts/bench_scan.py [--top N] [--keep DIR] [--baseline REV]

Exit status: 0 when the measured ratio meets the target (<= 0.45x MATIEC -O2) or MATIEC is not available to
measure it, 1 when it does not or a build answered a scan otherwise than ours, 2 when a build or a run failed or
REV is not a revision of this repository.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "plc" / "src"))
sys.path.insert(0, str(ROOT / "plc" / "tests"))

from test_openplc_differential import (  # noqa: E402
    Build, Host, _signal_addresses, build_matiec, build_ours, deploy_file)

TARGET = 0.45          # issue 33: Ir/scan <= 0.45x MATIEC -O2 on the same host script
SCAN_FUNCTION = {"ours": "plc_run", "matiec": "config_run__*"}   # g++ names it config_run__(unsigned long)
DEBUG = ("-g",)        # line information for the breakdown; it changes no instruction
LINES = 10             # the hottest source lines printed
OURS, MATIEC_O2, MATIEC_O0 = "ours, gcc -O2", "MATIEC, g++ -O2", "MATIEC, g++ -O0 (as OpenPLC)"


def revision(rev: str) -> str:
    """The commit `rev` names in this repository, abbreviated; BadRevision when it names none."""
    name = subprocess.run(["git", "rev-parse", "--short", "--verify", "--quiet", f"{rev}^{{commit}}"], cwd=ROOT,
                          capture_output=True, text=True)
    if name.returncode != 0:
        raise BadRevision(f"--baseline {rev}: not a revision of this repository")
    return name.stdout.strip()


def build_baseline(rev: str, deploy: Path, work: Path) -> Path:
    """The deploy file built as `build_ours` builds ours, by the compiler of commit `rev` (its plc package and
    plc_abi.h, exported with git archive into work/src), stepped by today's abi_driver.c: the driver."""
    src = work / "src"
    src.mkdir(parents=True)
    archive = subprocess.run(["git", "archive", "--format=tar", rev, "plc"], cwd=ROOT, capture_output=True,
                             check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
    return build_ours(deploy, work / "build", ("-O2", *DEBUG), source=src)


class BadRevision(Exception):
    """--baseline names no commit of this repository."""


def callgrind(scan_function: str, out: Path) -> tuple[str, ...]:
    return ("valgrind", "-q", "--tool=callgrind", "--collect-atstart=no", f"--toggle-collect={scan_function}",
            "--compress-strings=no", "--compress-pos=no", f"--callgrind-out-file={out}")


class Recording(Build):
    """A build whose host writes are kept, one line a scan: the script, to replay to every build."""

    def __init__(self, exe: Path):
        super().__init__(exe)
        self.lines: list[str] = []

    def scan(self, writes: dict[str, int]) -> tuple:
        self.lines.append(" ".join(f"{a}={v}" for a, v in writes.items()))
        return super().scan(writes)


def record_script(exe: Path) -> tuple[str, Host]:
    """The differential's host, its plan once, against our build run natively: the script it wrote."""
    build = Recording(exe)
    host = Host(build, _signal_addresses())
    try:
        host.run(min_scans=1)
    finally:
        build.close()
    return "".join(line + "\n" for line in build.lines), host


def answers(exe: Path, script: str) -> list[int]:
    """One hash a scan of every located variable after it, by address: two builds with equal lists took the same
    path through the script."""
    out = subprocess.run([str(exe)], input=script, capture_output=True, text=True, check=True).stdout.splitlines()
    addresses = [line.split()[1] for line in out if line.startswith("loc ")]
    order = sorted(range(len(addresses)), key=addresses.__getitem__)
    hashes = []
    for line in out:
        if line.startswith("o"):
            values = line.split()[1:]
            hashes.append(hash(tuple(values[i] for i in order)))
        elif line.startswith("fault"):
            hashes.append(hash(line))
    return hashes


def count(exe: Path, scan_function: str, script: str) -> Counter:
    """The script replayed to the driver (--quiet) under callgrind: Ir by source line, the scans alone."""
    out = exe.parent / "callgrind.out"
    run = subprocess.run([*callgrind(scan_function, out), str(exe), "--quiet"], input=script, text=True,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    if run.returncode != 0:
        raise RuntimeError(f"{exe} under callgrind exited with {run.returncode}:\n{run.stderr[-2000:]}")
    return line_costs(out, exe.parent)


def line_costs(out: Path, build_dir: Path) -> Counter:
    """Ir by (source file, line) from a callgrind output written with --compress-strings=no --compress-pos=no.
    A cost line after calls= is the call's inclusive cost (already counted in the callee's lines): skipped."""
    costs: Counter = Counter()
    current = fl = ""
    skip_next = False
    for raw in out.read_text(errors="replace").splitlines():
        if not raw or raw[0].isalpha():
            key, _, value = raw.partition("=")
            if key == "fl":
                current = fl = value
            elif key in ("fi", "fe"):
                current = value
            elif key == "fn":
                current = fl
            elif key == "calls":
                skip_next = True
            continue
        if raw[0].isdigit():
            if skip_next:
                skip_next = False
                continue
            fields = raw.split()
            if len(fields) >= 2:
                path = Path(current)
                costs[(str(path if path.is_absolute() else build_dir / path), int(fields[0]))] += int(fields[1])
    return costs


DEFINITION = re.compile(r"^[A-Za-z_][\w\s*]*?\b(\w+)\s*\(")
MACRO = re.compile(r"^#define\s+(\w+)")


def functions_of(path: str) -> list[tuple[int, int, str]]:
    """(first line, last line, name) of every function defined in a C file, and of every multi-line macro (OpenPLC's
    headers define their typed functions in macros). Generated code and OpenPLC's headers both open a definition at
    column 0 (its parameters may run over several lines) and close it with a '}' at column 0."""
    try:
        lines = Path(path).read_text(errors="replace").splitlines()
    except OSError:
        return []
    found = []
    number = 0
    while number < len(lines):
        line = lines[number]
        macro, m = MACRO.match(line), DEFINITION.match(line)
        if macro and line.endswith("\\"):
            last = number
            while last + 1 < len(lines) and lines[last].endswith("\\"):
                last += 1
            found.append((number + 1, last + 1, f"macro {macro.group(1)}"))
            number = last + 1
            continue
        if m and not line.startswith(("typedef", "struct", "#", "return", "else")):
            head = number
            while head < len(lines) and head < number + 40 and not lines[head].rstrip().endswith((";", "{", "}")):
                head += 1
            if head == number and "{" in line and line.rstrip().endswith("}"):        # on one line
                found.append((number + 1, number + 1, m.group(1)))
            elif head < len(lines) and lines[head].rstrip().endswith("{"):
                last = head + 1
                while last < len(lines) and not lines[last].startswith("}"):
                    last += 1
                found.append((number + 1, last + 1, m.group(1)))
                number = last + 1
                continue
        number += 1
    return found


def by_function(costs: Counter) -> Counter:
    """Ir by the function whose source line it is (a line outside any definition: the macro call it is, else
    '<file>, other')."""
    spans: dict[str, list[tuple[int, int, str]]] = {}
    totals: Counter = Counter()
    for (path, line), ir in costs.items():
        if path not in spans:
            spans[path] = functions_of(path)
        name = next((n for a, b, n in spans[path] if a <= line <= b), None)
        if name is None:      # OpenPLC's headers expand their typed functions from macro calls: name the call
            text = source_line(path, line)
            name = f"{Path(path).name}: {text}" if re.fullmatch(r"\w+\(\w*\)", text) else f"{Path(path).name}, other"
        totals[name] += ir
    return totals


def source_line(path: str, line: int) -> str:
    try:
        return Path(path).read_text(errors="replace").splitlines()[line - 1].strip()
    except (OSError, IndexError):
        return ""


def pou_name(function: str) -> str:
    """The POU a generated function belongs to, in MATIEC's spelling (FB_ATCCHANGER, F_NEXTPOCKET, TON)."""
    for pattern in (r"^P_(\w+)_body$", r"^(\w+)_body__$", r"^U_(\w+)$"):
        m = re.match(pattern, function)
        if m:
            return m.group(1)
    return function


def matiec_env() -> tuple[Path, Path, Path] | None:
    iec2c, lib, include = (os.environ.get(v) for v in ("IEC2C", "IEC2C_LIB", "IEC2C_CINCLUDE"))
    if not (iec2c and lib and include):
        print("MATIEC not measured: set IEC2C, IEC2C_LIB and IEC2C_CINCLUDE (plc/tests/test_matiec_optional.py)",
              file=sys.stderr)
        return None
    if shutil.which("g++") is None:
        print("MATIEC not measured: g++ is not installed", file=sys.stderr)
        return None
    return Path(iec2c), Path(lib), Path(include)


def table(head: tuple[str, ...], rows: list[tuple[str, ...]]) -> None:
    w = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    print("  ".join(h.ljust(w[i]) for i, h in enumerate(head)).rstrip())
    print("  ".join("-" * w[i] for i in range(len(head))))
    for r in rows:
        print("  ".join(c.ljust(w[i]) for i, c in enumerate(r)).rstrip())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n")[-1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--top", type=int, default=15, help="functions in the breakdown (default 15)")
    ap.add_argument("--keep", type=Path,
                    help="build in this directory (new or empty) and keep the builds and callgrind outputs")
    ap.add_argument("--baseline", metavar="REV",
                    help="also build the program with the compiler of git revision REV (e.g. the last stop's "
                         "commit) and report ours against it, measured in the same run")
    args = ap.parse_args()
    if args.keep and args.keep.exists() and any(args.keep.iterdir()):
        print(f"bench_scan: --keep {args.keep}: the directory is not empty", file=sys.stderr)
        return 2
    if shutil.which("valgrind") is None:
        print("skipped: valgrind is not installed (apt-get install valgrind)")
        return 0
    short = revision(args.baseline) if args.baseline else None
    matiec = matiec_env()
    with tempfile.TemporaryDirectory() as d:
        work = args.keep or Path(d)
        work.mkdir(parents=True, exist_ok=True)
        deploy = deploy_file(work / "deploy.st")
        builds = {OURS: (build_ours(deploy, work / "ours", ("-O2", *DEBUG)), "ours")}
        baseline = None
        if short:
            exe = build_baseline(short, deploy, work / "baseline")
            baseline = f"ours at {short} (--baseline), gcc -O2"
            builds[baseline] = (exe, "ours")
        if matiec:
            builds[MATIEC_O2] = (build_matiec(deploy, work / "matiec-O2", *matiec, ("-O2", *DEBUG)), "matiec")
            builds[MATIEC_O0] = (build_matiec(deploy, work / "matiec-O0", *matiec, DEBUG), "matiec")
        script, host = record_script(builds[OURS][0])
        scans = script.count("\n")
        reference = answers(builds[OURS][0], script)
        results, same = {}, {}
        for label, (exe, kind) in builds.items():
            same[label] = answers(exe, script) == reference
            costs = count(exe, SCAN_FUNCTION[kind], script)
            results[label] = (sum(costs.values()), by_function(costs))
            if label == OURS:       # read now: the sources go with the temporary directory
                hot = [(path, line, ir, source_line(path, line)) for (path, line), ir in costs.most_common(LINES)]
    print(f"host script: the MATIEC differential's plan once, {scans} scans, {dict(host.events)}")
    print("counted: valgrind --tool=callgrind --collect-atstart=no --toggle-collect=<scan function> (ours plc_run, "
          "MATIEC config_run__): the scans alone, start-up and the driver's I/O left out")
    per_scan = {label: ir / scans for label, (ir, _f) in results.items()}
    m2 = per_scan.get(MATIEC_O2)
    rows = []
    for label, ir in per_scan.items():
        ratio = f"{ir / m2:.2f}x" if m2 else "-"
        rows.append((label, f"{ir:,.0f}", f"{results[label][0]:,}", ratio, "yes" if same[label] else "NO"))
    table(("build", "Ir/scan", "Ir (all scans)", "/ MATIEC -O2", "same answers as ours"), rows)
    ok = True
    if m2:
        ratio = per_scan[OURS] / m2
        ok = ratio <= TARGET
        print(f"ours / MATIEC -O2: {ratio:.2f}x, measured in this run (target <= {TARGET}x): {'yes' if ok else 'NO'}")
    else:
        print("ours / MATIEC -O2: not measured (MATIEC is not available: see above)")
    if baseline:
        print(f"ours / {baseline.split(' (')[0]}: {per_scan[OURS] / per_scan[baseline]:.2f}x, measured in this run")
    print()
    print(f"where the instructions go: the top {args.top} functions of our build (self cost; code gcc inlined counts "
          "for the function it was written in)")
    others = {label: defaultdict(int) for label in results if label != OURS}
    for label in others:
        for fn, ir in results[label][1].items():
            others[label][pou_name(fn)] += ir
    rows = []
    total = results[OURS][0]
    for fn, ir in results[OURS][1].most_common(args.top):
        row = [fn, f"{ir / scans:,.0f}", f"{100 * ir / total:.1f}%"]
        for label in others:
            theirs = others[label].get(pou_name(fn))
            row.append(f"{theirs / scans:,.0f}" if theirs else "-")
        rows.append(tuple(row))
    table(("function (ours)", "Ir/scan", "share", *(f"{label}" for label in others)), rows)
    print("\nthe hottest source lines of our build (header lines are helpers gcc inlined into the POUs)")
    rows = []
    for path, line, ir, text in hot:
        rows.append((f"{Path(path).name}:{line}", f"{ir / scans:,.0f}", text[:90] + ("..." if len(text) > 90 else "")))
    table(("line", "Ir/scan", "C"), rows)
    for label in others:
        print(f"\n{label}: its top {args.top}")
        table(("function", "Ir/scan", "share"), [(fn, f"{ir / scans:,.0f}", f"{100 * ir / results[label][0]:.1f}%")
                                                  for fn, ir in results[label][1].most_common(args.top)])
    return 0 if ok and all(same.values()) else 1


if __name__ == "__main__":
    try:
        sys.exit(main())
    except (AssertionError, RuntimeError, subprocess.CalledProcessError, BadRevision) as failure:
        # a build or a run failed, or --baseline named no revision
        print(f"bench_scan: {failure}", file=sys.stderr)
        sys.exit(2)
