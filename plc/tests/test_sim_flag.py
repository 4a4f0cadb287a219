"""SimulatedPlant has one home, modbus_map/map.toml; the two things that raise it must agree with it: what
`plc run` hands the runtime's `--io sim` layer (atc.runsetup: `--sim-flag`; the runtime itself knows no address)
and the OpenPLC PSM script for demos (configs/openplc/psm_simulated_plant.py), which can only reach
%IX0.0..%IX49.7.  The script is read parsed (ast), not as text."""
from __future__ import annotations

import ast
import re
import subprocess
from pathlib import Path

import rt_harness as h
from atc.host.tags import load_map
from atc.runsetup import runtime_setup

REPO = Path(__file__).resolve().parents[2]
SIG = load_map(REPO / "modbus_map" / "map.toml").signal("SimulatedPlant")


def test_the_map_puts_simulated_plant_where_openplc_psm_can_raise_it():
    assert SIG.table == "discrete_input"
    assert SIG.address <= 399, f"discrete input {SIG.address} is beyond %IX49.7, out of the PSM layer's reach"


def test_plc_run_hands_the_sim_layer_the_map_address(tmp_path):
    setup = runtime_setup(REPO / "modbus_map" / "map.toml", tmp_path)
    assert setup.sim_flag == f"%IX{SIG.address // 8}.{SIG.address % 8}"


def test_the_sim_layer_raises_the_input_it_is_given_and_no_other():
    binary = h.runtime_binary()
    with h.Runtime(binary, "--no-rt", "--io", "sim", "--sim-flag", "%IX10.3") as rt:
        rt.wait_for(r"io sim: %IX10\.3 held TRUE")
        rt.wait_for(r"first scan done")
        with h.Client(rt.port) as c:
            assert c.read_discrete(80, 8) == [False, False, False, True, False, False, False, False]
            assert c.read_discrete(SIG.address) == [False]
    with h.Runtime(binary, "--no-rt", "--io", "sim") as rt:
        rt.wait_for(r"first scan done")
        with h.Client(rt.port) as c:
            h.wait_until(lambda: c.read_discrete(83) == [False], 2, "a scan with the inputs latched")
            assert c.read_discrete(SIG.address) == [False] and "held TRUE" not in rt.log


def test_a_sim_flag_outside_the_discrete_inputs_is_a_usage_error():
    r = subprocess.run([str(h.runtime_binary()), "--sim-flag", "%IX100.0"], capture_output=True, text=True,
                       timeout=30)
    assert r.returncode == 2 and "--sim-flag: '%IX100.0' is not a discrete input" in r.stderr


def psm_raised(source: str) -> list[int]:
    """The discrete inputs a PSM script raises, read from its parsed code (ast): module constants holding an
    "IXbyte.bit" string, named in a psm.set_var(NAME, True) call of update_inputs."""
    tree = ast.parse(source)
    names = {t.id: node.value.value for node in tree.body if isinstance(node, ast.Assign)
             and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)
             for t in node.targets if isinstance(t, ast.Name)}
    raised = []
    for fn in (n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "update_inputs"):
        for call in (n for n in ast.walk(fn) if isinstance(n, ast.Call)):
            f, args = call.func, call.args
            if (isinstance(f, ast.Attribute) and f.attr == "set_var" and isinstance(f.value, ast.Name)
                    and f.value.id == "psm" and len(args) == 2 and isinstance(args[0], ast.Name)
                    and isinstance(args[1], ast.Constant) and args[1].value is True):
                m = re.fullmatch(r"IX(\d+)\.([0-7])", names.get(args[0].id, ""))
                if m:
                    raised.append(8 * int(m.group(1)) + int(m.group(2)))
    return raised


def test_the_psm_script_raises_the_map_address():
    source = (REPO / "configs" / "openplc" / "psm_simulated_plant.py").read_text(encoding="utf-8")
    assert psm_raised(source) == [SIG.address]


def test_the_psm_reader_takes_the_code_not_its_comments():
    script = ('import psm\nFLAG = "IX49.6"\nOTHER = "IX1.0"\n# psm.set_var(OTHER, True) in a comment\n'
              'def update_inputs():\n    psm.set_var(FLAG, True)\n    psm.set_var(OTHER, False)\n')
    assert psm_raised(script) == [398]
    assert psm_raised(script.replace("def update_inputs", "def hardware_init")) == []


def test_the_simulated_plant_runs_only_when_asked(tmp_path):
    """A run configuration without an I/O layer gets the loop-back default but never the program's simulated plant:
    on a real machine that would answer every M6 as done while nothing moves."""
    from plc import runtime
    bare = tmp_path / "real.toml"
    bare.write_text('[modbus]\nport = 5999\n')
    sim = tmp_path / "sim.toml"
    sim.write_text('[io]\nlayer = "sim"\n')
    for path, flagged in ((bare, False), (sim, True)):
        cfg = runtime.load_config(path)
        cfg.sim_flag = "%IX49.7"
        argv = runtime.runtime_argv(Path("plc-runtime"), cfg)
        assert ("--sim-flag" in argv) == flagged, (path.name, argv)
        assert argv[argv.index("--io") + 1] == "sim"
