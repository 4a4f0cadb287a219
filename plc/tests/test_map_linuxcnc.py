"""The generated LinuxCNC files under real HAL: halrun + mb2hal (LinuxCNC 2.9) + atc_iov2.hal against `plc run`
of an echo PLC, with a stand-in for iov2's pins (linuxcnc_fixtures/fake_iov2.py).

Shows what the generated chain promises: the link watch lets iocontrol.0.emc-enable-in up and drops it when
the PLC stops; every prepare is answered; toolchanger-reason and FaultReason reach HAL signed. Whether
tool-prep-number/pocket reach the PLC before their request bit depends on the settle delay (settle_s in
modbus_map/map.toml) covering mb2hal's pace, a timing property: it is measured here and printed, and judged by
scripts/bench-mb2hal-settle (idle and under load), never by this test.

Needs linuxcnc-uspace (scripts/e2e-linuxcnc installs it) and root for private IPC/PID/mount namespaces
(`unshare`), so it never meets another LinuxCNC or halrun on the machine; skipped with the reason otherwise."""
from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from plc.diagnostics import Diagnostics
from atc.map import gen_st
from atc.map.generate import IOV2_HAL, MB2HAL_INI, load_and_check, outputs

REPO = Path(__file__).resolve().parents[2]
FIXTURES = Path(__file__).resolve().parent / "linuxcnc_fixtures"

pytestmark = [
    pytest.mark.skipif(shutil.which("halrun") is None or shutil.which("mb2hal") is None,
                       reason="LinuxCNC 2.9 (linuxcnc-uspace: halrun, mb2hal) is not installed"),
    pytest.mark.skipif(os.geteuid() != 0 or shutil.which("unshare") is None,
                       reason="needs root and unshare for a private HAL namespace"),
]

TEST_HAL = """loadrt threads name1=servo-thread period1=1000000
loadusr -Wn fakeiov2 /usr/bin/python3 fake_iov2.py
net estop-chain-ok iocontrol.0.user-enable-out
source atc_iov2.hal
net atc-fault-reason fakeprobe.fault-reason
start
loadusr -w ./wait_result.sh
"""
WAIT = "#!/bin/sh\ni=0\nwhile [ $i -lt 900 ]; do [ -f result.txt ] && exit 0; sleep 0.1; i=$((i+1)); done\nexit 1\n"


def echo_program(rmap) -> str:
    body = (FIXTURES / "echo_body.st").read_text()
    return ("PROGRAM AtcMain\n" + gen_st.region(rmap) + body + "END_PROGRAM\nCONFIGURATION Config0\n"
            "    RESOURCE Res0 ON PLC\n        TASK MainTask(INTERVAL := T#4ms, PRIORITY := 0);\n"
            "        PROGRAM Atc WITH MainTask : AtcMain;\n    END_RESOURCE\nEND_CONFIGURATION\n")


def run_chain(tmp: Path, hal_text: str, prepares: int) -> list[str]:
    loaded = load_and_check(REPO / "modbus_map" / "map.toml", Diagnostics())
    files = outputs(loaded)
    work = tmp / "hal"
    work.mkdir()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    (work / "atc_iov2.hal").write_text(hal_text)
    (work / "atc_mb2hal.ini").write_text(re.sub(r"(?m)^TCP_PORT=\d+", f"TCP_PORT={port}", files[MB2HAL_INI]))
    (work / "test.hal").write_text(TEST_HAL)
    (work / "wait_result.sh").write_text(WAIT)
    (work / "wait_result.sh").chmod(0o755)
    shutil.copy(FIXTURES / "fake_iov2.py", work)
    os.chmod(work, 0o777)
    src = tmp / "echo"
    src.mkdir()
    (src / "Echo.st").write_text(echo_program(loaded.rmap))
    plc_log = open(tmp / "plc.log", "wb")
    plc = subprocess.Popen([sys.executable, "-m", "plc.cli", "run", str(src), "--config",
                            str(REPO / "machines" / "default" / "runtime.toml"), "--port", str(port), "--retain",
                            str(tmp / "plc.retain"), "--build-dir", str(REPO / "build" / "runtime")],
                           cwd=REPO / "plc", stdout=plc_log, stderr=subprocess.STDOUT)
    hal = None
    try:
        deadline = time.monotonic() + 180
        while f"listening on 127.0.0.1:{port}" not in (tmp / "plc.log").read_text(errors="replace"):
            assert plc.poll() is None and time.monotonic() < deadline, (tmp / "plc.log").read_text()[-2000:]
            time.sleep(0.1)
        inner = ("mount -t tmpfs -o mode=1777 tmpfs /tmp && mkdir /tmp/rtapi && chown 65534 /tmp/rtapi && "
                 "RTAPI_UID=65534 RTAPI_FIFO_PATH=/tmp/rtapi/sock halrun -f test.hal")
        env = dict(os.environ, PREPARES=str(prepares))
        hal = subprocess.Popen(["unshare", "--ipc", "--pid", "--fork", "--mount-proc", "--mount", "--kill-child",
                                "/bin/bash", "-c", inner], cwd=work, env=env, stdout=open(tmp / "halrun.log", "wb"),
                               stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 120
        while not (work / "phase1").exists() and not (work / "result.txt").exists():
            assert hal.poll() is None and time.monotonic() < deadline, (tmp / "halrun.log").read_text()[-2000:]
            time.sleep(0.1)
        plc.send_signal(signal.SIGTERM)
        plc.wait(15)
        hal.wait(60)
    finally:
        for proc in (plc, hal):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait(10)
        plc_log.close()
    result = work / "result.txt"
    assert result.exists(), (tmp / "halrun.log").read_text()[-3000:]
    return result.read_text().splitlines()


@pytest.fixture
def work_dir():
    """Outside /tmp: the namespace mounts its own /tmp (LinuxCNC's lock and socket files)."""
    path = Path(tempfile.mkdtemp(prefix="atc-hal-test-", dir="/var/tmp"))
    yield path
    shutil.rmtree(path, ignore_errors=True)


def test_generated_hal_and_mb2hal_carry_the_handshakes_signs_and_link_watch(work_dir):
    hal_text = outputs(load_and_check(REPO / "modbus_map" / "map.toml", Diagnostics()))[IOV2_HAL]
    lines = run_chain(work_dir, hal_text, prepares=100)
    print("\n".join(lines))
    assert [line for line in lines if not line.startswith(("ok", "measure"))] == []
    assert len(lines) == 8 and [line for line in lines if line.startswith("measure 100 prepares:")]
