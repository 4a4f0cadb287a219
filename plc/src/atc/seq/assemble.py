"""Check a whole sequence set (or single files) and assemble the numbered sequences the generator writes.

Numbering is deterministic: Toolchanger Home, Length Measurement, then Put Tool for tools 1..N, then Get Tool for
tools 1..N; a sequence whose steps equal an earlier one's (same file, same resolved values) reuses its number.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from .checker import Context, check_sequence
from .diagnostics import Diagnostics
from .encoding import IO_CHANNELS, MAX_TOOLS, Kind, Sequence
from .index import IoMap, ProcedureDef, SequenceRef, SequenceSet, Values, load_index
from .model import SequenceFile
from .parser import parse_text

INDEX_NAME = "sequences.toml"  # the index a lone sequence file is checked against when it sits beside one


@dataclass
class Assembly:
    """A checked set: the distinct sequences by number (1-based) and which number runs for each kind and tool."""

    seqset: SequenceSet
    sequences: list[Sequence] = field(default_factory=list)  # sequences[i] has number i + 1
    select: dict[tuple[Kind, int], int] = field(default_factory=dict)  # (kind, tool or 0 or procedure slot) -> number
    procedures: list[tuple[ProcedureDef, int]] = field(default_factory=list)  # file order, with sequence numbers

    def users(self, number: int) -> list[tuple[Kind, int]]:
        return [key for key, n in self.select.items() if n == number]


def display_path(path: Path) -> str:
    """A path as the user can open it: relative to the working directory when it lies below it."""
    try:
        relative = os.path.relpath(path)
    except ValueError:  # another drive on Windows
        return str(path)
    return str(path) if relative.startswith("..") else relative


class _Files:
    """Reads and parses each sequence file once."""

    def __init__(self, diags: Diagnostics):
        self.diags = diags
        self.parsed: dict[Path, SequenceFile | None] = {}

    def get(self, path: Path, referrer: tuple[str, int, int, str] | None = None) -> SequenceFile | None:
        key = path.resolve()
        if key not in self.parsed:
            self.parsed[key] = self._read(path, referrer)
        return self.parsed[key]

    def _read(self, path: Path, referrer: tuple[str, int, int, str] | None) -> SequenceFile | None:
        name = display_path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            reason = getattr(exc, "strerror", None) or str(exc)
            if referrer:
                file, line, col, source = referrer
                self.diags.error(file, line, col, f"cannot read sequence file '{name}': {reason}",
                                 source_line=source, width=max(1, len(source.split("=")[0].strip())))
            else:
                self.diags.error(name, 0, 0, f"cannot read sequence file: {reason}")
            return None
        return parse_text(name, text, self.diags)


def _context(seqset: SequenceSet, kind: Kind, tools: tuple[int, ...], note: str = "") -> Context:
    io = seqset.io if kind.changer else seqset.procedure_io
    return Context(kind, tools, io, seqset.axes, seqset.tools, seqset.values, seqset.index_name, note)


def _default_context(kind: Kind, tool: int) -> Context:
    """For a lone file without an index: every channel, every axis, all MAX_TOOLS tools, no P/Q values."""
    channels = frozenset(range(IO_CHANNELS))
    return Context(kind, (tool,), IoMap(channels, channels), "XYZABC", MAX_TOOLS, Values())


def _groups(seqset: SequenceSet) -> dict[tuple[Kind, Path], list[SequenceRef]]:
    """Entries of the same kind that name the same file are checked together, once."""
    groups: dict[tuple[Kind, Path], list[SequenceRef]] = {}
    for ref in seqset.refs:
        groups.setdefault((ref.kind, ref.path.resolve()), []).append(ref)
    return groups


def _note(seqset: SequenceSet, kind: Kind, tools: tuple[int, ...]) -> str:
    if kind.per_tool and seqset.always_use_tool1 and len(tools) > 1:
        return "always_use_tool1 = true: the file runs for every tool"
    return ""


def _referrer(seqset: SequenceSet, ref: SequenceRef) -> tuple[str, int, int, str]:
    lines = seqset.index_path.read_text(encoding="utf-8").splitlines()
    source = lines[ref.line - 1] if 0 < ref.line <= len(lines) else ""
    return (seqset.index_name, ref.line, ref.col, source)


def check_set(index_path: Path, diags: Diagnostics) -> Assembly | None:
    """Check an index and every file it names; the assembly when there is no error."""
    seqset = load_index(index_path, display_path(index_path), diags)
    if seqset is None:
        return None
    files = _Files(diags)
    steps: dict[tuple[Kind, int], tuple] = {}
    for (kind, _), refs in _groups(seqset).items():
        seq = files.get(refs[0].path, _referrer(seqset, refs[0]))
        if seq is None:
            continue
        tools = tuple(sorted({t for ref in refs for t in seqset.tools_of(ref)}))
        if kind.per_tool and not tools:
            continue  # an entry that never runs (always_use_tool1 = true); already warned about
        result = check_sequence(seq, _context(seqset, kind, tools, _note(seqset, kind, tools)), diags)
        if result is None or diags.has_errors_in(seq.name):
            continue
        for ref in refs:
            for tool in (seqset.tools_of(ref) or (0,)):
                steps[(kind, tool)] = (ref.file, result[tool])
    bodies = _check_procedures(seqset, files, diags)
    if diags.has_errors():
        return None
    return _number(seqset, steps, bodies)


def _procedure_referrer(seqset: SequenceSet, proc: ProcedureDef) -> tuple[str, int, int, str]:
    lines = seqset.index_path.read_text(encoding="utf-8").splitlines()
    source = lines[proc.line - 1] if 0 < proc.line <= len(lines) else ""
    return (seqset.index_name, proc.line, proc.col, source)


def _check_procedures(seqset: SequenceSet, files: _Files, diags: Diagnostics) -> dict[int, tuple]:
    """Each procedure's body checked as a procedure (once per file): slot -> steps."""
    checked: dict[Path, tuple | None] = {}
    bodies: dict[int, tuple] = {}
    for proc in seqset.procedures:
        key = proc.path.resolve()
        if key not in checked:
            seq = files.get(proc.path, _procedure_referrer(seqset, proc))
            result = None if seq is None else check_sequence(seq, _context(seqset, Kind.PROCEDURE, ()), diags)
            checked[key] = None if result is None else result[0]
        if checked[key] is not None:
            bodies[proc.slot] = checked[key]
    return bodies


def _number(seqset: SequenceSet, steps: dict[tuple[Kind, int], tuple], bodies: dict[int, tuple]) -> Assembly:
    """Tool-change sequences first (Home, Length, Put 1..N, Get 1..N), then the procedures in file order."""
    assembly = Assembly(seqset)
    numbers: dict[tuple, int] = {}
    for kind in (k for k in Kind if k.changer):
        for tool in (range(1, seqset.tools + 1) if kind.per_tool else (0,)):
            if (kind, tool) not in steps:
                continue
            file, body = steps[(kind, tool)]
            sequence = Sequence(kind, tool, file, body)
            key = sequence.body_key()
            if key not in numbers:
                assembly.sequences.append(sequence)
                numbers[key] = len(assembly.sequences)
            assembly.select[(kind, tool)] = numbers[key]
    for proc in seqset.procedures:
        sequence = Sequence(Kind.PROCEDURE, proc.slot, proc.file, bodies[proc.slot])
        key = sequence.body_key()
        if key not in numbers:
            assembly.sequences.append(sequence)
            numbers[key] = len(assembly.sequences)
        assembly.select[(Kind.PROCEDURE, proc.slot)] = numbers[key]
        assembly.procedures.append((proc, numbers[key]))
    return assembly


def check_files(paths: list[Path], diags: Diagnostics, *, index: Path | None = None,
                kind: Kind = Kind.PUT, tool: int = 1) -> None:
    """Check sequence files and indexes given on the command line; results go to diags only.

    An index (*.toml) is checked as a whole set. A sequence file is checked in the context of `index`, or of the
    sequences.toml beside it; if that index names the file, with the kind and tools it runs for there, otherwise
    as `kind` for `tool`. Without any index the file is checked against the built-in defaults.
    """
    indexes: dict[Path, SequenceSet | None] = {}
    files = _Files(diags)
    for path in paths:
        if path.suffix.lower() == ".toml":
            check_set(path, diags)
            continue
        context_index = index or (path.parent / INDEX_NAME if (path.parent / INDEX_NAME).is_file() else None)
        seqset = None
        if context_index is not None:
            key = context_index.resolve()
            if key not in indexes:
                indexes[key] = load_index(context_index, display_path(context_index), diags)
            seqset = indexes[key]
        seq = files.get(path)
        if seq is None:
            continue
        for ctx in _contexts_for(path, seqset, kind, tool):
            check_sequence(seq, ctx, diags)


def _contexts_for(path: Path, seqset: SequenceSet | None, kind: Kind, tool: int) -> list[Context]:
    if seqset is None:
        return [_default_context(kind, tool)]
    refs = [ref for ref in seqset.refs if ref.path.resolve() == path.resolve()]
    procedure = any(proc.path.resolve() == path.resolve() for proc in seqset.procedures)
    if not refs and (procedure or kind is Kind.PROCEDURE):
        return [_context(seqset, Kind.PROCEDURE, ())]
    if not refs:
        return [_context(seqset, kind, (tool,) if kind.per_tool else ())]
    contexts = []
    for (ref_kind, _), group in _groups(seqset).items():
        if group[0].path.resolve() != path.resolve():
            continue
        tools = tuple(sorted({t for ref in group for t in seqset.tools_of(ref)}))
        if ref_kind.per_tool and not tools:
            continue
        contexts.append(_context(seqset, ref_kind, tools, _note(seqset, ref_kind, tools)))
    return contexts
