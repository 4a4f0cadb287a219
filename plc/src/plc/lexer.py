"""Hand-written lexer for IEC 61131-3 Structured Text (the MATIEC dialect).

Input: one file's text.  Output: a list of `Token`s ending with an EOF token, plus
diagnostics.  Identifiers and keywords are case-insensitive: `Token.value` holds
the upper-case spelling, `Token.text` the original.  The lexer never raises on bad
input; an unknown character becomes an error diagnostic and is skipped.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .diagnostics import Diagnostics, Pos
from .facts import Fact, fact

KEYWORDS = frozenset("""
FUNCTION END_FUNCTION FUNCTION_BLOCK END_FUNCTION_BLOCK PROGRAM END_PROGRAM
CONFIGURATION END_CONFIGURATION RESOURCE END_RESOURCE ON TASK WITH
TYPE END_TYPE STRUCT END_STRUCT ARRAY OF
VAR VAR_INPUT VAR_OUTPUT VAR_IN_OUT VAR_EXTERNAL VAR_GLOBAL VAR_TEMP VAR_ACCESS VAR_CONFIG END_VAR
CONSTANT RETAIN NON_RETAIN AT
IF THEN ELSIF ELSE END_IF CASE END_CASE FOR TO BY DO END_FOR WHILE END_WHILE
REPEAT UNTIL END_REPEAT EXIT CONTINUE RETURN
AND OR XOR NOT MOD TRUE FALSE
METHOD END_METHOD INTERFACE END_INTERFACE POINTER REF_TO EXTENDS IMPLEMENTS
STEP END_STEP TRANSITION END_TRANSITION ACTION END_ACTION INITIAL_STEP
""".split())

# Prefixes whose literal body is a duration or a date and is lexed as one token.
TIME_PREFIXES = {
    "T": "TIME", "TIME": "TIME", "LTIME": "LTIME", "LT": "LTIME",
    "TOD": "TOD", "TIME_OF_DAY": "TOD", "LTOD": "LTOD",
    "D": "DATE", "DATE": "DATE", "LDATE": "LDATE",
    "DT": "DT", "DATE_AND_TIME": "DT", "LDT": "LDT",
}

SYMBOLS = [":=", "=>", "<=", ">=", "<>", "**", "..",
           "(", ")", "[", "]", ",", ";", ":", ".", "+", "-", "*", "/", "=", "<", ">", "&", "^", "#"]

ESCAPES = {"$": "$", "'": "'", '"': '"', "L": "\n", "N": "\n", "P": "\f", "R": "\r", "T": "\t"}


@dataclass
class Token:
    kind: str      # IDENT KEYWORD INT REAL STRING TIME TYPEPFX DIRECT SYM EOF
    value: object  # upper-case name, int, float, decoded str, (kind, text), symbol
    text: str      # the source spelling
    pos: Pos

    def is_kw(self, *words: str) -> bool:
        return self.kind == "KEYWORD" and self.value in words

    def is_sym(self, *syms: str) -> bool:
        return self.kind == "SYM" and self.value in syms


# ASCII only: str.isdigit() and friends also accept '³', 'é' or Arabic digits, which
# are not IEC 61131-3 identifiers or numbers (and int('³') raises).
def is_digit(c: str) -> bool:
    return len(c) == 1 and "0" <= c <= "9"


def is_alpha(c: str) -> bool:
    return len(c) == 1 and ("a" <= c <= "z" or "A" <= c <= "Z")


def is_alnum(c: str) -> bool:
    return is_digit(c) or is_alpha(c)


class Lexer:
    def __init__(self, text: str, filename: str, diags: Diagnostics, facts: list | None = None):
        self.src = text
        self.file = filename
        self.diags = diags
        self.facts: list[Fact] = facts if facts is not None else []   # for the portability pass
        self.i = 0
        self.line = 1
        self.col = 1
        self.tokens: list[Token] = []

    # -- position bookkeeping -------------------------------------------------
    def pos(self) -> Pos:
        return Pos(self.file, self.line, self.col)

    def advance(self, n: int = 1) -> None:
        for _ in range(n):
            if self.i >= len(self.src):
                return
            if self.src[self.i] == "\n":
                self.line += 1
                self.col = 1
            else:
                self.col += 1
            self.i += 1

    def peek(self, k: int = 0) -> str:
        j = self.i + k
        return self.src[j] if j < len(self.src) else "\0"

    # -- main loop ---------------------------------------------------------------
    def run(self) -> list[Token]:
        while self.i < len(self.src):
            c = self.peek()
            if c in " \t\r\n\f\v":
                self.advance()
            elif c == "(" and self.peek(1) == "*":
                self.block_comment()
            elif c == "/" and self.peek(1) == "/":
                self.facts.append(fact("comment-line", self.pos()))
                while self.i < len(self.src) and self.peek() != "\n":
                    self.advance()
            elif c == "/" and self.peek(1) == "*":
                self.c_comment()
            elif c == "{":
                self.pragma()
            elif is_alpha(c) or c == "_":
                self.word()
            elif is_digit(c):
                self.number()
            elif c == "'" or c == '"':
                self.string(c)
            elif c == "%":
                self.direct()
            else:
                self.symbol()
        self.tokens.append(Token("EOF", None, "", self.pos()))
        return self.tokens

    def emit(self, kind: str, value: object, start: int, pos: Pos) -> None:
        self.tokens.append(Token(kind, value, self.src[start:self.i], pos))

    def block_comment(self) -> None:
        self.skip_comment("(*", "*)")

    def c_comment(self) -> None:
        self.facts.append(fact("comment-block", self.pos()))
        self.skip_comment("/*", "*/")

    def skip_comment(self, opener: str, closer: str) -> None:
        """Skip a comment from `opener` to the first `closer` (comments do not nest, as in MATIEC)."""
        start = self.pos()
        self.advance(2)
        while self.i < len(self.src):
            if self.src.startswith(closer, self.i):
                self.advance(2)
                return
            if opener == "(*" and self.src.startswith(opener, self.i):     # STruC++ nests comments
                self.facts.append(fact("strucpp-nested-comment", self.pos()))
            self.advance()
        self.diags.error(start, "unterminated comment", f"a '{opener}' comment needs a closing '{closer}'")

    def pragma(self) -> None:
        start = self.pos()
        self.facts.append(fact("pragma", start))
        while self.i < len(self.src) and self.peek() != "}":
            self.advance()
        if self.i >= len(self.src):
            self.diags.error(start, "unterminated pragma '{'")
        self.advance()

    def word(self) -> None:
        start, pos = self.i, self.pos()
        while is_alnum(self.peek()) or self.peek() == "_":
            self.advance()
        text = self.src[start:self.i]
        up = text.upper()
        if self.peek() == "#":
            if up in TIME_PREFIXES:
                self.advance()
                self.time_body(TIME_PREFIXES[up], start, pos)
                return
            self.emit("TYPEPFX", up, start, pos)
            self.advance()  # the '#'
            return
        if up in KEYWORDS:
            self.emit("KEYWORD", up, start, pos)
        else:
            self.emit("IDENT", up, start, pos)

    def time_body(self, kind: str, start: int, pos: Pos) -> None:
        body_start = self.i
        while True:
            c = self.peek()
            if is_alnum(c) or c in "_.:":
                self.advance()
            elif c in "+-" and (self.i == body_start or kind in ("DATE", "DT", "LDATE", "LDT")):
                self.advance()
            else:
                break
        body = self.src[body_start:self.i]
        if not body:
            self.diags.error(pos, f"empty {kind} literal")
        elif body[0] == "-" and kind in ("TIME", "LTIME"):
            prefix = self.src[start:body_start]
            self.facts.append(fact("strucpp-negative-time", pos, text=prefix + body, positive=prefix + body[1:]))
        self.emit("TIME", (kind, body), start, pos)

    def digits(self, ok) -> str:
        out = []
        while True:
            c = self.peek()
            if c == "_" or ok(c):
                if c != "_":
                    out.append(c)
                self.advance()
            else:
                return "".join(out)

    def to_int(self, digits: str, base: int, pos: Pos) -> int:
        """The value of a digit string; a literal no 64-bit type can hold is reported here, not converted."""
        if len(digits) > 70:
            self.diags.error(pos, f"integer literal of {len(digits)} digits is too long", "64 bits at most")
            return 0
        return int(digits, base)

    def to_real(self, text: str, pos: Pos) -> float:
        v = float(text)
        if math.isinf(v):
            self.diags.error(pos, "real literal is too large", "LREAL holds about 1.8E308 at most")
            return 0.0
        return v

    def number(self) -> None:
        start, pos = self.i, self.pos()
        whole = self.digits(is_digit)
        if self.peek() == "#":
            base = int(whole) if whole else 0
            self.advance()
            if base not in (2, 8, 16):
                self.diags.error(pos, f"invalid number base {base}", "bases are 2, 8 and 16")
                base = 16
            allowed = "0123456789abcdefABCDEF"[: base if base <= 10 else 10 + (base - 10) * 2]
            if base == 16:
                allowed = "0123456789abcdefABCDEF"
            body = self.digits(lambda c: c in allowed)
            if not body:
                self.diags.error(pos, f"missing digits after '{base}#'")
                body = "0"
            self.emit("INT", self.to_int(body, base, pos), start, pos)
            return
        if self.peek() == "." and is_digit(self.peek(1)):
            self.advance()
            frac = self.digits(is_digit)
            exp = ""
            if self.peek() in "eE":
                save = (self.i, self.line, self.col)
                self.advance()
                sign = ""
                if self.peek() in "+-":
                    sign = self.peek()
                    self.advance()
                e = self.digits(is_digit)
                if e:
                    exp = "e" + sign + e
                else:
                    self.i, self.line, self.col = save
            self.emit("REAL", self.to_real(f"{whole}.{frac}{exp}", pos), start, pos)
            return
        if self.peek() in "eE" and self.peek() != "" and (is_digit(self.peek(1)) or
                                                            (self.peek(1) in "+-" and is_digit(self.peek(2)))):
            self.advance()
            sign = ""
            if self.peek() in "+-":
                sign = self.peek()
                self.advance()
            e = self.digits(is_digit)
            self.emit("REAL", self.to_real(f"{whole}e{sign}{e}", pos), start, pos)
            return
        self.emit("INT", self.to_int(whole, 10, pos), start, pos)

    def string(self, quote: str) -> None:
        start, pos = self.i, self.pos()
        if quote == '"':
            self.facts.append(fact("wstring", pos))
        self.advance()
        out = []
        while True:
            c = self.peek()
            if c == "\0" and self.i >= len(self.src) or c == "\n":
                self.diags.error(pos, "unterminated string literal", f"close it with {quote}")
                break
            if c == quote:
                self.advance()
                break
            if c == "$":
                self.advance()
                e = self.peek()
                if e.upper() in ESCAPES:
                    out.append(ESCAPES[e.upper()])
                    self.advance()
                elif (len(self.src) > self.i + 1
                      and all(ch in "0123456789abcdefABCDEF" for ch in self.src[self.i:self.i + 2])):
                    out.append(chr(int(self.src[self.i:self.i + 2], 16)))
                    self.advance(2)
                else:
                    self.diags.error(self.pos(), f"invalid escape '${e}' in string",
                                     "escapes are $$ $' $L $N $P $R $T and $hh")
                continue
            out.append(c)
            self.advance()
        self.emit("STRING", "".join(out), start, pos)

    def direct(self) -> None:
        start, pos = self.i, self.pos()
        self.advance()
        area = self.peek().upper()
        if area not in ("I", "Q", "M"):
            self.diags.error(pos, "invalid direct address", "expected %I, %Q or %M, e.g. %QX0.1 or %IW3")
            self.emit("DIRECT", ("I", "X", [0]), start, pos)
            return
        self.advance()
        size = self.peek().upper()
        if size in ("X", "B", "W", "D", "L"):
            self.advance()
        elif is_digit(size):
            size = "X"
        else:
            self.diags.error(pos, "invalid direct address size", "sizes are X, B, W, D and L")
            size = "X"
        parts = []
        while True:
            d = self.digits(is_digit)
            if not d:
                self.diags.error(pos, "missing address number in direct variable")
                d = "0"
            parts.append(self.to_int(d, 10, pos))
            if self.peek() == "." and is_digit(self.peek(1)):
                self.advance()
                continue
            break
        self.emit("DIRECT", (area, size, parts), start, pos)

    def symbol(self) -> None:
        start, pos = self.i, self.pos()
        for s in SYMBOLS:
            if self.src.startswith(s, self.i):
                self.advance(len(s))
                self.emit("SYM", s, start, pos)
                return
        self.diags.error(pos, f"unexpected character {self.peek()!r}")
        self.advance()


def tokenize(text: str, filename: str, diags: Diagnostics, facts: list | None = None) -> list[Token]:
    """The tokens of `text`; problems go to diags, portability facts to `facts` (a list the caller keeps)."""
    return Lexer(text, filename, diags, facts).run()
