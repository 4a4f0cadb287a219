"""The repository explains itself: every cross-reference in it resolves to a file in it.

Comments and docs once cited documents a clone does not contain (a specification beside the checkout, a copy of
the Logosol manual); what the code relies on is now written in docs/ (index: docs/README.md). These tests keep
it that way, over every text file git knows of (tracked, or new and not ignored):

- no citation of the outside documents: the specification by name or section sign, or a "seed" document;
- every `docs/NAME.md` named anywhere exists (relative to the repository root), and every relative Markdown link
  `[text](path)` or `[text](path#anchor)` of a *.md file points at an existing file (relative to that file's
  folder; web links and pure #anchors are not checked);
- docs/README.md lists every page of docs/.
"""
from __future__ import annotations

import re
import subprocess
from pathlib import Path
from typing import Callable

REPO = Path(__file__).resolve().parents[2]
SELF = Path(__file__).resolve().relative_to(REPO).as_posix()   # this file spells the patterns out

# (pattern, what is wrong): citations of documents that are not in the repository.
CITATIONS = [
    (re.compile(r"\bSPEC(?:\.md\b|\s+sections?\b|\s*§)(?:\s*\d+)?"), "cites SPEC, which is not in the repository"),
    (re.compile(r"§"), "a bare '§': name the docs/ file instead"),
    (re.compile(r"\bseeds?\s+`?0\d\d", re.IGNORECASE), "cites a seed document, which is not in the repository"),
    (re.compile(r"\bthe seed's\b|\bof the seed\b", re.IGNORECASE), "cites 'the seed': name the Logosol manual "
                                                                     "(docs/logosol.md)"),
]
DOCS_PATH = re.compile(r"(?<![\w./-])docs/[\w.-]+\.md\b")
MD_LINK = re.compile(r"\[[^\]\n]*\]\(([^()\s]+)(?:\s+\"[^\"]*\")?\)")
WEB = re.compile(r"^[a-z][a-z0-9+.-]*:", re.IGNORECASE)   # http:, https:, mailto: ...


def line_of(text: str, offset: int) -> int:
    return text.count("\n", 0, offset) + 1


def citation_problems(text: str) -> list[tuple[int, str]]:
    """(line, message) for every citation of a document outside the repository."""
    found = []
    for pattern, message in CITATIONS:
        for m in pattern.finditer(text):
            found.append((line_of(text, m.start()), f"{message}: {m.group(0)!r}"))
    return found


def dangling_references(text: str, path: str, exists: Callable[[str], bool]) -> list[tuple[int, str]]:
    """(line, message) for every `docs/NAME.md` and (in *.md files) relative Markdown link that names no file.

    `path` is the file's path relative to the repository root; `exists` answers for a path relative to the root."""
    found = []
    for m in DOCS_PATH.finditer(text):
        if not exists(m.group(0)):
            found.append((line_of(text, m.start()), f"names {m.group(0)}, which does not exist"))
    if path.endswith(".md"):
        folder = Path(path).parent
        for m in MD_LINK.finditer(text):
            target = m.group(1).split("#", 1)[0]
            if not target or WEB.match(target):
                continue
            resolved = (folder / target).as_posix()
            if not exists(resolved):
                found.append((line_of(text, m.start()), f"links to {m.group(1)}, which does not exist"))
    return found


def check_text(text: str, path: str, exists: Callable[[str], bool]) -> list[str]:
    """Every problem of one file, as 'path:line: message'."""
    problems = citation_problems(text) + dangling_references(text, path, exists)
    return [f"{path}:{line}: {message}" for line, message in sorted(problems)]


def in_repository(relative: str) -> bool:
    target = (REPO / relative).resolve()
    return REPO in target.parents and target.is_file()


def repository_text_files() -> list[tuple[str, str]]:
    """(path, text) of every text file git tracks or would track (new, not ignored); binary files are skipped."""
    out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"], cwd=REPO,
                         capture_output=True, timeout=60)
    assert out.returncode == 0, out.stderr.decode(errors="replace")
    files = []
    for name in sorted(set(out.stdout.decode().split("\0")) - {"", SELF}):
        p = REPO / name
        if not p.is_file():
            continue                                   # deleted in the work tree, not yet in the index
        data = p.read_bytes()
        if b"\0" in data[:8192]:
            continue
        try:
            files.append((name, data.decode("utf-8")))
        except UnicodeDecodeError:
            continue
    return files


def test_no_citation_of_documents_outside_the_repository():
    problems = [f"{path}:{line}: {message}" for path, text in repository_text_files()
                for line, message in citation_problems(text)]
    assert problems == []


def test_every_docs_path_and_markdown_link_resolves():
    problems = [f"{path}:{line}: {message}" for path, text in repository_text_files()
                for line, message in dangling_references(text, path, in_repository)]
    assert problems == []


def test_the_checker_reports_a_dangling_docs_path_and_a_spec_citation():
    text = ("(* see docs/nothing.md and docs/iov2.md *)\n"
            "As SPEC section 2 says, and seed 003 too.\n")
    problems = check_text(text, "st_src/Example.st", in_repository)
    assert problems == ["st_src/Example.st:1: names docs/nothing.md, which does not exist",
                        "st_src/Example.st:2: cites SPEC, which is not in the repository: 'SPEC section 2'",
                        "st_src/Example.st:2: cites a seed document, which is not in the repository: 'seed 003'"]


def test_the_checker_resolves_markdown_links_from_the_files_folder():
    text = "[ok](iov2.md#faults) [up](../README.md) [gone](nothing.md) [web](https://example.org/x.md) [here](#top)\n"
    assert check_text(text, "docs/Example.md", in_repository) == [
        "docs/Example.md:1: links to nothing.md, which does not exist"]
    assert check_text("the command-line metavariable --io-device SPEC\n", "main.c", in_repository) == []


def test_the_docs_index_lists_every_page():
    index = (REPO / "docs" / "README.md").read_text(encoding="utf-8")
    linked = {Path(target.split("#", 1)[0]).name for target in MD_LINK.findall(index)}
    pages = {p.name for p in (REPO / "docs").glob("*.md")} - {"README.md"}
    assert sorted(pages - linked) == []
