"""SimulatedPlant has one home, modbus_map/map.toml; the two things that raise it must agree with it: the
runtime's `--io sim` layer (plc/src/plc/native/runtime/io_sim.c, SIM_FLAG_BIT) and the OpenPLC PSM script for demos
(configs/openplc/psm_simulated_plant.py), which can only reach %IX0.0..%IX49.7."""
from __future__ import annotations

import re
from pathlib import Path

from atc.host.tags import load_map

REPO = Path(__file__).resolve().parents[2]
SIG = load_map(REPO / "modbus_map" / "map.toml").signal("SimulatedPlant")


def test_the_map_puts_simulated_plant_where_openplc_psm_can_raise_it():
    assert SIG.table == "discrete_input"
    assert SIG.address <= 399, f"discrete input {SIG.address} is beyond %IX49.7, out of the PSM layer's reach"


def test_the_runtime_sim_layer_raises_the_map_address():
    text = (REPO / "plc" / "src" / "plc" / "native" / "runtime" / "io_sim.c").read_text(encoding="utf-8")
    m = re.search(r"#define SIM_FLAG_BIT (\d+)", text)
    assert m and int(m.group(1)) == SIG.address, m and m.group(0)


def test_the_psm_script_raises_the_map_address():
    text = (REPO / "configs" / "openplc" / "psm_simulated_plant.py").read_text(encoding="utf-8")
    m = re.search(r'SIMULATED_PLANT = "IX(\d+)\.(\d)"', text)
    assert m and 8 * int(m.group(1)) + int(m.group(2)) == SIG.address, m and m.group(0)
    assert "psm.set_var(SIMULATED_PLANT, True)" in text
