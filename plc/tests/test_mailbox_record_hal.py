"""The mailbox record inside LinuxCNC: no interleaving of mb2hal and the servo thread lets the M6 remap combine
fields of two requests (issue 36; docs/linuxcnc.md, "The mailbox record").

A model built from the shipped HAL files, not from a description of them: the functions of the servo thread in
their addf order (atc-sim.hal, the generated atc_iov2.hal, atc-remap.hal), the nets from each mb2hal pin of the
record through the conversions (sum2, lincurve, conv_float_s32) to the motion.analog-in pin the remap reads, and
mb2hal's transaction as atc_mb2hal.ini declares it. mb2hal sets a read's pins one after another in PIN_NAMES order,
from its own thread, so every pin write may fall between any two functions of any servo period. For each field
the remap uses and the record's id (analog-in-10), every placement of the four pin writes (field hi/lo, id hi/lo,
in that order) over three periods is simulated, with each pair of values either changing or equal in the high
word. A value is "new" when every pin it was computed from is new (a mixture of an old and a new half is neither
request's value). The remap reads the id first and the field afterwards, each from a snapshot of motion's inputs:
the design holds when motion never shows the new id before the new field.
"""
from __future__ import annotations

import re
from itertools import combinations_with_replacement
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
LCNC = REPO / "configs" / "linuxcnc"
HAL_FILES = ("atc-sim.hal", "atc_iov2.hal", "atc-remap.hal")
ID_PIN = "motion.analog-in-10"
# what the remap reads (atc_m6.ngc, atc_mbx_serve.ngc): opcode, text, axis mask, X, Y, Z, value
FIELD_PINS = tuple(f"motion.analog-in-{n:02d}" for n in (1, 2, 3, 4, 5, 6, 7))
COMPONENTS = {"sum2": ("in0", "in1"), "lincurve": ("in",), "conv_float_s32": ("in",)}
PERIODS = 3


class Hal:
    """The functions, instances and nets of HAL files, as far as the record's paths need them."""

    def __init__(self, texts: list[str]):
        self.kind: dict[str, str] = {}          # instance -> component
        self.functions: list[str] = []          # addf order (one thread: servo-thread)
        self.net_of: dict[str, str] = {}        # pin -> signal
        self.writer: dict[str, str] = {}        # signal -> output pin
        for text in texts:
            for line in text.splitlines():
                words = line.split("#", 1)[0].split()
                if not words:
                    continue
                if words[0] == "loadrt" and len(words) > 2:
                    names = next((w[6:] for w in words if w.startswith("names=")), "")
                    for name in filter(None, names.split(",")):
                        self.kind[name] = words[1]
                elif words[0] == "addf":
                    self.functions.append(words[1])
                elif words[0] == "unlinkp":
                    self.net_of.pop(words[1], None)
                elif words[0] == "net":
                    signal, pins = words[1], [w for w in words[2:] if w not in ("=>", "<=", "<=>")]
                    for pin in pins:
                        self.net_of[pin] = signal
                        if self._is_output(pin):
                            self.writer[signal] = pin

    def _is_output(self, pin: str) -> bool:
        inst, _, name = pin.rpartition(".")
        if inst in self.kind:
            return name == "out"
        return pin.startswith("mb2hal.") and "words-in" in pin

    def sources(self, pin: str) -> tuple[list[str], list[str]]:
        """(mb2hal pins, instances) the value on an input pin is computed from."""
        signal = self.net_of[pin]
        out = self.writer[signal]
        if out.startswith("mb2hal."):
            return [out], []
        inst = out.rpartition(".")[0]
        leaves, insts = [], [inst]
        for port in COMPONENTS[self.kind[inst]]:
            more, via = self.sources(f"{inst}.{port}")
            leaves += more
            insts += via
        return leaves, insts


def shipped_hal() -> Hal:
    return Hal([(LCNC / name).read_text() for name in HAL_FILES])


def record_pins() -> list[str]:
    """The mb2hal pins of the transaction that holds the record, in the order mb2hal sets them."""
    ini = (LCNC / "atc_mb2hal.ini").read_text()
    for block in ini.split("[TRANSACTION_")[1:]:
        if "MbxArgsId-lo" in block:
            name = re.search(r"^HAL_TX_NAME=(\S+)", block, re.M).group(1)
            pins = re.search(r"^PIN_NAMES=(\S+)", block, re.M).group(1).split(",")
            return [f"mb2hal.{name}.{p}.float" for p in pins]
    raise AssertionError("no transaction of atc_mb2hal.ini reads MbxArgsId")


def first_new_at_motion(hal: Hal, order: list[str], writes: dict[str, int], watched: dict[str, str]) -> dict:
    """Simulate PERIODS + 3 servo periods; writes: mb2hal pin -> gap (before function gap % n of period
    gap // n), pins not in writes are new from the start (an unchanged word). Returns watched name -> the
    first period whose motion sample shows it new (None: never)."""
    new: dict[str, bool] = {}              # mb2hal pin -> set to the new request's word
    value: dict[str, bool] = {}            # instance -> its output is the new request's value

    def input_new(pin: str) -> bool:
        out = hal.writer[hal.net_of[pin]]
        if out.startswith("mb2hal."):
            return new.get(out, out not in writes)
        return value.get(out.rpartition(".")[0], False)

    seen: dict[str, int | None] = {name: None for name in watched}
    n = len(order)
    for period in range(PERIODS + 3):
        for k, fn in enumerate(order):
            for pin, gap in writes.items():
                if gap == period * n + k:
                    new[pin] = True
            if fn == "motion-controller":
                for name, pin in watched.items():
                    if seen[name] is None and input_new(pin):
                        seen[name] = period
            else:
                value[fn] = all(input_new(f"{fn}.{port}") for port in COMPONENTS[hal.kind[fn]])
    return seen


def check_pair(hal: Hal, field: str, writes_in_order: list[str]) -> tuple[int, list[str]]:
    """Every interleaving of the record's pin writes for one field against the id: (count, violations)."""
    field_leaves, field_insts = hal.sources(field)
    id_leaves, id_insts = hal.sources(ID_PIN)
    pins = [p for p in writes_in_order if p in field_leaves + id_leaves]
    order = [f for f in hal.functions if f == "motion-controller" or f in set(field_insts + id_insts)]
    assert "motion-controller" in order, "motion must be a function of the servo thread"
    gaps = PERIODS * len(order)
    count, bad = 0, []
    for unchanged in ([], [p for p in pins if p.endswith("-hi.float")]):
        moving = [p for p in pins if p not in unchanged]
        for placement in combinations_with_replacement(range(gaps), len(moving)):
            count += 1
            writes = dict(zip(moving, placement, strict=True))
            seen = first_new_at_motion(hal, order, writes, {"field": field, "id": ID_PIN})
            assert seen["id"] is not None and seen["field"] is not None, "the simulation ran too short"
            if seen["field"] > seen["id"]:
                bad.append(f"{field}: writes at {writes}: motion shows the new id in period "
                           f"{seen['id']}, the field only in period {seen['field']}")
    return count, bad


def test_the_remap_reads_every_field_from_the_record():
    hal = shipped_hal()
    record = set(record_pins())
    for pin in FIELD_PINS + (ID_PIN,):
        leaves, _ = hal.sources(pin)
        assert leaves and set(leaves) <= record, f"{pin} comes from {leaves}, not from the record's one read"
    assert record_pins()[-2:] == [p for p in record_pins() if "MbxArgsId" in p], "the id is the record's end"


def test_the_remap_reads_the_id_before_the_fields_and_serves_only_a_new_id():
    m6 = (LCNC / "nc_subs" / "atc_m6.ngc").read_text()
    serve = (LCNC / "nc_subs" / "atc_mbx_serve.ngc").read_text()
    code = [line.split(";", 1)[0] for line in m6.splitlines()]
    at_id = next(i for i, line in enumerate(code) if "M66 E10 L0" in line)
    at_call = next(i for i, line in enumerate(code) if "o<atc_mbx_serve> call" in line)
    assert at_id < at_call, "the id must be read before the fields"
    assert not any(re.search(r"M66 E[1-7] ", line) for line in code), "atc_m6 reads no field itself"
    guard = next(line for line in code[at_id:at_call] if "o<new> if" in line)
    assert "#<id> NE #<answered>" in guard and "#<pending>" in guard
    assert "E10" not in serve and re.search(r"M66 E1 L0", serve)


def test_no_interleaving_shows_motion_a_new_id_with_an_old_field():
    hal, writes = shipped_hal(), record_pins()
    total = 0
    for field in FIELD_PINS:
        count, bad = check_pair(hal, field, writes)
        total += count
        assert not bad, f"{len(bad)} of {count} interleavings mix two requests, e.g. {bad[0]}"
    print(f"\n{total} interleavings of mb2hal and the servo thread checked for {len(FIELD_PINS)} fields: 0 mixed")
    assert total > 10000


@pytest.mark.parametrize("variant", ["conversions in address order", "id straight from its pin"])
def test_the_model_finds_the_mixed_request_of_the_designs_that_had_it(variant):
    """The check can fail: with the conversions added in address order (the generator before this fix) or with
    the id taken unconverted from its mb2hal pin (the remap before this fix), motion can show a new id with the
    last request's field; the model must find such an interleaving."""
    text = (LCNC / "atc_iov2.hal").read_text()
    remap = (LCNC / "atc-remap.hal").read_text()
    if variant == "conversions in address order":
        lines = text.splitlines()
        addf = [i for i, line in enumerate(lines) if line.startswith(("addf atc-join-", "addf atc-sign-"))]
        joins = sorted((lines[i] for i in addf if "join" in lines[i]), key=lambda line: "args-id" in line)
        signs = [lines[i] for i in addf if "sign" in lines[i]]
        for i, line in zip(addf, [*signs, *joins], strict=True):
            lines[i] = line
        text = "\n".join(lines)
    else:
        remap = remap.replace("net atc-mbx-args-id => motion.analog-in-10",
                              "net atc-mbx-args-id-raw2 mb2hal.atc-words-in-3.MbxArgsId-lo.float "
                              "=> motion.analog-in-10")
    hal = Hal([(LCNC / "atc-sim.hal").read_text(), text, remap])
    found = sum(len(check_pair(hal, field, record_pins())[1]) for field in FIELD_PINS[3:])
    assert found > 0, "the model did not find the defect it exists to find"
