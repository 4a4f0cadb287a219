"""Decode duration and date literals (T#, TOD#, D#, DT#) into nanoseconds."""
from __future__ import annotations

import datetime as _dt
from functools import lru_cache
import re
from fractions import Fraction

INT64_MAX = (1 << 63) - 1

_UNITS = [("d", 86_400_000_000_000), ("h", 3_600_000_000_000), ("ms", 1_000_000), ("us", 1_000),
          ("ns", 1), ("m", 60_000_000_000), ("s", 1_000_000_000)]
_PART = re.compile(r"(\d+(?:\.\d+)?)(d|h|ms|us|ns|m|s)", re.IGNORECASE)


def duration_ns(text: str) -> int | None:
    body = text.replace("_", "")
    neg = body.startswith("-")
    body = body.lstrip("+-")
    if not body:
        return None
    pos, total, seen = 0, Fraction(0), False
    while pos < len(body):
        m = _PART.match(body, pos)
        if not m or len(m.group(1)) > 40:
            return None
        unit = m.group(2).lower()
        total += Fraction(m.group(1)) * dict(_UNITS)[unit]       # exact: no float rounding
        pos = m.end()
        seen = True
    if not seen:
        return None
    ns = round(total)
    if ns > INT64_MAX:                 # TIME is a signed 64-bit count of nanoseconds
        return None
    return -ns if neg else ns


def tod_ns(text: str) -> int | None:
    m = re.fullmatch(r"(\d{1,2}):(\d{1,2}):(\d{1,2}(?:\.\d+)?)", text)
    if not m:
        return None
    h, mi, s = int(m.group(1)), int(m.group(2)), float(m.group(3))
    if h > 23 or mi > 59 or s >= 60:
        return None
    return int(round(((h * 60 + mi) * 60 + s) * 1e9))


def date_ns(text: str) -> int | None:
    m = re.fullmatch(r"(\d{4})-(\d{1,2})-(\d{1,2})", text)
    if not m:
        return None
    try:
        d = _dt.date(int(m.group(1)), int(m.group(2)), int(m.group(3)))
    except ValueError:
        return None
    return (d - _dt.date(1970, 1, 1)).days * 86_400_000_000_000


def dt_ns(text: str) -> int | None:
    m = re.fullmatch(r"(\d{4}-\d{1,2}-\d{1,2})-(.+)", text)
    if not m:
        return None
    d, t = date_ns(m.group(1)), tod_ns(m.group(2))
    if d is None or t is None:
        return None
    return d + t


def decode(kind: str, text: str) -> int | None:
    if kind == "TIME":
        return duration_ns(text)
    if kind == "TOD":
        return tod_ns(text)
    if kind == "DATE":
        return date_ns(text)
    if kind == "DT":
        return dt_ns(text)
    return None


# ---- OpenPLC v3's conversion of a TIME literal -------------------------------------------------------------------
# iec2c writes T#1s4ms as `__time_to_timespec(1, 4, 1, 0, 0, 0)` (sign, ms, s, m, h, d: each the literal's own
# number, a C int or double), and OpenPLC's iec_std_lib.h turns it into seconds and nanoseconds in `long double`:
# total = (((d*24 + h)*60 + m)*60 + s) + ms/1e3, tv_sec = (long)total, tv_nsec = (long)((total - tv_sec)*1e9).
# The last cast truncates, so a total a hair below the exact value loses a nanosecond: T#4ms is 3,999,999 ns.
# `openplc_duration_ns` repeats that arithmetic exactly, rounding every step to the significand of the platform's
# long double: 64 bits on x86-64 (x87 extended, what OpenPLC's PC and Docker builds use), 113 bits on 64-bit ARM
# (IEEE quad), 53 bits on 32-bit ARM (long double = double).  Checked against OpenPLC_v3's own header on x86-64:
# the same value for every T#0ms..T#99999ms and T#0.000s..T#99.999s (48,169 and 49,597 of them inexact).

LONG_DOUBLE_BITS = {"x86-64": 64, "arm64": 113, "arm32": 53}
_MATIEC_PART = re.compile(r"(\d+(?:\.\d+)?)(ms|d|h|m|s)", re.IGNORECASE)
_MATIEC_ORDER = ["d", "h", "m", "s", "ms"]


def _rounded(x: Fraction, bits: int) -> Fraction:
    """x rounded to nearest (ties to even) with a `bits`-bit significand, as the FPU does after each operation."""
    if x == 0:
        return x
    sign, x = (-1, -x) if x < 0 else (1, x)
    exp = x.numerator.bit_length() - x.denominator.bit_length()
    if Fraction(2) ** exp > x:
        exp -= 1                          # now 2**exp <= x < 2**(exp + 1)
    scale = Fraction(2) ** (exp - bits + 1)
    return sign * round(x / scale) * scale    # Fraction.__round__ rounds half to even


def _c_number(text: str, bits: int) -> Fraction:
    """A literal number as iec2c writes it into the C: an int stays exact, a decimal is a C double."""
    return Fraction(int(text)) if "." not in text else _rounded(Fraction(text), 53)


@lru_cache(maxsize=4096)
def openplc_duration_ns(text: str, platform: str = "x86-64") -> int | None:
    """The nanoseconds OpenPLC v3 makes of the TIME literal body `text` (after T#), or None when this is not a
    duration MATIEC writes through __time_to_timespec (a 'us'/'ns' unit: the `time-unit` rule's)."""
    bits = LONG_DOUBLE_BITS[platform]
    body = text.replace("_", "")
    negative = body.startswith("-")
    body = body.lstrip("+-")
    parts = {unit: Fraction(0) for unit in _MATIEC_ORDER}
    pos = 0
    while pos < len(body):
        m = _MATIEC_PART.match(body, pos)
        if not m:
            return None
        parts[m.group(2).lower()] = _c_number(m.group(1), bits)
        pos = m.end()
    if pos == 0:
        return None

    def r(x: Fraction) -> Fraction:
        return _rounded(x, bits)
    total = r(r(r(r(r(parts["d"] * 24) + parts["h"]) * 60) + parts["m"]) * 60)
    total = r(r(total + parts["s"]) + r(parts["ms"] / 1000))
    if negative:
        total = -total
    seconds = int(total)                              # C's (long) truncates toward zero
    nanoseconds = int(r(r(total - seconds) * 1_000_000_000))
    return seconds * 1_000_000_000 + nanoseconds


def exact_openplc_spelling(ns: int) -> str | None:
    """A spelling of the duration `ns` (whole milliseconds up to a day) that OpenPLC v3 converts exactly on every
    platform, or None when none of the usual ones does."""
    if ns < 0 or ns % 1_000_000 or ns >= 86_400_000_000_000:
        return None
    ms = ns // 1_000_000
    s, rest = divmod(ms, 1000)
    candidates = [f"{ms}ms", f"{s}.{rest:03d}s".replace(".000s", "s"), f"{s}s{rest}ms" if s and rest else None,
                  f"{ms * 1000}us"]
    for spelling in candidates:
        if spelling and all(openplc_duration_ns(spelling, p) == ns for p in LONG_DOUBLE_BITS):
            return f"T#{spelling}"
    return None


def ms_literal(ms: int) -> str:
    """The TIME literal a generator writes for `ms` milliseconds: T#<ms>ms, or a spelling OpenPLC v3 converts
    exactly where that one is a nanosecond short there (T#4ms -> T#0.004s)."""
    plain = f"T#{ms}ms"
    if all(openplc_duration_ns(f"{ms}ms", p) == ms * 1_000_000 for p in LONG_DOUBLE_BITS):
        return plain
    return exact_openplc_spelling(ms * 1_000_000) or plain


# ---- the durations MATIEC's lexer takes (stage1_2/iec_flex.ll of OpenPLC_v3's matiec_src) ------------------------
# The units follow one another without a gap (d, h, m, s, ms); the first is any integer or fixed-point number, each
# later one an integer within its unit (h 0..23, m and s 0..59, ms 0..999) and only the last may have a fraction.
# T#30m500ms (no seconds) and T#1s1500ms are errors there ("invalid value for duration"); T#30m0s500ms is not.
_INT = r"\d(?:_?\d)*"
_FIXED = rf"{_INT}\.{_INT}"
_I59 = r"(?:0_?)*(?:[0-5]_?)?\d"
_I23 = r"(?:(?:0_?)*(?:[01]_?)?\d|(?:0_?)*2_?[0-3])"
_I999 = r"\d(?:_?\d)?(?:_?\d)?"
_MS_X = rf"{_I999}(?:\.{_INT})?ms"
_S_X = rf"(?:{_I59}s(?:_?{_MS_X})?|{_I59}(?:\.{_INT})?s)"
_M_X = rf"(?:{_I59}m(?:_?{_S_X})?|{_I59}(?:\.{_INT})?m)"
_H_X = rf"(?:{_I23}h(?:_?{_M_X})?|{_I23}(?:\.{_INT})?h)"
_MATIEC_INTERVAL = re.compile(
    rf"{_INT}ms|{_FIXED}ms|{_INT}s(?:_?{_MS_X})?|{_FIXED}s|{_INT}m(?:_?{_S_X})?|{_FIXED}m"
    rf"|{_INT}h(?:_?{_M_X})?|{_FIXED}h|{_INT}d(?:_?{_H_X})?|{_FIXED}d", re.IGNORECASE)


def matiec_takes_duration(text: str) -> bool:
    """Whether MATIEC's lexer reads the TIME literal body `text` (after T#, sign included) as a duration."""
    return _MATIEC_INTERVAL.fullmatch(text.lstrip("+-")) is not None


def portable_spelling(ns: int) -> str:
    """A spelling of the duration `ns` that MATIEC reads: one OpenPLC converts exactly when there is one
    (exact_openplc_spelling), else plain milliseconds (T#1800500ms, T#2.5ms)."""
    sign = "-" if ns < 0 else ""
    exact = exact_openplc_spelling(abs(ns))
    if exact:
        return exact.replace("T#", "T#" + sign)
    whole, part = divmod(abs(ns), 1_000_000)
    fraction = f".{part:06d}".rstrip("0") if part else ""
    return f"T#{sign}{whole}{fraction}ms"
