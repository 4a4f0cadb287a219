"""The Logosol limit of 50 pockets has one home, atc.machine.MAX_POCKETS; the ST and the map, which cannot import it
(MATIEC takes no constant as an array bound), are checked against it here: the T_PocketTable type, every
MaxPockets constant (and RetainedWords = the map's retained INT words: 5 + MaxPockets), the map's PocketTool series, the sequences' tool limit.
No pocket table of the application is declared with a literal bound."""
from __future__ import annotations

import re
import tomllib
from pathlib import Path

from atc.machine import MAX_POCKETS
from atc.seq.encoding import MAX_TOOLS

REPO = Path(__file__).resolve().parents[2]
ST_DIRS = [REPO / "st_src", REPO / "iec_tests"]


def st_files():
    for d in ST_DIRS:
        yield from sorted(d.rglob("*.st"))


def test_the_pocket_table_type_has_the_limit():
    text = (REPO / "st_src" / "rotary" / "T_PocketTable.st").read_text()
    assert re.search(rf"T_PocketTable\s*:\s*ARRAY\[1\.\.{MAX_POCKETS}\] OF INT;", text)


def test_every_max_pockets_constant_agrees():
    rmap = tomllib.loads((REPO / "modbus_map" / "map.toml").read_text())
    retained_ints = [s["name"] for s in rmap["signal"] if s.get("retained") and s["type"] == "INT"]
    assert len(retained_ints) == 5 + MAX_POCKETS, retained_ints
    found = {}
    for path in st_files():
        for m in re.finditer(r"\bMaxPockets\s*:\s*INT\s*:=\s*(\d+)", path.read_text()):
            found[path.relative_to(REPO).as_posix()] = int(m.group(1))
        m = re.search(r"\bRetainedWords\s*:\s*INT\s*:=\s*(\d+)", path.read_text())
        if m:
            assert int(m.group(1)) == len(retained_ints), path
    assert len(found) >= 8, found
    assert {k: v for k, v in found.items() if v != MAX_POCKETS} == {}


def test_no_pocket_table_is_declared_with_a_literal_bound():
    bad = [f"{p.relative_to(REPO)}:{n}" for p in st_files()
           for n, line in enumerate(p.read_text().splitlines(), 1)
           if re.search(rf"ARRAY\[1\.\.{MAX_POCKETS}\] OF INT", line) and "T_PocketTable :" not in line]
    assert bad == []


def test_the_map_and_the_sequences_follow_the_limit():
    rmap = tomllib.loads((REPO / "modbus_map" / "map.toml").read_text())
    series = sorted(int(s["name"][len("PocketTool"):]) for s in rmap["signal"] if s["name"].startswith("PocketTool"))
    assert series == list(range(1, MAX_POCKETS + 1))
    assert MAX_TOOLS == MAX_POCKETS
