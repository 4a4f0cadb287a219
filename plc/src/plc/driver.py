"""The compile pipeline: files -> lexer/parser -> semantic passes -> portability -> C.

Every stage takes the previous stage's output; the AST is the only thing passed
between them.  `compile_sources` never raises for bad input: problems come back
as diagnostics.  The semantic passes run in the order SEMANTIC_PASSES names.
"""
from __future__ import annotations

import functools
import hashlib
import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

from . import ast as A
from . import buildcache, plcopen, sema
from .codegen import PieceMemo
from .codegen import generate as gen_c
from .diagnostics import Diagnostics, SourceSet
from .parser import parse, parse_text
from .portability import lint
from .resources import INCLUDE, STANDARD_FBS, STDLIB, TESTLIB

TEST_DECL = re.compile(r"\bFUNCTION_BLOCK\s+TEST_", re.IGNORECASE)

CFLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-O2"]


class UserError(Exception):
    """A problem the user must fix (bad path, missing compiler): printed without a traceback."""


@dataclass
class CompileResult:
    diags: Diagnostics
    sources: SourceSet
    files: list[A.SourceFile] = field(default_factory=list)
    program: object = None
    c_text: str | None = None
    texts: dict[str, str] = field(default_factory=dict)     # the ST text of each ST file parsed, by its name
    memo: PieceMemo | None = None                             # compile_sources(memo_cache=...)

    @property
    def ok(self) -> bool:
        return not self.diags.has_errors()


def is_source(path: Path) -> bool:
    """A source file the compiler reads: ST, or a PLCopen XML project."""
    return path.suffix.lower() == ".st" or plcopen.looks_like_plcopen(path)


def collect_files(paths: list[str | os.PathLike]) -> list[Path]:
    """The .st files and PLCopen .xml projects named by `paths` (directories are searched recursively, in
    sorted order; an .xml file that is not a PLCopen project is skipped there)."""
    out: list[Path] = []
    for p in paths:
        path = Path(p)
        if path.is_dir():
            out.extend(sorted(q for q in path.rglob("*") if q.suffix.lower() in (".st", ".xml") and q.is_file()
                              and is_source(q)))
        elif path.is_file():
            if path.suffix.lower() == ".xml" and not is_source(path):
                raise UserError(f"{p}: not a PLCopen TC6 XML project (namespace "
                                "http://www.plcopen.org/xml/tc6_0201 not found)")
            out.append(path)
        else:
            raise UserError(f"{p}: no such file or directory")
    seen = set()
    unique = []
    for f in out:
        key = f.resolve()
        if key not in seen:
            seen.add(key)
            unique.append(f)
    return unique


def display_name(path: Path) -> str:
    try:
        return os.path.relpath(path)
    except ValueError:
        return str(path)


def read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as e:
        raise UserError(f"{path}: {e.strerror}") from None


def decode(data: bytes) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def read_source(path: Path) -> str:
    return decode(read_bytes(path))


def load_user_file(path: Path, diags: Diagnostics, sources: SourceSet):
    """(name, ST text, translation or None) of one source file.  A PLCopen project becomes ST through
    the XML front end (plc/src/plc/plcopen); its XML text is kept in `sources` for rendering diagnostics,
    which `translation.remap(diags)` points back into the XML.  The text is None when it cannot be read."""
    name = display_name(path)
    if path.suffix.lower() != ".xml":
        return name, read_source(path), None
    data = read_bytes(path)
    sources.add(name, decode(data))
    tr = plcopen.translate(name, data, diags)
    if tr is None:
        return name, None, None
    return tr.st_name, tr.text, tr


def builtin_files(test_build: bool) -> list[Path]:
    files = [STANDARD_FBS]
    if test_build and TESTLIB.is_dir():
        files.extend(sorted(TESTLIB.glob("*.st")))
    return files


# The parser refuses nesting deeper than parser.MAX_DEPTH levels; the recursive passes over such a
# tree need a few thousand frames, whatever the caller's own stack depth (pytest, a worker) is.
STACK_FRAMES = 10_000


def deep_recursion(fn):
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        old = sys.getrecursionlimit()
        sys.setrecursionlimit(max(old, STACK_FRAMES))
        try:
            return fn(*args, **kwargs)
        finally:
            sys.setrecursionlimit(old)
    return wrapper


# The semantic passes in the order they run, by name (sema.PASSES: one class each in plc/src/plc/passes).
SEMANTIC_PASSES = ("declarations", "types", "scopes", "configuration", "externals", "bodies")


def analyze(files: list[A.SourceFile], diags: Diagnostics, builtin_files: set[str] | None = None,
            test_build: bool = False, skip_bodies=None):
    """The typed program (sema.Program): every semantic pass run over `files`, in SEMANTIC_PASSES order."""
    return sema.analyze(files, diags, SEMANTIC_PASSES, builtin_files, test_build, skip_bodies)


@deep_recursion
def compile_sources(paths: list[str | os.PathLike], *, test_build: bool = False, portability: bool = True,
                    target: str | None = None, generate: bool = True,
                    extra_texts: list[tuple[str, str]] | None = None,
                    memo_cache: buildcache.Cache | None = None) -> CompileResult:
    """The program of `paths` checked (diagnostics) and, with `generate`, its C as one unit.  With `memo_cache`
    (plc test: a test build, errors only), result.memo is a codegen.PieceMemo over it: the POUs whose C it holds
    are left out of the bodies pass (so their warnings are not reported) and their C comes from it."""
    diags = Diagnostics(portability=portability)
    sources = SourceSet()
    result = CompileResult(diags, sources)
    builtins = set()
    inputs: list[tuple[str, str]] = []
    user_inputs: list[tuple[str, str]] = []
    translations = []
    for f in collect_files(paths):
        name, text, tr = load_user_file(f, diags, sources)
        if text is not None:
            user_inputs.append((name, text))
        if tr is not None:
            translations.append(tr)
    user_inputs.extend(extra_texts or [])
    if test_build == "auto":
        # checking tests: load the test library when a file declares a TEST_ function block
        test_build = any(TEST_DECL.search(text) for _name, text in user_inputs)
    for f in builtin_files(test_build):
        name = f"<plc>/{f.name}" if f.parent == STDLIB else f"<plc>/testing/{f.name}"
        builtins.add(name)
        inputs.append((name, read_source(f)))
    inputs.extend(user_inputs)
    if test_build:
        inputs.append((ENUM_ASSERTS, None))         # written from the others' types, once they are parsed
    later: list[buildcache.Bodies] | None = [] if memo_cache is not None else None
    for name, text in inputs:
        if text is None:
            text = enum_asserts(result.files)
            builtins.add(name)
        sources.add(name, text)
        result.texts[name] = text
        if memo_cache is not None:          # parsed through the memo's cache, the POU bodies left for later
            result.files.append(memo_cache.parsed(text, name, diags, parse_text, later))
        else:
            result.files.append(parse(text, name, diags))
    for tr in translations:                 # placed in the XML once checked: not named by the ST text's name
        result.texts.pop(tr.st_name, None)
    skip = None
    if memo_cache is not None:
        result.memo = PieceMemo(memo_cache, result.texts, result.files, test_build)
        skip = result.memo.preload(item for f in result.files for item in f.items if isinstance(item, A.Pou))
        for bodies in later:                # the bodies of the files whose POUs are checked again, only
            if not all(skip(item) for item in bodies.tree.items if isinstance(item, A.Pou)):
                bodies.load()
    prog = analyze(result.files, diags, builtins, test_build=test_build, skip_bodies=skip)
    result.program = prog
    if diags.portability:       # the portability pass reports warnings only, through Diagnostics.portable
        lint(result.files, prog, diags, builtins, target=target)
    if len(prog.configs) > 1:
        for c in prog.configs[1:]:
            diags.error(c.decl.pos, "only one CONFIGURATION per build",
                        f"the first is {prog.configs[0].name} at {prog.configs[0].decl.pos}")
    for tr in translations:
        tr.remap(diags)
        tr.remap_tree(result.files)
    if generate and not diags.has_errors():
        result.c_text = gen_c(prog, test_build=test_build)
    return result


ENUM_ASSERTS = "<plc>/testing/enum_asserts.st"


def enum_asserts(files: list[A.SourceFile]) -> str:
    """ST text of AssertEqual_<Enum>(tc, expected, actual, msg) for every enumeration type of the build.

    Enumerations cannot be converted to numbers in MATIEC, so a typed assert per enum is generated;
    it reports the value names."""
    out = ["(* Generated by plc test: one typed assertion per enumeration type. *)"]
    for f in files:
        for item in f.items:
            if not isinstance(item, A.TypeBlock):
                continue
            for td in item.decls:
                if not isinstance(td.spec, A.EnumSpec) or any(e is not None for _v, _p, e in td.spec.values):
                    continue
                t = td.text
                fn = f"AssertEqual_{t}"
                out.append(f"""FUNCTION {fn} : BOOL
VAR_IN_OUT
    tc : ST_TestContext;
END_VAR
VAR_INPUT
    expected : {t};
    actual : {t};
    msg : STRING;
END_VAR
VAR
    names : ARRAY[0..1] OF STRING;
    k : INT;
    v : {t};
END_VAR
{fn} := expected = actual;
tc.Asserts := tc.Asserts + 1;
IF NOT {fn} THEN
    tc.Failures := tc.Failures + 1;
    tc.LastMessage := msg;
    FOR k := 0 TO 1 DO
        IF k = 0 THEN           (* names[0]: the expected value, names[1]: the actual one *)
            v := expected;
        ELSE
            v := actual;
        END_IF;
        CASE v OF
{_enum_case(td, t)}
        END_CASE;
    END_FOR;
    tc.LastExpected := names[0];
    tc.LastActual := names[1];
END_IF;
END_FUNCTION
""")
    return "\n".join(out) + "\n"


def _enum_case(td: A.TypeDecl, t: str) -> str:
    return "\n".join(f"            {t}#{v}: names[k] := '{text}';"
                     for (v, _p, _e), text in zip(td.spec.values, td.spec.texts, strict=True))


def print_diagnostics(result: CompileResult, stream=None, quiet: bool = False) -> None:
    stream = stream or sys.stderr
    for d in result.diags.sorted():
        if quiet and d.severity != "error":
            continue
        print(d.render(result.sources), file=stream)


def cc() -> str:
    for name in (os.environ.get("CC"), "gcc", "cc", "clang"):
        if name and shutil.which(name):
            return name
    raise UserError("no C compiler found (install gcc)")


class GeneratedCError(Exception):
    """The C compiler refused C that plc generated from a program that checked clean: a bug of plc's compiler,
    never of the user's program (an internal error, exit 3).  The C and the C compiler's output are kept."""

    def __init__(self, c_file: Path, log_file: Path, output: str) -> None:
        self.c_file, self.log_file, self.output = c_file, log_file, output
        lines = output.strip().splitlines() or ["(the C compiler printed nothing)"]
        shown = lines[:MAX_CC_LINES] + ([f"... ({len(lines) - MAX_CC_LINES} more lines)"]
                                        if len(lines) > MAX_CC_LINES else [])
        super().__init__("internal compiler error: the C compiler rejected the C generated for the program:\n  "
                         + "\n  ".join(shown) + f"\nthe generated C is kept in {c_file}, "
                         f"the C compiler's output in {log_file}")


MAX_CC_LINES = 30      # of the C compiler's output in the message (the log file has all of it)


def run_c_compiler(cmd: list[str], c_file: Path) -> None:
    """Run `cmd`, a C compiler given the generated `c_file`; its failure is a GeneratedCError, its output then
    kept beside the C file (`program.c` -> `program.cc.log`)."""
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        log = c_file.with_suffix(".cc.log")
        log.write_text(f"$ {shlex.join(cmd)}\n{proc.stdout}{proc.stderr}")
        raise GeneratedCError(c_file, log, proc.stderr + proc.stdout)


def compile_c(c_file: Path, out: Path) -> None:
    """The object file `out` of the generated `c_file` (plc build), from the build cache in use when it holds
    the object of this C text."""
    cache = buildcache.active()
    if cache is None:
        run_c_compiler([cc(), *CFLAGS, f"-I{INCLUDE}", "-c", str(c_file), "-o", str(out)], c_file)
        return
    unit = buildcache.Unit(c_file.stem, c_file.read_text())
    (obj,) = compile_units(cache, [unit], [*CFLAGS, f"-I{INCLUDE}"], [], c_file.parent)
    shutil.copyfile(obj, out)


def compile_units(cache: buildcache.Cache, units: list[buildcache.Unit], flags: list[str], headers: list[Path],
                  src_dir: Path) -> list[Path]:
    """buildcache.compile_units with the C compiler cc() and plc_rt.h and plc_abi.h among the headers; a unit
    the C compiler refuses is a GeneratedCError, its output kept beside its C (`NAME.c` -> `NAME.cc.log`)."""
    try:
        return buildcache.compile_units(cache, units, cc(), flags,
                                        [INCLUDE / "plc_rt.h", INCLUDE / "plc_abi.h", *headers], src_dir)
    except buildcache.UnitError as e:
        log = e.c_file.with_suffix(".cc.log")
        log.write_text(f"$ {shlex.join(e.command)}\n{e.output}")
        raise GeneratedCError(e.c_file, log, e.output) from None


def content_hash(*parts: str | bytes) -> str:
    h = hashlib.sha256()
    for p in parts:
        h.update(p.encode() if isinstance(p, str) else p)
        h.update(b"\0")
    return h.hexdigest()[:16]
