"""Program upgrades keep retained data value by value: each test runs version 1 of a small ST program, sets the
tool in the spindle, the pocket table and two RETAIN variables, stops, starts version 2 on the same retained
file and checks what came back and what the log names as lost.

Version 1 (the `base` variant): ToolInSpindle AT %MW0 and PocketTool1..3 AT %MW16..18 (located RETAIN, the
register map's retained signals), A and B (RETAIN INT), set from %MW100/%MW101 and shown in %MW110/%MW111.
Runs against the plain build, or the ASan/UBSan build with PLC_RUNTIME_SANITIZE=1.
"""
from __future__ import annotations

import hashlib
import os
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import pytest

import rt_harness as h
from plc import retainfile
from plc.driver import compile_sources

TOOL, POCKETS, SET_A, SHOW_A = 1024, 1040, 1124, 1134     # %MW0, %MW16, %MW100, %MW110
P = "CONFIG0.RES0.PROG."

SPINDLE = "ToolInSpindle AT %MW0 : INT;"
POCKET_TABLE = "PocketTool1 AT %MW16 : INT; PocketTool2 AT %MW17 : INT; PocketTool3 AT %MW18 : INT;"


def program(spindle: str = SPINDLE, pockets: str = POCKET_TABLE, retained: str = "A : INT; B : INT;",
            show: str = "ShowA := A; ShowB := B;", extra: str = "") -> str:
    return f"""
PROGRAM Main
VAR RETAIN
    {spindle}
END_VAR
VAR RETAIN
    {pockets}
END_VAR
VAR
    SetA AT %MW100 : INT; SetB AT %MW101 : INT; ShowA AT %MW110 : INT; ShowB AT %MW111 : INT;
END_VAR
VAR RETAIN
    {retained}
END_VAR
{extra}
IF SetA <> 0 THEN A := SetA; END_IF;
IF SetB <> 0 THEN B := SetB; END_IF;
{show}
END_PROGRAM

CONFIGURATION Config0
    RESOURCE Res0 ON PLC
        TASK Fast(INTERVAL := T#4ms, PRIORITY := 0);
        PROGRAM Prog WITH Fast : Main;
    END_RESOURCE
END_CONFIGURATION
"""


@dataclass
class Upgrade:
    name: str
    text: str                          # version 2
    tool: int = 5                      # expected after the upgrade
    pockets: list[int] = field(default_factory=lambda: [7, 0, 9])
    a: int = 111
    b: int = 222
    lost: list[str] = field(default_factory=list)     # log lines that must name a lost value
    pocket_at: int = POCKETS


UPGRADES = [
    Upgrade("same program", program()),
    Upgrade("add a RETAIN variable", program(retained="A : INT; B : INT; ToolChanges : UDINT;"),
            lost=[rf"{P}TOOLCHANGES \(UDINT\) has no saved value: it starts from its initial value"]),
    Upgrade("remove a RETAIN variable", program(retained="A : INT;", show="ShowA := A;")
            .replace("IF SetB <> 0 THEN B := SetB; END_IF;", ""), b=0,
            lost=[rf"{P}B \(INT\) is not retained by this program: its saved value is kept aside"]),
    Upgrade("reorder RETAIN variables", program(retained="B : INT; A : INT;",
                                                pockets="PocketTool3 AT %MW18 : INT; PocketTool1 AT %MW16 : INT; "
                                                        "PocketTool2 AT %MW17 : INT;")),
    Upgrade("rename a RETAIN variable", program(retained="Alpha : INT; B : INT;", show="ShowA := Alpha; ShowB := B;")
            .replace("A := SetA", "Alpha := SetA"), a=0,
            lost=[rf"{P}A \(INT\) is not retained by this program: its saved value is kept aside"]),
    Upgrade("retype a RETAIN variable (INT to DINT)",
            program(retained="A : INT; B : DINT;", show="ShowA := A; ShowB := DINT_TO_INT(B);")
            .replace("B := SetB", "B := INT_TO_DINT(SetB)"), b=0,
            lost=[rf"{P}B changed type from INT to DINT: its saved value is kept aside in the file and {P}B starts "
                  r"from its initial value"]),
    Upgrade("retained registers of the map move (%MW16-18 to %MW20-22)",
            program(pockets="PocketTool1 AT %MW20 : INT; PocketTool2 AT %MW21 : INT; PocketTool3 AT %MW22 : INT;"),
            pocket_at=POCKETS + 4, lost=[rf"{P}POCKETTOOL1 \(INT\) restored; it moved from %MW16 to %MW20"]),
    Upgrade("a register of the map is no longer retained",
            program(pockets="PocketTool1 AT %MW16 : INT; PocketTool2 AT %MW17 : INT;",
                    extra="VAR PocketTool3 AT %MW18 : INT; END_VAR"), pockets=[7, 0, 0],
            lost=[rf"{P}POCKETTOOL3 \(INT at %MW18\) is not retained by this program: its saved value is kept aside"]),
    Upgrade("a signal of the map is renamed at the same address",
            program(spindle="SpindleTool AT %MW0 : INT;"),
            lost=[rf"{P}SPINDLETOOL \(INT\) restored by address %MW0, where {P}TOOLINSPINDLE was saved"]),
    Upgrade("the tool's register changes type (INT to DINT at %MD)", program(spindle="ToolInSpindle AT %MD0 : DINT;"),
            tool=0, lost=[rf"{P}TOOLINSPINDLE changed type from INT to DINT"]),
]


def build(text: str, name: str) -> Path:
    h.CACHE.mkdir(parents=True, exist_ok=True)
    src = h.CACHE / f"upgrade_{hashlib.sha256(text.encode()).hexdigest()[:12]}.st"
    h.write_if_changed(src, text)
    res = compile_sources([src], portability=False)
    assert res.ok, f"{name}: " + "\n".join(d.render() for d in res.diags.errors)
    c_file = src.with_suffix(".c")
    h.write_if_changed(c_file, res.c_text)
    return h.runtime_binary(c_file)


@pytest.fixture(scope="module")
def base() -> Path:
    return build(program(), "base")


def signed(v: int) -> int:
    return v - 65536 if v & 0x8000 else v


def first_scan(c: h.Client) -> None:
    h.wait_until(lambda: h.read_diag(c)["scans"] >= 2, 2, "two scans")


def run_version_1(binary: Path, retain: Path) -> None:
    with h.Runtime(binary, "--no-rt", "--retain", str(retain)) as rt, h.Client(rt.port) as c:
        first_scan(c)
        c.write_register(TOOL, 5)
        c.write_registers(POCKETS, [7, 0, 9])
        c.write_registers(SET_A, [111, 222])
        h.wait_until(lambda: c.read_holding(SHOW_A, 2) == [111, 222], 2, "A and B set")
    saved = retainfile.read(retain).active()
    assert saved[P + "TOOLINSPINDLE"].number() == 5 and saved[P + "B"].number() == 222


OUTCOMES: list[tuple[str, str]] = []


@pytest.mark.parametrize("up", UPGRADES, ids=[u.name for u in UPGRADES])
def test_an_upgrade_keeps_every_value_it_can_and_names_the_others(base, tmp_path, up):
    retain = tmp_path / "plc.retain"
    run_version_1(base, retain)
    v2 = build(up.text, up.name)
    with h.Runtime(v2, "--no-rt", "--retain", str(retain)) as rt, h.Client(rt.port) as c:
        first_scan(c)
        for pattern in up.lost:
            rt.wait_for(pattern)
        tool = signed(c.read_holding(TOOL, 1)[0]) if "%MD0" not in up.text else c.read_holding(2048, 2)[1]
        pockets = c.read_holding(up.pocket_at, 3)
        shown = [signed(v) for v in c.read_holding(SHOW_A, 2)]
        log = rt.log
    assert tool == up.tool, log
    assert pockets == up.pockets, log
    assert shown[0] == up.a and (shown[1] == up.b or "ShowB" not in up.text), log
    lost_lines = [line.split("retain: ", 1)[1] for line in log.splitlines()
                  if any(k in line for k in ("kept aside", "restored by address", "has no saved value", "moved from"))]
    OUTCOMES.append((up.name, f"tool {tool}, pockets {pockets}, A {shown[0]}, B {shown[1]}; "
                               f"named: {'; '.join(lost_lines) or '-'}"))
    print(f"\n{up.name}: {OUTCOMES[-1][1]}")


def test_going_back_to_version_1_finds_the_values_kept_aside(base, tmp_path):
    retain = tmp_path / "plc.retain"
    run_version_1(base, retain)
    retyped = build(UPGRADES[5].text, "retype")
    with h.Runtime(retyped, "--no-rt", "--retain", str(retain)) as rt, h.Client(rt.port) as c:
        first_scan(c)
        c.write_registers(SET_A + 1, [-5 & 0xFFFF])             # B (now DINT) gets a value of its own
        h.wait_until(lambda: signed(c.read_holding(SHOW_A + 1, 1)[0]) == -5, 2, "B = -5")
    aside = retainfile.read(retain).kept_aside()
    assert [(e.path, e.type, e.number()) for e in aside] == [(P + "B", "INT", 222)]
    with h.Runtime(base, "--no-rt", "--retain", str(retain)) as rt, h.Client(rt.port) as c:
        first_scan(c)
        rt.wait_for(rf"retain: {P}B changed type from DINT to INT: its INT value kept aside earlier is restored "
                    r"and the DINT value is kept aside in the file")
        assert c.read_holding(SHOW_A, 2) == [111, 222] and c.read_holding(TOOL, 1) == [5]
    aside = retainfile.read(retain).kept_aside()
    assert [(e.path, e.type, e.number()) for e in aside] == [(P + "B", "DINT", -5)]


TYPES = """
TYPE
    E_Mode : (Auto, Manual);
    ST_Pocket : STRUCT Tool : INT; Valid : BOOL; END_STRUCT;
    T_Slot : INT (1..24);
END_TYPE
PROGRAM Main
VAR RETAIN
    Mode : E_Mode;
    Pockets : ARRAY[1..3] OF ST_Pocket;
    Slot : T_Slot := 1;
    Name : STRING;
END_VAR
VAR CONSTANT
    Limit : INT := 3;
END_VAR
VAR
    Scratch : INT;
END_VAR
Scratch := Limit;
END_PROGRAM
CONFIGURATION Config0
    VAR_GLOBAL RETAIN Counter : UDINT; END_VAR
    RESOURCE Res0 ON PLC
        TASK Fast(INTERVAL := T#4ms, PRIORITY := 0);
        PROGRAM Prog WITH Fast : Main;
    END_RESOURCE
END_CONFIGURATION
"""


def test_the_compiler_names_each_retained_type_in_full():
    """The type of a retained entry tells its storage apart: members, bounds and enum values included."""
    binary = build(TYPES, "types")
    out = subprocess.run([str(binary), "--describe-retain", "--retain-registers", "1030"], capture_output=True,
                         text=True, timeout=30 * h.SLOW, env={**os.environ, **h.SANITIZER_ENV})
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == [
        "retain\tCONFIG0.COUNTER\tUDINT\t-\t4",
        f"retain\t{P}MODE\tE_MODE(AUTO,MANUAL)\t-\t4",
        f"retain\t{P}POCKETS\tARRAY[1..3] OF ST_POCKET{{TOOL:INT;VALID:BOOL}}\t-\t12",
        f"retain\t{P}SLOT\tINT\t-\t2",
        f"retain\t{P}NAME\tSTRING\t-\t128",
        "retain\t%MW6\tWORD\t%MW6\t2",
    ]
