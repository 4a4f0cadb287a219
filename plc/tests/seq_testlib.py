"""Shared helpers of the test_seq_* files: paths of the corpus and the default configs, and a CLI runner."""

from __future__ import annotations

import contextlib
import io
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

from atc.seq.assemble import Assembly, check_set
from atc.seq.cli import main
from atc.seq.diagnostics import Diagnostics

TESTS = Path(__file__).resolve().parent
REPO = TESTS.parent.parent
CORPUS = TESTS / "seq_corpus"
VALID_INDEX = CORPUS / "valid" / "sequences.toml"
CONFIG_INDEX = REPO / "configs" / "sequences" / "sequences.toml"
GENERATED = REPO / "st_src" / "sequence" / "generated" / "SequenceTables.st"

# `file:line:col: error: message` (line and col optional), the first line of every rendered diagnostic.
DIAG_RE = re.compile(r"^(?P<file>[^:\n]+?)(?::(?P<line>\d+))?(?::(?P<col>\d+))?: (?P<sev>error|warning): (?P<msg>.*)$")


@dataclass
class Run:
    status: int
    out: str
    err: str

    def diagnostics(self, severity: str = "error") -> list[re.Match]:
        return [m for m in map(DIAG_RE.match, self.err.splitlines()) if m and m["sev"] == severity]


def run_cli(*args: str | Path) -> Run:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main([str(a) for a in args])
    return Run(status, out.getvalue(), err.getvalue())


def load_manifest(path: Path) -> dict:
    return tomllib.loads(path.read_text(encoding="utf-8"))


def assemble(index: Path) -> tuple[Assembly | None, Diagnostics]:
    diags = Diagnostics()
    return check_set(index, diags), diags
