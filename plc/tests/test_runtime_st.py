"""The runtime with a program compiled from ST by our own compiler (plc.driver), end to end:
located variables bound to the OpenPLC map, RETAIN kept across a restart, a division by
zero reported with its ST line.  Runs against the ASan/UBSan build with PLC_RUNTIME_SANITIZE=1.
"""

from __future__ import annotations

from pathlib import Path

import pytest

import rt_harness as h

MAIN = """\
PROGRAM Main
VAR
    inWord AT %IW512 : INT;
    echoWord AT %QW1 : INT;
    divisor AT %MW10 : INT;
    quotient AT %QW3 : INT;
    keepIn AT %MW20 : INT;
    keepOut AT %MW21 : INT;
    big AT %MD4 : DINT;
    bigger AT %MD5 : DINT;
    hostBit AT %IX50.0 : BOOL;
    echoBit AT %QX0.1 : BOOL;
END_VAR
VAR RETAIN
    keep : INT;
END_VAR
echoWord := inWord + 1;
echoBit := hostBit;
bigger := big + 1;
quotient := 100 / (divisor - 7);
IF keepIn <> 0 THEN
    keep := keepIn;
END_IF;
keepOut := keep;
END_PROGRAM
"""
DIVISION_LINE = 20



@pytest.fixture(scope="module")
def binary(tmp_path_factory) -> Path:
    return h.st_runtime_binary(tmp_path_factory.mktemp("st"), {"Main.st": MAIN, "Config0.st": h.MAIN_EVERY_4MS})


def test_compiled_st_runs_on_the_openplc_map_and_keeps_retain(binary, tmp_path):
    f = tmp_path / "plc.retain"
    with h.Runtime(binary, "--no-rt", "--retain", str(f)) as rt, h.Client(rt.port) as c:
        c.write_register(512, 41)                                # %QW512 -> %IW512 (sim loop-back)
        c.write_coil(400, True)                                  # %QX50.0 -> %IX50.0
        c.write_registers(2048 + 8, [0x0000, 0xFFFF])            # %MD4 = 65535
        c.write_register(1024 + 10, 9)                           # divisor - 7 = 2
        c.write_register(1024 + 20, 1234)
        h.wait_until(lambda: c.read_holding(1) == [42], 2, "echoWord := inWord + 1")
        h.wait_until(lambda: c.read_coils(1) == [True], 2, "echoBit := hostBit")
        h.wait_until(lambda: c.read_holding(2048 + 10, 2) == [1, 0], 2, "bigger := big + 1, high word first")
        h.wait_until(lambda: c.read_holding(3) == [50], 2, "quotient := 100 / 2")
        h.wait_until(lambda: c.read_holding(1024 + 21) == [1234], 2, "keepOut := keep")
    with h.Runtime(binary, "--no-rt", "--retain", str(f)) as rt, h.Client(rt.port) as c:
        rt.wait_for(r"retain: restored 1 of 1 values")
        h.wait_until(lambda: c.read_holding(1024 + 21) == [1234], 2, "keep restored after the restart")


def test_a_division_by_zero_in_st_stops_the_program_with_its_line(binary):
    with h.Runtime(binary, "--no-rt") as rt, h.Client(rt.port) as c:
        c.write_coil(400, True)
        h.wait_until(lambda: c.read_coils(1) == [True], 2, "echoBit on")
        c.write_register(1024 + 10, 7)
        h.wait_until(lambda: h.read_diag(c)["state"] == h.STATE_FAULTED, 2, "the fault")
        d = h.read_diag(c)
        assert (d["fault_kind"], d["fault_line"]) == (1, DIVISION_LINE)
        assert c.read_coils(1) == [False]
        rt.wait_for(rf"integer division by zero \(kind 1\) in \S+ at \S*Main\.st:{DIVISION_LINE}:\d+")
