"""The one TOML reader (plc.tomlconf): its scanner agrees with tomllib on every TOML file of the repository and on
the corners of the format; positions are those of the text; a schema reports every problem of a file at once."""
from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from plc import tomlconf
from plc.tomlconf import Bool, Field, Int, ListOf, OneOf, Str, Table

REPO = Path(__file__).resolve().parents[2]


def repository_toml_files() -> list[Path]:
    files = [REPO / "project.toml", REPO / "plc" / "pyproject.toml"]
    for folder in ("configs", "machines", "modbus_map", "plc/tests"):
        files += sorted((REPO / folder).rglob("*.toml"))
    return files


def test_the_repository_has_the_toml_files_the_agreement_is_checked_on():
    names = {p.relative_to(REPO).as_posix() for p in repository_toml_files()}
    assert {"project.toml", "modbus_map/map.toml", "modbus_map/reason_codes.toml", "configs/sequences/sequences.toml",
            "machines/default/machine.toml", "machines/default/runtime.toml"} <= names
    assert len(names) >= 30


@pytest.mark.parametrize("path", repository_toml_files(), ids=lambda p: p.relative_to(REPO).as_posix())
def test_the_scanner_agrees_with_tomllib_on_every_toml_file_of_the_repository(path):
    text = path.read_text(encoding="utf-8")
    try:
        values = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        with pytest.raises(tomlconf.TomlError):         # a broken corpus file: refused with its position
            tomlconf.parse(text, path.name)
        return
    tree, places = tomlconf.scan(text, path.name)
    assert tomlconf.plain(tree) == values
    # every key tomllib sees has a place, and that place's line holds the key
    lines = text.splitlines()
    for key_path in _paths(values):
        assert key_path in places, key_path
        name = key_path[-1]
        if isinstance(name, str):
            assert name in lines[places[key_path].key.line - 1], (key_path, places[key_path])


def _paths(value, path=()):
    if isinstance(value, dict):
        for k, v in value.items():
            yield path + (k,)
            yield from _paths(v, path + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield path + (i,)
            yield from _paths(v, path + (i,))


CORNERS = [
    'a.b.c = 1\n"q.k" = 2\n\'lit\' = "x"\n[t."x y".z]\nk = """multi\n"line" \\""" ok"""\n',
    "s = '''a\n'b'''''\nd = 1979-05-27T07:32:00Z\nd2 = 1979-05-27 07:32:00\nd3 = 1979-05-27 # date\nt = 07:32:00.5\n",
    "n = [1, -2, +3, 0x1F, 0o7, 0b101, 1_000, 3.14, -1e5, 6.02e+23, inf, -inf]\n",
    "[[a]]\nx = 1\n[[a.b]]\ny = 2\n[a.c]\nz = 3\n[[a]]\nx = 2\n[[a.b]]\ny=3\n",
    "arr = [ # c\n  { a = 1, b = { c = [1, {d = 2}] } },\n  [1, [2, 3]], # trailing\n]\ne = []\nf = {}\n",
    "[x.y]\nz = 1\n[x]\nw = 2\n",
    'k = "a\\"b # not a comment"  # a comment\nm = "\\u00e9"\n',
    "p.q = 1\np.r.s = {t = 1}\n",
    "  indented = true\n\t[tab]\n  v = false\n",
    'w = "x"\r\nv = 2\r\n',
    "[a]\n[a.'b.c']\nd = '''\n'''\n",
]


@pytest.mark.parametrize("text", CORNERS)
def test_the_scanner_agrees_with_tomllib_on_the_corners_of_the_format(text):
    tree, _places = tomlconf.scan(text)
    assert tomlconf.plain(tree) == tomllib.loads(text)


def test_positions_of_tables_keys_and_inline_elements():
    text = ('[io]\nlayer = "modbus"\n\n[[io.device]]\n  name = "a" # x\ncoils = [\n  { a = 1 },  # "{"\n'
            '  { b = "}" },\n]\n[[io.device]]\nport.number = 2\n')
    doc = tomlconf.parse(text, "run.toml")
    at = lambda pos: (pos.line, pos.col)                                   # noqa: E731
    assert at(doc.pos(("io", "layer"))) == (2, 1) and at(doc.value_pos(("io", "layer"))) == (2, 9)
    assert at(doc.pos(("io", "device", 0))) == (4, 1) and at(doc.key_pos(("io", "device", 0))) == (4, 3)
    assert at(doc.pos(("io", "device", 0, "name"))) == (5, 3)
    assert at(doc.pos(("io", "device", 0, "coils", 0))) == (7, 3)
    assert at(doc.pos(("io", "device", 0, "coils", 1))) == (8, 3)
    assert at(doc.pos(("io", "device", 0, "coils", 1, "b"))) == (8, 5)
    assert at(doc.pos(("io", "device", 1, "port", "number"))) == (11, 1)
    assert at(doc.pos(("io", "device", 1, "unit"))) == (10, 1)            # written nowhere: its table
    assert at(doc.pos(("absent",))) == (1, 1)
    place = doc.places[("io", "layer")]
    assert text[place.span[0]:place.span[1]] == '"modbus"'


def test_invalid_toml_is_one_positioned_diagnostic():
    with pytest.raises(tomlconf.TomlError) as e:
        tomlconf.parse("[a]\nb = 1\nc = 10.0.0\n", "x.toml")
    d = e.value.diagnostic
    assert (d.file, d.line, d.col) == ("x.toml", 3, 9) and d.message.startswith("invalid TOML: ")
    assert "(at line" not in d.message


def test_a_missing_file_is_said_so(tmp_path):
    with pytest.raises(tomlconf.TomlError, match="no such file"):
        tomlconf.read(tmp_path / "absent.toml")


SCHEMA = {
    "modbus": Table((Field("port", Int(0, 65535), default=5020), Field("read_only", Bool(), default=False),
                     Field("bind", Str()))),
    "io": Table((Field("layer", OneOf(("sim", "none", "modbus")), "the I/O layer", required=True),
                 Field("lines", ListOf(Int(0, 63), "channels 0..63")))),
}


def test_a_schema_reports_every_problem_of_a_file_at_once_at_its_place():
    text = ('[modbus]\nport = 70000\nprot = 1\nread_only = "yes"\n\n[io]\nlines = [1, 99]\n\n'
            '[networks]\nx = 1\n')
    doc = tomlconf.parse(text, "run.toml")
    checked = tomlconf.check_sections(doc, SCHEMA)
    found = [(d.line, d.col, d.message, d.hint) for d in doc.in_file_order()]
    assert found == [
        (2, 1, "[modbus] port: expected an integer 0..65535, got 70000", None),
        (3, 1, "[modbus] unknown key 'prot'", "did you mean 'port'?"),
        (4, 1, "[modbus] read_only: expected true or false, got 'yes'", None),
        (6, 1, "[io] layer is required (the I/O layer)", None),
        (7, 1, "[io] lines: expected a list of channels 0..63, got [1, 99]", None),
        (9, 1, "unknown section [networks]", "known: [io], [modbus]"),
    ]
    assert checked["modbus"].bad == {"port", "prot", "read_only"}
    assert checked["modbus"]["port"] == 5020 and "bind" not in checked["modbus"]   # a wrong value: its default


def test_a_schema_gives_the_defaults_and_the_values_it_accepted():
    doc = tomlconf.parse('[modbus]\nbind = "10.0.0.1"\n[io]\nlayer = "modbus"\nlines = [3]\n', "run.toml")
    checked = tomlconf.check_sections(doc, SCHEMA)
    assert doc.diagnostics == []
    assert checked["modbus"].values == {"bind": "10.0.0.1", "port": 5020, "read_only": False}
    assert checked["io"]["lines"] == [3] and checked["io"].ok


def test_a_value_where_a_section_belongs_and_an_unknown_top_level_key():
    doc = tomlconf.parse("modbus = 3\nio = { layer = \"sim\" }\nlayre = 1\n", "run.toml")
    tomlconf.check_sections(doc, SCHEMA)
    assert [(d.line, d.message, d.hint) for d in doc.in_file_order()] == [
        (1, "'modbus' must be a section [modbus]", None),
        (3, "unknown key 'layre'", "known: io, modbus"),
    ]
