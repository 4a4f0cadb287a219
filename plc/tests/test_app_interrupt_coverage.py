"""The interrupted-change scan tests (iec_tests/app/TEST_AbortAt*, TEST_EStopAt*) cover every step of the default
Put Tool and Get Tool sequences, and nothing beyond: one test per step and kind, each calling FB_InterruptAtStep
with its own step.  Adding a step to put.seq or get.seq without its tests fails here."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
APP_TESTS = REPO / "iec_tests" / "app"


def step_count(seq: Path) -> int:
    """Steps of a .seq file: every line that is not empty or a whole-line comment ('/')."""
    return sum(1 for line in seq.read_text(encoding="utf-8").splitlines()
               if line.strip() and not line.strip().startswith("/"))


@pytest.mark.parametrize("kind", ["Abort", "EStop"])
@pytest.mark.parametrize("phase,seq", [("Put", "put.seq"), ("Get", "get.seq")])
def test_every_step_has_its_interrupt_test(kind, phase, seq):
    steps = step_count(REPO / "configs" / "sequences" / seq)
    found = {}
    for path in APP_TESTS.glob(f"TEST_{kind}At{phase}Step*.st"):
        text = path.read_text(encoding="utf-8")
        m = re.search(r"AtStep := (\d+), PutPhase := (TRUE|FALSE), Kind := (\d)", text)
        assert m, f"{path.name}: no FB_InterruptAtStep call"
        assert m.group(2) == ("TRUE" if phase == "Put" else "FALSE"), path.name
        assert int(m.group(3)) == (0 if kind == "Abort" else 1), path.name
        assert path.stem.endswith(f"Step{int(m.group(1)):02d}"), f"{path.name} runs step {m.group(1)}"
        found[int(m.group(1))] = path.name
    assert sorted(found) == list(range(1, steps + 1)), f"{seq} has {steps} steps; tests for {sorted(found)}"
