"""When the runtime stops (SIGTERM, a program fault, a watchdog), every remote I/O device gets its `safe` values:
for the carousel's output lines those must be the Stop row on the wire. An inverted line (an active-low relay)
stops with TRUE, so the default safe value 0 would run the motor. `plc run --io modbus` and `plc deploy` refuse
such a run configuration, naming the coil, the line and the setting."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from atc.runsetup import stop_levels
from plc import runtime

REPO = Path(__file__).resolve().parents[2]
INVERTED = REPO / "machines" / "carousel-24-separate-inverted" / "machine.toml"


def device_config(path: Path, safe: str | None) -> Path:
    """A run configuration with one module whose 8 coils are the map's %QX2.0..%QX2.7 (channels 16..23)."""
    coils = '{ address = 0, count = 8, from = "%QX2.0"' + (f", safe = {safe}" if safe else "") + " }"
    path.write_text('[io]\nlayer = "modbus"\n\n[[io.device]]\nname = "carousel"\ntcp = "127.0.0.1"\nport = 1502\n'
                    f"coils = [{coils}]\n")
    return path


def test_the_stop_levels_are_the_invert_flags_of_the_used_output_lines():
    inverted = stop_levels(INVERTED)
    text = INVERTED.read_text()
    assert inverted and all(level for level, _ in inverted.values())
    assert all("inverted" in why and "invert_" in why for _, why in inverted.values())
    assert set(inverted) <= set(range(800)) and "separate" in text       # +DIR and -DIR, no Output ON
    plain = stop_levels(REPO / "machines" / "default" / "machine.toml")
    assert plain == {16: (False, plain[16][1]), 20: (False, plain[20][1])}
    assert "CarouselMotorOn is not inverted (invert_on = false" in plain[16][1]


def test_a_device_stopping_an_inverted_line_at_false_is_named(tmp_path):
    levels = {16: (True, "CarouselMotorOn is inverted (invert_on = true in machine.toml)")}
    wrong = runtime.stop_level_problems(runtime.load_config(device_config(tmp_path / "a.toml", None)), levels)
    assert wrong == ["  [[io.device]] 1 (carousel) coils 1: %QX2.0 (device coil 0) is false when stopped, but "
                     "CarouselMotorOn is inverted (invert_on = true in machine.toml): its stop level is true; set its "
                     "`safe` value"]
    right = runtime.load_config(device_config(tmp_path / "b.toml", "[true, false, false, false, false, false, false, "
                                                                    "false]"))
    assert runtime.stop_level_problems(right, levels) == []


def test_plc_run_refuses_a_module_that_would_run_the_motor_when_stopped(tmp_path):
    """The default machine's Output ON (channel 16) is not inverted: a module that holds it TRUE when stopped is
    refused before anything is built or started."""
    bad = device_config(tmp_path / "bad.toml", "[true, false, false, false, false, false, false, false]")
    r = subprocess.run([sys.executable, "-m", "plc.cli", "run", "--config", str(bad), "--port", "0", "--retain",
                        str(tmp_path / "r"), "--build-dir", str(REPO / "build" / "runtime")], cwd=REPO,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stderr
    assert "the remote I/O would not stop the machine when the runtime stops" in r.stderr
    assert "%QX2.0 (device coil 0) is true when stopped, but CarouselMotorOn is not inverted" in r.stderr
    assert "listening on" not in r.stderr


def test_plc_deploy_service_refuses_it_too(tmp_path):
    bad = device_config(tmp_path / "bad.toml", "[true, false, false, false, false, false, false, false]")
    r = subprocess.run([sys.executable, "-m", "plc.cli", "deploy", "service", "--out", str(tmp_path / "svc"),
                        "--config", str(bad)], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert r.returncode != 0, r.stdout + r.stderr
    assert "%QX2.0 (device coil 0) is true when stopped, but CarouselMotorOn is not inverted" in r.stderr
    assert not list((tmp_path / "svc").rglob("run")), "nothing half-built is left behind"
