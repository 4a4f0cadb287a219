"""Every machine of the project beside the default (machines/NAME/), commissioned end to end in its workspace
(`--machine NAME`): the machine scan tests (iec_tests/machine: a change to every pocket, the shorter way
and the tie, abort and E-stop mid-turn at the Stop row, stuck motor and dead sensor faults) in one compiled program
per machine, then `plc run --io sim` served on a free loopback port and a `T<n> M6` over Modbus with `plc host`.
Every wait is bounded generously (a hang, not speed, fails a test)."""
from __future__ import annotations

import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from machine_project import EXAMPLES, REPO, SCAN_TESTS, plc, project_for

try:
    from runtime_fixtures.rt_harness import SLOW
except ImportError:                 # the multiplier of the runtime harness, 1 when it is not there
    SLOW = 1.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module", params=[n for n in EXAMPLES if n != "default"])
def example(request, tmp_path_factory):
    return request.param, project_for(request.param)


def pockets_of(root: Path, name: str) -> int:
    text = (root / "machines" / name / "machine.toml").read_text()
    return int(re.search(r"(?m)^(?:pockets|positions)\s*=\s*(\d+)", text).group(1))


def test_the_example_checks_clean_and_nothing_drifts(example):
    name, root = example
    for args in (["machine", "check"], ["map", "check"], ["check", "--target", "openplc", "st_src"]):
        result = plc(*args, cwd=root)
        assert result.returncode == 0, f"{name}: plc {' '.join(args)}\n{result.stderr}"
        assert ": warning:" not in result.stderr, f"{name}: plc {' '.join(args)}\n{result.stderr}"


def test_plc_deploy_openplc_bundles_the_example(example):
    name, root = example
    out = root / "deploy" / "atc_openplc.st"
    result = plc("deploy", "openplc", "--out", str(out), cwd=root)
    assert result.returncode == 0, f"{name}:\n{result.stderr}"
    text = out.read_text()
    assert "CONFIGURATION Config0" in text and "FUNCTION_BLOCK FB_MachineConfig" in text
    pockets = pockets_of(root, name)
    assert f"Rotary.pockets := {pockets};" in text


def carousel_only(name: str, root: Path, what: str) -> None:
    """Skip, with the reason printed, a carousel test on a machine without a carousel (kind = "fixed-pockets")."""
    text = (root / "machines" / name / "machine.toml").read_text()
    if re.search(r'(?m)^kind\s*=\s*"fixed-pockets"', text):
        reason = (f"{name}: {what} (iec_tests/machine) drive a carousel; this rack machine has none, its plant "
                  "is tested by iec_tests/sequence/TEST_RackPlantPutsAndGetsAtItsPositions.st and "
                  "test_host_mailbox.py")
        print(f"SKIP {reason}")
        pytest.skip(reason)


def test_the_machine_scan_tests_pass(example):
    name, root = example
    carousel_only(name, root, "the machine scan tests")
    result = plc("test", "-q", *SCAN_TESTS, "--build-dir", str(root / "build" / "plc-test"), cwd=root,
                 timeout=600 * SLOW)
    assert result.returncode == 0, f"{name}:\n{result.stdout}\n{result.stderr}"
    assert re.search(r"\b6 passed, 0 failed", result.stdout), result.stdout


def test_plc_run_with_the_example_completes_an_m6_over_modbus(example):
    name, root = example
    port = free_port()
    log = root / "plc-run.log"
    cmd = [sys.executable, "-m", "plc.cli", "run", "--io", "sim", "--port", str(port), "--retain",
           str(root / "plc.retain"), "--build-dir", str(root / "build" / "runtime")]
    with open(log, "wb") as out:
        proc = subprocess.Popen(cmd, cwd=root, stdout=out, stderr=subprocess.STDOUT,
                                env={**__import__("os").environ, "PYTHONPATH": str(REPO / "plc" / "src")})
    try:
        deadline = time.monotonic() + 300 * SLOW
        while f"listening on 127.0.0.1:{port}" not in log.read_text(errors="replace"):
            assert proc.poll() is None, f"{name}: plc run exited {proc.returncode}:\n{log.read_text()[-3000:]}"
            assert time.monotonic() < deadline, f"{name}: plc run did not listen:\n{log.read_text()[-3000:]}"
            time.sleep(0.1)
        tool = 1 + pockets_of(root, name) // 2
        result = plc("host", "--port", str(port), f"T{tool} M6", cwd=root, timeout=300 * SLOW)
        assert result.returncode == 0, f"{name}: exit {result.returncode}\n{result.stdout}\n{result.stderr}"
        assert result.stdout.splitlines()[-1] == f"tool {tool} in spindle", result.stdout
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
