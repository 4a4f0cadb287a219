"""`plc deploy openplc`: one self-contained ST file for an OpenPLC upload, types first, checked for OpenPLC."""
from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from plc import ast as A
from atc import deploy, freshness
from atc.seq.cli import main as seq_main
from plc import plcopen
from plc.diagnostics import Diagnostics
from plc.driver import compile_sources
from plc.parser import parse

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bundle(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("deploy") / "atc_openplc.st"
    import os
    cwd = os.getcwd()
    os.chdir(REPO)
    try:
        assert deploy.main(["openplc", "--out", str(out), "-q"]) == 0
    finally:
        os.chdir(cwd)
    return out


def test_the_bundle_compiles_alone_for_openplc_without_warnings(bundle):
    result = compile_sources([bundle], target="openplc", generate=True)
    assert [d.render() for d in result.diags.items if d.severity in ("error", "warning")] == []
    assert result.c_text


def test_the_bundle_holds_every_pou_and_type_of_st_src_once_and_no_test_code(bundle):
    def declared(trees):
        names = []
        for tree in trees:
            for item in tree.items:
                if isinstance(item, A.TypeBlock):
                    names += [d.name for d in item.decls]
                elif isinstance(item, (A.Pou, A.Configuration)):
                    names.append(item.name)
        return names
    sources = [parse(p.read_text(), str(p), Diagnostics()) for p in sorted((REPO / "st_src").rglob("*.st"))]
    ladder = sorted((REPO / "st_src").rglob("*.xml"))
    assert ladder, "st_src/ holds the ladder interlocks as a PLCopen file"
    for p in ladder:       # PLCopen sources (the ladder interlocks) travel as their ST translation
        tr = plcopen.translate(str(p), p.read_bytes(), Diagnostics())
        sources.append(parse(tr.text, str(p), Diagnostics()))
    got = declared([parse(bundle.read_text(), "bundle", Diagnostics())])
    assert sorted(got) == sorted(declared(sources))
    assert not any(n.startswith("TEST_") or n.startswith("ASSERT") for n in got)
    assert got.count("CONFIG0") == 1 and re.search(r"RESOURCE Res0 ON PLC", bundle.read_text())
    assert "FB_CHANGERINTERLOCKS" in got


def test_types_come_first_each_after_the_types_it_uses(bundle):
    tree = parse(bundle.read_text(), "bundle", Diagnostics())
    kinds = ["TYPE" if isinstance(i, A.TypeBlock) else i.kind if isinstance(i, A.Pou) else "CONFIGURATION"
             for i in tree.items]
    rank = [deploy.KIND_ORDER[k] for k in kinds]
    assert rank == sorted(rank)
    known: set[str] = set()
    all_types = {d.name for i in tree.items if isinstance(i, A.TypeBlock) for d in i.decls}
    for item in tree.items:
        if not isinstance(item, A.TypeBlock):
            continue
        uses: set[str] = set()
        for d in item.decls:
            deploy._type_refs(d.spec, uses)
        own = {d.name for d in item.decls}
        assert (uses & all_types) - own <= known, f"{own} uses a type declared later"
        known |= own


def test_deploy_is_reproducible(bundle, tmp_path, monkeypatch):
    monkeypatch.chdir(REPO)
    again = tmp_path / "again.st"
    assert deploy.main(["openplc", "--out", str(again), "-q"]) == 0
    assert again.read_bytes() == bundle.read_bytes()


def test_comments_in_front_of_an_item_travel_with_it(tmp_path, monkeypatch):
    src = tmp_path / "src"
    src.mkdir()
    (src / "Main.st").write_text("(* the main program *)\nPROGRAM MainProg\nVAR\n    x : ST_Point;\nEND_VAR\n"
                                 "x.a := 1;\nEND_PROGRAM\n(* the config *)\nCONFIGURATION Config0\n"
                                 "    RESOURCE Res0 ON PLC\n        TASK t(INTERVAL := T#10ms, PRIORITY := 0);\n"
                                 "        PROGRAM p WITH t : MainProg;\n    END_RESOURCE\nEND_CONFIGURATION\n")
    (src / "ST_Point.st").write_text("(* a point *)\nTYPE\n    ST_Point : STRUCT\n        a : INT;\n"
                                     "    END_STRUCT;\nEND_TYPE\n")
    out = tmp_path / "out.st"
    monkeypatch.chdir(tmp_path)
    assert deploy.main(["openplc", "--out", str(out), "--src", str(src), "-q"]) == 0
    text = out.read_text()
    assert text.index("(* a point *)") < text.index("\nTYPE\n") < text.index("(* the main program *)") \
        < text.index("PROGRAM MainProg") < text.index("(* the config *)") < text.index("\nCONFIGURATION Config0")


def test_a_portability_warning_writes_nothing_and_fails(tmp_path, monkeypatch, capsys):
    src = tmp_path / "src"
    src.mkdir()
    (src / "Main.st").write_text("PROGRAM MainProg\nVAR\n    n : INT;\n    d : DINT;\nEND_VAR\nd := n;\n"
                                 "END_PROGRAM\nCONFIGURATION Config0\n    RESOURCE Res0 ON PLC\n"
                                 "        TASK t(INTERVAL := T#10ms, PRIORITY := 0);\n"
                                 "        PROGRAM p WITH t : MainProg;\n    END_RESOURCE\nEND_CONFIGURATION\n")
    out = tmp_path / "out.st"
    monkeypatch.chdir(tmp_path)
    assert deploy.main(["openplc", "--out", str(out), "--src", str(src)]) == 1
    assert not out.exists()
    assert "nothing written" in capsys.readouterr().err


def test_openplc_needs_config0_and_res0(tmp_path, monkeypatch, capsys):
    src = tmp_path / "src"
    src.mkdir()
    (src / "Main.st").write_text("PROGRAM MainProg\nVAR\n    n : INT;\nEND_VAR\nn := 1;\nEND_PROGRAM\n"
                                 "CONFIGURATION Machine\n    RESOURCE Cpu ON PLC\n"
                                 "        TASK t(INTERVAL := T#10ms, PRIORITY := 0);\n"
                                 "        PROGRAM p WITH t : MainProg;\n    END_RESOURCE\nEND_CONFIGURATION\n")
    monkeypatch.chdir(tmp_path)
    assert deploy.main(["openplc", "--out", str(tmp_path / "out.st"), "--src", str(src)]) == 1
    assert "OpenPLC needs CONFIGURATION Config0" in capsys.readouterr().err


def test_slave_devices_moves_the_machine_io_where_openplc_slave_devices_put_it(tmp_path, monkeypatch):
    """--slave-devices: the I/O module's inputs 0-31 at %IX100.0.., its coils 0-7 at %QX100.0.. (the layout of
    plc.io_config, the same module `plc run --io modbus` uses); host signals stay where the map puts them."""
    out = tmp_path / "atc_openplc_slaves.st"
    monkeypatch.chdir(REPO)
    assert deploy.main(["openplc", "--out", str(out), "--slave-devices", "-q"]) == 0
    text = out.read_text()
    assert re.search(r"\bEStopOk AT %IX100\.0\b", text) and re.search(r"\bCarouselPocket AT %IX102\.0\b", text)
    assert re.search(r"\bCarouselMotorOn AT %QX100\.0\b", text) and re.search(r"\bColletOpen AT %QX100\.3\b", text)
    assert re.search(r"\bToolPrepared AT %QX10\.0\b", text), "host signals keep their map address"
    assert not re.search(r" AT %IX[0-3]\.\d", text) and not re.search(r" AT %QX2\.\d", text)
    assert deploy.relocate("a AT %IX0.0 : BOOL;", {"B": "%IX100.0"})[1] == ["B"]


def test_a_copy_without_git_is_fresh_and_deploys_the_same_bundle(bundle, tmp_path, monkeypatch, capsys):
    """An archive of the project has no .git: the generated headers still name their files from the project root
    (project.toml), so the drift check finds nothing stale and the deploy gives the repository's bundle."""
    copy = tmp_path / "atc-plc"
    shutil.copytree(REPO, copy, ignore=shutil.ignore_patterns(".git", ".venv", "build", "plc", "__pycache__",
                                                              ".pytest_cache", "node_modules"))
    assert not (copy / ".git").exists() and (copy / "project.toml").is_file()
    assert freshness.problems(copy) == []
    tables = copy / freshness.SEQ_TABLES
    assert seq_main(["compile", str(copy / "configs/sequences/sequences.toml"), "--out", str(tables),
                     "--check-drift"]) == 0
    monkeypatch.chdir(copy)
    out = tmp_path / "atc_openplc.st"
    status = deploy.main(["openplc", "--out", str(out), "-q"])
    assert status == 0, capsys.readouterr().err
    assert out.read_bytes() == bundle.read_bytes()
