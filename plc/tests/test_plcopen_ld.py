"""LD and FBD bodies from PLCopen XML: one scan test per element kind and modifier.

Each test draws a function block `Uut` with plcopen_build (the shape OpenPLC Editor and Beremiz
write), translates it with the XML front end, compiles it with a driver PROGRAM that feeds one input
row per scan, runs it under the sanitizers and asserts the outputs scan by scan.
"""
from __future__ import annotations

import pytest

from harness import run_st
from plc.diagnostics import Diagnostics
from plc.driver import compile_sources
from plc.plcopen import translate
from plcopen_build import Body, pou, project

KINDS_COVERED: set[str] = set()


def st_literal(v) -> str:
    if isinstance(v, bool):
        return "TRUE" if v else "FALSE"
    return str(v)


def st_type(v) -> str:
    return "BOOL" if isinstance(v, bool) else "INT"


def translated(xml: str) -> str:
    diags = Diagnostics()
    tr = translate("uut.xml", xml.encode(), diags)
    assert tr is not None and not diags.has_errors(), "\n".join(d.render() for d in diags.items)
    return tr.text


def scan(body: Body, inputs: dict[str, list], outputs, locals_=(), extra_pous=()) -> tuple[dict, str]:
    """Run Uut for as many scans as the input rows; the outputs as one list per name."""
    outs = [(o, "BOOL") if isinstance(o, str) else o for o in outputs]
    n = len(next(iter(inputs.values())))
    xml = project([pou("Uut", "functionBlock", body, inputs=[(k, st_type(v[0])) for k, v in inputs.items()],
                       outputs=outs, locals_=locals_), *extra_pous])
    st = translated(xml)
    decl = "\n".join(f"    i_{k} : ARRAY[1..{n}] OF {st_type(v[0])} := [{', '.join(map(st_literal, v))}];"
                     for k, v in inputs.items())
    decl += "\n" + "\n".join(f"    o_{o} : {t};" for o, t in outs)
    args = ", ".join(f"{k} := i_{k}[k]" for k in inputs)
    copy = "\n".join(f"o_{o} := dut.{o};" for o, _t in outs)
    driver = f"""
PROGRAM Main
VAR
    dut : Uut;
    k : INT;
{decl}
END_VAR
k := k + 1;
dut({args});
{copy}
END_PROGRAM
"""
    run = run_st(st + driver, scans=n)
    return {o: run.series(f"Main.o_{o}") for o, _t in outs}, st


# ------------------------------------------------------------------------- contacts --
def test_series_contacts_normal_and_negated_and():
    b = Body().left_rail(1).contact(2, "a", 1).contact(3, "b", 2, x=150, negated=True).coil(4, "q", 3) \
        .right_rail(5, [4])
    out, _ = scan(b, {"a": [False, True, True, False], "b": [False, False, True, True]}, ["q"])
    assert out["q"] == [False, True, False, False]
    KINDS_COVERED.update({"leftPowerRail", "rightPowerRail", "contact", "contact negated", "coil"})


def test_parallel_contacts_are_a_wired_or():
    b = Body().left_rail(1).contact(2, "a", 1).contact(3, "b", 1, y=40).coil(4, "q", [2, 3]).right_rail(5, [4])
    out, st = scan(b, {"a": [False, True, False, True], "b": [False, False, True, True]}, ["q"])
    assert out["q"] == [False, True, True, True]
    assert "a OR b" in st
    KINDS_COVERED.add("wired OR")


def test_rising_and_falling_contacts():
    b = Body().left_rail(1, points=2).contact(2, "a", 1, edge="rising").coil(3, "up", 2) \
        .contact(4, "a", 1, y=40, edge="falling").coil(5, "down", 4, y=40).right_rail(6, [3, 5])
    a = [True, True, False, False, True, False]
    out, st = scan(b, {"a": a}, ["up", "down"])
    assert out["up"] == [True, False, False, False, True, False]
    assert out["down"] == [False, False, True, False, False, True]
    assert "rise2(CLK := a);" in st and "fall4(CLK := a);" in st
    KINDS_COVERED.update({"contact rising", "contact falling"})


def test_edge_contact_behind_a_contact_samples_the_variable_every_scan():
    # the edge is sensed whatever the power flow on the left (IEC 61131-3 transition-sensing contact)
    b = Body().left_rail(1).contact(2, "enable", 1).contact(3, "a", 2, x=150, edge="rising").coil(4, "q", 3) \
        .right_rail(5, [4])
    out, _ = scan(b, {"enable": [False, True, True], "a": [True, True, True]}, ["q"])
    assert out["q"] == [False, False, False]


# ---------------------------------------------------------------------------- coils --
def test_negated_coil():
    b = Body().left_rail(1).contact(2, "a", 1).coil(3, "q", 2, negated=True).right_rail(4, [3])
    out, _ = scan(b, {"a": [False, True]}, ["q"])
    assert out["q"] == [True, False]
    KINDS_COVERED.add("coil negated")


def test_set_and_reset_coils_latch():
    b = Body().left_rail(1, points=2).contact(2, "s", 1).coil(3, "q", 2, storage="set") \
        .contact(4, "r", 1, y=40).coil(5, "q", 4, y=40, storage="reset").right_rail(6, [3, 5])
    out, _ = scan(b, {"s": [False, True, False, False, True], "r": [False, False, False, True, False]}, ["q"])
    assert out["q"] == [False, True, True, False, True]
    KINDS_COVERED.update({"coil set", "coil reset"})


def test_rising_and_falling_coils_pulse_one_scan():
    b = Body().left_rail(1, points=2).contact(2, "a", 1).coil(3, "up", 2, edge="rising") \
        .contact(4, "a", 1, y=40).coil(5, "down", 4, y=40, edge="falling").right_rail(6, [3, 5])
    out, _ = scan(b, {"a": [False, True, True, False, False]}, ["up", "down"])
    assert out["up"] == [False, True, False, False, False]
    assert out["down"] == [False, False, False, True, False]
    KINDS_COVERED.update({"coil rising", "coil falling"})


def test_serial_coil_chain_passes_the_flow_unchanged_issue_836():
    # FirstScan -> S Output1 -> R FirstScan -> S Output2: IEC power flow sets Output2 too
    b = Body().left_rail(1).contact(2, "firstScan", 1).coil(3, "output1", 2, storage="set") \
        .coil(4, "firstScan", 3, x=400, storage="reset").coil(5, "output2", 4, x=500, storage="set") \
        .right_rail(6, [5])
    xml_locals = [("firstScan", "BOOL", "TRUE")]
    out, st = scan(b, {"dummy": [False, False]}, ["output1", "output2"], locals_=xml_locals)
    assert out["output1"] == [True, True]
    assert out["output2"] == [True, True], st
    KINDS_COVERED.add("serial coils")


def test_parallel_coils_see_the_same_flow():
    # two coils in parallel behind one contact; the first resets the contact's variable
    b = Body().left_rail(1).contact(2, "firstScan", 1).coil(3, "firstScan", 2, storage="reset") \
        .coil(4, "output2", 2, y=40, storage="set").right_rail(5, [3, 4])
    out, _ = scan(b, {"dummy": [False, False]}, ["output2"], locals_=[("firstScan", "BOOL", "TRUE")])
    assert out["output2"] == [True, True]
    KINDS_COVERED.add("parallel coils")


def test_contact_after_a_coil_on_the_same_path_reads_the_new_value():
    # a -> (S) x -> | x | -> ( y ): left to right, y sees x set in the same scan
    b = Body().left_rail(1).contact(2, "a", 1).coil(3, "x", 2, storage="set") \
        .contact(4, "x", 3, x=400).coil(5, "y", 4, x=500).right_rail(6, [5])
    out, _ = scan(b, {"a": [False, True, False]}, ["x", "y"])
    assert out["x"] == [False, True, True]
    assert out["y"] == [False, True, False]


def test_negated_set_coil_is_rejected_with_its_local_id():
    b = Body().left_rail(1).contact(2, "a", 1).coil(3, "q", 2, negated=True, storage="set").right_rail(4, [3])
    xml = project([pou("Uut", "functionBlock", b, inputs=[("a", "BOOL")], outputs=[("q", "BOOL")])])
    diags = Diagnostics()
    assert translate("bad.xml", xml.encode(), diags) is None
    msg = diags.errors[0].render()
    assert "localId 3" in msg and "negated set coil" in msg and "in Uut" in msg


# --------------------------------------------------------------------------- blocks --
def test_function_block_in_a_rung_with_constant_input():
    b = Body().left_rail(1).contact(2, "start", 1).in_var(3, "T#8ms", y=60) \
        .block(4, "TON", {"IN": 2, "PT": 3}, ["Q", "ET"], instance="delay").coil(5, "q", (4, "Q")) \
        .right_rail(6, [5])
    out, _ = scan(b, {"start": [True] * 5}, ["q"], locals_=[("delay", "TON")])
    # 4 ms scans: Q once 8 ms have elapsed (scan 3, like MATIEC's TON)
    assert out["q"] == [False, False, True, True, True]
    KINDS_COVERED.update({"block FB", "inVariable constant"})


def test_en_eno_chain_of_functions():
    # flow -> ADD(EN) -> ENO -> MUL(EN) -> ENO -> coil ; results into output variables
    b = Body().left_rail(1).contact(2, "go", 1).in_var(3, "n", y=60).in_var(4, "INT#1", y=90) \
        .block(5, "ADD", {"EN": 2, "IN1": 3, "IN2": 4}, ["ENO", "OUT"]) \
        .in_var(6, "INT#3", y=120) \
        .block(7, "MUL", {"EN": (5, "ENO"), "IN1": (5, "OUT"), "IN2": 6}, ["ENO", "OUT"], x=400) \
        .coil(8, "done", (7, "ENO"), x=600).out_var(9, "r", (7, "OUT"), x=600, y=60).right_rail(10, [8])
    out, st = scan(b, {"go": [False, True, False], "n": [1, 4, 9]}, ["done", ("r", "INT")])
    assert out["done"] == [False, True, False]
    assert out["r"][1] == 15
    assert "EN := go" in st and "ENO => eno5" in st
    KINDS_COVERED.update({"block function", "EN", "ENO", "outVariable"})



def test_functions_with_en_and_eno_but_their_out_unread_are_portable(tmp_path):
    """ENO used, OUT wired nowhere: the call still assigns its result (to the block's outN), a bare FUNCTION
    call being no statement in MATIEC; `plc check --target openplc` has nothing to say."""
    b = Body().left_rail(1).contact(2, "go", 1).in_var(3, "n", y=60).in_var(4, "INT#1", y=90) \
        .block(5, "ADD", {"EN": 2, "IN1": 3, "IN2": 4}, ["ENO", "OUT"]) \
        .block(6, "MOVE", {"EN": (5, "ENO"), "IN": 3}, ["ENO", "OUT"], x=300) \
        .coil(7, "done", (6, "ENO"), x=600).right_rail(8, [7])
    out, st = scan(b, {"go": [False, True, True, False], "n": [1, 4, 9, 2]}, ["done"])
    assert out["done"] == [False, True, True, False]
    assert "out5 := ADD(EN := go, IN1 := n, IN2 := INT#1, ENO => eno5);" in st
    assert "out6 := MOVE(EN := eno5, IN := n, ENO => eno6);" in st
    xml = tmp_path / "uut.xml"
    xml.write_text(project([pou("Uut", "functionBlock", b, inputs=[("go", "BOOL"), ("n", "INT")],
                                outputs=[("done", "BOOL")])]))
    res = compile_sources([xml], target="openplc", generate=False)
    assert res.ok and [d.render() for d in res.diags.sorted()] == []

def test_expression_as_block_input():
    b = Body("FBD").in_var(1, "a * 2 + 1").in_var(2, "b", y=40) \
        .block(3, "MAX", {"IN1": 1, "IN2": 2}, ["OUT"]).out_var(4, "m", (3, "OUT"))
    out, _ = scan(b, {"a": [1, 5], "b": [4, 4]}, [("m", "INT")])
    assert out["m"] == [4, 11]
    KINDS_COVERED.add("inVariable expression")


# ---------------------------------------------------------------- jumps and return --
def test_forward_jump_skips_rungs_up_to_its_label():
    b = Body().left_rail(1, points=3).contact(2, "skip", 1).jump(3, "After", 2) \
        .contact(4, "a", 1, y=40).coil(5, "q1", 4, y=40) \
        .label(6, "After", y=80) \
        .contact(7, "a", 1, y=120).coil(8, "q2", 7, y=120).right_rail(9, [5, 8])
    out, st = scan(b, {"skip": [False, True, True], "a": [True, True, False]}, ["q1", "q2"])
    assert out["q1"] == [True, True, True]     # not written while skipped: keeps TRUE
    assert out["q2"] == [True, True, False]
    assert "skipToAfter" in st
    KINDS_COVERED.update({"jump", "label"})


def test_return_ends_the_body():
    b = Body().left_rail(1, points=2).contact(2, "stop", 1).ret(3, 2) \
        .contact(4, "a", 1, y=40).coil(5, "q", 4, y=40).right_rail(6, [5])
    out, _ = scan(b, {"stop": [False, True, False], "a": [True, True, False]}, ["q"])
    assert out["q"] == [True, True, False]
    KINDS_COVERED.add("return")


def test_backward_jump_loops_within_the_scan_until_its_condition_falls():
    # n := 0; Top: n := n + 1 (EN from the rail); n < limit -> jump Top; done := TRUE after the loop
    b = Body().left_rail(1, points=3) \
        .in_var(2, "INT#0", y=0).out_var(3, "n", 2, y=0) \
        .label(4, "Top", y=40) \
        .in_var(5, "n", y=80).in_var(6, "INT#1", y=100) \
        .block(7, "ADD", {"EN": 1, "IN1": 5, "IN2": 6}, ["ENO", "OUT"], y=80) \
        .out_var(8, "n", (7, "OUT"), y=80) \
        .in_var(9, "n", y=140).in_var(10, "limit", y=160) \
        .block(11, "LT", {"IN1": 9, "IN2": 10}, ["OUT"], y=140) \
        .jump(12, "Top", (11, "OUT"), y=140) \
        .contact(13, "go", 1, y=200).coil(14, "done", 13, y=200).right_rail(15, [14], y=200)
    out, st = scan(b, {"limit": [3, 5, 1, 0], "go": [True, True, False, True]}, [("n", "INT"), "done"])
    assert out["n"] == [3, 5, 1, 1]                # at least one pass, then round again while n < limit
    assert out["done"] == [True, True, False, True]
    assert "WHILE segment >= 0 DO" in st and "skipToTop" in st
    KINDS_COVERED.add("jump backward")


def test_a_backward_jump_in_an_fb_keeps_forward_jumps_and_return_working():
    # Top: k := k + 1; k >= 4 -> return; jump Top (unconditionally from the rail)... bounded by the return
    b = Body().left_rail(1, points=3) \
        .label(2, "Top", y=0) \
        .in_var(3, "k", y=40).in_var(4, "INT#1", y=60) \
        .block(5, "ADD", {"EN": 1, "IN1": 3, "IN2": 4}, ["ENO", "OUT"], y=40) \
        .out_var(6, "k", (5, "OUT"), y=40) \
        .in_var(7, "k", y=100).in_var(8, "stopAt", y=120) \
        .block(9, "GE", {"IN1": 7, "IN2": 8}, ["OUT"], y=100) \
        .ret(10, (9, "OUT"), y=100) \
        .jump(11, "Top", 1, y=160)
    out, _ = scan(b, {"stopAt": [4, 6, 0]}, [("k", "INT")], locals_=())
    assert out["k"] == [4, 6, 7]                   # k persists: 0 -> 4, then -> 6, then one pass -> 7


# -------------------------------------------------------------------- rung ordering --
def two_rungs(order_top=None, order_bottom=None) -> Body:
    # top rung reads `mid`, bottom rung writes it
    return Body().left_rail(1, points=2) \
        .contact(2, "mid", 1, y=0, order=order_top).coil(3, "q", 2, y=0, order=order_top) \
        .contact(4, "a", 1, y=40, order=order_bottom).coil(5, "mid", 4, y=40, order=order_bottom) \
        .right_rail(6, [3, 5])


def test_without_execution_order_rungs_run_top_to_bottom_as_drawn():
    # as Beremiz orders them: the top rung reads `mid` before the rung below writes it (one scan later)
    out, _ = scan(two_rungs(), {"a": [True, False, False]}, ["q"], locals_=[("mid", "BOOL")])
    assert out["q"] == [False, True, False]
    KINDS_COVERED.add("rung order as drawn")


def test_execution_order_id_is_honoured():
    out, _ = scan(two_rungs(order_top=2, order_bottom=1), {"a": [True, False, False]}, ["q"],
                  locals_=[("mid", "BOOL")])
    assert out["q"] == [True, False, False]      # the bottom rung runs first: the same scan
    KINDS_COVERED.add("rung order executionOrderId")


def test_the_one_shot_idiom_pulses_for_one_scan():
    # rung 1: a AND NOT aPrev -> pulse; rung 2: a -> aPrev.  Drawn in that order it pulses once per rising
    # edge of a (a data-flow order would run rung 2 first and never pulse)
    b = Body().left_rail(1, points=2).contact(2, "a", 1).contact(3, "aPrev", 2, x=150, negated=True) \
        .coil(4, "pulse", 3).contact(5, "a", 1, y=40).coil(6, "aPrev", 5, y=40).right_rail(7, [4, 6])
    out, _ = scan(b, {"a": [False, True, True, False, True]}, ["pulse"], locals_=[("aPrev", "BOOL")])
    assert out["pulse"] == [False, True, False, False, True]


def test_independent_rungs_run_top_to_bottom_whatever_the_file_order():
    b = Body().left_rail(1, points=2)
    b.contact(4, "a", 1, y=40).coil(5, "q2", 4, y=40)     # written first in the file, drawn below
    b.contact(2, "a", 1, y=0).coil(3, "q1", 2, y=0)
    b.right_rail(6, [3, 5])
    _, st = scan(b, {"a": [True]}, ["q1", "q2"])
    assert st.index("q1 := a") < st.index("q2 := a")


def test_grid_rails_with_many_connection_points():
    # OpenPLC Editor draws one rail pair with a connection point per rung
    b = Body().left_rail(1, points=6)
    for k in range(6):
        b.contact(10 + k, f"i{k}", 1, y=40 * k).coil(20 + k, f"o{k}", 10 + k, y=40 * k)
    b.right_rail(2, [20 + k for k in range(6)])
    ins = {f"i{k}": [k % 2 == 0, k % 3 == 0] for k in range(6)}
    out, st = scan(b, ins, [f"o{k}" for k in range(6)])
    for k in range(6):
        assert out[f"o{k}"] == ins[f"i{k}"]
    assert st.count("(* rung ") == 6
    KINDS_COVERED.add("grid rails")


def test_edge_names_do_not_change_when_another_rung_is_added():
    base = Body().left_rail(1, points=2).contact(7, "a", 1, edge="rising").coil(8, "q", 7)
    more = Body().left_rail(1, points=2).contact(3, "b", 1, y=-40).coil(4, "r", 3, y=-40) \
        .contact(7, "a", 1, edge="rising").coil(8, "q", 7)
    for b in (base, more):
        st = translated(project([pou("Uut", "functionBlock", b, inputs=[("a", "BOOL"), ("b", "BOOL")],
                                     outputs=[("q", "BOOL"), ("r", "BOOL")])]))
        assert "rise7 : R_TRIG" in st


# ---------------------------------------------------------------------------- FBD --
def test_fbd_blocks_connectors_negated_pins():
    b = Body("FBD").in_var(1, "a").in_var(2, "b", y=40) \
        .block(3, "AND", {"IN1": 1, "IN2": 2}, ["OUT"], negated_in=("IN2",)) \
        .connector(4, "c1", (3, "OUT"), x=300).continuation(5, "c1", y=100) \
        .block(6, "OR", {"IN1": 5, "IN2": 2}, ["OUT"], y=100, negated_out=("OUT",)) \
        .out_var(7, "x", (6, "OUT"), y=100)
    out, _ = scan(b, {"a": [False, True, True, False], "b": [False, False, True, True]}, ["x"])
    # x = NOT ((a AND NOT b) OR b)
    assert out["x"] == [True, False, False, False]
    KINDS_COVERED.update({"FBD block", "connector", "continuation", "negated input pin", "negated output pin",
                          "inVariable"})


def test_fbd_feedback_reads_the_previous_scan():
    # ADD's output wired back to its own IN1: a counter
    b = Body("FBD").in_var(1, "INT#1", y=40).block(2, "ADD", {"IN1": (2, "OUT"), "IN2": 1}, ["OUT"]) \
        .out_var(3, "n", (2, "OUT"))
    out, st = scan(b, {"dummy": [False] * 4}, [("n", "INT")])
    assert out["n"] == [1, 2, 3, 4], st
    KINDS_COVERED.add("feedback")


def test_fbd_loop_of_functions_through_a_connector_reads_the_previous_scan():
    # NOT's output back into its own input through connector/continuation 'c': no variable on the loop, so
    # NOT runs as a statement and the continuation reads its output of the previous scan (a toggle)
    b = Body("FBD").block(2, "NOT", {"IN": 4}, ["OUT"]).connector(3, "c", (2, "OUT")).continuation(4, "c", y=60) \
        .out_var(5, "x", (2, "OUT"))
    out, st = scan(b, {"dummy": [False] * 4}, ["x"])
    assert out["x"] == [True, False, True, False], st


def test_a_coil_with_nothing_wired_in_passes_false_on():
    # coil 4 has no input: the wired OR into coil 5 and the NOT block read FALSE from it
    b = Body().left_rail(1).contact(2, "a", 1).coil(4, "r", None, y=40).coil(5, "x", [2, 4]) \
        .block(6, "NOT", {"IN": 4}, ["OUT"], y=80).coil(7, "y", (6, "OUT"), y=80)
    out, st = scan(b, {"a": [False, True]}, ["x", "y", "r"])
    assert out["x"] == [False, True] and out["y"] == [True, True] and out["r"] == [False, False], st


def test_fbd_in_out_variable():
    b = Body("FBD").in_var(1, "a").in_out_var(2, "mem", 1).block(3, "NOT", {"IN": 2}, ["OUT"]) \
        .out_var(4, "x", (3, "OUT"))
    out, _ = scan(b, {"a": [True, False]}, ["x"], locals_=[("mem", "BOOL")])
    assert out["x"] == [False, True]
    KINDS_COVERED.add("inOutVariable")


def test_fbd_edge_on_a_block_input_pin():
    b = Body("FBD").in_var(1, "a").block(2, "MOVE", {"IN": 1}, ["OUT"], edge_in={"IN": "rising"}) \
        .out_var(3, "q", (2, "OUT"))
    out, st = scan(b, {"a": [False, True, True, False, True]}, ["q"])
    assert out["q"] == [False, True, False, False, True]
    assert "rise2In(CLK := a);" in st
    KINDS_COVERED.add("edge on a block input pin")


def test_fbd_negated_input_and_output_variables():
    b = Body("FBD").in_var(1, "a", negated=True).out_var(2, "q", 1, negated=True) \
        .in_var(3, "a", y=40).out_var(4, "r", 3, y=40, negated=True)
    out, _ = scan(b, {"a": [False, True]}, ["q", "r"])
    assert out["q"] == [False, True] and out["r"] == [True, False]
    KINDS_COVERED.update({"inVariable negated", "outVariable negated"})


def test_set_coil_on_a_rising_edge():
    b = Body().left_rail(1, points=2).contact(2, "a", 1).coil(3, "q", 2, storage="set", edge="rising") \
        .contact(4, "r", 1, y=40).coil(5, "q", 4, y=40, storage="reset").right_rail(6, [3, 5])
    # a held high does not set q again after the reset: only its rising edge does
    out, _ = scan(b, {"a": [True, True, True, False, True], "r": [False, False, True, False, False]}, ["q"])
    assert out["q"] == [True, True, False, False, True]
    KINDS_COVERED.add("coil set on an edge")


def test_fbd_execution_order_ids_order_the_blocks():
    # two outVariables in one network, both fed by one block; Beremiz writes executionOrderId on each
    b = Body("FBD").in_var(1, "a", order=0).block(2, "MOVE", {"IN": 1}, ["OUT"], order=1) \
        .out_var(3, "x", (2, "OUT"), order=3).out_var(4, "y", (2, "OUT"), y=40, order=2)
    out, st = scan(b, {"a": [True, False]}, ["x", "y"])
    assert out["x"] == [True, False] and out["y"] == [True, False]
    assert st.index("y :=") < st.index("x :=")


def test_element_kinds_covered_is_reported():
    if len(KINDS_COVERED) < 5:
        pytest.skip("the coverage figure needs the whole file to run")
    # runs last in this file (pytest keeps file order): the figure for the closing note
    print(f"\nLD/FBD element kinds and modifiers covered by scan tests: {len(KINDS_COVERED)}: "
          f"{', '.join(sorted(KINDS_COVERED))}")
    assert len(KINDS_COVERED) >= 40
