"""Issue 27 point 4: an abort from a second host ends the first host's wait at once, in every interleaving. Host A
runs `T<n> M6`; at a random moment (before A connected, while it prepares, at start-change, during the change,
after it) host B runs `abort`. Each time: B's abort is acknowledged; A either completed the change before the
abort (and the plant's spindle holds the tool) or ends on the abort itself ("aborted by another host", or the
fault the abort latched) and never on one of its own timeouts; no change is reported done that the plant did
not do. After each trial the operator's recovery (clear, home, confirm) makes the next trial start clean. The
counts of each outcome are printed (pytest -s). Every wait is bounded generously."""
from __future__ import annotations

import random
import re
import subprocess
import sys

import pytest

from test_host_system import REPO, Plc
from test_host_takeover import recover, spindle

TRIALS = 16


@pytest.fixture(scope="module")
def plc(tmp_path_factory):
    p = Plc(tmp_path_factory.mktemp("abort_race"))
    p.start()
    yield p
    p.stop()


def test_an_abort_from_another_host_ends_the_first_hosts_wait(plc):
    rng = random.Random(2704)
    outcomes: dict[str, int] = {}
    for trial in range(TRIALS):
        before = spindle(plc)[0]
        tool = before % 6 + 1
        first = subprocess.Popen([sys.executable, "-m", "plc.cli", "host", "--port", str(plc.port), f"T{tool} M6"],
                                 cwd=REPO / "plc", stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            out_a, _ = first.communicate(timeout=rng.uniform(0.2, 5.0))   # A finished before the abort came
        except subprocess.TimeoutExpired:
            out_a = None
        second = plc.host("abort", timeout=60)
        if out_a is None:
            out_a, _ = first.communicate(timeout=60)
        out_b = second.stdout + second.stderr
        what = f"trial {trial}: A:\n{out_a}\nB:\n{out_b}"
        assert second.returncode == 0 and "acknowledged by the PLC" in out_b, what
        assert "timeout" not in out_a and "Traceback" not in out_a, what
        if first.returncode == 0:
            outcome = "A completed, then B aborted"
            assert f"M6: tool {tool} in spindle" in out_a, what
            assert spindle(plc) == (tool, tool), f"{what}\nPLC and plant disagree: {spindle(plc)}"
        else:
            ended = re.search(r"aborted by another host|toolchanger error -?\d+|toolchanger fault -?\d+", out_a)
            assert ended, what
            outcome = f"A ended by the abort ({ended.group(0).split(':')[0]})"
            assert f"M6: tool {tool} in spindle" not in out_a, what
            recover(plc, out_a + out_b)
        outcomes[outcome] = outcomes.get(outcome, 0) + 1
        held, plant = spindle(plc)
        assert held in (plant, -1), f"{what}\nthe PLC claims tool {held}, the plant holds {plant}"
        if held != plant:
            recover(plc, "toolchanger error")
            assert spindle(plc)[0] == spindle(plc)[1], what
    print(f"\n{TRIALS} aborts from a second host: {outcomes}")
    assert sum(outcomes.values()) == TRIALS
