"""plc.runtime: building the runtime with a program, the run configuration, `plc run`.

The `plc run` tests start `python -m plc.runtime PROGRAM.c ...`, the same code path that
the `plc run` subcommand uses once the ST compiler has produced the C file.
"""

from __future__ import annotations

import argparse
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import rt_harness as h
from plc import runtime

PLC_ROOT = Path(__file__).resolve().parent.parent


# ----------------------------------------------------------------------- building

def test_build_is_cached_by_content(tmp_path):
    program = tmp_path / "program.c"
    shutil.copy(h.BASIC, program)
    out = tmp_path / "build"
    first = runtime.build_runtime(program, out, sanitize=h.SANITIZE)
    stamp = first.stat().st_mtime_ns
    assert runtime.build_runtime(program, out, sanitize=h.SANITIZE) == first
    assert first.stat().st_mtime_ns == stamp                       # not rebuilt
    program.write_text(program.read_text() + "\n/* changed */\n")
    second = runtime.build_runtime(program, out, sanitize=h.SANITIZE)
    assert second != first and second.is_file()
    assert second.name.endswith("-asan") == h.SANITIZE
    result = subprocess.run([str(second), "--version"], capture_output=True, text=True, timeout=30)
    assert result.returncode == 0 and "ABI 2" in result.stdout


def test_the_runtime_objects_are_compiled_once_for_every_program(tmp_path, monkeypatch):
    """A second program reuses the runtime's own objects (only the program is compiled): in PLC_RUNTIME_OBJECTS
    when set, else in the build directory's objects/."""
    monkeypatch.delenv("PLC_RUNTIME_OBJECTS", raising=False)
    out = tmp_path / "build"
    first = tmp_path / "first.c"
    shutil.copy(h.BASIC, first)
    runtime.build_runtime(first, out, sanitize=h.SANITIZE)
    objects = {p.name: p.stat().st_mtime_ns for p in (out / "objects").iterdir()}
    assert len(objects) == len(list(runtime.RUNTIME_DIR.glob("*.c")))
    second = tmp_path / "second.c"
    second.write_text(first.read_text() + "\n/* another program */\n")
    binary = runtime.build_runtime(second, out, sanitize=h.SANITIZE)
    assert {p.name: p.stat().st_mtime_ns for p in (out / "objects").iterdir()} == objects
    leftovers = [p.name for p in out.iterdir() if p.name != "objects" and "." in p.name]   # a temporary file
    assert leftovers == []
    result = subprocess.run([str(binary), "--version"], capture_output=True, text=True, timeout=30)
    assert result.returncode == 0 and "ABI 2" in result.stdout
    shared = tmp_path / "shared"
    monkeypatch.setenv("PLC_RUNTIME_OBJECTS", str(shared))
    runtime.build_runtime(first, tmp_path / "other-build", sanitize=h.SANITIZE)
    assert len(list(shared.iterdir())) == len(objects) and not (tmp_path / "other-build" / "objects").exists()


def test_a_changed_included_header_rebuilds(tmp_path):
    (tmp_path / "values.h").write_text("#define FIXTURE_LAYOUT_HASH 1u\n")
    program = tmp_path / "program.c"
    program.write_text(f'#include "values.h"\n#include "{h.BASIC}"\n')
    first = runtime.build_runtime(program, tmp_path / "build")
    (tmp_path / "values.h").write_text("#define FIXTURE_LAYOUT_HASH 2u\n")
    assert runtime.build_runtime(program, tmp_path / "build") != first


def test_build_errors_are_plain_messages(tmp_path):
    with pytest.raises(runtime.RuntimeBuildError, match=r"program C file .*missing\.c does not exist"):
        runtime.build_runtime(tmp_path / "missing.c", tmp_path / "build")
    bad = tmp_path / "bad.c"
    bad.write_text("#include \"plc_abi.h\"\nconst plc_program_t plc_program = { .abi_version = };\n")
    with pytest.raises(runtime.RuntimeBuildError) as e:
        runtime.build_runtime(bad, tmp_path / "build")
    assert "building the runtime with" in str(e.value) and "bad.c:2" in str(e.value)
    result = subprocess.run([sys.executable, "-m", "plc.runtime", str(bad), "--build-only",
                             "--build-dir", str(tmp_path / "build")], capture_output=True, text=True,
                            cwd=PLC_ROOT, timeout=120)
    assert result.returncode == 1
    assert result.stderr.startswith("plc run: error: building the runtime with")
    assert "Traceback" not in result.stderr
    assert not list((tmp_path / "build").glob("plc-runtime-*"))    # no half-built executable left


# ------------------------------------------------------------------------- config

FULL_CONFIG = """
[modbus]
bind = "127.0.0.1"
port = 5021
max_clients = 4
frame_timeout_ms = 500
read_only = true
allow = ["127.0.0.1", "10.1.2.0/24"]
writable_coils = ["400-799"]
writable_registers = ["1024-1030", 2000]

[io]
layer = "none"

[retain]
file = "state/plc.retain"
interval_ms = 50
registers = ["1024-1027"]

[scan]
realtime = false
rt_priority = 20
cpu = 1
cpu_latency_us = 0
status_interval_s = 2.5
watchdog_ms = 250
"""


def test_a_full_config_is_read(tmp_path):
    cfg_file = tmp_path / "plc.toml"
    cfg_file.write_text(FULL_CONFIG)
    cfg = runtime.load_config(cfg_file)
    assert cfg == runtime.RunConfig(
        bind="127.0.0.1", port=5021, max_clients=4, frame_timeout_ms=500, read_only=True,
        allow=["127.0.0.1/32", "10.1.2.0/24"], writable_coils=["400-799"],
        writable_registers=["1024-1030", "2000-2000"], io="none", io_chosen=True,
        retain_file=tmp_path / "state" / "plc.retain", retain_interval_ms=50, retain_registers=["1024-1027"],
        realtime=False, rt_priority=20, cpu=1, cpu_latency_us=0, status_interval_s=2.5, watchdog_ms=250)
    argv = runtime.runtime_argv(Path("/x/plc-runtime"), cfg)
    assert argv[0] == "/x/plc-runtime"
    # option -> value up to the first flag without one (--no-rt); the options after it are looked up by index
    pairs = dict(zip(argv[1::2], argv[2::2], strict=False))
    assert pairs["--port"] == "5021" and pairs["--io"] == "none" and pairs["--max-clients"] == "4"
    assert pairs["--allow"] == "127.0.0.1/32,10.1.2.0/24" and pairs["--frame-timeout"] == "500"
    assert "--read-only" in argv
    assert pairs["--writable-registers"] == "1024-1030,2000-2000"
    assert pairs["--retain"] == str(tmp_path / "state" / "plc.retain")
    assert pairs["--watchdog"] == "250" and pairs["--status-interval"] == "2.5"
    assert "--no-rt" in argv
    assert argv[argv.index("--cpu") + 1] == "1"
    assert argv[argv.index("--cpu-latency") + 1] == "0"


def test_defaults_and_empty_writable_lists():
    cfg = runtime.RunConfig(writable_coils=[], writable_registers=None)
    argv = runtime.runtime_argv(Path("rt"), cfg)
    assert argv[argv.index("--writable-coils") + 1] == "none"
    assert "--writable-registers" not in argv                     # the runtime's documented default
    assert "--read-only" not in argv and argv[argv.index("--frame-timeout") + 1] == "2000"
    assert argv[argv.index("--retain") + 1] == str(Path("var") / "plc.retain")
    assert argv[argv.index("--bind") + 1] == "127.0.0.1" and argv[argv.index("--port") + 1] == "5020"
    assert "--cpu" not in argv                                    # the scan thread is not pinned by default
    assert "--cpu-latency" not in argv                            # nor any PM QoS request


@pytest.mark.parametrize("text, message", [
    ("[modbus\n", "invalid TOML"),
    ("[network]\nport = 1\n", "unknown section [network]"),
    ("[modbus]\nprot = 5020\n", "[modbus] unknown key 'prot'"),
    ("modbus = 3\n", "'modbus' must be a section"),
    ("[modbus]\nport = \"5020\"\n", "[modbus] port: expected an integer 0..65535, got '5020'"),
    ("[modbus]\nport = 70000\n", "[modbus] port: expected an integer 0..65535"),
    ("[modbus]\nport = true\n", "[modbus] port: expected an integer"),
    ("[modbus]\nbind = \"localhost\"\n", "[modbus] bind: 'localhost' is not an IPv4 address"),
    ("[modbus]\nallow = [\"10.0.0.0/33\"]\n", "[modbus] allow: '10.0.0.0/33' is not an IPv4 address"),
    ("[modbus]\nmax_clients = 0\n", "[modbus] max_clients: expected an integer 1..256"),
    ("[modbus]\nframe_timeout_ms = 0\n", "[modbus] frame_timeout_ms: expected an integer 1..3600000, got 0"),
    ("[modbus]\nread_only = \"yes\"\n", "[modbus] read_only: expected true or false, got 'yes'"),
    ("[modbus]\nwritable_coils = [\"400-800\"]\n", "[modbus] writable_coils: range '400-800' is outside 0-799"),
    ("[modbus]\nwritable_registers = [\"9-2\"]\n", "range '9-2' is outside"),
    ("[modbus]\nwritable_registers = [\"abc\"]\n", "'abc' is not an address or a range"),
    ("[modbus]\nwritable_registers = 12.5\n", "expected a list of ranges"),
    ("[io]\nlayer = \"gpio\"\n", "[io] layer: expected one of \"sim\", \"none\", \"modbus\", got 'gpio'"),
    ("[retain]\nfile = 3\n", "[retain] file: expected a file name"),
    ("[retain]\ninterval_ms = -1\n", "[retain] interval_ms: expected an integer"),
    ("[retain]\nregisters = [\"8192\"]\n", "[retain] registers: range '8192' is outside 0-8191"),
    ("[scan]\nrealtime = \"yes\"\n", "[scan] realtime: expected true or false"),
    ("[scan]\nrt_priority = 99\n", "[scan] rt_priority: expected an integer 1..98"),
    ("[scan]\ncpu = -1\n", "[scan] cpu: expected an integer 0..1023, got -1"),
    ("[scan]\ncpu = 1024\n", "[scan] cpu: expected an integer 0..1023, got 1024"),
    ("[scan]\ncpu = \"1\"\n", "[scan] cpu: expected an integer 0..1023, got '1'"),
    ("[scan]\ncpu = true\n", "[scan] cpu: expected an integer 0..1023, got True"),
    ("[scan]\ncpu = 1.0\n", "[scan] cpu: expected an integer 0..1023, got 1.0"),
    ("[scan]\ncpu_latency_us = -1\n", "[scan] cpu_latency_us: expected an integer 0..2000000000, got -1"),
    ("[scan]\ncpu_latency_us = \"0\"\n", "[scan] cpu_latency_us: expected an integer 0..2000000000, got '0'"),
    ("[scan]\nstatus_interval_s = 0\n", "[scan] status_interval_s: expected a number of seconds >= 0.1"),
    ("[scan]\nwatchdog_ms = 1.5\n", "[scan] watchdog_ms: expected an integer 0..3600000"),
])
def test_bad_configs_are_rejected_with_the_place_and_the_reason(tmp_path, text, message):
    cfg_file = tmp_path / "plc.toml"
    cfg_file.write_text(text)
    with pytest.raises(runtime.ConfigError) as e:
        runtime.load_config(cfg_file)
    # one problem, said with its position (file:line:col: error:)
    assert len(e.value.problems) == 1 and re.match(re.escape(str(cfg_file)) + r":\d+:\d+: error: ",
                                                   e.value.problems[0]), str(e.value)
    assert message in str(e.value)


def test_the_shipped_config_pins_nothing_and_its_cpu_example_is_valid(tmp_path):
    shipped = PLC_ROOT.parent / "machines" / "default" / "runtime.toml"
    assert runtime.load_config(shipped).cpu is None
    text = shipped.read_text()
    assert "\n# [scan]\n# cpu = 1 " in text
    example = tmp_path / "runtime.toml"
    example.write_text(text.replace("\n# [scan]\n# cpu = 1 ", "\n[scan]\ncpu = 1 "))
    assert runtime.load_config(example).cpu == 1
    assert runtime.load_config(shipped).cpu_latency_us is None
    assert "\n# cpu_latency_us = 0 " in text
    example.write_text(text.replace("\n# [scan]\n", "\n[scan]\n").replace("\n# cpu_latency_us = 0 ",
                                                                          "\ncpu_latency_us = 0 "))
    assert runtime.load_config(example).cpu_latency_us == 0


def test_a_missing_config_file(tmp_path):
    with pytest.raises(runtime.ConfigError, match="no such file"):
        runtime.load_config(tmp_path / "absent.toml")


def test_mistakes_of_two_sections_are_reported_together_a_misspelt_key_with_its_right_name(tmp_path):
    """The run configuration is checked by its schema (runtime.RUN_CONFIG): a misspelt key of [modbus] and a bad
    value of [monitor] are one report, in file order, the misspelling answered with the key it resembles."""
    cfg_file = tmp_path / "plc.toml"
    cfg_file.write_text('[modbus]\nprot = 5020\n\n[monitor]\nenabled = "yes"\n')
    with pytest.raises(runtime.ConfigError) as e:
        runtime.load_config(cfg_file)
    assert e.value.problems == [
        f"{cfg_file}:2:1: error: [modbus] unknown key 'prot' (did you mean 'port'?)",
        f"{cfg_file}:5:1: error: [monitor] enabled: expected true or false, got 'yes'"]
    assert str(e.value).startswith(f"2 problem(s) in the run configuration {cfg_file}:\n")


def test_a_command_line_option_is_checked_as_its_configuration_key(tmp_path):
    parser = argparse.ArgumentParser()
    runtime.add_run_arguments(parser)
    for argv, message in ((["--bind", "localhost"], "--bind: 'localhost' is not an IPv4 address"),
                          (["--port", "70000"], "--port: expected an integer 0..65535, got 70000"),
                          (["--sim-flag", "%IX100.0"], "--sim-flag: expected a discrete input %IX0.0..%IX99.7")):
        with pytest.raises(runtime.ConfigError) as e:
            runtime.prepare_run(parser.parse_args(argv), tmp_path / "program.c")
        assert str(e.value).startswith(message), str(e.value)


# ------------------------------------------------------------------------ plc run

def plc_run(*args: str) -> h.Runtime:
    return h.Runtime(Path(sys.executable), "-m", "plc.runtime", str(h.BASIC), *args, cwd=PLC_ROOT, raw=True)


def test_plc_run_serves_with_the_config_and_stops_cleanly(tmp_path):
    cfg_file = tmp_path / "plc.toml"
    cfg_file.write_text('[modbus]\nport = 1\nallow = ["127.0.0.1"]\nwritable_registers = ["1024-1030"]\n'
                        '[scan]\nrealtime = false\n')
    args = ["--config", str(cfg_file), "--port", "0", "--retain", str(tmp_path / "var" / "plc.retain"),
            "--build-dir", str(h.CACHE)] + (["--sanitize"] if h.SANITIZE else [])
    rt = plc_run(*args).start()                                    # --port 0 overrides the file's port 1
    try:
        with h.Client(rt.port) as c:
            h.wait_until(lambda: h.read_diag(c)["scans"] >= 1, 2, "the first scan")
            c.write_register(1024, 5)
            with pytest.raises(h.ModbusError) as e:
                c.write_register(512, 5)                           # not in the configured ranges
            assert e.value.code == 2
        assert (tmp_path / "var").is_dir()
        assert "clients allowed from 127.0.0.1/32" in rt.log
        assert "real-time scheduling off" in rt.log
    finally:
        rc = rt.stop(signal.SIGTERM)
    rt.assert_clean_exit(rc)
    assert (tmp_path / "var" / "plc.retain").is_file(), rt.log


def test_plc_run_rejects_a_bad_config_before_anything_runs(tmp_path):
    cfg_file = tmp_path / "plc.toml"
    cfg_file.write_text("[modbus]\nport = 99999\n")
    build_dir = tmp_path / "build"
    result = subprocess.run([sys.executable, "-m", "plc.runtime", str(h.BASIC), "--config", str(cfg_file),
                             "--build-dir", str(build_dir)], capture_output=True, text=True, cwd=PLC_ROOT,
                            timeout=60)
    assert result.returncode == 1
    assert result.stderr == (f"plc run: error: 1 problem(s) in the run configuration {cfg_file}:\n"
                             f"{cfg_file}:2:1: error: [modbus] port: expected an integer 0..65535, got 99999\n")
    assert not build_dir.exists()


def test_a_taken_port_is_exit_2_and_writes_nothing(tmp_path):
    """Issue 27: another process listens on the port: `plc run` and the runtime itself exit 2 (an environment
    problem, README) and leave no retain file, no token, no folder behind."""
    import socket
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        state = tmp_path / "var"
        result = subprocess.run([sys.executable, "-m", "plc.runtime", str(h.BASIC), "--port", str(port), "--retain",
                                 str(state / "plc.retain"), "--build-dir", str(h.CACHE)], capture_output=True,
                                text=True, cwd=PLC_ROOT, timeout=300)
        assert result.returncode == 2, result.stderr
        assert f"cannot listen on 127.0.0.1:{port}: Address already in use" in result.stderr
        assert "nothing was written" in result.stderr and not state.exists()
        state.mkdir()                               # the runtime alone: its folder exists, the file must not appear
        direct = h.Runtime(h.runtime_binary(), "--port", str(port), "--retain", str(state / "plc.retain"),
                           "--no-rt", raw=True)
        rc = direct.wait(30 * h.SLOW)                 # and its log to the end
        assert rc == 2, direct.log
        assert f"cannot listen on 127.0.0.1:{port}" in direct.log, direct.log
        assert list(state.iterdir()) == [], direct.log


def test_run_arguments_can_be_added_to_any_parser():
    parser = argparse.ArgumentParser()
    runtime.add_run_arguments(parser)
    args = parser.parse_args(["--bind", "127.0.0.1", "--port", "5021", "--io", "none", "--retain", "x.retain"])
    assert (args.bind, args.port, args.io, args.retain, args.config) == ("127.0.0.1", 5021, "none",
                                                                          Path("x.retain"), None)
    assert args.read_only is None and parser.parse_args(["--read-only"]).read_only is True
    with pytest.raises(SystemExit):
        parser.parse_args(["--io", "gpio"])
