"""Issue 26: one project, several machines at once. In a copy of the project made a git repository of its own, a
machine is added as the README says (machines/mill-2/ with a description and a run configuration giving its own
port); the default machine and the new one then run at the same time from that one checkout, each completing a
`T<n> M6` through `plc host` on its own port with its own state directory; `plc test` and `plc deploy openplc` of
each succeed; after all of it `git status --porcelain` names only the added machine. Every wait is bounded
generously (a hang, not speed, fails the test)."""
from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from machine_project import REPO, copy_project, plc

try:
    from runtime_fixtures.rt_harness import SLOW
except ImportError:
    SLOW = 1.0

NEW = "mill-2"
GIT_ENV = {"GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@example.invalid", "GIT_COMMITTER_NAME": "t",
           "GIT_COMMITTER_EMAIL": "t@example.invalid"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def git(root: Path, *args: str) -> str:
    result = subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, timeout=120,
                            env={**os.environ, **GIT_ENV})
    assert result.returncode == 0, result.stderr
    return result.stdout


@pytest.fixture(scope="module")
def checkout(tmp_path_factory) -> Path:
    """The copy as a checkout: every file committed, .gitignore as the repository's."""
    root = copy_project(tmp_path_factory.mktemp("side") / "checkout")
    shutil.copytree(REPO / "iec_tests", root / "iec_tests", dirs_exist_ok=True)
    shutil.copy2(REPO / ".gitignore", root / ".gitignore")
    shutil.rmtree(root / ".git")
    git(root, "init", "-q")
    git(root, "add", "-A")
    git(root, "commit", "-q", "-m", "the project")
    assert git(root, "status", "--porcelain") == ""
    return root


class Running:
    def __init__(self, root: Path, log: Path, *args: str):
        self.log = log
        with open(log, "wb") as out:
            self.proc = subprocess.Popen([sys.executable, "-m", "plc.cli", "run", "--io", "sim", *args], cwd=root,
                                         stdout=out, stderr=subprocess.STDOUT,
                                         env={**os.environ, "PYTHONPATH": str(REPO / "plc" / "src")})

    def text(self) -> str:
        return self.log.read_text(errors="replace")

    def wait_listening(self, port: int) -> None:
        deadline = time.monotonic() + 300 * SLOW
        while f"listening on 127.0.0.1:{port}" not in self.text():
            assert self.proc.poll() is None, f"plc run exited {self.proc.returncode}:\n{self.text()[-3000:]}"
            assert time.monotonic() < deadline, f"plc run did not listen on {port}:\n{self.text()[-3000:]}"
            time.sleep(0.1)

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(15 * SLOW)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)


def test_two_machines_run_at_once_and_only_the_added_machine_shows_in_git_status(checkout, tmp_path):
    root = checkout
    # 1. add a machine as the README says: its description from the closest shipped one, its own port
    (root / "machines" / NEW).mkdir()
    shutil.copy2(root / "machines" / "seed-pocket-code" / "machine.toml", root / "machines" / NEW / "machine.toml")
    new_port, default_port = free_port(), free_port()
    (root / "machines" / NEW / "runtime.toml").write_text(f"[modbus]\nbind = \"127.0.0.1\"\nport = {new_port}\n")
    listed = plc("machine", "list", cwd=root)
    assert listed.returncode == 0 and NEW in listed.stdout.split(), listed.stdout + listed.stderr

    # 2. both at once from this checkout: the new one on its run configuration's port, state in var/mill-2/
    new = Running(root, tmp_path / "new.log", "--machine", NEW)
    default = Running(root, tmp_path / "default.log", "--port", str(default_port), "--retain",
                      str(tmp_path / "default.retain"))
    try:
        new.wait_listening(new_port)
        default.wait_listening(default_port)
        assert f"using {root / 'machines' / NEW / 'runtime.toml'}" in new.text(), new.text()[:2000]
        assert f"{root / 'var' / NEW / 'plc.retain'}" in new.text(), new.text()[:2000]
        changed = plc("host", "--machine", NEW, "T4 M6", cwd=root, timeout=300 * SLOW)   # the machine's port
        other = plc("host", "--port", str(default_port), "T3 M6", cwd=root, timeout=300 * SLOW)
        assert changed.returncode == 0, changed.stdout + changed.stderr
        assert changed.stdout.splitlines()[-1] == "tool 4 in spindle", changed.stdout
        assert other.returncode == 0, other.stdout + other.stderr
        assert other.stdout.splitlines()[-1] == "tool 3 in spindle", other.stdout
        status = plc("status", "--machine", NEW, cwd=root)                 # follows the machine's port too
        assert status.returncode == 0 and "RUNNING" in status.stdout, status.stdout + status.stderr
        assert new.proc.poll() is None and default.proc.poll() is None
    finally:
        new.stop()
        default.stop()
    # the new machine is the Logosol pocket+code sample: its program has the code lines, the default's has not
    program = (root / "build" / "machines" / NEW / "st_src" / "app" / "AtcMain.st").read_text()
    assert "CarouselCode1 AT" in program and "CarouselCode1 AT" not in (root / "st_src/app/AtcMain.st").read_text()

    # 3. the machine scan tests and the OpenPLC bundle of each
    for machine in (NEW, "default"):
        tests = plc("test", "-q", "--machine", machine, "iec_tests/machine", "iec_tests/app/FB_AppRig.st",
                    cwd=root, timeout=900 * SLOW)
        assert tests.returncode == 0, f"{machine}:\n{tests.stdout}\n{tests.stderr}"
        assert re.search(r"\b6 passed, 0 failed", tests.stdout), tests.stdout
        bundle = tmp_path / f"{machine}.st"
        deployed = plc("deploy", "openplc", "--machine", machine, "--out", str(bundle), cwd=root, timeout=300)
        assert deployed.returncode == 0, f"{machine}:\n{deployed.stderr}"
        text = bundle.read_text()
        assert "CONFIGURATION Config0" in text
        assert ("Rotary.pockets := 6;" in text) and (("CarouselCode1 AT" in text) == (machine == NEW))

    # 4. a service of the new machine: its own name and port, nothing inside the checkout named
    out = tmp_path / "svc"
    service = plc("deploy", "service", "--machine", NEW, "--out", str(out), "--prefix", str(out), cwd=root,
                  timeout=600)
    assert service.returncode == 0, service.stderr
    unit = out / f"atc-plc-{NEW}.service"
    assert f"127.0.0.1:{new_port}" in unit.read_text() and "SIMULATED" not in unit.read_text()
    run = (out / "current" / "run").read_text()
    assert "--io none" in run and "--sim-flag" not in run, run
    for f in (out / "current" / "run", unit, out / "install.sh", out / "uninstall.sh", out / "README.md"):
        assert str(root) not in f.read_text(), f"{f} names the checkout {root}"

    # 5. nothing of the project was rewritten: only the added machine is new
    status = git(root, "status", "--porcelain", "--untracked-files=all").splitlines()
    assert sorted(status) == [f"?? machines/{NEW}/machine.toml", f"?? machines/{NEW}/runtime.toml"], status
