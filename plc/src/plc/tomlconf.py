"""One reader for every TOML file: values with their positions, and a declarative schema.

tomllib (Python 3.11) parses TOML but keeps no positions.  `parse` lets tomllib judge the syntax and give the
values, then walks the same text with a small scanner of its own that records, for every key path, where its
entry starts, where its key is written and where its value is::

    doc = tomlconf.parse(text, "run.toml")            # or tomlconf.read(path)
    doc.data["io"]["device"][0]["coils"][1]           # tomllib's values
    doc.pos(("io", "device", 0, "coils", 1))          # run.toml:9:3, the second inline table of that array
    doc.error(("modbus", "port"), "[modbus] port: ...")   # a Diagnostic at the key, kept in doc.diagnostics

A key path is a tuple of table names, keys and array indexes, as one would index `data`.  A path written
nowhere is placed at its nearest written ancestor (a missing key at its table's header).

A schema is a `Table` of `Field`s (name, kind, doc, required, default); a kind (`Int`, `Number`, `Bool`,
`Str`, `OneOf`, `ListOf`, `Check`) refuses a value with a sentence.  `Table.check` reports every problem of a
table at once -- unknown keys (with a did-you-mean when one is close), values of the wrong type or range,
missing keys -- each as a `Diagnostic` at its file:line:col, and returns the values it accepted.  The messages
read `{label} unknown key 'k'`, `{label} k: expected an integer 1..99, got 100`, `{label} k is required`;
the label names the table the way the file's tool always did (`[modbus]`, `[[io.device]] 2:`, `signal:`).

The scanner agrees with tomllib's values on every TOML file of the repository (tests/test_tomlconf.py).
"""
from __future__ import annotations

import bisect
import difflib
import ipaddress
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from . import buildcache
from .diagnostics import GCC, Diagnostic, Layout, Pos

KeyPath = tuple  # ("io", "device", 0, "coils", 1): table names, keys and array indexes


# ------------------------------------------------------------------------------------------------ positions

@dataclass(frozen=True)
class Place:
    """Where one entry of a TOML text is written."""
    start: Pos                    # the entry: a header's `[`, a `key = value`'s key, an array element
    key: Pos                      # its own key (for a header, the name inside the brackets); = start for elements
    width: int = 1                # characters of that key as written
    value: Pos | None = None      # its value (None for a table opened by a header)
    span: tuple[int, int] | None = None   # offsets of the value's text in the document


@dataclass
class Document:
    """A parsed TOML file: tomllib's values, the place of every entry, and the problems found in it.

    `layout`, `show_source`, `unplaced` and `anchor` say how this file's tool writes its diagnostics: the layout of
    the position, the source line under each, where a path written nowhere is (default line 1, column 1), and
    whether a problem points at the start of an entry or at its key (for a `[a.b]` header, `[` or `b`)."""
    file: str
    text: str
    data: dict
    places: dict[KeyPath, Place]
    layout: Layout = GCC
    show_source: bool = False
    unplaced: tuple[int, int] = (1, 1)
    anchor: str = "start"                     # "start" | "key"
    diagnostics: list[Diagnostic] = field(default_factory=list)

    def place(self, path: KeyPath) -> Place | None:
        """The place of `path`, or of its nearest written ancestor; None when nothing of it is written."""
        path = tuple(path)
        while path:
            if path in self.places:
                return self.places[path]
            path = path[:-1]
        return None

    def _pos(self, path: KeyPath, which: str) -> tuple[Pos, int]:
        p = self.place(path)
        if p is None:
            return Pos(self.file, *self.unplaced), 1
        if which == "value" and tuple(path) in self.places and p.value is not None:
            return p.value, 1
        if which == "key":
            return p.key, p.width
        return p.start, (p.width if p.start == p.key else 1)

    def pos(self, path: KeyPath) -> Pos:
        """Where the entry of `path` starts (or its nearest written ancestor's)."""
        return self._pos(path, "start")[0]

    def key_pos(self, path: KeyPath) -> Pos:
        return self._pos(path, "key")[0]

    def value_pos(self, path: KeyPath) -> Pos:
        """Where the value of `path` is written (its entry's start when it has no value of its own)."""
        return self._pos(path, "value")[0]

    def line(self, number: int) -> str:
        lines = self.text.splitlines()
        return lines[number - 1] if 0 < number <= len(lines) else ""

    def diagnostic(self, severity: str, path: KeyPath, message: str, hint: str | None = None,
                   at: str | None = None) -> Diagnostic:
        """A Diagnostic at `path` (at its start, key or value: `at`, default the document's anchor)."""
        pos, width = self._pos(path, at or self.anchor)
        source = self.line(pos.line) if self.show_source else ""
        return Diagnostic(severity, pos, message, hint or None, source_line=source, width=width,
                          layout=self.layout)

    def error(self, path: KeyPath, message: str, hint: str | None = None, at: str | None = None) -> Diagnostic:
        d = self.diagnostic("error", path, message, hint, at)
        self.diagnostics.append(d)
        return d

    def warning(self, path: KeyPath, message: str, hint: str | None = None, at: str | None = None) -> Diagnostic:
        d = self.diagnostic("warning", path, message, hint, at)
        self.diagnostics.append(d)
        return d

    @property
    def errors(self) -> list[Diagnostic]:
        return [d for d in self.diagnostics if d.severity == "error"]

    def in_file_order(self) -> list[Diagnostic]:
        """The problems by line and column (the order they were found in is the checks')."""
        return sorted(self.diagnostics, key=lambda d: (d.pos.line, d.pos.col))


class TomlError(Exception):
    """A text tomllib refuses: `diagnostic` says where and why."""

    def __init__(self, diagnostic: Diagnostic) -> None:
        super().__init__(diagnostic.message)
        self.diagnostic = diagnostic


_AT = re.compile(r"\s*\(at line (\d+), column (\d+)\)|\s*\(at end of document\)")


def parse(text: str, file: str, *, layout: Layout = GCC, show_source: bool = False,
          unplaced: tuple[int, int] = (1, 1), anchor: str = "start") -> Document:
    """The document of `text` (shown as `file` in diagnostics); TomlError when it is not valid TOML, positioned
    where tomllib stopped (`invalid TOML: ...`).  With a build cache in use (buildcache.use: plc test, plc build,
    plc run), a text read before under the same name is loaded from it (values and places)."""
    cache = buildcache.active()
    if cache is None:
        data, places = _parse(text, file, layout, show_source)
    else:
        key = buildcache.sha256("toml", buildcache.toolchain_digest("tomlconf.py"), file, text)
        data, places = cache.value("toml", key, lambda: _parse(text, file, layout, show_source))
    return Document(file, text, data, places, layout, show_source, unplaced, anchor)


def _parse(text: str, file: str, layout: Layout, show_source: bool) -> tuple[dict, dict[KeyPath, Place]]:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"\(at line (\d+), column (\d+)\)", str(exc))
        if m:
            line, col = int(m.group(1)), int(m.group(2))
        else:                                                  # "at end of document"
            line = max(1, len(text.splitlines()))
            col = len(text.splitlines()[-1]) + 1 if text.splitlines() else 1
        lines = text.splitlines()
        source = lines[line - 1] if show_source and 0 < line <= len(lines) else ""
        raise TomlError(Diagnostic("error", Pos(file, line, col), f"invalid TOML: {_AT.sub('', str(exc))}",
                                   source_line=source, layout=layout)) from None
    _tree, places = scan(text, file)
    return data, places


def read(path: Path, label: str | None = None, **style: Any) -> Document:
    """Read and parse a file (shown as `label`, default the path); TomlError when it cannot be read ("no such
    file", "cannot read: ...", at line 0) or is not valid TOML."""
    name = str(label if label is not None else path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise TomlError(Diagnostic("error", Pos(name, 0, 0), "no such file",
                                   layout=style.get("layout", GCC))) from None
    except (OSError, UnicodeDecodeError) as exc:
        why = getattr(exc, "strerror", None) or exc
        raise TomlError(Diagnostic("error", Pos(name, 0, 0), f"cannot read: {why}",
                                   layout=style.get("layout", GCC))) from None
    return parse(text, name, **style)


# -------------------------------------------------------------------------------------------- the scanner

class _Raw(str):
    """A scalar's text as written (converted by tomllib only when the values are compared)."""


_BARE = re.compile(r"[A-Za-z0-9_-]+")
_WS = re.compile(r"[ \t]*")
_DATETIME = re.compile(r"\d{4}-\d{2}-\d{2}(?:[Tt ]\d{2}:\d{2}(?::\d{2})?(?:\.\d+)?(?:[Zz]|[+-]\d{2}:\d{2})?)?"
                       r"|\d{2}:\d{2}(?::\d{2})?(?:\.\d+)?")
_NUMBER = re.compile(r"[+-]?(?:inf|nan|0x[0-9A-Fa-f_]+|0o[0-7_]+|0b[01_]+|[0-9_]+(?:\.[0-9_]+)?(?:[eE][+-]?[0-9_]+)?)")


class _Scanner:
    """Walks a text tomllib accepted and records the place of every entry; builds the same tree of tables and
    arrays (scalars kept as text) so that a test can compare it with tomllib's values."""

    def __init__(self, text: str, file: str) -> None:
        self.s = text
        self.i = 0
        self.file = file
        self.starts = [0] + [m.end() for m in re.finditer("\n", text)]
        self.places: dict[KeyPath, Place] = {}
        self.implicit: set[KeyPath] = set()      # tables only mentioned on the way to another
        self.root: dict = {}

    # positions
    def at(self, offset: int) -> Pos:
        line = bisect.bisect_right(self.starts, offset)
        return Pos(self.file, line, offset - self.starts[line - 1] + 1)

    def place(self, path: KeyPath, place: Place, implicit: bool = False) -> None:
        if path in self.places and path not in self.implicit:
            return
        self.places[path] = place
        if implicit:
            self.implicit.add(path)
        else:
            self.implicit.discard(path)

    # lexing
    def peek(self, n: int = 1) -> str:
        return self.s[self.i:self.i + n]

    def blank(self) -> None:
        """Spaces and tabs."""
        self.i = _WS.match(self.s, self.i).end()

    def blank_lines(self) -> None:
        """Spaces, tabs, comments and newlines (inside arrays)."""
        while self.i < len(self.s):
            ch = self.s[self.i]
            if ch in " \t\r\n":
                self.i += 1
            elif ch == "#":
                self.skip_comment()
            else:
                return

    def skip_comment(self) -> None:
        end = self.s.find("\n", self.i)
        self.i = len(self.s) if end < 0 else end

    def string_end(self, i: int) -> int:
        """The offset after the string starting at `i` (basic, literal, multi-line)."""
        s = self.s
        for quote in ('"""', "'''"):
            if s.startswith(quote, i):
                j = i + 3
                while True:
                    if quote == '"""' and s[j] == "\\":
                        j += 2
                        continue
                    if s.startswith(quote, j):
                        j += 3
                        extra = 0
                        while extra < 2 and j < len(s) and s[j] == quote[0]:
                            j += 1
                            extra += 1
                        return j
                    j += 1
        quote = s[i]
        j = i + 1
        while s[j] != quote:
            j += 2 if (quote == '"' and s[j] == "\\") else 1
        return j + 1

    def key(self) -> list[tuple[str, int, int]]:
        """A dotted key: (name, start offset, width) of each part."""
        parts = []
        while True:
            self.blank()
            start = self.i
            if self.peek() in "\"'":
                end = self.string_end(start)
                name = next(iter(tomllib.loads(self.s[start:end] + " = 0")))
            else:
                end = _BARE.match(self.s, start).end()
                name = self.s[start:end]
            parts.append((name, start, end - start))
            self.i = end
            self.blank()
            if self.peek() != ".":
                return parts
            self.i += 1

    # structure
    def run(self) -> None:
        table: dict = self.root
        path: KeyPath = ()
        while True:
            self.blank_lines()
            if self.i >= len(self.s):
                return
            if self.peek() == "[":
                table, path = self.header()
            else:
                self.pair(table, path)
            self.blank()
            if self.peek() == "#":
                self.skip_comment()

    def header(self) -> tuple[dict, KeyPath]:
        start = self.i
        array = self.peek(2) == "[["
        self.i += 2 if array else 1
        parts = self.key()
        self.i += 2 if array else 1
        table, path = self.root, ()
        key_start = parts[0][1]
        whole = Place(self.at(start), self.at(key_start), parts[-1][1] + parts[-1][2] - key_start)
        for n, (name, offset, width) in enumerate(parts):
            last = n == len(parts) - 1
            if last and array:
                items = table.setdefault(name, [])
                self.place(path + (name,), whole)
                path = path + (name, len(items))
                items.append({})
                table = items[-1]
                self.place(path, whole)
                continue
            child = table.setdefault(name, {})
            if isinstance(child, list):                       # [[a]] then [a.b]: the last element of a
                path = path + (name, len(child) - 1)
                table = child[-1]
            else:
                path = path + (name,)
                table = child
            if last:
                self.place(path, whole)
            else:
                self.place(path, Place(self.at(start), self.at(offset), width), implicit=True)
        return table, path

    def pair(self, table: dict, path: KeyPath) -> None:
        start = self.i
        parts = self.key()
        for name, offset, width in parts[:-1]:
            table = table.setdefault(name, {})
            path = path + (name,)
            self.place(path, Place(self.at(start), self.at(offset), width), implicit=True)
        name, offset, width = parts[-1]
        self.i += 1                                           # '='
        self.blank()
        value_start = self.i
        full = path + (name,)
        value = self.value(full)
        self.places[full] = Place(self.at(start), self.at(start), offset + width - start,
                                  self.at(value_start), (value_start, self.i))
        self.implicit.discard(full)
        table[name] = value

    def value(self, path: KeyPath) -> Any:
        ch = self.peek()
        if ch in "\"'":
            end = self.string_end(self.i)
            raw = _Raw(self.s[self.i:end])
            self.i = end
            return raw
        if ch == "[":
            return self.array(path)
        if ch == "{":
            return self.inline_table(path)
        for word in ("true", "false"):
            if self.s.startswith(word, self.i):
                self.i += len(word)
                return _Raw(word)
        m = _DATETIME.match(self.s, self.i) or _NUMBER.match(self.s, self.i)
        self.i = m.end()
        return _Raw(m.group(0))

    def array(self, path: KeyPath) -> list:
        self.i += 1
        items: list = []
        while True:
            self.blank_lines()
            if self.peek() == "]":
                self.i += 1
                return items
            start = self.i
            here = path + (len(items),)
            item = self.value(here)
            self.places.setdefault(here, Place(self.at(start), self.at(start), 1, self.at(start), (start, self.i)))
            items.append(item)
            self.blank_lines()
            if self.peek() == ",":
                self.i += 1

    def inline_table(self, path: KeyPath) -> dict:
        self.i += 1
        table: dict = {}
        while True:
            self.blank()
            if self.peek() == "}":
                self.i += 1
                return table
            self.pair(table, path)
            self.blank()
            if self.peek() == ",":
                self.i += 1


def scan(text: str, file: str = "<toml>") -> tuple[dict, dict[KeyPath, Place]]:
    """The tree of tables and arrays of a valid TOML text (scalars as their text) and the place of every entry."""
    scanner = _Scanner(text, file)
    scanner.run()
    return scanner.root, scanner.places


def plain(tree: Any) -> Any:
    """The scanner's tree with every scalar converted by tomllib: equal to tomllib.loads of the same text."""
    if isinstance(tree, dict):
        return {k: plain(v) for k, v in tree.items()}
    if isinstance(tree, list):
        return [plain(v) for v in tree]
    return tomllib.loads("v = " + tree)["v"]


# --------------------------------------------------------------------------------------------------- schema

class Invalid(Exception):
    """A value a kind refuses; str() is the problem, e.g. "expected an integer 1..99, got 100"."""


class Kind:
    """How one value is checked: `check` returns it (possibly converted) or raises Invalid."""
    what = "a value"

    def check(self, value: Any) -> Any:
        return value

    def refuse(self, value: Any) -> Invalid:
        return Invalid(f"expected {self.what}, got {value!r}")


def ipv4(value: Any) -> str:
    """A Check function: an IPv4 address in its canonical text (the run configuration's bind, a TCP device)."""
    try:
        return str(ipaddress.IPv4Address(value))
    except (ipaddress.AddressValueError, ValueError, TypeError):
        raise Invalid(f"{value!r} is not an IPv4 address") from None


def _integer(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


@dataclass(frozen=True)
class Int(Kind):
    lo: int | None = None
    hi: int | None = None

    @property
    def what(self) -> str:
        if self.lo is not None and self.hi is not None:
            return f"an integer {self.lo}..{self.hi}"
        if self.lo is not None:
            return f"an integer >= {self.lo}"
        return "an integer" if self.hi is None else f"an integer <= {self.hi}"

    def check(self, value: Any) -> int:
        if not _integer(value) or (self.lo is not None and value < self.lo) or \
                (self.hi is not None and value > self.hi):
            raise self.refuse(value)
        return value


@dataclass(frozen=True)
class Number(Kind):
    """An integer or a float (kept as written)."""
    lo: float | None = None
    hi: float | None = None

    @property
    def what(self) -> str:
        if self.lo is not None and self.hi is not None:
            return f"a number {self.lo:g}..{self.hi:g}"
        return "a number" if self.lo is None else f"a number >= {self.lo:g}"

    def check(self, value: Any) -> float | int:
        if not _number(value) or value != value or (self.lo is not None and value < self.lo) or \
                (self.hi is not None and value > self.hi):
            raise self.refuse(value)
        return value


@dataclass(frozen=True)
class Bool(Kind):
    what = "true or false"

    def check(self, value: Any) -> bool:
        if not isinstance(value, bool):
            raise self.refuse(value)
        return value


@dataclass(frozen=True)
class Str(Kind):
    nonempty: bool = False

    @property
    def what(self) -> str:
        return "a non-empty string" if self.nonempty else "a string"

    def check(self, value: Any) -> str:
        if not isinstance(value, str) or (self.nonempty and not value):
            raise self.refuse(value)
        return value


@dataclass(frozen=True)
class OneOf(Kind):
    choices: tuple

    @property
    def what(self) -> str:
        return "one of " + ", ".join(f'"{c}"' for c in self.choices)

    def check(self, value: Any) -> Any:
        if isinstance(value, bool) or value not in self.choices:
            raise self.refuse(value)
        return value


@dataclass(frozen=True)
class ListOf(Kind):
    item: Kind
    items: str = ""                # the items in a message ("integers"); default: "values"

    @property
    def what(self) -> str:
        return f"a list of {self.items or 'values'}"

    def check(self, value: Any) -> list:
        if not isinstance(value, list):
            raise self.refuse(value)
        out = []
        for v in value:
            try:
                out.append(self.item.check(v))
            except Invalid:
                raise self.refuse(value) from None
        return out


@dataclass(frozen=True)
class Check(Kind):
    """A kind of the caller's: `fn(value)` returns the value (converted) or raises Invalid with the problem."""
    fn: Callable[[Any], Any]
    what: str = "a value"          # type: ignore[misc]

    def check(self, value: Any) -> Any:
        return self.fn(value)


MISSING = object()


@dataclass(frozen=True)
class Field:
    name: str
    kind: Kind
    doc: str = ""                  # one line: what it means, its unit (said with a missing key)
    required: bool = False
    default: Any = MISSING         # the value when absent (none given: absent from the result)
    hint: str = ""                 # what a right value looks like (with its problems)


@dataclass(frozen=True)
class Table:
    """The keys of one table.  `extra`: the kind of keys the fields do not name (None: they are unknown)."""
    fields: tuple[Field, ...]
    doc: str = ""
    extra: Kind | None = None

    @property
    def names(self) -> list[str]:
        return [f.name for f in self.fields]

    def field(self, name: str) -> Field | None:
        return next((f for f in self.fields if f.name == name), None)

    def replace(self, *fields: Field) -> Table:
        """The same table with these fields in place of the ones of their names."""
        new = {f.name: f for f in fields}
        return Table(tuple(new.get(f.name, f) for f in self.fields), self.doc, self.extra)

    def check(self, doc: Document, path: KeyPath, value: Any, label: str) -> Checked:
        """Every problem of the table at `path` (its value `value`) into doc.diagnostics; the values accepted."""
        out = Checked()
        if not isinstance(value, dict):
            doc.error(path, _say(label, "must be a table"))
            out.bad.add("")
            return out
        for key, v in value.items():
            f = self.field(key)
            kind = f.kind if f is not None else self.extra
            if kind is None:
                unknown_key(doc, path + (key,), key, self.names, label)
                out.bad.add(key)
                continue
            try:
                out.values[key] = kind.check(v)
            except Invalid as exc:
                doc.error(path + (key,), _say(label, f"{key}: {exc}"), f.hint if f is not None else None)
                out.bad.add(key)
                if f is not None and f.default is not MISSING:
                    out.values[key] = f.default         # the rest of the checks go on with the default
        for f in self.fields:
            if f.name in value:
                continue
            if f.required:
                doc.error(path, _say(label, f"{f.name} is required" + (f" ({f.doc})" if f.doc else "")), f.hint)
                out.bad.add(f.name)
            elif f.default is not MISSING:
                out.values[f.name] = f.default
        return out


@dataclass
class Checked:
    """What `Table.check` accepted: the values (defaults included) and the keys found wrong or missing."""
    values: dict[str, Any] = field(default_factory=dict)
    bad: set[str] = field(default_factory=set)

    @property
    def ok(self) -> bool:
        return not self.bad

    def get(self, key: str, default: Any = None) -> Any:
        return self.values.get(key, default)

    def __getitem__(self, key: str) -> Any:
        return self.values[key]

    def __contains__(self, key: str) -> bool:
        return key in self.values


def suggestion(name: str, known: Iterable[str], what: str = "") -> str:
    """`did you mean 'x'?` when a known name is close to `name`, else the known names."""
    known = sorted(known)
    close = difflib.get_close_matches(name, known, n=1)
    if close:
        return f"did you mean {what.replace('{}', close[0]) if what else repr(close[0])}?"
    return "known: " + ", ".join(what.replace("{}", k) if what else k for k in known)


def unknown_key(doc: Document, path: KeyPath, key: str, known: Iterable[str], label: str) -> Diagnostic:
    return doc.error(path, _say(label, f"unknown key '{key}'"), suggestion(key, known))


def _say(label: str, text: str) -> str:
    return f"{label} {text}" if label else text


def check_sections(doc: Document, sections: dict[str, Table | None], labels: Callable[[str], str] | None = None
                   ) -> dict[str, Checked]:
    """The top level of a file made of sections: an unknown one, a known one that is not a table (a value
    `modbus = 3`), then each table by its schema (None: the caller checks it).  Returns the checked sections."""
    out: dict[str, Checked] = {}
    label = labels or (lambda s: f"[{s}]")
    for name, value in doc.data.items():
        if name not in sections:
            if isinstance(value, (dict, list)):
                doc.error((name,), f"unknown section [{name}]", suggestion(name, sections, "[{}]"))
            else:
                unknown_key(doc, (name,), name, sections, "")
        elif not isinstance(value, (dict, list)) or (isinstance(value, list) and sections[name] is not None):
            doc.error((name,), f"'{name}' must be a section [{name}]")
    for name, schema in sections.items():
        value = doc.data.get(name)
        if schema is not None and isinstance(value, dict):
            out[name] = schema.check(doc, (name,), value, label(name))
    return out
