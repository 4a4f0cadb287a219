"""The [[io.device]] tables of the run configuration (`plc run --io modbus`): every mistake is reported with
file:line:col before anything starts; good devices become the runtime's --io-device arguments, which the C
runtime parses again (a hand-written bad one is refused with exit 2)."""
from __future__ import annotations

import subprocess
import textwrap
from pathlib import Path

import pytest

from plc import runtime

HEAD = '[io]\nlayer = "modbus"\n\n'
GOOD_DEVICE = textwrap.dedent("""\
    [[io.device]]
    name = "changer"
    tcp = "127.0.0.1"
    port = 1502
    poll_ms = 5
    timeout_ms = 20
    max_age_ms = 12
    status_input = "%IX5.0"
    discrete_inputs = [{ address = 0, count = 32, to = "%IX0.0" }]
    coils = [{address = 0, count = 8, from = "%QX2.0", safe = [false, true, false, false, false, false, false, false]}]
    input_registers = [{ address = 0, count = 2, to = "%IW0" }]
    holding_registers_read = [{ address = 0, count = 2, to = "%IW2" }]
    holding_registers_write = [{ address = 10, count = 2, from = "%QW0", safe = -1 }]
    """)


def load(tmp_path: Path, text: str) -> runtime.RunConfig:
    path = tmp_path / "run.toml"
    path.write_text(text)
    return runtime.load_config(path)


def error_of(tmp_path: Path, text: str) -> str:
    with pytest.raises(runtime.ConfigError) as e:
        load(tmp_path, text)
    return str(e.value)


def test_a_good_device_becomes_the_runtime_arguments(tmp_path):
    cfg = load(tmp_path, HEAD + GOOD_DEVICE)
    assert cfg.io == "modbus"
    assert cfg.io_devices == ["name=changer tcp=127.0.0.1:1502 unit=1 poll=5 timeout=20 age=12 backoff=100-2000 "
                              "status=40 di=0:32:0 co=0:8:16:0,1,0,0,0,0,0,0 ir=0:2:0 hr=0:2:2 hw=10:2:0:65535,65535"]
    argv = runtime.runtime_argv(Path("/bin/plc-runtime"), cfg)
    assert argv[argv.index("--io") + 1] == "modbus" and argv[argv.index("--io-device") + 1] == cfg.io_devices[0]


def test_the_default_age_limit_is_two_polls_and_the_time_out(tmp_path):
    cfg = load(tmp_path, HEAD + '[[io.device]]\ntcp = "10.0.0.2"\npoll_ms = 7\ntimeout_ms = 30\n'
                              'coils = [{ address = 0, count = 1, from = "%QX0.0" }]\n')
    assert " age=44 " in cfg.io_devices[0] and "name=device1" in cfg.io_devices[0]


# (text after HEAD, expected "line:col: error: ..." fragment); a key of a range is reported where it is written
BAD = [
    (GOOD_DEVICE + 'colour = "red"\n', ":14:1: error: [[io.device]] 1: unknown key 'colour'"),
    (GOOD_DEVICE.replace('to = "%IW2"', 'to = "%IW1"'),
     ":12:27: error: [[io.device]] 1: holding_registers_read %IW1..%IW2 overlaps input_registers of device 1"),
    (GOOD_DEVICE.replace('"%QX2.0"', '"%QX99.4"'),
     ":10:10: error: [[io.device]] 1: coils[1]: 8 values from %QX99.4 end at %QX100.3, outside the image"),
    (GOOD_DEVICE.replace('count = 2, to = "%IW0"', 'count = 2, to = "%IW1023"'),
     ":11:20: error: [[io.device]] 1: input_registers[1]: 2 values from %IW1023 end at %IW1024, outside the image"),
    ('[[io.device]]\nrtu = "/dev/no-such-tty"\nbaud = 19200\n'
     'discrete_inputs = [{ address = 0, count = 8, to = "%IX0.0" }]\n',
     ":2:1: error: [[io.device]] 1: rtu: serial device /dev/no-such-tty does not exist"),
    ('[[io.device]]\nrtu = "/dev/null"\nbaud = 12345\ndiscrete_inputs = [{ address = 0, count = 8, to = "%IX0.0" }]\n',
     ":3:1: error: [[io.device]] 1: baud: 12345 is not a rate the serial driver can set"),
    ('[[io.device]]\ntcp = "127.0.0.1"\nport = 502\n', ":1:1: error: [[io.device]] 1: no ranges"),
    ('[[io.device]]\ntcp = "127.0.0.1"\nholding_registers_read = [\n'
     + "".join(f'  {{ address = {i}, count = 1, to = "%IW{i}" }},\n' for i in range(33)) + ']\n',
     ":1:1: error: [[io.device]] 1: 33 ranges: a device has at most 32"),
    ('[[io.device]]\ntcp = "plc.local"\ncoils = [{ address = 0, count = 1, from = "%QX0.0" }]\n',
     ":2:1: error: [[io.device]] 1: tcp: 'plc.local' is not an IPv4 address"),
    ('[[io.device]]\ntcp = "127.0.0.1"\nrtu = "/dev/null"\ncoils = [{ address = 0, count = 1, from = "%QX0.0" }]\n',
     ":1:1: error: [[io.device]] 1: give exactly one of tcp"),
    ('[[io.device]]\ntcp = "127.0.0.1"\npoll_ms = 10\nmax_age_ms = 5\n'
     'coils = [{ address = 0, count = 1, from = "%QX0.0" }]\n',
     ":4:1: error: [[io.device]] 1: max_age_ms (5) is shorter than poll_ms (10)"),
    ('[[io.device]]\ntcp = "127.0.0.1"\ncoils = [{ address = 0, count = 1970, from = "%QX0.0" }]\n',
     ":3:25: error: [[io.device]] 1: coils[1]: count: expected an integer 1..1968"),
    ('[[io.device]]\ntcp = "127.0.0.1"\ndiscrete_inputs = [{ address = 0, count = 8, to = "%QX0.0" }]\n',
     ":3:46: error: [[io.device]] 1: discrete_inputs[1]: to: expected a location like %IX0.0"),
    ('[[io.device]]\ntcp = "127.0.0.1"\ncoils = [{ address = 0, count = 8, from = "%QX0.0", savef = 1 }]\n',
     ":3:53: error: [[io.device]] 1: coils[1]: unknown key 'savef' (did you mean 'safe'?)"),
    ('[[io.device]]\ntcp = "127.0.0.1"\ncoils = [\n  { address = 0, count = 4, from = "%QX0.0" },\n'
     '  { address = 2, count = 4, from = "%QX1.0" },\n]\n',
     ":5:3: error: [[io.device]] 1: coils addresses 2..5 overlap coils 0..3 on the same device"),
    ('[[io.device]]\ntcp = "127.0.0.1"\ncoils = [{ address = 0, count = 8, from = "%QX2.0" }]\n\n'
     '[[io.device]]\ntcp = "127.0.0.2"\ncoils = [{ address = 0, count = 8, from = "%QX2.4" }]\n',
     ":7:10: error: [[io.device]] 2: coils %QX2.4..%QX3.3 overlaps coils of device 1 (%QX2.0..%QX2.7)"),
    ('[[io.device]]\ntcp = "127.0.0.1"\nstatus_input = "%IX0.3"\n'
     'discrete_inputs = [{ address = 0, count = 8, to = "%IX0.0" }]\n',
     ":3:1: error: [[io.device]] 1: status_input %IX0.3 lies in discrete_inputs of device 1"),
    ('[[io.device]]\ntcp = "127.0.0.1"\nstatus_input = "%IX49.6"\n'
     'discrete_inputs = [{ address = 0, count = 8, to = "%IX0.0" }]\n',
     ":3:1: error: [[io.device]] 1: status_input %IX49.6 is the runtime's ForcesActive"),
    ('[[io.device]]\ntcp = "127.0.0.1"\ndiscrete_inputs = [{ address = 0, count = 16, to = "%IX48.0" }]\n',
     ":3:20: error: [[io.device]] 1: discrete_inputs %IX48.0..%IX49.7 covers %IX49.6, the runtime's ForcesActive"),
    # issue 27: a range over the inputs the runtime drives itself (SimulatedPlant, a device's IoModuleNLost)
    ('[[io.device]]\ntcp = "127.0.0.1"\ndiscrete_inputs = [{ address = 0, count = 8, to = "%IX49.0" }]\n',
     ":3:20: error: [[io.device]] 1: discrete_inputs %IX49.0..%IX49.7 covers %IX49.7, the runtime's SimulatedPlant"),
    ('[[io.device]]\ntcp = "127.0.0.1"\ndiscrete_inputs = [{ address = 0, count = 48, to = "%IX0.0" }]\n\n'
     '[[io.device]]\ntcp = "127.0.0.2"\nstatus_input = "%IX5.0"\n'
     'coils = [{ address = 0, count = 8, from = "%QX2.0" }]\n',
     ":7:1: error: [[io.device]] 2: status_input %IX5.0 lies in discrete_inputs of device 1"),
    ('[[io.device]]\nrtu = "/dev/null"\nunit = 1\ndiscrete_inputs = [{ address = 0, count = 8, to = "%IX0.0" }]\n\n'
     '[[io.device]]\nrtu = "/dev/null"\nunit = 1\ncoils = [{ address = 0, count = 8, from = "%QX2.0" }]\n',
     ":8:1: error: [[io.device]] 2: unit 1 is already device 1 on serial line /dev/null"),
    ('[[io.device]]\nrtu = "/dev/null"\nunit = 1\ndiscrete_inputs = [{ address = 0, count = 8, to = "%IX0.0" }]\n\n'
     '[[io.device]]\nrtu = "/dev/null"\nbaud = 9600\nunit = 2\ncoils = [{ address = 0, count = 8, from = "%QX2.0" }]\n',
     ":7:1: error: [[io.device]] 2: serial line /dev/null is device 1's: give it the same baud"),
    ('[[io.device]]\nrtu = "/dev/null"\nport = 502\nunit = 0\n'
     'discrete_inputs = [{ address = 0, count = 8, to = "%IX0.0" }]\n',
     ":3:1: error: [[io.device]] 1: port belongs to a tcp device"),
]


@pytest.mark.parametrize("text,expected", BAD, ids=[b[1].split("error: ")[1][:40] for b in BAD])
def test_bad_devices_are_rejected_with_their_position(tmp_path, text, expected):
    message = error_of(tmp_path, HEAD + text)
    path = str(tmp_path / "run.toml")
    assert message.splitlines()[1].startswith(path + ":"), message
    line, col, rest = expected.split(":", 3)[1], expected.split(":", 3)[2], expected.split(":", 3)[3]
    # positions are relative to the device text: HEAD adds three lines
    shifted = f":{int(line) + 3}:{col}:{rest}"
    assert shifted in message, message


def test_every_problem_is_reported_at_once(tmp_path):
    message = error_of(tmp_path, HEAD + '[[io.device]]\ntcp = "x"\nbaud = 9600\ncolour = 1\n'
                                        'coils = [{ address = 0, count = 1, from = "%QX0.0" }]\n')
    assert message.count(": error: ") == 3 and message.startswith("3 problem(s) in the run configuration"), message


def test_mistakes_of_every_kind_are_reported_in_one_run_with_their_lines(tmp_path):
    """Issue 37: an unknown key no longer hides an overlap found across devices, nor a mistake in another table,
    nor a serial line whose age limit cannot hold; each is reported at its own line, in file order."""
    text = (HEAD                                                                     # lines 1-3
            + '[modbus]\nport = 99999\n\n'                                            # 4-6: a bad value
            + '[[io.device]]\ntcp = "10.0.0.2"\ncolour = "red"\n'                      # 7-9: an unknown key
            + 'discrete_inputs = [{ address = 0, count = 16, to = "%IX0.0" }]\n\n'    # 10
            + '[[io.device]]\ntcp = "10.0.0.3"\n'                                     # 12-13
            + 'discrete_inputs = [{ address = 0, count = 8, to = "%IX1.0" }]\n\n'     # 14: overlaps line 10
            + '[[io.device]]\nrtu = "/dev/null"\nunit = 3\ntimeout_ms = 80\nmax_age_ms = 500\n'   # 16-20
            + 'coils = [{ address = 0, count = 8, from = "%QX2.0" }]\n\n'             # 21
            + '[[io.device]]\nrtu = "/dev/null"\nunit = 9\ntimeout_ms = 80\nmax_age_ms = 500\n'   # 23-27
            + 'discrete_inputs = [{ address = 0, count = 8, to = "%IX4.0" }]\n')       # 28
    message = error_of(tmp_path, text)
    path = str(tmp_path / "run.toml")
    found = [line.split(": error: ")[0].rsplit(":", 1)[0] for line in message.splitlines()[1:]]
    assert found == [f"{path}:{n}" for n in (5, 9, 14, 20, 27)], message
    assert message.startswith("5 problem(s) in the run configuration"), message
    assert "[modbus] port: expected an integer 0..65535, got 99999" in message
    assert "unknown key 'colour'" in message
    assert "[[io.device]] 2: discrete_inputs %IX1.0..%IX1.7 overlaps discrete_inputs of device 1" in message
    assert "max_age_ms 500 cannot hold on serial line /dev/null shared by 2 units" in message
    assert "give max_age_ms >= 570" in message     # poll 10 + 2 time-outs x 2 units, + the margin 3 x 80


def test_a_shared_serial_line_without_max_age_gets_its_worst_case(tmp_path):
    cfg = load(tmp_path, HEAD + '[[io.device]]\nrtu = "/dev/null"\nunit = 3\npoll_ms = 5\ntimeout_ms = 80\n'
                              'coils = [{ address = 0, count = 8, from = "%QX2.0" }]\n\n'
                              '[[io.device]]\nrtu = "/dev/null"\nunit = 9\npoll_ms = 10\ntimeout_ms = 80\n'
                              'discrete_inputs = [{ address = 0, count = 8, to = "%IX4.0" }]\n')
    # line poll 5 ms + 2 time-outs for each of the 2 units, + the 3 time-outs of the line margin
    assert all(" age=565 " in spec for spec in cfg.io_devices), cfg.io_devices


def test_layer_modbus_needs_devices(tmp_path):
    message = error_of(tmp_path, HEAD)
    assert "[io] layer: layer \"modbus\" needs at least one [[io.device]]" in message


def test_plc_run_io_modbus_without_devices_is_a_user_error(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    parser = __import__("argparse").ArgumentParser()
    runtime.add_run_arguments(parser)
    args = parser.parse_args(["--io", "modbus"])
    with pytest.raises(runtime.ConfigError, match=r"--io modbus needs the remote I/O devices"):
        runtime.prepare_run(args, tmp_path / "program.c")


def test_two_mistakes_of_one_range_are_both_reported_each_at_its_key(tmp_path):
    """The schema checks a range's every key: an unknown key no longer hides a bad count beside it (it stopped the
    range's checks), and each is reported where it is written, not at the range's brace."""
    message = error_of(tmp_path, HEAD + '[[io.device]]\ntcp = "127.0.0.1"\n'
                                        'coils = [{ address = 0, count = 1970, from = "%QX0.0", savef = 1 }]\n')
    path = str(tmp_path / "run.toml")
    assert message.startswith("2 problem(s) in the run configuration"), message
    assert f"{path}:6:25: error: [[io.device]] 1: coils[1]: count: expected an integer 1..1968, got 1970" in message
    assert f"{path}:6:56: error: [[io.device]] 1: coils[1]: unknown key 'savef' (did you mean 'safe'?)" in message


# The runtime's own checks of --io-device are the bounds a C program must check anyway (issue 28 point 2): a token it
# can read, buffers, libmodbus' limit of one request, the device's addresses and the image.  Everything else (overlaps,
# a shared line's settings and units, no range) is plc run's, tested above with positions.
@pytest.mark.parametrize("spec,why", [
    ("tcp=127.0.0.1:1502 di=0:8:799", "inside libmodbus' limit of one request, the device's addresses and the image"),
    ("tcp=127.0.0.1:1502 di=65530:8:0", "the device's addresses"),
    ("tcp=127.0.0.1:1502 co=0:1969:0", "limit of one request"),
    ("tcp=127.0.0.1:1502 di=0:8:0:1", "SAFE on co and hw only"),
    ("tcp=127.0.0.1:1502 co=0:4:0:1,0", "one value, or one per address"),
    ("tcp=127.0.0.1:1502 " + " ".join(f"di=0:1:{n}" for n in range(33)), "too many ranges"),
    ("tcp=127.0.0.1:1502 rtu=/dev/null di=0:8:0", "exactly one of"),
    ("tcp=127.0.0.1:1502 colour=red di=0:8:0", "unknown key"),
    ("tcp=127.0.0.1:1502 poll=ten di=0:8:0", "unknown key or value out of range"),
])
def test_the_runtime_refuses_a_device_argument_out_of_its_bounds(spec, why):
    from rt_harness import runtime_binary
    result = subprocess.run([str(runtime_binary()), "--io", "modbus", "--io-device", spec, "--port", "0",
                             "--duration", "0.1", "--no-rt", "--status", "off"], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 1 and why in result.stderr, result.stderr
