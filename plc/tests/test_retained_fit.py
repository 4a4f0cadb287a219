"""Issue 27 point 2: retained data meet the machine they restart on. The retain file of one machine is given to a
`plc run` of a machine with another pocket count (as when an integrator changes `pockets` or deploys another
machine to the same runtime); each case end to end through `plc run` restarts and `plc host`:

- tool 10 in the spindle of a 10-pocket machine, restart on the 6-pocket default: the log names the pockets
  dropped and the tool without a pocket; every change is refused (-108, with what to do); confirming tool 10 is
  refused; the documented recovery (take it out, `plc host confirm 0`) leads to a completed `T3 M6`; no
  `plc monitor write` anywhere;
- 6 -> 10 pockets: pockets 7..10 start full (pocket n holds tool n): the pocket table, the page's data and the
  plant agree (`T7 M6` then `T9 M6` bring the plant's tools 7 and 9).
Every wait is bounded generously."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
from atc.host.tags import Tags, load_map
from machine_project import REPO, copy_project, plc
from plc.modbus import ModbusClient
from test_host_system import free_port

try:
    from runtime_fixtures.rt_harness import SLOW
except ImportError:
    SLOW = 1.0


def wait_for(log, text: str, timeout: float = 20.0) -> None:
    """Until the log (a text getter) holds `text`; bounded."""
    deadline = time.monotonic() + timeout * SLOW
    while text not in log():
        assert time.monotonic() < deadline, f"no {text!r} in the log:\n{log()[-3000:]}"
        time.sleep(0.1)


@pytest.fixture(scope="module")
def project(tmp_path_factory) -> Path:
    root = copy_project(tmp_path_factory.mktemp("fit") / "project")
    text = (REPO / "machines" / "default" / "machine.toml").read_text()
    text, n = re.subn(r"(?m)^pockets = 6\b", "pockets = 10", text)
    assert n == 1, "the default machine's pockets line"
    (root / "machines" / "ten").mkdir()
    (root / "machines" / "ten" / "machine.toml").write_text(text)
    return root


def map_of(project: Path, machine: str) -> Path:
    base = project if machine == "default" else project / "build" / "machines" / machine
    return base / "modbus_map" / "map.toml"


@contextmanager
def running(project: Path, machine: str, retain: Path, log: Path):
    """`plc run --machine MACHINE --io sim` on a free port with this retain file; yields (port, log text getter);
    stopped with SIGTERM (the retain file is written at the stop)."""
    port = free_port()
    with open(log, "wb") as out:
        proc = subprocess.Popen([sys.executable, "-m", "plc.cli", "run", "--machine", machine, "--io", "sim",
                                 "--port", str(port), "--retain", str(retain)], cwd=project, stdout=out,
                                stderr=subprocess.STDOUT, env={**os.environ, "PYTHONPATH": str(REPO / "plc" / "src")})

    def text() -> str:
        return log.read_text(errors="replace")

    try:
        deadline = time.monotonic() + 300 * SLOW
        while f"listening on 127.0.0.1:{port}" not in text():
            assert proc.poll() is None, f"plc run exited {proc.returncode}:\n{text()[-3000:]}"
            assert time.monotonic() < deadline, f"plc run did not listen:\n{text()[-3000:]}"
            time.sleep(0.1)
        yield port, text
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            assert proc.wait(30 * SLOW) == 0, f"plc run did not stop cleanly:\n{text()[-3000:]}"
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
            raise


def host(project: Path, machine: str, port: int, *commands: str) -> tuple[int, str]:
    result = plc("host", "--machine", machine, "--port", str(port), *commands, cwd=project, timeout=300 * SLOW)
    return result.returncode, result.stdout + result.stderr


def read(project: Path, machine: str, port: int, *names: str) -> dict:
    client = ModbusClient("127.0.0.1", port)
    client.connect()
    try:
        return Tags(load_map(map_of(project, machine)), client).read(*names)
    finally:
        client.close()


def test_a_spindle_tool_the_machine_has_no_pocket_for_is_confirmed_out(project, tmp_path):
    retain = tmp_path / "plc.retain"
    with running(project, "ten", retain, tmp_path / "ten.log") as (port, _log):
        code, out = host(project, "ten", port, "T10 M6")
        assert code == 0 and "M6: tool 10 in spindle" in out, out
    with running(project, "default", retain, tmp_path / "six.log") as (port, log):
        wait_for(log, "tool 10 in the spindle has no pocket")
        assert re.search(r"saved on a machine with 10 pockets; this one has 6", log()), log()
        assert re.search(r"pockets 7\.\.9 are not on this machine: what they held \(T7, T8, T9\) is dropped",
                         log()), log()
        state = read(project, "default", port, "Recovery", "UncertainTool", "ToolInSpindle", "PocketTool7",
                     "SimSpindleTool", "RestartFit")
        assert state == {"Recovery": 2, "UncertainTool": 10, "ToolInSpindle": -1, "PocketTool7": 0,
                         "SimSpindleTool": 0, "RestartFit": 1 + 2 + 8}, state
        for word in ("T0 M6", "T3 M6"):                   # nothing gets past the confirmation, T0 included
            code, out = host(project, "default", port, word)
            assert code != 0 and "toolchanger error -108" in out, out
            assert "tool 10 has no pocket on this machine: take it out of the spindle by hand" in out, out
            code, out = host(project, "default", port, "clear")
            assert code == 0 and "clear: no fault" in out, out
        code, out = host(project, "default", port, "confirm 10")
        assert code != 0 and "has no pocket on this machine" in out, out
        assert read(project, "default", port, "Recovery")["Recovery"] == 2
        code, out = host(project, "default", port, "confirm 0", "T3 M6")
        assert code == 0, out
        assert "confirm: tool 0 in the spindle, tool 10 taken out (no pocket here)" in out, out
        assert "M6: tool 3 in spindle" in out, out
        state = read(project, "default", port, "ToolInSpindle", "SimSpindleTool", "Recovery", "FaultReason")
        assert state == {"ToolInSpindle": 3, "SimSpindleTool": 3, "Recovery": 0, "FaultReason": 0}, state
    # the fitted data are what is saved now: the next start takes them as they are
    with running(project, "default", retain, tmp_path / "again.log") as (port, log):
        state = read(project, "default", port, "ToolInSpindle", "RestartFit", "PocketCount", "Recovery")
        assert state == {"ToolInSpindle": 3, "RestartFit": 0, "PocketCount": 6, "Recovery": 0}, state
        assert "retained data:" not in log(), log()


def test_new_pockets_start_full_and_the_plant_agrees(project, tmp_path):
    retain = tmp_path / "plc.retain"
    with running(project, "default", retain, tmp_path / "six.log") as (port, _log):
        code, out = host(project, "default", port, "T3 M6")
        assert code == 0 and "M6: tool 3 in spindle" in out, out
    with running(project, "ten", retain, tmp_path / "ten.log") as (port, log):
        wait_for(log, "start as on a first start")
        assert "saved on a machine with 6 pockets; this one has 10" in log(), log()
        names = [f"PocketTool{n}" for n in range(1, 11)]
        table = read(project, "ten", port, *names, "ToolInSpindle", "RestartFit", "Recovery")
        assert [table[n] for n in names] == [1, 2, 0, 4, 5, 6, 7, 8, 9, 10], table
        assert (table["ToolInSpindle"], table["RestartFit"], table["Recovery"]) == (3, 1 + 4, 0), table
        page = page_pockets(project, port)
        assert page == {n: (n if n != 3 else 0) for n in range(1, 11)}, page
        code, out = host(project, "ten", port, "T7 M6", "T9 M6")
        assert code == 0 and "M6: tool 9 in spindle" in out, out
        state = read(project, "ten", port, "ToolInSpindle", "SimSpindleTool", "PocketTool7", "PocketTool3")
        assert state == {"ToolInSpindle": 9, "SimSpindleTool": 9, "PocketTool7": 7, "PocketTool3": 3}, state


def page_pockets(project: Path, port: int) -> dict[int, int]:
    """The pocket table as the page draws it: `plc hmi --machine ten`'s pocket count (/api/info) and the
    PocketTool values of its live state (/ws)."""
    import asyncio

    import aiohttp
    hmi_port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "plc.cli", "hmi", "--machine", "ten", "--plc-port", str(port),
                             "--port", str(hmi_port), "--no-monitor"], cwd=project, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, env={**os.environ, "PYTHONPATH": str(REPO / "plc" / "src")})

    async def fetch() -> dict[int, int]:
        base = f"http://127.0.0.1:{hmi_port}"
        deadline = time.monotonic() + 60 * SLOW
        async with aiohttp.ClientSession() as session:
            while True:
                try:
                    async with session.get(base + "/api/info") as r:
                        pockets = (await r.json())["pockets"]
                    break
                except aiohttp.ClientError:
                    assert proc.poll() is None, proc.stdout.read().decode(errors="replace")
                    assert time.monotonic() < deadline, "the page did not start"
                    await asyncio.sleep(0.2)
            async with session.ws_connect(base + "/ws") as ws:
                while time.monotonic() < deadline:
                    msg = json.loads((await ws.receive(timeout=30 * SLOW)).data)
                    values = msg.get("values") or {}
                    if msg.get("t") == "state" and f"PocketTool{pockets}" in values:
                        return {n: int(values[f"PocketTool{n}"]) for n in range(1, pockets + 1)}
        raise AssertionError("the page's state did not come")

    try:
        return asyncio.run(fetch())
    finally:
        proc.terminate()
        proc.wait(10)
