"""The Logosol limit of 50 pockets has one home, atc.machine.MAX_POCKETS; the ST and the map, which cannot import it
(MATIEC takes no constant as an array bound), are checked against it here: the T_PocketTable type, every
MaxPockets constant (and RetainedWords = the map's retained INT words: 5 + MaxPockets of the pocket table, then the
tool table's row count + 7 columns of MaxPockets), the map's PocketTool and Table* series,
the sequences' tool limit.
No pocket table of the application is declared with a literal bound.  The ST is read parsed (plc.parser): a
declaration counts, a comment or a string does not."""
from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from atc.machine import MAX_POCKETS
from atc.seq.encoding import MAX_TOOLS
from code_rules import int_literal, parse_st, parse_st_files, st_nodes
from plc import ast as A

REPO = Path(__file__).resolve().parents[2]
ST_DIRS = [REPO / "st_src", REPO / "iec_tests"]


@pytest.fixture(scope="module")
def trees() -> list[A.SourceFile]:
    """Every ST file of the library and its tests, parsed (plc.parser): the rules below read declarations."""
    return parse_st_files([p for d in ST_DIRS for p in sorted(d.rglob("*.st"))], REPO)


def where(node: A.Node) -> str:
    return f"{node.pos.file}:{node.pos.line}"


def is_int_array(spec: object, lo: int, hi: int) -> bool:
    """ARRAY[lo..hi] OF INT, both bounds written as literals."""
    return (isinstance(spec, A.ArraySpec) and len(spec.dims) == 1
            and (int_literal(spec.dims[0][0]), int_literal(spec.dims[0][1])) == (lo, hi)
            and isinstance(spec.elem, A.TypeRef) and spec.elem.name.upper() == "INT")


def pocket_table_types(trees: list[A.SourceFile]) -> list[A.TypeDecl]:
    return [t for t in st_nodes(trees, A.TypeDecl) if t.name.upper() == "T_POCKETTABLE"]


def int_constants(trees: list[A.SourceFile], name: str) -> dict[str, int]:
    """file:line -> value of every variable `name` declared INT with an integer literal as its initial value."""
    return {where(d): int_literal(d.init) for d in st_nodes(trees, A.VarDecl)
            if d.name.upper() == name.upper() and isinstance(d.spec, A.TypeRef) and d.spec.name.upper() == "INT"
            and int_literal(d.init) is not None}


def literal_pocket_tables(trees: list[A.SourceFile], limit: int) -> list[str]:
    """Where an ARRAY[1..limit] OF INT is declared anywhere but as T_PocketTable itself."""
    own = {id(t.spec) for t in pocket_table_types(trees)}
    return [where(spec) for spec in st_nodes(trees, A.ArraySpec)
            if is_int_array(spec, 1, limit) and id(spec) not in own]


def test_the_pocket_table_type_has_the_limit(trees):
    (table,) = pocket_table_types(trees)
    assert where(table).startswith("st_src/rotary/T_PocketTable.st:")
    assert is_int_array(table.spec, 1, MAX_POCKETS)


def test_every_max_pockets_constant_agrees(trees):
    rmap = tomllib.loads((REPO / "modbus_map" / "map.toml").read_text())
    retained_ints = [s["name"] for s in rmap["signal"] if s.get("retained") and s["type"] == "INT"]
    assert len(retained_ints) == 5 + MAX_POCKETS + 1 + 7 * MAX_POCKETS, retained_ints
    found = int_constants(trees, "MaxPockets")
    assert len(found) >= 8, found
    assert {k: v for k, v in found.items() if v != MAX_POCKETS} == {}
    retained_words = int_constants(trees, "RetainedWords")
    assert retained_words, "no RetainedWords constant found"
    assert {k: v for k, v in retained_words.items() if v != len(retained_ints)} == {}


def test_no_pocket_table_is_declared_with_a_literal_bound(trees):
    assert literal_pocket_tables(trees, MAX_POCKETS) == []


def test_the_pocket_rules_read_declarations_not_text():
    snippet = parse_st(
        "TYPE\n    T_PocketTable : ARRAY[1..50] OF INT;\nEND_TYPE\n"
        "FUNCTION_BLOCK FB_Holder\n"
        "VAR\n    own : T_PocketTable;\n    copy : ARRAY[1..50] OF INT;\n    words : ARRAY[1..55] OF INT;\nEND_VAR\n"
        "VAR CONSTANT\n    MaxPockets : INT := 49;     (* MaxPockets : INT := 12 and ARRAY[1..50] OF INT *)\n"
        "END_VAR\nwords[1] := 0;\nEND_FUNCTION_BLOCK\n", "snippet.st")
    assert literal_pocket_tables([snippet], 50) == ["snippet.st:7"]
    assert int_constants([snippet], "MaxPockets") == {"snippet.st:11": 49}
    assert [is_int_array(t.spec, 1, 50) for t in pocket_table_types([snippet])] == [True]


def test_the_map_and_the_sequences_follow_the_limit():
    rmap = tomllib.loads((REPO / "modbus_map" / "map.toml").read_text())
    series = sorted(int(s["name"][len("PocketTool"):]) for s in rmap["signal"] if s["name"].startswith("PocketTool"))
    assert series == list(range(1, MAX_POCKETS + 1))
    for column in ("TableTool", "TablePocket", "TableGroup", "TableLife", "TableUsedMin", "TableUsedSec", "TableFlags"):
        rows = sorted(int(s["name"][len(column):]) for s in rmap["signal"]
                      if s["name"].startswith(column) and s["name"][len(column):].isdigit())
        assert rows == list(range(1, MAX_POCKETS + 1)), column
    assert MAX_TOOLS == MAX_POCKETS
