"""Decode duration and date literals (T#, TOD#, D#, DT#) into nanoseconds."""
from __future__ import annotations

import datetime as _dt
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
