"""The soft-PLC as a systemd service: the unit `plc deploy service` writes, a kill -9 and restart that keeps the
tool in the spindle, program upgrades on a running machine (`plc deploy upgrade/rollback`), and `plc run PATHS`
(the runtime's notify protocol and journald priorities: test_runtime_notify.py).

systemd itself does not run here: a shell loop stands in for `Restart=always` (it starts PREFIX/current/run
again whenever the runtime exits, as systemd does with the unit's ExecStart).  Loopback only; every wait is
bounded (SLOW multiplier under the sanitizers).
"""
from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

import rt_harness as h
from plc import retainfile

from atc.host.tags import load_map
from atc.map.run_ranges import retained_registers

REPO = Path(__file__).resolve().parents[2]
TOOL = "CONFIG0.RES0.ATC.TOOLINSPINDLE"


def plc_cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "plc.cli", *args], cwd=REPO / "plc", capture_output=True,
                          text=True, timeout=timeout * h.SLOW)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def deployment(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("deploy") / "atc-plc"
    result = plc_cli("deploy", "service", "--out", str(out), "--prefix", str(out), "--simulated")
    assert result.returncode == 0, result.stderr
    assert f"run configuration {REPO / 'machines' / 'default' / 'runtime.toml'}" in result.stderr
    assert "warning: --simulated: this service runs the simulated plant" in result.stderr
    return out


# ---------------------------------------------------------------------------- the unit

def test_the_simulated_plant_is_deployed_only_when_asked_and_then_says_so(deployment, tmp_path):
    """Issue 26: the default machine's run configuration names no I/O layer. Without --simulated the service runs
    with none (nothing moves, so no change is answered as done) and says so; a configuration naming the simulated
    plant is refused without --simulated, nothing written; with --simulated the unit, its README and the output
    say it is a simulation."""
    out = tmp_path / "none"
    plain = plc_cli("deploy", "service", "--out", str(out), "--prefix", str(out))
    assert plain.returncode == 0, plain.stderr
    assert "names no I/O layer ([io] layer): the service runs with none (nothing moves)" in plain.stderr
    run = (out / "current" / "run").read_text()
    assert "--io none" in run and "--io sim" not in run and "--sim-flag" not in run, run
    assert "SIMULATED" not in (out / "atc-plc.service").read_text()
    assert f"run configuration {REPO / 'machines' / 'default' / 'runtime.toml'}" in plain.stderr

    asked = tmp_path / "sim.toml"
    asked.write_text('[io]\nlayer = "sim"\n')
    out = tmp_path / "refused"
    refused = plc_cli("deploy", "service", "--out", str(out), "--prefix", str(out), "--config", str(asked))
    assert refused.returncode == 2, refused.stderr
    assert 'layer = "sim": the service would run the simulated plant' in refused.stderr
    assert "Traceback" not in refused.stderr and not out.exists(), "nothing written"

    unit = (deployment / "atc-plc.service").read_text()
    assert re.search(r"^Description=.*SIMULATED PLANT, no machine I/O$", unit, re.M), unit
    assert "**This service runs the simulated plant**" in (deployment / "README.md").read_text()
    assert "--io sim" in (deployment / "current" / "run").read_text()

    real = tmp_path / "runtime.toml"
    real.write_text('[io]\nlayer = "none"\n')
    out = tmp_path / "machine"
    ok = plc_cli("deploy", "service", "--out", str(out), "--prefix", str(out), "--config", str(real))
    assert ok.returncode == 0, ok.stderr
    assert "SIMULATED" not in (out / "atc-plc.service").read_text() and "warning" not in ok.stderr
    run = (out / "current" / "run").read_text()
    assert "--io none" in run and "--io sim" not in run, run

    # self-contained: the monitor's socket, token and audit log in the service's own directories, and nothing
    # the service runs or installs names the checkout it was built from
    assert '--monitor "$run/plc.monitor" --monitor-token "$state/monitor.token" --audit "$state/audit.log"' in run
    assert "RuntimeDirectory=atc-plc" in (out / "atc-plc.service").read_text()
    for f in ("current/run", "atc-plc.service", "install.sh", "uninstall.sh", "README.md"):
        assert str(REPO) not in (out / f).read_text(), f"{f} names the checkout {REPO}"


def test_the_unit_asks_for_what_a_machine_needs(deployment):
    unit = (deployment / "atc-plc.service").read_text()
    for line in ("Type=notify", "NotifyAccess=main", f"ExecStart={deployment}/current/run", "Restart=always",
                 "WatchdogSec=3", "StateDirectory=atc-plc", "LimitRTPRIO=51", "LimitMEMLOCK=infinity",
                 "StandardError=journal", "WantedBy=multi-user.target"):
        assert re.search(rf"^{re.escape(line)}$", unit, re.M), line
    run = (deployment / "current" / "run").read_text()
    registers = ",".join(retained_registers(load_map(REPO / "modbus_map" / "map.toml")))
    assert '--retain "$state/plc.retain"' in run and f"--retain-registers {registers}" in run
    layout = (deployment / "current" / "retain-layout.txt").read_text()
    assert f"retain\t{TOOL}\tINT\t%MW0\t2" in layout
    readme = (deployment / "README.md").read_text()
    assert "sudo ./install.sh" in readme and "sudo ./uninstall.sh" in readme


def test_the_unit_passes_systemd_analyze_verify(deployment):
    tool = shutil.which("systemd-analyze")
    if tool is None:
        pytest.skip("systemd-analyze is not installed (Debian package systemd; scripts/setup installs it)")
    result = subprocess.run([tool, "verify", str(deployment / "atc-plc.service")], capture_output=True, text=True,
                            timeout=60)
    print(result.stdout, result.stderr)
    assert result.returncode == 0, result.stderr
    assert "atc-plc.service" not in result.stderr, result.stderr        # no warning about our unit


# ------------------------------------------------------------- crash, restart, upgrade

class Service:
    """PREFIX/current/run started again whenever it exits (systemd's Restart=always), on a free port."""

    def __init__(self, prefix: Path, tmp: Path):
        self.prefix, self.port = prefix, free_port()
        self.state = tmp / "state"
        self.state.mkdir(exist_ok=True)
        self.log = tmp / "service.log"
        self.pidfile = tmp / "runtime.pid"
        loop = (f'while :; do "{prefix}/current/run" --port {self.port} --no-rt & echo $! > "{self.pidfile}"; '
                'wait $! || sleep 0.2; done')
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen(["sh", "-c", loop], stdout=log, stderr=subprocess.STDOUT,
                                         env={**os.environ, "STATE_DIRECTORY": str(self.state)},
                                         start_new_session=True)
        self.wait_running(0)

    def text(self) -> str:
        return self.log.read_text(errors="replace")

    def wait_running(self, offset: int, timeout: float = 30) -> None:
        """Wait for a first scan logged after byte `offset` of the log."""
        h.wait_until(lambda: "first scan done" in self.text()[offset:], timeout, "the runtime's first scan")

    def pid(self) -> int:
        return int(self.pidfile.read_text())

    def host(self, *words: str) -> str:
        result = plc_cli("host", "--port", str(self.port), *words, timeout=90)
        assert result.returncode == 0, f"{result.stdout}\n{result.stderr}\n{self.text()[-3000:]}"
        return result.stdout

    def saved_tool(self) -> int | None:
        try:
            return retainfile.read(self.state / "plc.retain").active()[TOOL].number()
        except (retainfile.RetainFileError, KeyError):
            return None

    def stop(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)      # the loop and the runtime it started
            try:
                self.proc.wait(15 * h.SLOW)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(5)


@pytest.fixture
def service(deployment, tmp_path):
    s = Service(deployment, tmp_path)
    yield s
    s.stop()


def test_kill_9_restarts_the_runtime_and_the_tool_stays_in_the_spindle(service):
    assert service.host("clear", "T5 M6").splitlines()[-1] == "tool 5 in spindle"
    h.wait_until(lambda: service.saved_tool() == 5, 3, "the tool saved")
    offset = len(service.text())
    old = service.pid()
    os.kill(old, signal.SIGKILL)
    service.wait_running(offset)
    assert service.pid() != old
    assert re.search(r"retain: restored (\d+) of \1 values", service.text()[offset:]), service.text()[offset:]
    out = service.host("status")
    assert ": tool 5 in spindle" in out.splitlines()[0], out
    assert service.host("T2 M6").splitlines()[-1] == "tool 2 in spindle"


def app_with_tool_change_counter(tmp: Path) -> Path:
    """st_src/ with one RETAIN variable more (an integrator's tool-change counter)."""
    src = tmp / "st_src_v2"
    shutil.copytree(REPO / "st_src", src)
    main = src / "app" / "AtcMain.st"
    text = main.read_text()
    anchor = "(* retained (kept in %MW/%MD across restarts) *)\n"
    assert anchor in text
    main.write_text(text.replace(anchor, "VAR RETAIN\n    ToolChanges : UDINT; (* tool changes since "
                                         "commissioning *)\nEND_VAR\n" + anchor, 1))
    return src


def test_upgrade_keeps_the_tool_refuses_a_loss_and_rolls_back(deployment, service, tmp_path):
    config = str(REPO / "machines" / "default" / "runtime.toml")
    restart = f'kill -TERM "$(cat {service.pidfile})"'
    first = (deployment / "current").resolve()
    assert service.host("clear", "T5 M6").splitlines()[-1] == "tool 5 in spindle"
    h.wait_until(lambda: service.saved_tool() == 5, 3, "the tool saved")

    # the scenario: one RETAIN variable more
    v2 = app_with_tool_change_counter(tmp_path)
    offset = len(service.text())
    up = plc_cli("deploy", "upgrade", "--prefix", str(deployment), "--src", str(v2), "--config", config,
                 "--simulated", "--restart-command", restart, "--log", str(service.log))
    assert up.returncode == 0, up.stderr + service.text()[offset:]
    assert "TOOLCHANGES (UDINT) is new: it starts from its initial value" in up.stderr
    switch = re.search(r"switch-over ([\d.]+) ms \(outputs safe -> first scan of ", up.stdout)
    assert switch, up.stdout
    print(f"switch-over {switch.group(1)} ms")
    service.wait_running(offset)
    second = (deployment / "current").resolve()
    assert second != first and (deployment / "previous").resolve() == first
    log = service.text()[offset:]
    assert "has no saved value" in log and "TOOLCHANGES" in log and "rejected" not in log
    assert ": tool 5 in spindle" in service.host("status").splitlines()[0]

    # back to the sources without the counter: its value would be lost, so no upgrade without --force
    releases = sorted(p.name for p in (deployment / "releases").iterdir())
    refused = plc_cli("deploy", "upgrade", "--prefix", str(deployment), "--src", str(REPO / "st_src"), "--config",
                      config, "--simulated", "--restart-command", "false", "--log", str(service.log))
    assert refused.returncode == 1, refused.stderr
    assert "error: CONFIG0.RES0.ATC.TOOLCHANGES (UDINT) is no longer retained" in refused.stderr
    assert "upgrade refused: 1 retained value(s) would not be restored" in refused.stderr
    assert (deployment / "current").resolve() == second
    assert sorted(p.name for p in (deployment / "releases").iterdir()) == releases

    # rollback: the first release again; the counter's value is kept aside, the tool stays
    offset = len(service.text())
    back = plc_cli("deploy", "rollback", "--prefix", str(deployment), "--restart-command", restart, "--log",
                   str(service.log))
    assert back.returncode == 0, back.stderr
    assert (deployment / "current").resolve() == first and (deployment / "previous").resolve() == second
    service.wait_running(offset)
    assert "TOOLCHANGES (UDINT) is not retained by this program: its saved value is kept aside" in \
        service.text()[offset:]
    assert ": tool 5 in spindle" in service.host("status").splitlines()[0]


# ------------------------------------------------------------------- plc run PATHS

class PlcRun:
    """`plc run PATHS` on a free port with its own retain file; stderr (plc's and the runtime's) in a log."""

    def __init__(self, tmp: Path, paths: list[Path], *options: str):
        self.port, self.log = free_port(), tmp / f"run{len(list(tmp.glob('run*.log')))}.log"
        cmd = [sys.executable, "-m", "plc.cli", "run", *map(str, paths), "--port", str(self.port), "--retain",
               str(tmp / "plc.retain"), "--build-dir", str(REPO / "build" / "runtime"), *options]
        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen(cmd, cwd=REPO / "plc", stdout=log, stderr=subprocess.STDOUT)
        h.wait_until(lambda: "first scan done" in self.text() or self.proc.poll() is not None, 180, "plc run")
        assert self.proc.poll() is None, self.text()

    def text(self) -> str:
        return self.log.read_text(errors="replace")

    def host(self, *words: str) -> str:
        result = plc_cli("host", "--port", str(self.port), *words, timeout=90)
        assert result.returncode == 0, f"{result.stdout}\n{result.stderr}\n{self.text()[-3000:]}"
        return result.stdout

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        self.proc.wait(15 * h.SLOW)


def test_plc_run_with_paths_keeps_the_tool_through_a_program_with_one_retain_variable_more(tmp_path):
    """The issue's scenario: plc run st_src, T5 M6, stop; one RETAIN variable more; plc run again: tool 5."""
    first = PlcRun(tmp_path, [REPO / "st_src"], "--io", "sim")
    try:
        assert f"plc run: using {REPO / 'machines' / 'default' / 'runtime.toml'} (the project's run "\
               "configuration)" in first.text()
        assert first.host("clear", "T5 M6").splitlines()[-1] == "tool 5 in spindle"
    finally:
        first.stop()
    v2 = app_with_tool_change_counter(tmp_path)
    # sources outside the project get neither its run configuration nor its application's simulation flag: the
    # simulated plant is asked for by name
    second = PlcRun(tmp_path, [v2], "--io", "sim", "--sim-flag", "%IX49.7")
    try:
        log = second.text()
        assert "plc run: no run configuration (the sources are outside the project)" in log
        assert "io sim: %IX49.7 held TRUE (--sim-flag)" in log
        m = re.search(r"retain: restored (\d+) of (\d+) values", log)
        assert "rejected" not in log and m and int(m.group(2)) == int(m.group(1)) + 1, log   # all but the new one
        assert "TOOLCHANGES (UDINT) has no saved value: it starts from its initial value" in log
        assert ": tool 5 in spindle" in second.host("status").splitlines()[0]
    finally:
        second.stop()
