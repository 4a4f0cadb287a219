"""The build cache: parse results and object files, each stored under a hash of everything it comes from.

An edit then redoes only what depends on it (issue 33): `plc test`, `plc build` and `plc run` of a project keep
one cache in its build/plc-cache/ (git ignores build/; removing the directory is always safe), or in the
directory PLC_CACHE_DIR names (one cache for many checkouts: the entries are keyed by content).

- A parsed file (parser.parse) is keyed by its name, its text and the compiler's own sources; it stores the
  tree (its POU bodies apart: plc test loads only those it checks again) and the diagnostics the lexer and the
  parser reported, which a hit reports again.
- A TOML file read through tomlconf (the project's checks before plc test and plc run read a dozen) is keyed the
  same way by its name, its text and the sources of tomlconf; it stores the values and the places of the entries.
- An object file (compile_units) is keyed by the C text of its translation unit (self-contained: every
  declaration it uses is in its text), the headers it includes, the C compiler's identity and the flags.

Every entry carries the SHA-256 of its payload and of its key; an entry whose payload or key does not match
(a truncated write, a damaged disk, a file copied in by hand) is never used: it is built again and replaced.
Entries are written to a temporary file and renamed, so a build stopped half-way leaves no half entry.

The cache keeps to a size (PLC_CACHE_MAX_MB, default 256 MB): a command that added entries removes, as it ends,
the least recently used ones beyond that (an entry used is touched), down to three quarters of it.
"""
from __future__ import annotations

import atexit
import gc
import hashlib
import os
import pickle
import re
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from . import ast as A
from .diagnostics import Diagnostics

CACHE_DIR = Path("build") / "plc-cache"
MAGIC = b"plc-cache 1\n"
KINDS = ("parse", "toml", "iface", "cpiece", "obj")      # the directories of entries, each an entry kind
DEFAULT_MAX_MB = 256

_active: Cache | None = None


def sha256(*parts: str | bytes) -> str:
    h = hashlib.sha256()
    for p in parts:
        h.update(p.encode() if isinstance(p, str) else p)
        h.update(b"\0")
    return h.hexdigest()


_digests: dict[str, str] = {}


def toolchain_digest(start: str = "parser.py") -> str:
    """A hash of the Python version and the sources of the module `start` (default the parser) and every module of
    the package it imports, however indirectly (module_sources): a changed parser never reuses a parse result of
    an older one, and an edit elsewhere in the toolchain keeps them."""
    if start not in _digests:
        package = Path(__file__).resolve().parent
        h = hashlib.sha256(sys.version.encode())
        for f in module_sources(start):
            h.update(f.relative_to(package).as_posix().encode() + b"\0")
            h.update(f.read_bytes())
        _digests[start] = h.hexdigest()
    return _digests[start]


def parser_sources() -> list[Path]:
    """parser.py and every module of the package it imports (relative imports, followed transitively), sorted."""
    return module_sources("parser.py")


def module_sources(start: str) -> list[Path]:
    """The module `start` of this package and every module of the package it imports (relative imports,
    followed transitively), sorted."""
    package = Path(__file__).resolve().parent
    todo, seen = [package / start], set()
    while todo:
        f = todo.pop()
        if f in seen or not f.is_file():
            continue
        seen.add(f)
        for module, names in RELATIVE_IMPORT.findall(f.read_text()):
            base = package.joinpath(*module.split(".")) if module else package
            paths = [base / n for n in re.findall(r"\w+", re.sub(r"\bas\s+\w+", "", names))]
            for path in paths + ([base] if module else []):
                todo += [path.with_suffix(".py"), path / "__init__.py"]
    return sorted(seen)


# `from .module import a, b as c` and `from . import (a, b)` at the start of a line (a regular expression, not
# the ast module: this runs in every command, and parsing the sources costs more than the lines it finds)
RELATIVE_IMPORT = re.compile(r"^[ \t]*from[ \t]+\.(?!\.)([\w.]*)[ \t]+import[ \t]+(\([^)]*\)|[^\n#]*)", re.M)


class Cache:
    """One cache directory: `parse/` and `obj/` entries named by their key."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self._root = str(self.root)
        self.hits = 0
        self.misses = 0
        self.compiled: list[str] = []      # the units compile_units compiled (not found in the cache), by name
        self.written = (0, 0)               # of a test build: the POUs whose C was written (not memoised), of all

    # -------------------------------------------------------------- entries --
    def _path(self, kind: str, key: str, suffix: str) -> Path:
        return self.root / kind / key[:2] / (key + suffix)

    def load(self, kind: str, key: str, suffix: str = "") -> bytes | None:
        """The payload stored under `key`, or None when absent or not intact (its checksums do not match); an
        entry found is touched (the least recently used go first when the cache is trimmed)."""
        path = os.path.join(self._root, kind, key[:2], key + suffix)     # (a thousand a build: no pathlib)
        try:
            with open(path, "rb") as f:
                data = f.read()
            os.utime(path)
        except OSError:
            return None
        head = len(MAGIC) + 128
        if len(data) < head or not data.startswith(MAGIC):
            return None
        stored_key = data[len(MAGIC):len(MAGIC) + 64].decode("ascii", "replace")
        stored_sum = data[len(MAGIC) + 64:head].decode("ascii", "replace")
        payload = data[head:]
        if stored_key != key or stored_sum != hashlib.sha256(payload).hexdigest():
            return None
        return payload

    def store(self, kind: str, key: str, payload: bytes, suffix: str = "") -> None:
        """Write the entry atomically; a cache that cannot be written only makes the next build slower."""
        path = self._path(kind, key, suffix)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=path.name + ".", dir=path.parent)
            with os.fdopen(fd, "wb") as f:
                f.write(MAGIC + key.encode() + hashlib.sha256(payload).hexdigest().encode() + payload)
            os.replace(tmp, path)
        except OSError:
            pass

    def trim(self, limit_bytes: int) -> int:
        """Remove the least recently used entries while the cache is larger than `limit_bytes`, down to three
        quarters of it; returns the number of files removed.  Only a cache that grew in this process is looked
        at (a fully cached command does not walk the directory)."""
        if self.misses == 0:
            return 0
        files = []
        for kind in KINDS:
            for dirpath, _dirs, names in os.walk(self.root / kind):
                for name in names:
                    path = os.path.join(dirpath, name)
                    try:
                        st = os.stat(path)
                    except OSError:
                        continue
                    files.append((st.st_mtime, st.st_size, path))
        total = sum(size for _t, size, _p in files)
        if total <= limit_bytes:
            return 0
        removed = 0
        for _mtime, size, path in sorted(files):
            if total <= limit_bytes * 3 // 4:
                break
            try:
                os.unlink(path)
            except OSError:
                continue
            total -= size
            removed += 1
        return removed

    # -------------------------------------------------------------- parsing --
    def parsed(self, text: str, filename: str, diags: Diagnostics, parse_fn, later: list | None = None):
        """parse_fn(text, filename, diags) through the cache: the tree, its diagnostics added to `diags`.

        The POU bodies are stored apart from the rest of the tree.  With `later` (a list), a tree loaded from
        the cache comes without them (every Pou.body empty) and a Bodies is appended to `later`: its load()
        puts them in (plc test loads the bodies of the POUs it checks again only: codegen.PieceMemo)."""
        # the lexer and the parser record portability facts on the tree, never a warning: one entry serves
        # every Diagnostics setting
        key = sha256("parse", toolchain_digest(), filename, text)
        payload = self.load("parse", key)
        if payload is not None:
            with paused_gc():          # a tree is many small objects, none of them cyclic garbage
                try:
                    tree, items, blob = pickle.loads(payload)
                    bodies = Bodies(tree, blob, text, filename, parse_fn)
                    if later is None:
                        bodies.load()
                except Exception:   # an entry that does not load is a miss, whatever broke it
                    tree = None
            if tree is not None:
                self.hits += 1
                diags.items.extend(items)
                if later is not None:
                    later.append(bodies)
                return tree
        self.misses += 1
        own = Diagnostics(portability=diags.portability)
        tree = parse_fn(text, filename, own)
        diags.items.extend(own.items)
        pous = [item for item in tree.items if isinstance(item, A.Pou)]
        kept = [pou.body for pou in pous]
        try:
            blob = pickle.dumps(kept, protocol=pickle.HIGHEST_PROTOCOL)
            for pou in pous:
                pou.body = []
            payload = pickle.dumps((tree, own.items, blob), protocol=pickle.HIGHEST_PROTOCOL)
        except RecursionError:      # a tree nested deeper than pickle goes: parsed again next time
            return tree
        finally:
            for pou, body in zip(pous, kept, strict=True):
                pou.body = body
        self.store("parse", key, payload)
        return tree

    def value(self, kind: str, key: str, compute):
        """compute() through the cache: a value stored under `key` (pickled) is loaded, else computed and stored.
        `key` must name everything the value comes from (the text read, the sources of the code computing it)."""
        payload = self.load(kind, key)
        if payload is not None:
            try:
                value = pickle.loads(payload)
            except Exception:       # an entry that does not load is a miss, whatever broke it
                pass
            else:
                self.hits += 1
                return value
        self.misses += 1
        value = compute()
        try:
            self.store(kind, key, pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))
        except (pickle.PicklingError, RecursionError, TypeError, AttributeError):
            pass
        return value


class Bodies:
    """The POU bodies of a tree loaded from the cache without them (Cache.parsed with `later`)."""

    def __init__(self, tree, blob: bytes, text: str, filename: str, parse_fn) -> None:
        self.tree, self._blob, self._text, self._filename, self._parse = tree, blob, text, filename, parse_fn

    def load(self) -> None:
        """Put every POU's body back into the tree (once); a stored body that does not load is parsed again."""
        if self._blob is None:
            return
        pous = [item for item in self.tree.items if isinstance(item, A.Pou)]
        try:
            with paused_gc():
                bodies = pickle.loads(self._blob)
            if len(bodies) != len(pous):
                raise ValueError("bodies and POUs differ in number")
        except Exception:
            fresh = self._parse(self._text, self._filename, Diagnostics())
            bodies = [item.body for item in fresh.items if isinstance(item, A.Pou)]
        for pou, body in zip(pous, bodies, strict=True):
            pou.body = body
        self._blob = None


@contextmanager
def paused_gc():
    """Python's cycle collector off while a command compiles: the front end makes about a million objects that
    all live until the compile ends and are no cyclic garbage, so the collector's passes over them are pure
    cost (a fifth of `plc test -k` after an edit, measured).  Restored afterwards: long-lived commands
    (plc run's supervision) and in-process callers keep their collector."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def project_cache(root: Path) -> Path:
    """The cache directory of the project at `root`: PLC_CACHE_DIR when set, else its build/plc-cache/."""
    shared = os.environ.get("PLC_CACHE_DIR")
    return Path(shared) if shared else root / CACHE_DIR


def use(root: Path | None) -> Cache | None:
    """Make the cache at `root` the one this process uses (None: no cache); return it.  As the process ends, the
    cache is trimmed to its size limit (max_bytes)."""
    global _active
    _active = Cache(root) if root is not None else None
    if _active is not None:
        atexit.register(_active.trim, max_bytes())
    return _active


def max_bytes() -> int:
    """The cache's size limit: PLC_CACHE_MAX_MB (a whole number of megabytes), default DEFAULT_MAX_MB."""
    text = os.environ.get("PLC_CACHE_MAX_MB", "")
    megabytes = int(text) if text.isdigit() else DEFAULT_MAX_MB
    return megabytes * 1024 * 1024


def active() -> Cache | None:
    return _active


# ----------------------------------------------------------------- objects --
@dataclass
class Unit:
    """A translation unit to compile: its name (for the C file's name and messages) and its C text."""
    name: str
    text: str


class UnitError(Exception):
    """The C compiler refused a unit: its C file, the command and the compiler's output."""

    def __init__(self, c_file: Path, command: list[str], output: str) -> None:
        super().__init__(output)
        self.c_file, self.command, self.output = c_file, command, output


_cc_ids: dict[str, str] = {}


def compiler_identity(cc: str) -> str:
    """The C compiler's name and `--version` line: a different compiler never reuses an object."""
    if cc not in _cc_ids:
        proc = subprocess.run([cc, "--version"], capture_output=True, text=True)
        _cc_ids[cc] = cc + "\n" + (proc.stdout.splitlines() or [""])[0]
    return _cc_ids[cc]


def compile_units(cache: Cache, units: list[Unit], cc: str, flags: list[str], headers: list[Path],
                  src_dir: Path, jobs: int | None = None) -> list[Path]:
    """The object file of every unit, compiled only when its cache entry is missing or not intact (in parallel,
    `jobs` at a time: default the CPU count).  Each unit's C is written to `src_dir` (where a failure's C is
    kept); raises UnitError for the first unit the C compiler refuses."""
    ident = compiler_identity(cc)
    head = sha256(ident, *flags, *(h.name.encode() + b"\0" + h.read_bytes() for h in headers))
    src_dir.mkdir(parents=True, exist_ok=True)
    objects: list[Path | None] = [None] * len(units)
    todo = []
    for k, u in enumerate(units):
        key = sha256("object", head, u.text)
        obj = cache.root / "obj" / key[:2] / f"{key}.o"
        if obj.is_file() and cache.load("obj", key, ".sum") == _object_sum(obj):
            cache.hits += 1
            try:
                os.utime(obj)
            except OSError:
                pass
            objects[k] = obj
        else:
            todo.append((k, u, key, obj))

    def build(item):
        k, u, key, obj = item
        c_file = src_dir / f"{u.name}.c"
        c_file.write_text(u.text)
        obj.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=obj.name + ".", suffix=".o", dir=obj.parent)
        os.close(fd)
        cmd = [cc, *flags, "-c", str(c_file), "-o", tmp]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            os.unlink(tmp)
            return k, UnitError(c_file, cmd, proc.stderr + proc.stdout)
        os.replace(tmp, obj)
        cache.store("obj", key, _object_sum(obj), ".sum")
        return k, obj

    cache.misses += len(todo)
    cache.compiled = [u.name for _k, u, _key, _obj in todo]
    with ThreadPoolExecutor(max_workers=jobs or os.cpu_count() or 1) as pool:
        for k, out in pool.map(build, todo):
            if isinstance(out, UnitError):
                raise out
            objects[k] = out
    return objects   # type: ignore[return-value]


def _object_sum(obj: Path) -> bytes | None:
    try:
        return hashlib.sha256(obj.read_bytes()).hexdigest().encode()
    except OSError:
        return None
