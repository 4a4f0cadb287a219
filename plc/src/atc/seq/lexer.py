"""Split one line of a sequence file into words with their columns.

The language is line based: a command and its arguments separated by blanks, `/` starts a comment that runs to
the end of the line (the Logosol manual writes `OUT 17 1 / brake is OFF`). A slash therefore cannot appear in a MESSAGE
text. Columns are 1-based and count characters; a tab counts as one.
"""

from __future__ import annotations

from dataclasses import dataclass

COMMENT = "/"


@dataclass(frozen=True)
class Word:
    text: str
    col: int  # 1-based column of the first character

    @property
    def width(self) -> int:
        return len(self.text)

    @property
    def end_col(self) -> int:
        """Column just past the word."""
        return self.col + len(self.text)


def strip_comment(line: str) -> str:
    """The line without its comment and trailing blanks or line end."""
    cut = line.find(COMMENT)
    code = line if cut < 0 else line[:cut]
    return code.rstrip()


def split_words(line: str) -> list[Word]:
    """Blank-separated words of the code part of a line."""
    code = strip_comment(line)
    words: list[Word] = []
    i = 0
    while i < len(code):
        if code[i].isspace():
            i += 1
            continue
        start = i
        while i < len(code) and not code[i].isspace():
            i += 1
        words.append(Word(code[start:i], start + 1))
    return words


def rest_of_line(line: str, col: int) -> tuple[str, int]:
    """The code part of the line from `col` on, stripped, with the column where it starts (for MESSAGE texts)."""
    code = strip_comment(line)
    i = col - 1
    while i < len(code) and code[i].isspace():
        i += 1
    return code[i:], i + 1
