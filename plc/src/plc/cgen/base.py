"""What the C generator's parts share: C spelling helpers and `GenBase`, the output buffer and generation state."""
from __future__ import annotations

import re
import zlib
from contextlib import contextmanager
from dataclasses import dataclass

from .. import ast as A
from ..passes.context import Program
from ..symbols import FuncSym

C_RESERVED = re.compile(r"^(NULL|NAN|INFINITY|HUGE_VAL[FL]?|EOF|BUFSIZ|FILENAME_MAX|TMP_MAX|RAND_MAX|EXIT_SUCCESS|"
                        r"EXIT_FAILURE|MB_CUR_MAX|FP_[A-Z]+|M_[A-Z0-9_]+|MATH_ERR[A-Z]+|L_tmpnam|SEEK_[A-Z]+|"
                        r"(U?INT|INT_FAST|INT_LEAST|UINT_FAST|UINT_LEAST)[0-9]*_(MAX|MIN|C)|U?INTMAX_(MAX|MIN|C)|"
                        r"U?INTPTR_(MAX|MIN)|PTRDIFF_(MAX|MIN)|SIZE_MAX|SIG_[A-Z]+|WCHAR_(MAX|MIN)|WINT_(MAX|MIN)|"
                        r"SIG_ATOMIC_(MAX|MIN)|PLC_.*|_IO.*|E[A-Z0-9]+)$")


# How every generated function, variable and table is declared: file-local, and maybe unused (not every program
# uses every helper, and gcc's -Wunused under -Werror must not stop the build).  Inline helpers are "static inline".
STATIC = "static PLC_UNUSED"


def cid(name: str) -> str:
    """C spelling of an (upper-case) ST identifier."""
    return name + "_V" if C_RESERVED.match(name) else name


# The units of a split build (codegen.Gen.units) besides one per source file.
MAIN_UNIT = "<main>"        # configuration, its tables, the state every unit shares
TESTS_UNIT = "<tests>"      # the table of tests (plc_tests)
SITES_UNIT = "<sites>"      # the table of sites, each unit's site map
TYPES_UNIT = "<types>"      # the initialisers of arrays and structures


def unit_id(unit: str) -> str:
    """A C identifier (and file name) for a unit: a source file's is stable across builds."""
    if unit in (MAIN_UNIT, TESTS_UNIT, SITES_UNIT, TYPES_UNIT):
        return unit.strip("<>")
    stem = re.sub(r"[^A-Za-z0-9]+", "_", unit).strip("_")[-48:]
    return f"u_{stem}_{zlib.crc32(unit.encode()):08x}"


@dataclass
class Piece:
    """A run of the buffer's lines: a declaration (`defines` the C names it declares: a split build's units
    take the declarations their text names), a definition in one translation unit (`unit`), or, with neither,
    part of the preamble every unit starts with."""
    start: int
    end: int
    defines: tuple[str, ...] = ()
    unit: str | None = None


PLAIN = re.compile(r'[ !#-\[\]-~]*')     # printable ASCII but '"' and '\\': written as it is


def c_string(s: str) -> str:
    if PLAIN.fullmatch(s):
        return f'"{s}"'
    out = []
    for ch in s.encode("latin-1", "replace"):
        c = chr(ch)
        if c == "\\":
            out.append("\\\\")
        elif c == '"':
            out.append('\\"')
        elif 32 <= ch < 127:
            out.append(c)
        else:
            out.append(f"\\{ch:03o}")
    return '"' + "".join(out) + '"'


def c_compare(a: str, cop: str, b: str) -> str:
    """A C comparison; `x = x` is legal ST, so keep gcc's -Wtautological-compare quiet about it."""
    return f"({a} {cop} +({b}))" if a == b else f"({a} {cop} {b})"


class GenBase:
    def __init__(self, prog: Program, test_build: bool = False, config_name: str | None = None,
                 split: bool = False):
        self.p = prog
        self.test_build = test_build
        # split: one translation unit per source file (codegen.Gen.units), what units share declared extern
        self.split = split
        self.linkage = "PLC_UNUSED" if split else STATIC    # of the functions and variables units share
        self.pieces: list[Piece] = []                       # marks over `out`
        self.unit: str | None = None                        # the unit being written (split build)
        self.unit_sites: dict[str, list[int]] = {}          # per unit, the sites its text names, in order
        self.memo = None                                    # a split build's codegen.PieceMemo, if any
        self.out: list[str] = []
        self.ind = 0
        self.fn: FuncSym | None = None        # FUNCTION being generated
        self.pou: A.Pou | None = None
        self.tmp = 0
        self.fold_constants = False         # reads of CONSTANTs as literals (ExpressionGen.folded): in bodies
        self.folding: set[int] = set()      # the CONSTANTs being folded (a cycle is not folded)
        self.for_locals: dict[int, str] = {}    # id(VarSym) -> the C local a FOR loop reads it from
        self.cfg = None
        if prog.configs:
            self.cfg = prog.configs[0]

    # ------------------------------------------------------------------ output --
    @contextmanager
    def piece(self, *defines: str, unit: str | None = None):
        """Mark the lines written inside as one Piece."""
        start = len(self.out)
        prev, self.unit = self.unit, unit if unit is not None else self.unit
        yield
        self.unit = prev
        self.pieces.append(Piece(start, len(self.out), defines, unit))

    def w(self, line: str = "") -> None:
        self.out.append("    " * self.ind + line if line else "")
