"""`plc check --target T`: what the deploy target refuses fails the check (exit 1), at its position.

Without a target a portability warning leaves the exit code alone (the program is still ours to run); with one,
the question asked is "does this deploy there as written", so the warning decides. The two MATIEC cases are the
ones real iec2c rejects and our compiler accepted (issue 28): a STRUCT member of a TYPE declared further down the
file, and a type's initial value naming an enumeration value that two enumerations share.
"""
from __future__ import annotations

from plc.cli import main as plc_main

CONFIG = """
CONFIGURATION Config0
RESOURCE Res0 ON PLC
TASK t0 (INTERVAL := T#4ms, PRIORITY := 0);
PROGRAM i0 WITH t0 : Main;
END_RESOURCE
END_CONFIGURATION
"""
MAIN = "PROGRAM Main\nVAR\n    o : ST_Outer;\nEND_VAR\no.inner.n := o.inner.n + 1;\nEND_PROGRAM\n"

TYPE_LATER = """TYPE
    ST_Outer : STRUCT
        inner : ST_Inner;
    END_STRUCT;
END_TYPE

TYPE
    ST_Inner : STRUCT
        n : INT;
    END_STRUCT;
END_TYPE
"""

SHARED_VALUE = """TYPE
    E_Light : (Red, Green);
    E_Flag : (Green, White);
    ST_Outer : STRUCT
        inner : ST_Inner;
        lamp : E_Light := Green;
    END_STRUCT;
    ST_Inner : STRUCT
        n : INT;
    END_STRUCT;
END_TYPE
"""


def check(tmp_path, capsys, types: str, *opts: str) -> tuple[int, str, str]:
    f = tmp_path / "types.st"
    f.write_text(types)
    (tmp_path / "main.st").write_text(MAIN)
    (tmp_path / "config.st").write_text(CONFIG)
    try:
        rc = plc_main(["check", *opts, str(tmp_path)])
    except SystemExit as e:
        rc = e.code
    out = capsys.readouterr()
    return rc, out.out + out.err, types


def line_col(text: str, needle: str, nth: int = 1) -> str:
    at = -1
    for _ in range(nth):
        at = text.index(needle, at + 1)
    line = text.count("\n", 0, at) + 1
    return f"{line}:{at - (text.rfind(chr(10), 0, at) + 1) + 1}"


def test_a_struct_member_of_a_type_declared_later_fails_the_openplc_check_at_its_place(tmp_path, capsys):
    rc, out, text = check(tmp_path, capsys, TYPE_LATER, "--target", "openplc")
    assert rc == 1, out
    # at the member that names the later type
    assert f"types.st:{line_col(text, 'inner : ST_Inner')}: warning: portability: TYPE ST_Outer uses ST_Inner" \
        in out, out
    assert "not deployable as written" in out
    rc, out, _ = check(tmp_path, capsys, TYPE_LATER)                # no target: a warning, the exit code is 0
    assert rc == 0 and "TYPE ST_Outer uses ST_Inner" in out, out


def test_an_initial_value_two_enumerations_share_fails_the_openplc_check_at_its_place(tmp_path, capsys):
    rc, out, text = check(tmp_path, capsys, SHARED_VALUE, "--target", "openplc")
    assert rc == 1, out
    assert f"types.st:{line_col(text, 'Green', 3)}: warning: portability: 'Green' is a value of several " \
           "enumerations" in out, out
    rc, out, _ = check(tmp_path, capsys, SHARED_VALUE)
    assert rc == 0, out


def test_a_program_the_target_takes_checks_clean_with_exit_0(tmp_path, capsys):
    fixed = TYPE_LATER.split("TYPE\n    ST_Inner")[0]
    fixed = "TYPE\n    ST_Inner : STRUCT\n        n : INT;\n    END_STRUCT;\nEND_TYPE\n\n" + fixed
    rc, out, _ = check(tmp_path, capsys, fixed, "--target", "openplc")
    assert rc == 0 and "clean" in out, out
