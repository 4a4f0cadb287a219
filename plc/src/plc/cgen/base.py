"""What the C generator's parts share: C spelling helpers and `GenBase`, the output buffer and generation state."""
from __future__ import annotations

import re

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


def c_string(s: str) -> str:
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
    def __init__(self, prog: Program, test_build: bool = False, config_name: str | None = None):
        self.p = prog
        self.test_build = test_build
        self.out: list[str] = []
        self.ind = 0
        self.fn: FuncSym | None = None        # FUNCTION being generated
        self.pou: A.Pou | None = None
        self.tmp = 0
        self.cfg = None
        if prog.configs:
            self.cfg = prog.configs[0]

    # ------------------------------------------------------------------ output --
    def w(self, line: str = "") -> None:
        self.out.append("    " * self.ind + line if line else "")
