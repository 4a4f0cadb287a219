"""Compile an ST snippet with plc, run it N scans under ASan/UBSan, read the variables back.

The snippet goes through the real pipeline (`plc.driver.compile_sources`); the
C it produces is linked with tests/scan_driver.c, a generic host that sees the
program only through plc_abi.h.  When the snippet has no CONFIGURATION the
harness adds `Config0`/`Res0` with one 4 ms task and one instance per PROGRAM,
named `<Program>Inst`, in declaration order.

Builds are cached by content hash (the C text, the driver, the headers and the
flags) under $PLC_HARNESS_CACHE or the system temp directory, so re-running the
suite only recompiles what changed.

    run = run_st(SRC, scans=8)
    run.value("Main.n")            # after the last scan
    run.value("Main.n", scan=3)    # after scan 3 (1-based)
    run.series("Main.t1.Q")        # one value per scan

Every scan goes through the runtime's scan core (input latch, forced values,
tasks due, output publication) with direct I/O: `before_latch`/`mid_scan`
write image slots of located variables, and `run.image[n]`/`run.mid_image[n]`
show the slots at the end of scan n+1 and between its tasks and publication.
"""
from __future__ import annotations

import hashlib
import os
import re
import struct
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent

from plc.driver import INCLUDE, compile_sources  # noqa: E402
from plc.resources import RUNTIME_SRC  # noqa: E402
DRIVER_C = HERE / "scan_driver.c"
SCAN_CORE_C = RUNTIME_SRC / "scan_core.c"      # the runtime's scan core: the driver runs every scan through it
SAN = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all"]
CFLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", *SAN]
RUN_ENV = {"ASAN_OPTIONS": "detect_leaks=0:abort_on_error=0:exitcode=86",
           "UBSAN_OPTIONS": "print_stacktrace=1:halt_on_error=1"}
RUN_TIMEOUT = 60

# plc_type_t codes from plc_abi.h
T_BOOL, T_REAL, T_LREAL, T_STRING, T_OTHER = 1, 14, 15, 20, 0

_PROGRAM = re.compile(r"^\s*PROGRAM\s+([A-Za-z_]\w*)\s*$", re.I | re.M)
_CONFIG = re.compile(r"^\s*CONFIGURATION\b", re.I | re.M)


class HarnessError(AssertionError):
    """The snippet did not compile, the C did not build, or the run failed (sanitizer, crash, timeout)."""


def cache_dir() -> Path:
    root = os.environ.get("PLC_HARNESS_CACHE")
    d = Path(root) if root else Path(tempfile.gettempdir()) / f"plc-harness-{os.getuid()}"
    d.mkdir(parents=True, exist_ok=True)
    return d


def with_config(text: str, interval: str = "T#4ms") -> tuple[str, dict[str, str]]:
    """The snippet plus a generated configuration (unless it has one), and program -> instance names."""
    programs = _PROGRAM.findall(text)
    if _CONFIG.search(text):
        return text, {}
    if not programs:
        raise HarnessError("snippet has neither a PROGRAM nor a CONFIGURATION")
    inst = {p.upper(): f"{p}Inst".upper() for p in programs}
    lines = ["", "CONFIGURATION Config0", "    RESOURCE Res0 ON PLC",
             f"        TASK task0(INTERVAL := {interval}, PRIORITY := 0);"]
    lines += [f"        PROGRAM {p}Inst WITH task0 : {p};" for p in programs]
    lines += ["    END_RESOURCE", "END_CONFIGURATION", ""]
    return text + "\n".join(lines), inst


def compile_st(text: str, name: str = "snippet.st", **kw):
    """compile_sources on one in-memory file (plus the built-in standard FBs)."""
    return compile_sources([], extra_texts=[(name, text)], **kw)


def render(res) -> str:
    return "\n".join(d.render(res.sources) for d in res.diags.sorted())


def _hash(*parts: bytes | str) -> str:
    h = hashlib.sha256()
    for p in parts:
        h.update(p.encode() if isinstance(p, str) else p)
        h.update(b"\0")
    return h.hexdigest()[:20]


def _gcc(args: list[str]) -> None:
    proc = subprocess.run(["gcc", *args], capture_output=True, text=True)
    if proc.returncode != 0:
        raise HarnessError("gcc failed: " + " ".join(args) + "\n" + proc.stderr[-4000:])


def _headers() -> bytes:
    return b"".join(p.read_bytes() for p in [*sorted(INCLUDE.glob("*.h")), RUNTIME_SRC / "scan_core.h"])


def _driver_sources() -> bytes:
    return DRIVER_C.read_bytes() + b"\0" + SCAN_CORE_C.read_bytes()


def driver_object() -> Path:
    """The scan driver and the scan core, compiled and linked into one relocatable object; cached."""
    key = _hash(_driver_sources(), _headers(), *CFLAGS)
    obj = cache_dir() / f"driver-{key}.o"
    if not obj.exists():
        tmp = obj.with_suffix(f".{os.getpid()}.tmp.o")
        parts = [obj.with_suffix(f".{os.getpid()}.{src.stem}.o") for src in (DRIVER_C, SCAN_CORE_C)]
        try:
            for src, part in zip((DRIVER_C, SCAN_CORE_C), parts, strict=True):
                _gcc([*CFLAGS, f"-I{INCLUDE}", f"-I{RUNTIME_SRC}", "-c", str(src), "-o", str(part)])
            _gcc(["-r", "-nostdlib", *map(str, parts), "-o", str(tmp)])
        finally:
            for part in parts:
                part.unlink(missing_ok=True)
        os.replace(tmp, obj)
    return obj


def build_c(c_text: str) -> Path:
    """Compile generated C with the sanitizers and link it with the scan driver; cached."""
    key = _hash(c_text, _driver_sources(), _headers(), *CFLAGS)
    exe = cache_dir() / f"prog-{key}"
    if exe.exists():
        return exe
    drv = driver_object()
    work = Path(tempfile.mkdtemp(prefix="build-", dir=cache_dir()))
    try:
        c_file = work / "program.c"
        c_file.write_text(c_text)
        _gcc([*CFLAGS, f"-I{INCLUDE}", "-c", str(c_file), "-o", str(work / "program.o")])
        _gcc([*SAN, str(work / "program.o"), str(drv), "-lm", "-o", str(work / "prog")])
        os.replace(work / "prog", exe)
    finally:
        for f in work.iterdir():
            f.unlink()
        work.rmdir()
    return exe


def _parse_string(s: str) -> str:
    assert s.startswith('"') and s.endswith('"'), s
    body = s[1:-1]
    return re.sub(r"\\x([0-9a-f]{2})", lambda m: chr(int(m.group(1), 16)), body)


def _parse_value(code: int, text: str):
    if code == T_STRING:
        return _parse_string(text)
    if text.startswith("#"):
        return bytes.fromhex(text[1:])
    if code in (T_REAL, T_LREAL):
        return float(text)
    if code == T_BOOL:
        return text == "1"
    return int(text)


@dataclass
class Fault:
    kind: int
    pou: str
    line: int
    col: int


@dataclass
class VarInfo:
    type: int
    retain: bool
    constant: bool
    size: int


@dataclass
class Located:
    address: str
    area: str
    size: str
    type: int
    index: int
    bit: int


@dataclass
class ScanRun:
    """What the driver printed: per-scan run() results, variables and faults."""
    base_tick_ns: int
    tasks: list[tuple[str, int, int, int]]
    rcs: list[int] = field(default_factory=list)
    scans: list[dict[str, object]] = field(default_factory=list)
    faults: list[Fault | None] = field(default_factory=list)
    instances: dict[str, str] = field(default_factory=dict)
    c_text: str = ""
    var_table: dict[str, VarInfo] = field(default_factory=dict)
    located: dict[str, Located] = field(default_factory=dict)     # by variable path
    image: list[dict[str, object]] = field(default_factory=list)       # per scan: address -> image slot at scan end
    mid_image: list[dict[str, object]] = field(default_factory=list)   # per scan: the slot after the tasks ran
    done: list[int] = field(default_factory=list)        # scan numbers the core's scan_done hook reported

    def path(self, name: str) -> str:
        """Full upper-case path of `Program.var...` (or of a full CONFIG0... path)."""
        up = name.upper()
        if up in self.var_table or up in self.located or (self.scans and up in self.scans[-1]):
            return up
        head, _, rest = up.partition(".")
        if head in self.instances:
            return f"CONFIG0.RES0.{self.instances[head]}.{rest}"
        if len(self.instances) == 1:
            return f"CONFIG0.RES0.{next(iter(self.instances.values()))}.{up}"
        return up

    def value(self, name: str, scan: int | None = None):
        """Value after `scan` (1-based; default the last scan)."""
        vals = self.scans[-1] if scan is None else self.scans[scan - 1]
        p = self.path(name)
        if p not in vals:
            raise KeyError(f"{name} ({p}) not printed; known: {sorted(vals)[:40]}")
        return vals[p]

    def info(self, name: str) -> VarInfo:
        return self.var_table[self.path(name)]

    def series(self, name: str) -> list:
        p = self.path(name)
        return [s[p] for s in self.scans]

    def ints(self, name: str, fmt: str, scan: int | None = None) -> list:
        """An array of elementary values decoded from its bytes; fmt is a struct code ('h' for INT...)."""
        raw = self.value(name, scan)
        n = len(raw) // struct.calcsize(fmt)
        return list(struct.unpack(f"<{n}{fmt}", raw))

    @property
    def fault(self) -> Fault | None:
        return next((f for f in self.faults if f is not None), None)


World = dict[int, dict[str, int]]    # scan (1-based) -> {located address: value}


def _world_args(flag: str, writes: World | None) -> list[str]:
    return [a for scan, slots in sorted((writes or {}).items()) for addr, v in slots.items()
            for a in (flag, f"{scan}:{addr}={int(v)}")]


def run_c(c_text: str, scans: int, paths: list[str] | None = None, last_only: bool = False,
          before_latch: World | None = None, mid_scan: World | None = None,
          forced: dict[str, int] | None = None) -> ScanRun:
    """Run the program `scans` scans through the scan core.  The world writes image slots of located variables:
    `before_latch` just before the input latch of a scan, `mid_scan` after the latch, before the tasks.
    `forced` forces located variables (address -> value) through the core's forcing hooks in every scan."""
    exe = build_c(c_text)
    args = [str(exe), str(scans)]
    if last_only:
        args.append("-l")
    args += _world_args("-w", before_latch) + _world_args("-m", mid_scan)
    args += [a for addr, v in (forced or {}).items() for a in ("-f", f"{addr}={int(v)}")]
    args += paths or []
    try:
        proc = subprocess.run(args, capture_output=True, text=True, timeout=RUN_TIMEOUT,
                              env={**os.environ, **RUN_ENV})
    except subprocess.TimeoutExpired as e:
        raise HarnessError(f"program did not finish {scans} scans in {RUN_TIMEOUT} s") from e
    if proc.returncode != 0 or "runtime error" in proc.stderr or "Sanitizer" in proc.stderr:
        raise HarnessError(f"driver exited {proc.returncode}:\n{proc.stderr[-4000:]}")
    run = ScanRun(0, [], c_text=c_text)
    for line in proc.stdout.splitlines():
        kind, _, rest = line.partition(" ")
        if kind == "base":
            run.base_tick_ns = int(rest)
        elif kind == "task":
            n, iv, every, prio = rest.split()
            run.tasks.append((n, int(iv), int(every), int(prio)))
        elif kind == "var":
            path, code, retain, const, size = rest.split()
            run.var_table[path] = VarInfo(int(code), retain == "1", const == "1", int(size))
        elif kind == "loc":
            addr, path, area, size, code, index, bit = rest.split()
            run.located[path] = Located(addr, area, size, int(code), int(index), int(bit))
        elif kind == "scan":
            _, _, rc = rest.split()
            run.rcs.append(int(rc))
            run.scans.append({})
            run.faults.append(None)
            run.image.append({})
        elif kind == "done":
            run.done.append(int(rest))
        elif kind in ("i", "m"):
            addr, code, val = rest.split(" ", 2)
            if kind == "m":       # printed during the scan, before its "scan" line
                while len(run.mid_image) <= len(run.scans):
                    run.mid_image.append({})
                run.mid_image[len(run.scans)][addr] = _parse_value(int(code), val)
            else:
                run.image[-1][addr] = _parse_value(int(code), val)
        elif kind == "fault":
            k, pou, ln, col = rest.split()
            run.faults[-1] = Fault(int(k), pou, int(ln), int(col))
        elif kind == "v":
            path, code, val = rest.split(" ", 2)
            run.scans[-1][path] = _parse_value(int(code), val)
    if last_only:
        last = run.scans[-1]
        run.scans = [{} for _ in run.scans[:-1]] + [last]
    return run


def run_st(text: str, scans: int = 1, paths: list[str] | None = None, last_only: bool = False,
           interval: str = "T#4ms", before_latch: World | None = None, mid_scan: World | None = None,
           forced: dict[str, int] | None = None) -> ScanRun:
    """Compile `text` (adding a configuration if it has none), run `scans` scans, return the values."""
    full, inst = with_config(text, interval)
    res = compile_st(full)
    if not res.ok or res.c_text is None:
        raise HarnessError("snippet does not compile:\n" + render(res))
    tmp = ScanRun(0, [], instances=inst)
    wanted = [tmp.path(p) for p in paths] if paths else None
    run = run_c(res.c_text, scans, wanted, last_only, before_latch, mid_scan, forced)
    run.instances = inst
    return run
