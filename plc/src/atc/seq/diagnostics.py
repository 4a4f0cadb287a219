"""Diagnostics of the sequence tools: collected, never thrown one at a time.

Every problem found in a sequence file or a sequence-set index is the toolchain's one `Diagnostic`
(plc/src/plc/diagnostics.py) with its file, 1-based line and column, a message and an optional hint. `render` prints
it the way compilers do:

    put.seq:3:1: error: unknown command 'MOVEABZ'
        MOVEABZ Z-5
        ^~~~~~~
      hint: did you mean MOVEABS?
"""

from __future__ import annotations

from dataclasses import dataclass, field

from plc.diagnostics import SEQ, Diagnostic, Pos, Severity


def seq_diagnostic(severity: Severity, file: str, line: int, col: int, message: str, hint: str = "",
                   source_line: str = "", width: int = 1) -> Diagnostic:
    """The shared Diagnostic, written the sequence tools' way (a zero line or column left out)."""
    return Diagnostic(severity, Pos(file, line, col), message, hint, None, source_line, width, SEQ)


@dataclass
class Diagnostics:
    """An ordered collection of diagnostics that every stage appends to."""

    items: list[Diagnostic] = field(default_factory=list)

    def add(self, diagnostic: Diagnostic) -> None:
        """Append, unless the very same diagnostic is already there (a file checked in two contexts)."""
        if diagnostic not in self.items:
            self.items.append(diagnostic)

    def error(self, file: str, line: int, col: int, message: str, *, hint: str = "",
              source_line: str = "", width: int = 1) -> None:
        self.add(seq_diagnostic(Severity.ERROR, file, line, col, message, hint, source_line, width))

    def warning(self, file: str, line: int, col: int, message: str, *, hint: str = "",
                source_line: str = "", width: int = 1) -> None:
        self.add(seq_diagnostic(Severity.WARNING, file, line, col, message, hint, source_line, width))

    def has_errors_in(self, file: str) -> bool:
        return any(d.severity == Severity.ERROR and d.file == file for d in self.items)

    @property
    def errors(self) -> list[Diagnostic]:
        return [d for d in self.items if d.severity == Severity.ERROR]

    @property
    def warnings(self) -> list[Diagnostic]:
        return [d for d in self.items if d.severity is Severity.WARNING]

    def has_errors(self) -> bool:
        return any(d.severity == Severity.ERROR for d in self.items)

    def sorted(self) -> list[Diagnostic]:
        """Files in the order they were first reported, then line and column; discovery order breaks ties."""
        file_rank: dict[str, int] = {}
        for d in self.items:
            file_rank.setdefault(d.file, len(file_rank))
        indexed = list(enumerate(self.items))
        indexed.sort(key=lambda pair: (file_rank[pair[1].file], pair[1].line, pair[1].col, pair[0]))
        return [d for _, d in indexed]


def format_ranges(numbers) -> str:
    """[1, 2, 3, 5] -> '1-3, 5'; an empty collection -> 'none'."""
    ordered = sorted(set(numbers))
    if not ordered:
        return "none"
    parts: list[str] = []
    start = prev = ordered[0]
    for n in ordered[1:] + [None]:
        if n is not None and n == prev + 1:
            prev = n
            continue
        parts.append(str(start) if start == prev else f"{start}-{prev}")
        if n is not None:
            start = prev = n
    return ", ".join(parts)
