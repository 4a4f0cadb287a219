"""System tests of `plc host` serving the sequence mailbox: `plc run --io sim` with the real application (and a
variant whose Get Tool asks a DIALOG and shows a MESSAGE), driven by `plc host` in its own process.  The expected
requests are read from the shipped sequence files, not written down here.  Loopback only; every wait is bounded."""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tomllib
from itertools import pairwise

import pytest

from test_host_system import REPO, Plc, ok

SEQ_DIR = REPO / "configs" / "sequences"


def expected_requests(*names: str) -> list[str]:
    """The mailbox lines the shipped .seq files ask for, in order, as `plc host` prints them."""
    values = tomllib.loads((SEQ_DIR / "sequences.toml").read_text())["values"]

    def num(word: str) -> str:
        v = float(values[word]) if word.upper().startswith("P") else float(word)
        return f"{v:.3f}".rstrip("0").rstrip(".") if v != int(v) else f"{int(v)}"

    out = []
    for name in names:
        for line in (SEQ_DIR / name).read_text().splitlines():
            line = line.split("/", 1)[0].strip()
            words = line.split()
            if not words:
                continue
            if words[0] == "MOVEABS":
                pairs = re.findall(r"([XYZABC])\s*(\S+)", " ".join(words[1:]))
                out.append("MOVEABS " + " ".join(f"{a}{num(v)}" for a, v in pairs))
            elif words[0] == "FEEDRATE":
                out.append(f"FEEDRATE {float(num(words[1])) / 1000:g} units/s")
    return out


def served(out: str) -> list[tuple[int, str]]:
    """(id, request) of every mailbox line `plc host` printed."""
    lines = re.findall(r"^mailbox #(\d+): (.*?)(?: \(|: )", out, re.MULTILINE)
    return [(int(i), r) for i, r in lines]


@pytest.fixture(scope="module")
def plc(tmp_path_factory):
    p = Plc(tmp_path_factory.mktemp("plc"))
    p.start()
    yield p
    p.stop()


def test_the_host_executes_the_put_and_get_moves_in_sequence_order(plc):
    ok(plc.host("--answer", "ok", "clear", "T2 M6"))
    out = ok(plc.host("--answer", "ok", "T4 M6"))
    assert "mailbox: this host executes the sequences' requests (MbxHostActive)" in out
    got = served(out)
    assert [r for _, r in got] == expected_requests("put.seq", "get.seq"), out
    ids = [i for i, _ in got]
    assert all(b == a + 1 for a, b in pairwise(ids)), f"request ids not consecutive: {ids}"
    client, tags = plc.tags()
    with client:
        s = tags.read("MbxAnswerId", "MbxRequestId", "MbxHostActive", "ToolInSpindle", "MbxOpcode", "MbxArgsId")
    assert s["MbxAnswerId"] == ids[-1] == s["MbxRequestId"] == s["MbxArgsId"]
    assert s["MbxHostActive"] is False, "the host leaves MbxHostActive FALSE when it exits"
    assert s["ToolInSpindle"] == 4 and s["MbxOpcode"] == 0


class FakeTags:
    """The PLC's mailbox registers as a dict; writes recorded."""

    def __init__(self, values: dict):
        self.values, self.writes = dict(values), []

    def get(self, name: str):
        return self.values[name]

    def has(self, name: str) -> bool:
        return name in self.values

    def read(self, *names: str) -> dict:
        return {n: self.values[n] for n in names}

    def write(self, **values) -> None:
        self.writes.append(values)
        self.values.update(values)


def _request(rid: int, opcode: int, mask: int, z: int, text: int = 0) -> dict:
    """The PLC's mailbox registers for one request: block 0..13 and the record (2048..2069)."""
    return {"MbxRequestId": rid, "MbxOpcode": opcode, "MbxText": text, "MbxAxisMask": mask,
            "MbxX": 50000 if mask & 1 else 0, "MbxY": 20000 if mask & 2 else 0, "MbxZ": z,
            "MbxA": 0, "MbxB": 0, "MbxC": 0, "MbxValue": 0 if opcode != 3 else 40000,
            "MbxArgsOpcode": opcode, "MbxArgsText": text, "MbxArgsMask": mask, "MbxArgsId": rid}


def test_the_host_executes_the_record_one_read_shows_whatever_the_other_block_shows():
    """Skew injection for `plc host`: block 0..13 (MbxRequestId, MbxOpcode, MbxText, MbxAxisMask) is another read
    than the record, so it may show the last request, the next, or any mix. For every mix of those four fields
    (old request 25, X/Y move; new request 26, Z only) next to the old and then the new record, the host executes
    nothing while the record is the answered one and exactly the record's request once it is new."""
    from itertools import product

    from atc.host.mailbox import MOVEABS, RESULT_OK, Mailbox
    old, new = _request(25, MOVEABS, 3, 0), _request(26, MOVEABS, 4, -5000)
    head = ("MbxRequestId", "MbxOpcode", "MbxText", "MbxAxisMask")
    executed = 0
    for mix in product((old, new), repeat=len(head)):
        for record in (old, new):
            shown = dict(record, **{name: src[name] for name, src in zip(head, mix, strict=True)})
            tags = FakeTags(shown)
            box = Mailbox(tags, [].append, answer="ok")
            box._last_id = 25                               # request 25 was answered
            req = box.step(shown)
            if record is old:
                assert req is None and tags.writes == [], f"executed the answered request with {shown}"
                continue
            executed += 1
            assert req is not None and req.id == 26 and req.axes == {"Z": -5.0}, (req, shown)
            assert tags.writes == [{"MbxAnswerResult": RESULT_OK}, {"MbxAnswerId": 26}]
    assert executed == 2 ** len(head)


def test_a_request_withdrawn_while_executed_is_not_answered():
    from atc.host.mailbox import MOVEABS, Mailbox
    shown = _request(9, MOVEABS, 4, -5000)
    tags = FakeTags(dict(shown, MbxArgsOpcode=0))        # the PLC withdrew it (abort) before the host answered
    said: list[str] = []
    box = Mailbox(tags, said.append, answer="ok")
    assert box.step(shown) is not None and tags.writes == []
    assert any("withdrawn" in line for line in said), said


def test_the_host_reads_the_whole_record_in_one_request():
    """The session's poll reads the record's registers in one Modbus request, so the runtime's between-scans
    answer makes it one request's record; a map whose record is split is refused when the mailbox is attached."""
    from atc.host.mailbox import RECORD, REQUEST
    from atc.host.tags import Tags, load_map
    rmap = load_map(REPO / "modbus_map" / "map.toml")
    tags = Tags(rmap, client=None)
    watch = tuple(s.name for s in rmap.signals) + REQUEST
    assert tags.read_together(watch, RECORD)
    assert not tags.read_together(watch, RECORD + ("MbxRequestId",)), "block 0..13 is another request"


def test_without_the_mailbox_the_plc_answers_itself(plc):
    out = ok(plc.host("--no-mailbox", "T3 M6"))
    assert "mailbox" not in out
    assert out.splitlines()[-1] == "tool 3 in spindle"


# ---- a variant application whose Get Tool asks the operator ----------------------------------------------------

DIALOG_TEXT = "Check the holder of the new tool"
MESSAGE_TEXT = "Get Tool begins"


@pytest.fixture(scope="module")
def dialog_plc(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("dialog")
    seqs = tmp / "sequences"
    shutil.copytree(SEQ_DIR, seqs)
    get = (seqs / "get.seq").read_text().splitlines()
    at = next(i for i, line in enumerate(get) if line.startswith("WAITIN 19 1"))
    get[at:at] = [f"MESSAGE {MESSAGE_TEXT}", f"DIALOG {DIALOG_TEXT}"]
    (seqs / "get.seq").write_text("\n".join(get) + "\n")
    src = tmp / "st_src"
    shutil.copytree(REPO / "st_src", src)
    res = subprocess.run([sys.executable, "-m", "plc.cli", "seq", "compile", str(seqs / "sequences.toml"), "--out",
                          str(src / "sequence" / "generated" / "SequenceTables.st")],
                         cwd=REPO / "plc", capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    p = Plc(tmp)
    p.src = src
    p.start(timeout=600.0)
    p.seqs = seqs
    yield p
    p.stop()


def test_a_dialog_answered_ok_continues_and_a_message_is_skipped_from_m6(dialog_plc):
    out = ok(dialog_plc.host("--sequences", str(dialog_plc.seqs / "sequences.toml"), "--answer", "ok", "clear",
                             "T2 M6"))
    assert re.search(rf"mailbox #\d+: DIALOG \d+: {DIALOG_TEXT}: answered OK", out), out
    assert "MESSAGE" not in out, "a MESSAGE of a sequence run from M6 must be skipped by the PLC"
    assert out.splitlines()[-1] == "tool 2 in spindle"


def test_a_dialog_asked_at_the_prompt(dialog_plc):
    cmd = [sys.executable, "-m", "plc.cli", "host", "--port", str(dialog_plc.port), "--sequences",
           str(dialog_plc.seqs / "sequences.toml"), "T3 M6"]
    res = subprocess.run(cmd, cwd=REPO / "plc", input="ok\n", capture_output=True, text=True, timeout=90)
    assert res.returncode == 0, res.stdout + res.stderr
    assert re.search(rf"DIALOG \d+: {DIALOG_TEXT}  \[OK/cancel\]", res.stdout), res.stdout
    assert res.stdout.splitlines()[-1] == "tool 3 in spindle"


def test_a_dialog_cancelled_aborts_the_change_with_a_fault(dialog_plc):
    res = dialog_plc.host("--sequences", str(dialog_plc.seqs / "sequences.toml"), "--answer", "cancel", "T5 M6")
    assert res.returncode == 1, res.stdout + res.stderr
    assert re.search(rf"DIALOG \d+: {DIALOG_TEXT}: answered CANCEL", res.stdout), res.stdout
    assert re.search(r"toolchanger fault -\d+", res.stdout), res.stdout
    client, tags = dialog_plc.tags()
    with client:
        s = tags.read("ToolInSpindle", "FaultReason", "CarouselMotorOn")
    assert s["ToolInSpindle"] != 5 and s["FaultReason"] < 0 and not s["CarouselMotorOn"]


# ---- the example rack machine (machines/rack8): fixed pockets, positions from Q coordinates ------------

RACK = REPO / "machines" / "rack8" / "sequences"          # its sequences; the machine is rack8.toml beside it


@pytest.fixture(scope="module")
def rack_plc(tmp_path_factory):
    from machine_project import project_for
    tmp = tmp_path_factory.mktemp("rack")
    root = project_for("rack8")                 # its workspace (--machine rack8)
    p = Plc(tmp)
    p.src = root / "st_src"
    p.start(timeout=600.0)
    yield p
    p.stop()


def test_the_rack_example_changes_tools_at_their_q_positions(rack_plc):
    values = tomllib.loads((RACK / "sequences.toml").read_text())["values"]
    out = ok(rack_plc.host("--answer", "ok", "--sequences", str(RACK / "sequences.toml"), "T2 M6", "T7 M6"))
    xy = re.findall(r"MOVEABS X(-?[0-9.]+) Y(-?[0-9.]+)", out)
    want = [(values["T2Q1"], values["T2Q2"]), (values["T2Q1"], values["T2Q2"]), (values["T7Q1"], values["T7Q2"])]
    assert [(float(x), float(y)) for x, y in xy] == [(float(x), float(y)) for x, y in want], out
    client, tags = rack_plc.tags()
    with client:
        s = tags.read("ToolInSpindle", "SimSpindleTool", "PocketTool2", "PocketTool7", "CarouselMotorOn")
    assert s["ToolInSpindle"] == 7 and s["SimSpindleTool"] == 7, s        # the simulated rack gave tool 7
    assert s["PocketTool2"] == 2 and s["PocketTool7"] == 0, s
    assert not s["CarouselMotorOn"]
