"""Issue 27 point 4: a host takes over from one that died. `plc host` is killed (SIGKILL) during a change at a
random moment, 20 times; each time a new `plc host "T<n> M6"` either completes, or names what the PLC needs (a
fault to clear, the changer to home, the tool to confirm) and completes after the host did it. No change is ever
reported done that the simulated plant did not do: after every completed change the plant's spindle holds the
tool. The counts of each path are printed (pytest -s). Every wait is bounded generously."""
from __future__ import annotations

import random
import re
import signal
import subprocess
import sys
import time

import pytest

from test_host_system import REPO, Plc

KILLS = 20


@pytest.fixture(scope="module")
def plc(tmp_path_factory):
    p = Plc(tmp_path_factory.mktemp("takeover"))
    p.start()
    yield p
    p.stop()


def spindle(plc: Plc) -> tuple[int, int]:
    client, tags = plc.tags()
    with client:
        s = tags.read("ToolInSpindle", "SimSpindleTool")
    return int(s["ToolInSpindle"]), int(s["SimSpindleTool"])


def recover(plc: Plc, out: str) -> list[str]:
    """What the host's refusal names, done as the operator would: clear, home, confirm the tool the plant holds."""
    steps = []
    if "toolchanger error" in out or "faulted" in out:
        steps.append("clear")
    result = plc.host(*steps, "status") if steps else plc.host("status")
    text = result.stdout
    recovery = re.search(r"recovery[^\n]*", text, re.I)
    if recovery and "home" in recovery.group(0).lower():
        steps.append("home")
        plc.host("home")
        text = plc.host("status").stdout
        recovery = re.search(r"recovery[^\n]*", text, re.I)
    if recovery and "confirm" in recovery.group(0).lower():
        _, held = spindle(plc)
        steps.append(f"confirm {held}")
        plc.host("confirm", str(held))
    return steps


def test_a_new_host_completes_after_one_killed_mid_change(plc):
    rng = random.Random(27)
    counts = {"completed at once": 0, "completed after recovery": 0}
    seen_steps: dict[str, int] = {}
    for trial in range(KILLS):
        tool = 1 + (trial % 6)
        tool = tool % 6 + 1 if tool == spindle(plc)[0] else tool
        victim = subprocess.Popen([sys.executable, "-m", "plc.cli", "host", "--port", str(plc.port), f"T{tool} M6"],
                                  cwd=REPO / "plc", stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        time.sleep(rng.uniform(0.3, 4.5))             # a change takes 2.5..5.5 s: anywhere in it, or after
        victim.send_signal(signal.SIGKILL)
        victim.wait(10)
        target = (spindle(plc)[0] % 6) + 1
        first = plc.host(f"T{target} M6", timeout=180)
        out = first.stdout + first.stderr
        if first.returncode == 0:
            counts["completed at once"] += 1
        else:
            steps = recover(plc, out)
            for step in steps:
                seen_steps[step.split()[0]] = seen_steps.get(step.split()[0], 0) + 1
            again = plc.host(f"T{target} M6", timeout=180)
            assert again.returncode == 0, f"trial {trial}: after {steps}:\n{out}\n{again.stdout}{again.stderr}"
            out += again.stdout
            counts["completed after recovery"] += 1
        assert f"tool {target} in spindle" in out.splitlines()[-1] or out.rstrip().endswith(
            f"tool {target} in spindle"), out
        assert spindle(plc) == (target, target), f"trial {trial}: PLC and plant disagree: {spindle(plc)}\n{out}"
        assert "Traceback" not in out
    print(f"\n{KILLS} kills: {counts}; recovery steps taken: {seen_steps}")
    assert sum(counts.values()) == KILLS
