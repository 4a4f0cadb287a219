"""`plc map check`: every rule reports at the right file:line, and drift of any generated file fails.

Each test copies the project's map, reason codes, st_src/ and generated files into a temporary project,
changes one thing, and runs the check."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from plc.diagnostics import Diagnostics
from atc.map import cli as map_cli
from atc.map.generate import drift, load_and_check, outputs, write

REPO = Path(__file__).resolve().parents[2]
GENERATED = ["hmi_tags", "machines/default/machine.toml", "configs/sequences", "configs/linuxcnc/atc_mb2hal.ini",
             "configs/linuxcnc/atc_iov2.hal", "configs/linuxcnc/atc_io.hal", "project.toml", "docs/register-map.md",
             "configs/openplc-v4"]


@pytest.fixture
def project(tmp_path: Path) -> Path:
    for rel in ["modbus_map", "st_src", *GENERATED]:
        src = REPO / rel
        dst = tmp_path / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.is_dir():
            shutil.copytree(src, dst)
        else:
            shutil.copy2(src, dst)
    return tmp_path


def check(root: Path) -> Diagnostics:
    diags = Diagnostics()
    loaded = load_and_check(root / "modbus_map" / "map.toml", diags)
    if loaded is not None and not diags.has_errors():
        drift(loaded, diags, show_diff=False)
    return diags


def edit(path: Path, old: str, new: str, count: int = 1) -> int:
    """Replace the first `count` occurrences of old; return the 1-based line of the first replacement."""
    text = path.read_text()
    at = text.index(old)
    path.write_text(text.replace(old, new, count))
    return text.count("\n", 0, at) + 1


def errors(diags: Diagnostics) -> list[str]:
    return [f"{d.pos.file}:{d.pos.line}: {d.message}" for d in diags.errors]


def one_error(diags: Diagnostics, text: str) -> str:
    found = [e for e in errors(diags) if text in e]
    assert found, f"no error with {text!r} in {errors(diags)}"
    return found[0]


def test_the_project_map_is_clean_and_up_to_date():
    diags = check(REPO)
    assert errors(diags) == []
    assert [d.message for d in diags.warnings] == []


def test_cli_check_exits_0_on_the_project_and_1_on_a_problem(project, capsys):
    assert map_cli.main(["check", "--map", str(REPO / "modbus_map" / "map.toml")]) == 0
    edit(project / "modbus_map" / "map.toml", 'address = 81\n', 'address = 80\n')
    assert map_cli.main(["check", "--map", str(project / "modbus_map" / "map.toml")]) == 1
    assert "modbus_map/map.toml:" in capsys.readouterr().err


def test_duplicate_name_is_reported_at_the_second_one(project):
    line = edit(project / "modbus_map" / "map.toml", 'name = "ToolChanged"', 'name = "toolprepared"')
    assert one_error(check(project), "used twice").startswith(f"modbus_map/map.toml:{line}:")


def test_two_signals_on_one_coil(project):
    line = edit(project / "modbus_map" / "map.toml", 'address = 81\n', 'address = 80\n')
    assert one_error(check(project), "coil 80 is already taken by ToolPrepared").startswith(
        f"modbus_map/map.toml:{line}:")


def test_a_dint_overlapping_the_next_one(project):
    edit(project / "modbus_map" / "map.toml", 'address = 2050\n', 'address = 2049\n')
    assert "lives in %MD only" in one_error(check(project), "MbxY")


@pytest.mark.parametrize("old,new,message", [
    ('name = "PlcReady"\ntable = "coil"', 'name = "PlcReady"\ntable = "holding_register"',
     "BOOL belongs in a coil"),
    ('name = "PlcHeartbeat"\ntable = "holding_register"', 'name = "PlcHeartbeat"\ntable = "coil"',
     "a coil holds one bit, not UINT"),
    ('address = 2048\ntype = "DINT"', 'address = 20\ntype = "DINT"', "lives in %MD only"),
    ('address = 14\ntype = "UINT"', 'address = 2100\ntype = "UINT"', "is in %MD (32-bit)"),
    ('address = 90\n', 'address = 800\n', "outside OpenPLC's map (0..799)"),
    ('address = 6\n', 'address = 4096\n', "outside OpenPLC's map (0..4095)"),
    ('type = "BOOL"\ndirection = "input"', 'type = "REAL"\ndirection = "input"', "a discrete_input holds one bit"),
    ('type = "INT"\ndirection = "plc_to_host"\nenum', 'type = "LREAL"\ndirection = "plc_to_host"\nenum',
     "cannot be exchanged"),
])
def test_table_type_and_address_rules(project, old, new, message):
    edit(project / "modbus_map" / "map.toml", old, new)
    one_error(check(project), message)


def test_host_writable_only_for_host_to_plc(project):
    path = project / "modbus_map" / "map.toml"
    line = edit(path, 'direction = "plc_to_host"\nhal = "atc-plc-ready"',
                'direction = "plc_to_host"\nhost_writable = true\nhal = "atc-plc-ready"')
    assert one_error(check(project), "host_writable is only for host_to_plc").startswith(
        f"modbus_map/map.toml:{line + 1}:")


def test_host_to_plc_must_be_host_writable(project):
    edit(project / "modbus_map" / "map.toml", 'direction = "host_to_plc"\nhost_writable = true\nhal = "atc-home',
         'direction = "host_to_plc"\nhal = "atc-home')
    one_error(check(project), "HomeRequest: a host_to_plc signal must be host_writable")


def test_physical_inputs_are_read_only(project):
    edit(project / "modbus_map" / "map.toml", 'type = "BOOL"\ndirection = "input"',
         'type = "BOOL"\ndirection = "host_to_plc"\nhost_writable = true')
    one_error(check(project), "physical inputs (read-only for host and program)")


def test_retained_only_in_memory_words(project):
    edit(project / "modbus_map" / "map.toml", 'name = "ScanCount"\ntable = "holding_register"\naddress = 14\n'
         'type = "UINT"\ndirection = "plc_to_host"', 'name = "ScanCount"\ntable = "holding_register"\n'
         'address = 14\ntype = "UINT"\ndirection = "plc_to_host"\nretained = true')
    one_error(check(project), "retained signals must be holding registers in %MW/%MD")


def test_signal_names_must_be_portable_st(project):
    edit(project / "modbus_map" / "map.toml", 'name = "SeqStep"', 'name = "Step"')
    one_error(check(project), "signal name 'Step' is a keyword to MATIEC")


def test_description_cannot_close_the_st_comment(project):
    edit(project / "modbus_map" / "map.toml", 'description = "spindle collet opened"',
         'description = "spindle collet opened *) oops"')
    one_error(check(project), "contains '(*' or '*)'")


def test_unknown_key_and_bad_toml(project):
    path = project / "modbus_map" / "map.toml"
    line = edit(path, 'name = "ColletOpened"', 'name = "ColletOpened"\nadress = 3')
    assert one_error(check(project), "unknown key 'adress'").startswith(f"modbus_map/map.toml:{line + 1}:")
    path.write_text(path.read_text() + "\n[[signal]\n")
    assert "invalid TOML" in one_error(check(project), "invalid TOML")


def test_mistakes_of_a_signal_a_section_and_the_reason_file_are_reported_together(project):
    """map.toml and reason_codes.toml are read by the one TOML reader and checked by their schemas
    (atc.map.model.SIGNAL, SECTIONS, REASON): a signal's misspelt key beside its wrong-typed address, a wrong type
    in [link] and a reason without its text are reported in one run, each at its key, a misspelling with the key
    it resembles."""
    path = project / "modbus_map" / "map.toml"
    at = edit(path, 'name = "ColletOpened"\ntable = "discrete_input"\naddress = ',
              'name = "ColletOpened"\ntable = "discrete_input"\nadress = 1\naddress = "x" # ')
    link = edit(path, "plc_timeout_ms = 1000\n", "plc_timeout_ms = \"1 s\"\n")
    reasons = project / "modbus_map" / "reason_codes.toml"
    before = reasons.read_text().splitlines()
    reason = edit(reasons, 'text = "no fault"\n', "")
    header = max(n for n, line in enumerate(before[:reason], 1) if line.startswith("[[reason]]"))
    diags = Diagnostics()
    load_and_check(path, diags)
    found = {(d.pos.file, d.pos.line, d.message, d.hint) for d in diags.errors}
    assert {("modbus_map/map.toml", at + 2, "signal: unknown key 'adress'", "did you mean 'address'?"),
            ("modbus_map/map.toml", at + 3, "signal: address: expected an integer, got 'x'", None),
            ("modbus_map/map.toml", link, "[link] plc_timeout_ms: expected an integer, got '1 s'", None),
            ("modbus_map/reason_codes.toml", header, "reason: text is required", None)} <= found, found


def test_hal_pins_are_iov2_pins_in_the_right_direction(project):
    path = project / "modbus_map" / "map.toml"
    edit(path, 'hal = "iocontrol.0.tool-prepared"', 'hal = "iocontrol.0.tool-prepare"')
    diags = check(project)
    one_error(diags, "iocontrol.0.tool-prepare is an iov2 output; the PLC cannot drive it")
    one_error(diags, "iocontrol.0.tool-prepare is already wired to ToolPrepared")
    edit(path, 'hal = "iocontrol.0.tool-changed"', 'hal = "iocontrol.0.tool-chnged"')
    one_error(check(project), "iov2 has no pin 'iocontrol.0.tool-chnged'")


def test_host_bits_for_mb2hal_must_be_contiguous(project):
    edit(project / "modbus_map" / "map.toml", 'hal = "iocontrol.0.start-change"\n', '')
    one_error(check(project), "coil 402 lies inside the host bits that mb2hal writes in one FC15 transaction "
              "(400..413) but is StartChange")


def test_a_read_whose_pin_names_line_linuxcnc_would_cut_is_an_error(project):
    """mb2hal (LinuxCNC 2.9) keeps 254 characters of a PIN_NAMES line and silently has no pins for the rest."""
    edit(project / "modbus_map" / "map.toml", 'address = 2068\n', 'address = 2082\n')      # MbxArgsId, 14 spares on
    assert "LinuxCNC 2.9 reads 254" in one_error(check(project), "PIN_NAMES line of")


def test_host_command_coils_own_their_bytes(project):
    """OpenPLC v3 applies FC15 by whole bytes: a host's write rewrites every coil of the byte."""
    path = project / "modbus_map" / "map.toml"
    edit(path, 'name = "SimEStop"\ntable = "coil"\naddress = 417', 'name = "SimEStop"\ntable = "coil"\naddress = 411')
    one_error(check(project), "SimEStop: coil 411 shares byte 51 with coils mb2hal writes")


def test_settle_time_must_cover_an_mb2hal_pass(project):
    edit(project / "modbus_map" / "map.toml", "settle_s = 0.05", "settle_s = 0.01")
    one_error(check(project), "settle_s (0.01 s) must be at least one mb2hal pass")


def test_link_signals_must_exist_and_fit(project):
    path = project / "modbus_map" / "map.toml"
    edit(path, 'plc_alive = "PlcAlive"', 'plc_alive = "PlcHeartbeat"')
    one_error(check(project), "plc_alive: PlcHeartbeat must be a plc_to_host BOOL coil")
    edit(path, "plc_timeout_ms = 1000", "plc_timeout_ms = 150")
    one_error(check(project), "plc_timeout_ms must be at least three toggle periods")


def test_reason_severity_must_agree_with_the_sign(project):
    path = project / "modbus_map" / "reason_codes.toml"
    line = edit(path, 'code = 106\nname = "BAD_POCKET"\nseverity = "soft"',
                'code = 106\nname = "BAD_POCKET"\nseverity = "hard"')
    assert one_error(check(project), "code 106 is soft").startswith(f"modbus_map/reason_codes.toml:{line + 2}:")


def test_reason_codes_are_unique_and_fit_an_int(project):
    path = project / "modbus_map" / "reason_codes.toml"
    edit(path, "code = -202\n", "code = -201\n")
    one_error(check(project), "code -201 is already used by SEQ_WAITIN_TIMEOUT")
    edit(path, "code = -305\n", "code = -40000\n")
    one_error(check(project), "does not fit an INT register")


def test_reason_text_is_one_short_line(project):
    edit(project / "modbus_map" / "reason_codes.toml", 'text = "no fault"', 'text = "' + "x" * 81 + '"')
    one_error(check(project), "text must be 1..80 characters")


def test_st_constants_must_agree_with_the_table(project):
    st = project / "st_src" / "app" / "FB_AtcChanger.st"
    line = edit(st, "ReasonEStop : DINT := -101;", "ReasonEStop : DINT := -99;")
    msg = one_error(check(project), "FB_AtcChanger.ReasonEStop is -99")
    assert f"st_src/app/FB_AtcChanger.st:{line}" in msg


def test_a_reason_constant_missing_from_the_table_is_an_error(project):
    st = project / "st_src" / "app" / "FB_AtcChanger.st"
    line = edit(st, "ReasonEStop : DINT := -101;", "ReasonEStop : DINT := -101;\n    ReasonNew : DINT := -109;")
    assert one_error(check(project), "FB_ATCCHANGER.REASONNEW = -109 is not in").startswith(
        f"st_src/app/FB_AtcChanger.st:{line + 1}:")


def test_sequence_codes_are_checked_against_f_seqreasoncode(project):
    edit(project / "st_src" / "sequence" / "F_SeqReasonCode.st", "F_SeqReasonCode := -205;",
         "F_SeqReasonCode := -250;")
    one_error(check(project), "F_SeqReasonCode gives -250 for SeqFaultEdgeNotFound, the table says -205")


def test_every_rotary_error_has_a_reason(project):
    path = project / "modbus_map" / "reason_codes.toml"
    text = path.read_text()
    start = text.index('[[reason]]\ncode = -322')
    path.write_text(text[:start])
    one_error(check(project), "E_RotaryError value RotaryErrCodeOrder has no reason code")


def test_rotary_codes_follow_the_documented_rule(project):
    edit(project / "modbus_map" / "reason_codes.toml", "code = -311\n", "code = -306\n")
    one_error(check(project), "ErrorID 16#0201 is reason -311 by the documented rule, not -306")


def test_program_file_needs_its_markers(project):
    edit(project / "st_src" / "app" / "AtcMain.st", "(* END GENERATED *)", "(* END *)")
    one_error(check(project), "needs exactly one line")


@pytest.mark.parametrize("rel", ["hmi_tags/atc_tags.csv", "configs/linuxcnc/atc_iov2.hal", "docs/register-map.md",
                                 "st_src/app/AtcMain.st", "configs/linuxcnc/atc_mb2hal.ini"])
def test_drift_of_any_generated_file_fails_and_generate_repairs_it(project, rel):
    path = project / rel
    lines = path.read_text().splitlines(keepends=True)
    at = len(lines) // 2
    lines.insert(at, "x\n")
    path.write_text("".join(lines))
    assert one_error(check(project), "drift").startswith(f"{rel}:{at + 1}:")
    diags = Diagnostics()
    loaded = load_and_check(project / "modbus_map" / "map.toml", diags)
    assert write(loaded) == [rel]
    assert errors(check(project)) == []


def test_a_missing_generated_file_is_drift(project):
    (project / "configs" / "linuxcnc" / "atc_io.hal").unlink()
    one_error(check(project), "drift: the file does not exist")


def test_generate_is_reproducible_and_writes_nothing_the_second_time(project):
    edit(project / "modbus_map" / "map.toml", 'description = "spindle collet opened"',
         'description = "spindle collet opened (changed)"')
    diags = Diagnostics()
    loaded = load_and_check(project / "modbus_map" / "map.toml", diags)
    first = write(loaded)
    snapshot = {rel: (project / rel).read_bytes() for rel in outputs(loaded)}
    assert "hmi_tags/atc_tags.csv" in first and "st_src/app/AtcMain.st" in first
    loaded = load_and_check(project / "modbus_map" / "map.toml", Diagnostics())
    assert write(loaded) == []
    assert {rel: (project / rel).read_bytes() for rel in outputs(loaded)} == snapshot


def test_a_carousel_line_on_a_taken_channel_names_both_files(project):
    """The carousel lines come from the machine description: a channel another signal of the map uses is an
    error at the machine's line that names the map's line."""
    machine = project / "machines" / "default" / "machine.toml"
    line = edit(machine, "home = 17 ", "home = 19 ")
    msg = one_error(check(project), "is already taken by")
    assert msg.startswith(f"machines/default/machine.toml:{line}:") or "machines/default/machine.toml" in msg, msg
    assert "modbus_map/map.toml:" in msg, msg
