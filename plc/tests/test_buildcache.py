"""The build cache (issue 33): an edit recompiles only the C units whose text it changes, a changed TYPE or
function block interface recompiles every unit that uses it (and the verdict is then a clean build's), and an
entry that is damaged or stored under another key is never used.  A parse result from the cache is the parse."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from plc import buildcache
from plc.codegen import PieceMemo, generate, generate_units
from plc.diagnostics import Diagnostics
from plc.driver import compile_sources
from plc.parser import parse_text
from plc.testrunner import build_tests

ROOT = Path(__file__).resolve().parents[2]

TYPES = """TYPE
    ST_Limits : STRUCT
        low : INT := 2;
        high : INT := 9;
    END_STRUCT;
END_TYPE
"""

CLAMP = """FUNCTION_BLOCK FB_Clamp
VAR_INPUT
    value : INT;
    limits : ST_Limits;
END_VAR
VAR_OUTPUT
    out : INT;
END_VAR
out := LIMIT(limits.low, value, limits.high);
END_FUNCTION_BLOCK
"""

TWICE = """FUNCTION F_Twice : INT
VAR_INPUT
    x : INT;
END_VAR
F_Twice := x * 2;
END_FUNCTION
"""

TEST = """FUNCTION_BLOCK TEST_ClampKeepsTheLimits
VAR_IN_OUT
    tc : ST_TestContext;
END_VAR
VAR
    clamp : FB_Clamp;
    limits : ST_Limits;
END_VAR
clamp(value := F_Twice(x := 10), limits := limits);
tc.Ok := AssertEqualINT(tc, 9, clamp.out, 'clamped to the high limit');
tc.Done := TRUE;
END_FUNCTION_BLOCK
"""


def project(tmp: Path) -> tuple[Path, Path]:
    src, tests = tmp / "st_src", tmp / "iec_tests"
    src.mkdir()
    tests.mkdir()
    (src / "ST_Limits.st").write_text(TYPES)
    (src / "FB_Clamp.st").write_text(CLAMP)
    (src / "F_Twice.st").write_text(TWICE)
    (tests / "TEST_ClampKeepsTheLimits.st").write_text(TEST)
    return src, tests


def build_and_run(src: Path, tests: Path, build: Path, cache: buildcache.Cache) -> tuple[list[str], list[str]]:
    """(the units compiled, the runner's verdict lines) of one build."""
    _res, exe = build_tests([str(tests)], [str(src)], build, quiet=True, cache=cache)
    out = subprocess.run([str(exe)], capture_output=True, text=True, timeout=60).stdout
    return cache.compiled, [line for line in out.splitlines() if line.startswith(("END ", "ASSERT "))]


def unit_of(name: str, compiled: list[str]) -> bool:
    return any(f"_{name}_st_" in u for u in compiled)


def test_an_edit_recompiles_only_its_own_unit(tmp_path):
    src, tests = project(tmp_path)
    cache = buildcache.Cache(tmp_path / "cache")
    first, verdict = build_and_run(src, tests, tmp_path / "b", cache)
    assert unit_of("F_Twice", first) and unit_of("FB_Clamp", first) and "main" in first
    assert [v.split()[2] for v in verdict if v.startswith("END ")] == ["PASS"]
    again, _ = build_and_run(src, tests, tmp_path / "b", cache)
    assert again == []                                  # nothing changed: every object from the cache
    (src / "F_Twice.st").write_text(TWICE.replace("x * 2", "x * 3"))
    edited, verdict = build_and_run(src, tests, tmp_path / "b", cache)
    assert edited == [u for u in first if "_F_Twice_st_" in u]
    assert [v.split()[2] for v in verdict if v.startswith("END ")] == ["PASS"]     # 30 clamps to 9 too


def test_a_changed_type_or_fb_interface_rebuilds_its_users_and_the_verdict_is_a_clean_builds(tmp_path):
    src, tests = project(tmp_path)
    cache = buildcache.Cache(tmp_path / "cache")
    build_and_run(src, tests, tmp_path / "b", cache)
    # a member before `high`: every unit that lays out ST_Limits changes, the function's does not
    (src / "ST_Limits.st").write_text(TYPES.replace("high : INT := 9;", "mid : SINT := 5;\n        high : INT := 7;"))
    compiled, incremental = build_and_run(src, tests, tmp_path / "b", cache)
    assert unit_of("FB_Clamp", compiled) and unit_of("TEST_ClampKeepsTheLimits", compiled)
    assert not unit_of("F_Twice", compiled)
    _, clean = build_and_run(src, tests, tmp_path / "clean", buildcache.Cache(tmp_path / "clean-cache"))
    assert incremental == clean and "FAIL" in clean[-1], clean      # high is 7 now: expected 9, actual 7
    # an input added to the function block: its callers' units change with its layout
    (src / "FB_Clamp.st").write_text(CLAMP.replace("value : INT;", "value : INT;\n    offset : INT := 2;")
                                     .replace("value, limits.high", "value + offset, limits.high"))
    compiled, incremental = build_and_run(src, tests, tmp_path / "b", cache)
    assert unit_of("FB_Clamp", compiled) and unit_of("TEST_ClampKeepsTheLimits", compiled)
    assert not unit_of("F_Twice", compiled)
    _, clean = build_and_run(src, tests, tmp_path / "clean2", buildcache.Cache(tmp_path / "clean-cache2"))
    assert incremental == clean


def test_a_damaged_or_misplaced_object_is_never_used(tmp_path):
    src, tests = project(tmp_path)
    cache = buildcache.Cache(tmp_path / "cache")
    _, verdict = build_and_run(src, tests, tmp_path / "b", cache)
    by_size = sorted((tmp_path / "cache" / "obj").rglob("*.o"), key=lambda o: o.stat().st_size)
    big = by_size[-1]
    big.write_bytes(big.read_bytes()[: big.stat().st_size // 2])           # a truncated write
    compiled, again = build_and_run(src, tests, tmp_path / "b2", cache)
    assert len(compiled) == 1 and again == verdict
    # another unit's object and its checksum entry copied over this one's: the key inside does not match
    victim, other = by_size[:2]
    victim.write_bytes(other.read_bytes())
    victim.with_suffix(".sum").write_bytes(other.with_suffix(".sum").read_bytes())
    compiled, again = build_and_run(src, tests, tmp_path / "b3", cache)
    assert len(compiled) == 1 and again == verdict


def test_a_parse_result_from_the_cache_is_the_parse_with_its_diagnostics(tmp_path):
    cache = buildcache.Cache(tmp_path / "cache")
    bad = TWICE.replace("F_Twice := x * 2;", "F_Twice := x * ;")
    for text in (TWICE, bad):
        fresh = Diagnostics()
        want = parse_text(text, "f.st", fresh)
        for expect_hit in (False, True):
            diags = Diagnostics()
            hits = cache.hits
            tree = cache.parsed(text, "f.st", diags, parse_text)
            assert (cache.hits > hits) == expect_hit
            assert repr(tree) == repr(want) and tree is not want     # nodes compare by identity: by their dump
            assert [d.render() for d in diags.items] == [d.render() for d in fresh.items]
    assert any(d.severity == "error" for d in fresh.items)      # the bad file's error is reported on a hit too
    # damaged: one byte of the payload changed; misplaced: another file's entry under this key
    key = buildcache.sha256("parse", buildcache.toolchain_digest(), "f.st", TWICE)
    path = cache._path("parse", key, "")
    data = bytearray(path.read_bytes())
    data[-5] ^= 0xFF
    path.write_bytes(bytes(data))
    misses = cache.misses
    good = repr(parse_text(TWICE, "f.st", Diagnostics()))
    assert repr(cache.parsed(TWICE, "f.st", Diagnostics(), parse_text)) == good
    assert cache.misses == misses + 1
    other = buildcache.sha256("parse", buildcache.toolchain_digest(), "f.st", bad)
    path.write_bytes(cache._path("parse", other, "").read_bytes())
    assert repr(cache.parsed(TWICE, "f.st", Diagnostics(), parse_text)) == good
    assert cache.misses == misses + 2


def test_the_project_compiles_to_the_same_c_from_cached_parses(tmp_path):
    """Every file of st_src/ and iec_tests/ loaded from the cache: the same program, to the byte of its C and
    the text of its diagnostics."""
    paths = [str(ROOT / "st_src"), str(ROOT / "iec_tests")]

    def build():
        res = compile_sources(paths, test_build=True)
        return res.c_text, [d.render(res.sources) for d in res.diags.sorted()]

    before = buildcache.active()
    try:
        cache = buildcache.use(tmp_path / "cache")
        want = build()                      # parsed (an empty cache: a text met twice is loaded), and stored
        hits, misses = cache.hits, cache.misses
        got = build()                       # every file loaded
        assert cache.misses == misses > 100 and cache.hits - hits >= misses
    finally:
        buildcache.use(before.root if before is not None else None)
    assert got == want and (want[0] is not None or want[1])


def test_the_split_build_is_the_single_unit_build_cut_into_units(tmp_path):
    """The units together define what the single unit defines, and each compiles on its own (the runner links)."""
    src, tests = project(tmp_path)
    res = compile_sources([str(src), str(tests)], test_build=True)
    single = generate(res.program, test_build=True)
    res = compile_sources([str(src), str(tests)], test_build=True, generate=False)
    units = dict(generate_units(res.program, test_build=True))
    assert {"main", "tests", "sites", "types"} <= set(units)
    def definitions(text: str) -> list[str]:
        return [line.split("(")[0].split()[-1] for line in text.splitlines()
                if line.endswith("{") and "(" in line and not line.startswith((" ", "static inline"))]
    defined = definitions(single)
    assert {"P_FB_CLAMP_body", "U_F_TWICE", "T_TEST_CLAMPKEEPSTHELIMITS_body", "plc_run"} <= set(defined)
    assert sorted(n for text in units.values() for n in definitions(text) if n != "plc_raise") == \
        sorted(n for n in defined if n != "plc_raise")       # each once; plc_raise is every unit's own


def test_plc_test_keeps_the_cache_in_the_projects_build_directory(tmp_path):
    project(tmp_path)
    cmd = [sys.executable, "-m", "plc.cli", "test", "-v"]
    env = {k: v for k, v in os.environ.items() if k != "PLC_CACHE_DIR"}     # the suite shares one cache
    first = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path, env=env)
    assert first.returncode == 0, first.stdout + first.stderr
    assert (tmp_path / "build" / "plc-cache" / "obj").is_dir() and (tmp_path / "build" / "plc-cache" / "parse").is_dir()
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path, env=env)
    assert "(0 C unit(s) compiled, the others from the cache; the C of 0 of " in again.stdout, again.stdout
    assert again.stdout.splitlines()[-1] == first.stdout.splitlines()[-1] == "1 passed, 0 failed"


def test_a_parse_result_is_keyed_by_every_module_the_parser_imports():
    """The key names the sources of every plc module that importing the parser loads (and no others, so an edit
    of the C generator keeps the parse results)."""
    code = ("import sys, plc.parser; print('\\n'.join(sorted(m.__file__ for n, m in sys.modules.items() "
            "if n.startswith('plc.') and getattr(m, '__file__', None))))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    keyed = {str(p) for p in buildcache.parser_sources()}
    assert {str(Path(f).resolve()) for f in loaded} <= keyed and len(keyed) >= 6
    assert not any(p.name in ("codegen.py", "sema.py") for p in buildcache.parser_sources())


def test_the_cache_keeps_to_its_size_dropping_the_least_recently_used_entries(tmp_path):
    import os
    cache = buildcache.Cache(tmp_path / "cache")
    payload = b"x" * 1000
    keys = [buildcache.sha256("entry", str(k)) for k in range(10)]
    for age, key in enumerate(keys):
        cache.store("parse", key, payload)
        then = 1_000_000 + age                      # stored in order: keys[0] the oldest
        os.utime(cache._path("parse", key, ""), (then, then))
    assert cache.load("parse", keys[0]) == payload   # used now: the most recent
    assert cache.trim(10**6) == 0                     # nothing new in this cache: the directory is not walked
    cache.misses = 1
    entry = len(buildcache.MAGIC) + 128 + len(payload)
    assert cache.trim(10**6) == 0                     # within the limit: nothing removed
    removed = cache.trim(6 * entry)                   # down to 3/4 of 6 entries: 4 entries stay
    assert removed == 6
    kept = [k for k in keys if cache.load("parse", k) is not None]
    assert kept == [keys[0], *keys[7:]]               # the one just used and the three newest


def test_the_size_limit_comes_from_plc_cache_max_mb(monkeypatch):
    monkeypatch.setenv("PLC_CACHE_MAX_MB", "3")
    assert buildcache.max_bytes() == 3 * 1024 * 1024
    monkeypatch.setenv("PLC_CACHE_MAX_MB", "lots")
    assert buildcache.max_bytes() == buildcache.DEFAULT_MAX_MB * 1024 * 1024


def test_a_toml_file_read_before_is_loaded_from_the_cache_with_its_places(tmp_path):
    """tomlconf.parse through the cache in use (the project's checks before plc test read a dozen TOML files):
    the same values and places as a fresh parse, a changed text or name parsed again, invalid TOML refused each
    time and never stored."""
    from plc import tomlconf
    text = '[modbus]\nport = 5020\n\n[[io.device]]\nname = "rack"\ncoils = [{ at = 1 }, { at = 2 }]\n'
    want = tomlconf.parse(text, "run.toml")
    before = buildcache.active()
    try:
        cache = buildcache.use(tmp_path / "cache")
        first = tomlconf.parse(text, "run.toml")
        again = tomlconf.parse(text, "run.toml")
        assert (cache.misses, cache.hits) == (1, 1)
        for doc in (first, again):
            assert doc.data == want.data and doc.places == want.places
            assert doc.pos(("io", "device", 0, "coils", 1)) == want.pos(("io", "device", 0, "coils", 1))
        other = tomlconf.parse(text, "other.toml")                  # positions name the file: another entry
        assert cache.misses == 2 and other.pos(("modbus", "port")).file == "other.toml"
        tomlconf.parse(text.replace("5020", "502"), "run.toml")
        assert cache.misses == 3
        for _ in range(2):
            with pytest.raises(tomlconf.TomlError, match="invalid TOML"):
                tomlconf.parse("[modbus\n", "run.toml")
        assert cache.misses == 5 and cache.hits == 1
    finally:
        buildcache.use(before.root if before is not None else None)


def test_the_c_of_the_pous_an_edit_leaves_alone_comes_from_the_memo_and_equals_the_c_written_afresh(tmp_path):
    """plc test writes again the C of the POUs an edit can change (codegen.PieceMemo) and takes the others' from
    the cache: after each edit the units and the site table are those of a generation without the memo; a body or
    a function's own constant rewrites that function only, a TYPE or an FB's variables rewrite every POU."""
    src, tests = project(tmp_path)
    cache = buildcache.Cache(tmp_path / "cache")

    def generate_both() -> list[str]:
        res = compile_sources([str(src), str(tests)], test_build=True, generate=False)
        assert res.ok, [d.render() for d in res.diags.errors]
        known = len(res.program.sites)
        memo = PieceMemo(cache, res.texts, res.files, test_build=True)
        with_memo = generate_units(res.program, test_build=True, memo=memo)
        sites_memo = [(s.pos, s.pou) for s in res.program.sites]
        del res.program.sites[known:]
        afresh = generate_units(res.program, test_build=True)
        assert with_memo == afresh
        assert sites_memo == [(s.pos, s.pou) for s in res.program.sites]
        return memo.written

    everything = generate_both()
    assert {"F_TWICE", "FB_CLAMP", "TEST_CLAMPKEEPSTHELIMITS", "TON"} <= set(everything)
    assert generate_both() == []                                    # nothing changed: every POU from the memo
    (src / "F_Twice.st").write_text(TWICE.replace("x * 2", "x * 3"))
    assert generate_both() == ["F_TWICE"]                           # a body
    (src / "F_Twice.st").write_text(TWICE.replace("END_VAR\n", "END_VAR\nVAR CONSTANT\n    k : INT := 3;\nEND_VAR\n")
                                    .replace("x * 2", "x * k"))
    assert generate_both() == ["F_TWICE"]                           # a function's own constant
    (src / "ST_Limits.st").write_text("(* limits *)\n" + TYPES)
    assert generate_both() == []                                    # a comment: the declarations are the same
    (src / "ST_Limits.st").write_text(TYPES.replace("high : INT := 9;", "high : INT := 8;"))
    assert sorted(generate_both()) == sorted(everything)            # a TYPE
    (src / "FB_Clamp.st").write_text(CLAMP.replace("VAR_OUTPUT", "VAR\n    calls : INT;\nEND_VAR\nVAR_OUTPUT"))
    assert sorted(generate_both()) == sorted(everything)            # an FB's own variables (its layout)


def test_the_pous_the_memo_holds_are_not_checked_again_and_their_sites_point_where_they_did(tmp_path):
    """plc test's build (compile_sources with the cache): the POUs whose C the memo holds skip the bodies pass;
    their assertion sites are numbered as their C is replayed, so only the site table's order differs from a
    build that checks everything: every unit's site map names the same positions."""
    src, tests = project(tmp_path)
    cache = buildcache.Cache(tmp_path / "cache")
    site_map = re.compile(r"const int32_t (plc_sitemap_\w+)\[\] = \{([^}]*)\};")

    def build(memo_cache):
        res = compile_sources([str(src), str(tests)], test_build=True, generate=False, memo_cache=memo_cache)
        assert res.ok, [d.render() for d in res.diags.errors]
        units = dict(generate_units(res.program, test_build=True, memo=res.memo))
        sites = res.program.sites
        maps = {name: [(sites[int(n)].pos, sites[int(n)].pou) for n in body.split(",")]
                for name, body in site_map.findall(units.pop("sites"))}
        return res, units, maps

    build(cache)                                                    # every POU written: the memo filled
    (src / "F_Twice.st").write_text(TWICE.replace("x * 2", "x * 3"))
    res, units, maps = build(cache)
    assert res.memo.written == ["F_TWICE"] and len(res.memo.held) > 3
    test_pou = next(p for f in res.files for p in f.items if getattr(p, "name", "") == "TEST_CLAMPKEEPSTHELIMITS")
    assert id(test_pou) in res.memo.held                            # its body was not checked: no site yet...
    assert test_pou.body == []                                      # (nor even loaded from the cache)
    twice = next(p for f in res.files for p in f.items if getattr(p, "name", "") == "F_TWICE")
    assert twice.body and id(twice) not in res.memo.held
    _, afresh, afresh_maps = build(None)
    assert units == afresh and maps == afresh_maps                  # ...and its assertion still reports its line
    assert any(pos.file.endswith("TEST_ClampKeepsTheLimits.st") for m in maps.values() for pos, _pou in m)


def test_a_tree_loaded_without_its_bodies_gets_them_back_as_parsed(tmp_path):
    """Cache.parsed with `later`: the POU bodies stay out of a loaded tree until Bodies.load(), which gives the
    tree the parser gives; a stored body that does not load is parsed again."""
    cache = buildcache.Cache(tmp_path / "cache")
    text = TYPES + CLAMP + TWICE
    want = repr(parse_text(text, "f.st", Diagnostics()))
    later: list = []
    first = cache.parsed(text, "f.st", Diagnostics(), parse_text, later)
    assert later == [] and repr(first) == want                      # parsed now: whole
    tree = cache.parsed(text, "f.st", Diagnostics(), parse_text, later)
    pous = [item for item in tree.items if hasattr(item, "body")]
    assert len(later) == 1 and len(pous) == 2 and all(p.body == [] for p in pous)
    later[0].load()
    assert repr(tree) == want
    later.clear()
    tree = cache.parsed(text, "f.st", Diagnostics(), parse_text, later)
    later[0]._blob = b"not a pickle"
    later[0].load()
    assert repr(tree) == want


def test_plc_run_takes_its_program_object_from_the_build_cache(tmp_path):
    """plc run's runtime build compiles the program through the build cache in use (plc build's and plc test's):
    a second build directory links the object the first one compiled; a changed program is compiled again."""
    from plc.runtime import build_runtime
    src, _tests = project(tmp_path)
    (src / "Main.st").write_text("PROGRAM Main\nVAR\n    n : INT;\nEND_VAR\nn := F_Twice(x := n);\nEND_PROGRAM\n"
                                 "CONFIGURATION C\n    RESOURCE R ON PLC\n        TASK T(INTERVAL := T#10ms, "
                                 "PRIORITY := 0);\n        PROGRAM M WITH T : Main;\n    END_RESOURCE\n"
                                 "END_CONFIGURATION\n")
    res = compile_sources([str(src)], portability=False)
    assert res.ok, [d.render() for d in res.diags.errors]
    before = buildcache.active()
    try:
        cache = buildcache.use(tmp_path / "cache")
        for k, text in enumerate((res.c_text, res.c_text, res.c_text.replace("/* Generated", "/* Edited"))):
            c_file = tmp_path / f"run{k}" / "program" / "program.c"
            c_file.parent.mkdir(parents=True)
            c_file.write_text(text)
            exe = build_runtime(c_file, tmp_path / f"run{k}" / "bin")
            assert exe.is_file() and cache.compiled == ([] if k == 1 else ["program"])
    finally:
        buildcache.use(before.root if before is not None else None)
