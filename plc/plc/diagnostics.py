"""One diagnostic type for every stage: severity, position, message, hint.

Stages collect diagnostics into a `Diagnostics` bag instead of raising, so one run
reports every problem.  `render()` prints the gcc-style line, the source line and
a caret under the column.
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Pos:
    """A position in a source file; line and col are 1-based."""
    file: str
    line: int
    col: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.col}"


NOWHERE = Pos("<builtin>", 0, 0)


class InternalError(Exception):
    """A compiler bug: a pass met something it does not handle.  Raised, never turned into output."""

    def __init__(self, pos: Pos, message: str) -> None:
        super().__init__(f"{pos}: internal compiler error: {message}")
        self.pos = pos
        self.message = message


@dataclass
class Diagnostic:
    severity: str          # "error" | "warning" | "note"
    pos: Pos
    message: str
    hint: str | None = None
    code: str | None = None   # stable identifier, e.g. "portability.comment"

    def render(self, sources: "SourceSet | None" = None) -> str:
        out = [f"{self.pos}: {self.severity}: {self.message}"]
        if sources is not None and self.pos.line > 0:
            text = sources.line(self.pos.file, self.pos.line)
            if text is not None:
                shown = text.rstrip("\n").replace("\t", " ")
                out.append("    " + shown)
                out.append("    " + " " * max(0, self.pos.col - 1) + "^")
        if self.hint:
            out.append(f"    hint: {self.hint}")
        return "\n".join(out)


class SourceSet:
    """The text of every file read, for rendering source lines under diagnostics."""

    def __init__(self) -> None:
        self._lines: dict[str, list[str]] = {}

    def add(self, name: str, text: str) -> None:
        self._lines[name] = text.splitlines()

    def line(self, name: str, line: int) -> str | None:
        lines = self._lines.get(name)
        if lines is None or not (1 <= line <= len(lines)):
            return None
        return lines[line - 1]


@dataclass
class Diagnostics:
    items: list[Diagnostic] = field(default_factory=list)
    portability: bool = True      # report portability warnings

    def error(self, pos: Pos, message: str, hint: str | None = None, code: str | None = None) -> None:
        self.items.append(Diagnostic("error", pos, message, hint, code))

    def warning(self, pos: Pos, message: str, hint: str | None = None, code: str | None = None) -> None:
        self.items.append(Diagnostic("warning", pos, message, hint, code))

    def portable(self, pos: Pos, message: str, hint: str | None = None, code: str = "portability") -> None:
        """A portability warning: what our compiler accepts but MATIEC/OpenPLC does not."""
        if self.portability:
            self.items.append(Diagnostic("warning", pos, f"portability: {message}", hint, code))

    @property
    def errors(self) -> list[Diagnostic]:
        return [d for d in self.items if d.severity == "error"]

    @property
    def warnings(self) -> list[Diagnostic]:
        return [d for d in self.items if d.severity == "warning"]

    def has_errors(self) -> bool:
        return any(d.severity == "error" for d in self.items)

    def sorted(self) -> list[Diagnostic]:
        seen = set()
        out = []
        for d in sorted(self.items, key=lambda d: (d.pos.file, d.pos.line, d.pos.col)):
            key = (d.severity, d.pos, d.message)
            if key not in seen:
                seen.add(key)
                out.append(d)
        return out
