#!/usr/bin/env python3
"""Fuzz the plc front end and C generator: whatever the input, no traceback and no hang.

    python plc/tests/fuzz_compiler.py --runs 10000 --seed 1 [--jobs 2] [--save DIR] [--check-c 50]

Inputs are mutations of the project's own Structured Text (st_src/, iec_tests/,
the compiler's stdlib, and the ST snippets of the conformance tests): token
deletions, duplications, swaps and replacements, random bytes, truncation,
splices from other files, deep nesting, huge literals, unterminated comments
and strings.  Each input goes through `compile_sources(..., generate=True)` in a
worker process; an exception escaping it is a traceback, an input taking more
than --timeout seconds is a hang (the worker is killed and replaced).
--check-c N also compiles every Nth generated C file with gcc -Werror and
counts the failures.  Exit status 1 when anything was found.
"""
from __future__ import annotations

import argparse
import ast
import multiprocessing as mp
import os
import random
import re
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
PLC_DIR = HERE.parent
ROOT = PLC_DIR.parent

TOKEN = re.compile(r"\(\*.*?\*\)|'(?:\$.|[^'$])*'|\"(?:\$.|[^\"$])*\"|[A-Za-z_][A-Za-z0-9_]*(?:#[A-Za-z0-9_.:#-]+)?"
                   r"|\d[\d_]*(?:\.\d+)?(?:[eE][-+]?\d+)?|%[IQM][XBWDL]?[\d.]*|:=|=>|<=|>=|<>|\*\*|\.\.|\s+|.",
                   re.S)
KEYWORDS = ["IF", "THEN", "ELSIF", "ELSE", "END_IF", "CASE", "OF", "END_CASE", "FOR", "TO", "BY", "DO", "END_FOR",
            "WHILE", "END_WHILE", "REPEAT", "UNTIL", "END_REPEAT", "EXIT", "RETURN", "VAR", "VAR_INPUT", "VAR_OUTPUT",
            "VAR_IN_OUT", "VAR_EXTERNAL", "VAR_GLOBAL", "VAR_TEMP", "CONSTANT", "RETAIN", "END_VAR", "AT", "TYPE",
            "END_TYPE", "STRUCT", "END_STRUCT", "ARRAY", "OF", "FUNCTION", "END_FUNCTION", "FUNCTION_BLOCK",
            "END_FUNCTION_BLOCK", "PROGRAM", "END_PROGRAM", "CONFIGURATION", "END_CONFIGURATION", "RESOURCE", "ON",
            "END_RESOURCE", "TASK", "WITH", "INTERVAL", "PRIORITY", "SINGLE", "NOT", "AND", "OR", "XOR", "MOD",
            "TRUE", "FALSE", "INT", "DINT", "BOOL", "REAL", "TIME", "STRING", "WORD", "TON", "EN", "ENO",
            ":=", "=>", ";", ":", ",", "(", ")", "[", "]", ".", "..", "#", "+", "-", "*", "/", "**", "=", "<>",
            "<", ">", "^", "&", "{", "}", "%QX0.0", "%IW3", "T#5s", "16#FF", "WORD#16#8000", "'text'", "2.5E3"]
HUGE = ["9" * 400, "16#" + "F" * 200, "2#" + "1" * 300, "T#" + "9" * 50 + "d", "1.0E999999", "1" + "0" * 30 + ".5",
        "INT#" + "9" * 40, "'" + "x" * 5000 + "'", "T#1d" * 200, "D#99999-99-99", "TOD#99:99:99.999999999",
        "DT#1970-01-01-" + "9" * 30 + ":00:00", "%QW" + "9" * 30, "%QX0." + "9" * 20, "ARRAY[1.." + "9" * 25 + "]",
        "-" * 3000 + "1", "NOT " * 3000 + "TRUE"]
# Replacements that usually keep a program valid, so the mutant reaches the C generator.
SAME_CLASS = [["+", "-", "*", "/", "MOD"], ["AND", "OR", "XOR", "&"], ["<", ">", "<=", ">=", "=", "<>"],
              ["TRUE", "FALSE"], ["0", "1", "-1", "2", "7", "127", "255", "32767", "-32768", "65535", "2147483647"],
              ["T#0s", "T#1ms", "T#4ms", "T#1s500ms", "T#-5s", "T#1d2h3m4s5ms"]]
UNTERMINATED = ["(*", "/*", "'", '"', "{", "(* (* ", "'$", "16#", "T#", "%", "2#102", "8#9", "1.", "1e"]


# ----------------------------------------------------------------------------- corpus
def corpus() -> list[tuple[str, str]]:
    """(name, text) of every ST source the project has, plus the conformance snippets."""
    items: list[tuple[str, str]] = []
    for d in (ROOT / "st_src", ROOT / "iec_tests", PLC_DIR / "src" / "plc" / "stdlib"):
        for p in sorted(d.rglob("*.st")) if d.is_dir() else []:
            items.append((str(p.relative_to(ROOT)), p.read_text(errors="replace")))
    for p in sorted(HERE.glob("test_*.py")):
        try:
            tree = ast.parse(p.read_text())
        except SyntaxError:
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and "END_" in node.value \
                    and len(node.value) > 40:
                items.append((f"{p.name}:{node.lineno}", node.value))
    return items


# -------------------------------------------------------------------------- mutations
def tokens(text: str) -> list[str]:
    return TOKEN.findall(text)


def significant(toks: list[str]) -> list[int]:
    return [i for i, t in enumerate(toks) if not t.isspace()]


def mutate(text: str, rng: random.Random, others: list[tuple[str, str]]) -> tuple[str, list[str]]:
    ops = []
    for _ in range(rng.choice((1, 1, 1, 2, 2, 3, 5))):
        toks = tokens(text)
        sig = significant(toks)
        op = rng.choice(("delete", "delete", "duplicate", "swap", "replace", "replace", "bytes", "truncate",
                         "splice", "nest", "huge", "unterminated", "repeat", "mild", "mild", "mild", "mild",
                         "mild", "mild", "line"))
        ops.append(op)
        if not sig:
            op = "bytes"
        if op == "delete":
            del toks[rng.choice(sig)]
        elif op == "duplicate":
            i = rng.choice(sig)
            toks.insert(i, toks[i] + (" " if rng.random() < 0.5 else ""))
        elif op == "swap":
            i, j = rng.choice(sig), rng.choice(sig)
            if rng.random() < 0.5:                      # neighbours
                k = sig.index(i)
                j = sig[min(k + 1, len(sig) - 1)]
            toks[i], toks[j] = toks[j], toks[i]
        elif op == "replace":
            toks[rng.choice(sig)] = rng.choice(KEYWORDS) if rng.random() < 0.7 else rng.choice(tokens(
                rng.choice(others)[1]) or ["x"])
        elif op == "bytes":
            i = rng.randrange(len(toks) + 1)
            junk = "".join(chr(rng.choice((rng.randrange(0, 32), rng.randrange(32, 127), rng.randrange(127, 256),
                                           rng.randrange(256, 0x3000)))) for _ in range(rng.randint(1, 8)))
            toks.insert(i, junk)
        elif op == "truncate":
            cut = rng.randrange(len(text) + 1)
            return text[:cut], ops
        elif op == "splice":
            other = tokens(rng.choice(others)[1])
            if other:
                a = rng.randrange(len(other))
                piece = other[a:a + rng.randint(1, 40)]
                i = rng.randrange(len(toks) + 1)
                toks[i:i] = piece
        elif op == "nest":
            depth = rng.choice((50, 200, 1000, 3000))
            kind = rng.choice(("if", "paren", "call", "while", "case", "array"))
            if kind == "if":
                piece = "IF TRUE THEN " * depth + "x := 1; " + "END_IF; " * depth
            elif kind == "paren":
                piece = "x := " + "(" * depth + "1" + ")" * depth + ";"
            elif kind == "call":
                piece = "x := " + "ABS(" * depth + "1" + ")" * depth + ";"
            elif kind == "while":
                piece = "WHILE FALSE DO " * depth + "x := 1; " + "END_WHILE; " * depth
            elif kind == "case":
                piece = "CASE x OF 1: " * depth + "x := 1; " + "END_CASE; " * depth
            else:
                piece = "x : ARRAY[1..2] OF " * depth + "INT;"
            i = rng.randrange(len(toks) + 1)
            toks.insert(i, piece)
        elif op == "huge":
            nums = [k for k in sig if toks[k][:1].isdigit() or "#" in toks[k]]
            k = rng.choice(nums) if nums and rng.random() < 0.8 else rng.choice(sig)
            toks[k] = rng.choice(HUGE)
        elif op == "unterminated":
            toks.insert(rng.randrange(len(toks) + 1), rng.choice(UNTERMINATED))
        elif op == "mild":
            cands = [(k, cls) for k in sig for cls in SAME_CLASS if toks[k].upper() in cls]
            if cands:
                k, cls = rng.choice(cands)
                toks[k] = rng.choice(cls)
        elif op == "line":                              # duplicate a whole statement line
            lines = text.splitlines(keepends=True)
            stmts = [i for i, ln in enumerate(lines) if ln.rstrip().endswith(";") and ":=" in ln]
            if stmts:
                i = rng.choice(stmts)
                lines.insert(i, lines[i])
                text = "".join(lines)
                continue
        elif op == "repeat":
            i = rng.choice(sig)
            toks[i:i + 1] = [toks[i]] * rng.choice((2, 10, 500))
        text = "".join(toks)
    return text, ops


# ----------------------------------------------------------------------------- worker
def compile_one(text: str, check_c: bool) -> tuple[str, str]:
    """("ok" | "error" | "traceback" | "cc-fail", detail) for one input."""
    from plc.driver import INCLUDE, compile_sources
    try:
        res = compile_sources([], extra_texts=[("fuzz.st", text)], generate=True)
    except BaseException as e:            # anything escaping is what we are looking for
        if isinstance(e, KeyboardInterrupt):
            raise
        tb = traceback.extract_tb(e.__traceback__)
        where = next((f"{Path(f.filename).name}:{f.lineno}" for f in reversed(tb) if "/src/plc/" in f.filename),
                     f"{Path(tb[-1].filename).name}:{tb[-1].lineno}" if tb else "?")
        return "traceback", f"{type(e).__name__} at {where}: {str(e)[:200]}"
    if res.c_text is None:
        return "error", ""
    if check_c:
        with tempfile.TemporaryDirectory() as d:
            c = Path(d) / "p.c"
            c.write_text(res.c_text)
            proc = subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-fsyntax-only", f"-I{INCLUDE}",
                                   str(c)], capture_output=True, text=True)
            if proc.returncode != 0:
                first = next((ln for ln in proc.stderr.splitlines() if "error" in ln), proc.stderr[:200])
                return "cc-fail", re.sub(r"^.*?p\.c:\d+:\d+: ", "", first)[:200]
    return "ok", ""


def worker(conn) -> None:
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 1000))
    while True:
        msg = conn.recv()
        if msg is None:
            return
        idx, text, check_c = msg
        conn.send((idx,) + compile_one(text, check_c))


class Pool:
    """Worker processes fed one input at a time, so a hang costs one worker, not the run."""

    def __init__(self, jobs: int, timeout: float):
        self.ctx = mp.get_context("fork")
        self.timeout = timeout
        self.slots = [self.spawn() for _ in range(jobs)]

    def spawn(self):
        a, b = self.ctx.Pipe()
        p = self.ctx.Process(target=worker, args=(b,), daemon=True)
        p.start()
        return {"proc": p, "conn": a, "job": None, "t0": 0.0}

    def run(self, jobs, on_result) -> None:
        jobs = iter(jobs)
        pending = True
        while True:
            for s in self.slots:
                if s["job"] is None and pending:
                    try:
                        job = next(jobs)
                    except StopIteration:
                        pending = False
                        continue
                    s["job"], s["t0"] = job, time.monotonic()
                    s["conn"].send((job[0], job[1], job[2]))
            busy = [s for s in self.slots if s["job"] is not None]
            if not busy:
                return
            ready = mp.connection.wait([s["conn"] for s in busy], timeout=0.05)
            for s in busy:
                if s["conn"] in ready:
                    try:
                        _idx, status, detail = s["conn"].recv()
                    except EOFError:
                        status, detail = "traceback", "worker died"
                    on_result(s["job"], status, detail, time.monotonic() - s["t0"])
                    s["job"] = None
                    if status == "traceback" and detail == "worker died":
                        self.replace(s)
                elif time.monotonic() - s["t0"] > self.timeout:
                    on_result(s["job"], "hang", f"> {self.timeout:g} s", time.monotonic() - s["t0"])
                    self.replace(s)

    def replace(self, s) -> None:
        s["proc"].kill()
        s["proc"].join()
        s.update(self.spawn())

    def close(self) -> None:
        for s in self.slots:
            try:
                s["conn"].send(None)
            except OSError:
                pass
            s["proc"].join(timeout=2)
            if s["proc"].is_alive():
                s["proc"].kill()


# ------------------------------------------------------------------------------- main
def fuzz(runs: int, seed: int, jobs: int = 1, timeout: float = 2.0, check_c_every: int = 0,
         save: Path | None = None, verbose: bool = False) -> dict:
    rng = random.Random(seed)
    items = corpus()
    # Snippets and the stdlib compile on their own, so their mutants reach the C generator;
    # project files alone mostly stop at unresolved names.  Favour the former.
    whole = [it for it in items if ".py:" in it[0] or "/stdlib/" in it[0]] or items
    stats = {"runs": 0, "ok": 0, "error": 0, "traceback": 0, "hang": 0, "cc-fail": 0, "cc-checked": 0,
             "slowest": 0.0, "findings": {}}

    def inputs():
        for k in range(runs):
            name, text = rng.choice(whole if rng.random() < 0.6 else items)
            mutated, ops = mutate(text, rng, items)
            check = bool(check_c_every) and k % check_c_every == 0
            yield (k, mutated, check, name, ops)

    def on_result(job, status, detail, elapsed):
        k, text, check, name, ops = job
        stats["runs"] += 1
        stats[status] += 1
        stats["cc-checked"] += int(check and status in ("ok", "cc-fail"))
        stats["slowest"] = max(stats["slowest"], elapsed)
        if status in ("traceback", "hang", "cc-fail"):
            key = f"{status}: {detail}"
            first = stats["findings"].setdefault(key, {"count": 0, "example": k, "source": name, "ops": ops})
            first["count"] += 1
            if save is not None and first["count"] == 1:
                save.mkdir(parents=True, exist_ok=True)
                (save / f"{status}-{k}.st").write_text(text, errors="replace")
            if verbose:
                print(f"[{k}] {key} ({name}, {'+'.join(ops)})", file=sys.stderr)

    pool = Pool(jobs, timeout)
    try:
        pool.run(inputs(), on_result)
    finally:
        pool.close()
    return stats


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Fuzz the plc compiler with mutations of the project's ST.")
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    ap.add_argument("--timeout", type=float, default=2.0, help="seconds before an input counts as a hang")
    ap.add_argument("--check-c", type=int, default=0, metavar="N",
                    help="also compile every Nth generated C file with gcc -Werror (0: never)")
    ap.add_argument("--save", type=Path, help="write the first input of every finding here")
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    s = fuzz(args.runs, args.seed, args.jobs, args.timeout, args.check_c, args.save, args.verbose)
    wall = time.monotonic() - t0
    print(f"runs {s['runs']}  compiled to C {s['ok'] + s['cc-fail']}  rejected with diagnostics {s['error']}  "
          f"tracebacks {s['traceback']}  hangs {s['hang']}  C checked {s['cc-checked']} (failed {s['cc-fail']})  "
          f"slowest input {s['slowest']:.2f} s  wall {wall:.1f} s  (seed {args.seed}, {args.jobs} job(s))")
    for key, f in sorted(s["findings"].items(), key=lambda kv: -kv[1]["count"]):
        print(f"  {f['count']:5d}x {key}  [first: run {f['example']}, from {f['source']}, {'+'.join(f['ops'])}]")
    return 1 if s["traceback"] or s["hang"] or s["cc-fail"] else 0


if __name__ == "__main__":
    sys.exit(main())
