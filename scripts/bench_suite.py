"""The test suite's wall time (issue 33 point 3), from the runs scripts/test recorded on this machine.

A whole `scripts/test` takes 20 to 90 minutes, so the bench does not run it: every run of scripts/test appends one
line to build/suite-times.tsv (the time it ended, the commit, with or without the LinuxCNC suites, the 1-minute load
at its end, its wall time in seconds, passed/failed/skipped and each phase's seconds), and this script prints the
newest runs as a table and the newest run's wall time as a ratio of the newest earlier run of another commit with
the same suites (e2e or not). Those two runs are not the same run, so the load of each is printed beside it: a
ratio between runs at very different loads says more about the machine than about the change.

    scripts/bench_suite.py [--file PATH] [--last N]

Exit status: 0 (also when no run is recorded yet: it says so), 2 when the file has a line it cannot read.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import NamedTuple

ROOT = Path(__file__).resolve().parent.parent


class BadRecord(Exception):
    """A line of the record that is not one scripts/test wrote: its position and what is wrong."""


class Run(NamedTuple):
    ended: str
    commit: str
    suites: str
    load: float
    wall: int
    counts: str
    phases: str


def read_runs(path: Path) -> list[Run]:
    runs = []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip():
            continue
        fields = line.split("\t")
        try:
            ended, commit, suites, load, wall, counts, phases = fields
            runs.append(Run(ended, commit, suites, float(load), int(wall), counts, phases))
        except ValueError:
            raise BadRecord(f"{path}:{number}: not a scripts/test record (7 tab-separated fields: time, commit, "
                            f"suites, load, wall seconds, passed/failed/skipped, phases): {line[:80]!r}") from None
    return runs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--file", type=Path, default=ROOT / "build" / "suite-times.tsv",
                    help="the record scripts/test writes (default: build/suite-times.tsv)")
    ap.add_argument("--last", type=int, default=6, help="how many of the newest runs to list (default 6)")
    args = ap.parse_args()
    if not args.file.is_file():
        print(f"no scripts/test run recorded on this machine yet ({args.file}): run scripts/test")
        return 0
    try:
        runs = read_runs(args.file)
    except BadRecord as e:
        print(e, file=sys.stderr)
        return 2
    if not runs:
        print(f"no scripts/test run recorded in {args.file}")
        return 0
    rows = [("ended", "commit", "suites", "load", "wall", "passed/failed/skipped", "phases")]
    rows += [(r.ended, r.commit, r.suites, f"{r.load:.1f}", f"{r.wall} s", r.counts, r.phases)
             for r in runs[-args.last:]]
    widths = [max(len(row[i]) for row in rows) for i in range(6)]
    for row in rows[:1] + [tuple("-" * w for w in widths) + ("-" * 6,)] + rows[1:]:
        print("  ".join(cell.ljust(widths[i]) for i, cell in enumerate(row[:6])) + "  " + row[6])
    newest = runs[-1]
    earlier = [r for r in runs[:-1] if r.commit != newest.commit and r.suites == newest.suites]
    if earlier:
        base = earlier[-1]
        print(f"suite wall time: {newest.wall} s at {newest.commit} (load {newest.load:.1f}) = "
              f"{newest.wall / base.wall:.2f}x {base.wall} s at {base.commit} (load {base.load:.1f}), {newest.suites}")
    else:
        print(f"suite wall time: {newest.wall} s at {newest.commit} (load {newest.load:.1f}), {newest.suites}; "
              f"no earlier run of another commit with the same suites to compare with")
    return 0


if __name__ == "__main__":
    sys.exit(main())
