"""User procedures in a sequence set (docs/procedures.md): [[procedures]] checked with positioned errors and
compiled into F_ProcedureDef, F_SequenceSelect(KindProcedure, slot) and F_ProcedureOutput."""

from __future__ import annotations

from pathlib import Path

from atc.seq.encoding import Kind, Opcode
from atc.seq.stgen import generate
from seq_testlib import CONFIG_INDEX, assemble, run_cli

PROCEDURE = """
[[procedures]]
id = {id}
name = "{name}"
mode = {mode}
interval = {interval}
stop_on_error = false
can_stop_gcode = true
err_msg = "{name} failed"
file = "{file}"
"""


def make_set(tmp_path: Path, procedures: str, bodies: dict[str, str], io: str = "") -> Path:
    """The default set copied into tmp_path with these [[procedures]] (and extra [io] keys) instead of its own."""
    text = CONFIG_INDEX.read_text(encoding="utf-8")
    text = text[:text.index("[[procedures]]")]
    if io:
        kept = [line for line in text.splitlines() if not line.startswith("procedure_")]
        text = "\n".join(kept).replace("[io]\n", "[io]\n" + io + "\n") + "\n"
    for name in ("home", "put", "get", "length"):
        (tmp_path / f"{name}.seq").write_text((CONFIG_INDEX.parent / f"{name}.seq").read_text())
    for name, body in bodies.items():
        (tmp_path / name).write_text(body)
    index = tmp_path / "sequences.toml"
    index.write_text(text + procedures)
    return index


def errors(index: Path) -> list[tuple[str, int, int, str]]:
    run = run_cli("check", index)
    return [(Path(m["file"]).name, int(m["line"] or 0), int(m["col"] or 0), m["msg"]) for m in run.diagnostics()]


def test_the_shipped_example_procedures_check_clean_and_compile_in_file_order():
    run = run_cli("check", "--werror", CONFIG_INDEX)
    assert run.status == 0, run.err
    assembly, diags = assemble(CONFIG_INDEX)
    assert assembly is not None, [d.render() for d in diags.errors]
    (lube, lube_seq), (alarm, alarm_seq) = assembly.procedures
    assert (lube.slot, lube.id, lube.mode, lube.interval_ms, lube.stop_on_error, lube.can_stop_gcode) == \
        (1, 0, 0, 240000, False, True)
    assert (alarm.slot, alarm.id, alarm.mode) == (2, 3, 3)
    steps = assembly.sequences[lube_seq - 1].steps
    assert [(s.opcode, s.channel, s.level, s.duration_ms) for s in steps] == [
        (Opcode.OUT, 4, True, 0), (Opcode.WAIT_IN, 4, True, 15000), (Opcode.OUT, 4, False, 0)]
    assert assembly.select[(Kind.PROCEDURE, 1)] == lube_seq and assembly.select[(Kind.PROCEDURE, 2)] == alarm_seq
    st = generate(assembly, "sequences.toml", "SequenceTables.st")
    select = "KindProcedure:\n        CASE tool OF (* the procedure's slot *)\n            1: F_SequenceSelect := 5;"
    assert select in st
    assert "procData.interval := T#240000ms;" in st and "4..7: F_ProcedureOutput := TRUE;" in st
    assert "F_SequenceMessage := 'lubrication: no oil pressure within 15 s';" in st


def test_a_procedure_file_checks_on_its_own_as_a_procedure():
    run = run_cli("check", "--werror", CONFIG_INDEX.parent / "lube.seq")
    assert run.status == 0, run.err


def test_commands_a_procedure_may_not_use_are_positioned_errors(tmp_path):
    body = "OUT 4 1\nMESSAGE hello\nMOVEABS Z-5\nIFIN 4 1 DIALOG go\nHOME ROTARY\nWAITIN 4 1 100\nDELAY 10\n"
    index = make_set(tmp_path, PROCEDURE.format(id=1, name="p", mode=1, interval=0, file="p.seq"), {"p.seq": body})
    found = errors(index)
    assert [(f, line, col) for f, line, col, _ in found] == [("p.seq", 2, 1), ("p.seq", 3, 1), ("p.seq", 4, 10),
                                                               ("p.seq", 5, 1)]
    assert [msg.split(" is not")[0] for *_, msg in found] == ["MESSAGE", "MOVEABS", "DIALOG", "HOME ROTARY"]


def test_a_procedure_writes_only_its_own_outputs(tmp_path):
    body = "OUT 17 1\nWAITIN 9 1 100\n"
    index = make_set(tmp_path, PROCEDURE.format(id=1, name="p", mode=2, interval=0, file="p.seq"), {"p.seq": body})
    found = errors(index)
    assert [(f, line, col) for f, line, col, _ in found] == [("p.seq", 1, 5), ("p.seq", 2, 8)]
    assert "OUT may write procedure_outputs 4-7" in found[0][3]
    assert "procedures may read procedure_inputs 4-7" in found[1][3]


def test_procedure_outputs_shared_with_the_tool_change_are_an_error(tmp_path):
    index = make_set(tmp_path, "", {}, io='procedure_inputs = ["4-7"]\nprocedure_outputs = ["4-7", 18]')
    found = errors(index)
    assert len(found) == 1 and found[0][0] == "sequences.toml" and "18 also in [io] outputs" in found[0][3]


def test_index_errors_are_positioned_at_their_key(tmp_path):
    procedures = (PROCEDURE.format(id=1, name="a", mode=0, interval=0, file="a.seq")        # no interval
                  + PROCEDURE.format(id=1, name="b", mode=1, interval=0, file="a.seq")      # id twice
                  + PROCEDURE.format(id=2, name="c", mode=4, interval=0, file="a.seq")      # mode 4
                  + PROCEDURE.format(id=3, name="d", mode=1, interval=0, file="none.seq")   # no file
                  + "[[procedures]]\nid = 4\nname = \"e\"\nmode = 1\nfile = \"a.seq\"\nintervall = 5\n")
    index = make_set(tmp_path, procedures, {"a.seq": "OUT 4 1\n"})
    lines = index.read_text().splitlines()
    found = errors(index)

    def line_of(text: str, nth: int = 0) -> int:
        return [n for n, line in enumerate(lines, start=1) if line.startswith(text)][nth]

    assert [(line, msg.split(":")[0] if "is already" not in msg else "id") for _, line, _, msg in found[:3]] == [
        (line_of("mode = 0"), "mode 0 runs every interval ms"),
        (line_of("id = 1", 1), "id"),
        (line_of("mode = 4"), "[[procedures]] 3"),
    ]
    assert found[3][1] == line_of('file = "none.seq"') and "cannot read sequence file" in found[3][3]
    assert found[4][1] == line_of("intervall") and "unknown key 'intervall'" in found[4][3]
    assert len(found) == 5


def test_err_msg_longer_than_a_message_is_an_error(tmp_path):
    procedures = PROCEDURE.format(id=1, name="x" * 81, mode=1, interval=0, file="a.seq").replace(
        'name = "' + "x" * 81 + '"', 'name = "x"')
    index = make_set(tmp_path, procedures, {"a.seq": "OUT 4 1\n"})
    found = errors(index)
    assert len(found) == 1 and "err_msg" in found[0][3] and "at most 80" in found[0][3]
    assert index.read_text().splitlines()[found[0][1] - 1].startswith("err_msg")


def test_more_than_sixteen_procedures_are_refused(tmp_path):
    procedures = "".join(PROCEDURE.format(id=n, name=f"p{n}", mode=1, interval=0, file="a.seq") for n in range(17))
    index = make_set(tmp_path, procedures, {"a.seq": "OUT 4 1\n"})
    found = errors(index)
    assert len(found) == 1 and "at most 16 procedures; this is procedure 17" in found[0][3]


def test_procedures_with_the_same_body_share_a_table(tmp_path):
    procedures = (PROCEDURE.format(id=1, name="a", mode=1, interval=0, file="a.seq")
                  + PROCEDURE.format(id=2, name="b", mode=2, interval=0, file="a.seq"))
    index = make_set(tmp_path, procedures, {"a.seq": "OUT 4 1\n"})
    assembly, diags = assemble(index)
    assert assembly is not None, [d.render() for d in diags.errors]
    assert [number for _, number in assembly.procedures] == [5, 5]
    assert len(assembly.sequences) == 5
