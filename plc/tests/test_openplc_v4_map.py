"""OpenPLC v4's Modbus slave configuration for our register map (atc.map.gen_v4, docs/openplc-v4.md).

The v4 slave packs its segments end to end (%QW | %MW | %MD two registers each | %ML four; coils %QX | %MX):
the generated conf/modbus_slave.json keeps v3's counts, so every signal is served where the map puts it.
"""
from __future__ import annotations

import copy
import json
from pathlib import Path

from plc.diagnostics import Diagnostics
from atc.map import gen_v4
from atc.map.model import Signal, iec_address, load

ROOT = Path(__file__).resolve().parents[2]


def project_map():
    diags = Diagnostics()
    rmap = load(ROOT / "modbus_map" / "map.toml", diags)
    assert rmap is not None and not diags.has_errors()
    return rmap


def test_the_generated_file_is_the_configuration_and_the_map_fits_it():
    rmap = project_map()
    assert (ROOT / gen_v4.SLAVE_JSON).read_text() == gen_v4.modbus_slave_json(rmap)
    config = json.loads((ROOT / gen_v4.SLAVE_JSON).read_text())
    assert config["word_order"] == "high_word_first"
    diags = Diagnostics()
    gen_v4.check(rmap, diags, config)
    assert diags.items == []
    located = [s for s in rmap.signals if iec_address(s)]
    assert {iec_address(s)[1:3] for s in located} >= {"QX", "IX", "QW", "MW", "MD"}   # every area checked


def test_with_v3s_counts_every_address_is_v3s():
    config = gen_v4.slave_config()
    for table, top in (("holding_register", 4096), ("input_register", 1024), ("coil", 800),
                       ("discrete_input", 800)):
        for address in range(top):
            want = iec_address(Signal(0, "S", table, address, "INT", "output", ""))
            assert gen_v4.served_as(table, address, config) == want, (table, address)
    assert gen_v4.served_as("holding_register", 2049, config) is None          # second word of %MD0
    assert gen_v4.served_as("holding_register", 4096, config) == "%ML0"
    assert gen_v4.served_as("holding_register", 4096 + 4 * 1024, config) is None


def test_a_smaller_segment_moves_the_later_ones_and_the_check_says_where():
    rmap = project_map()
    config = gen_v4.slave_config()
    config["buffer_mapping"]["holding_registers"]["qw_count"] = 100         # %MW0 now at register 100
    assert gen_v4.served_as("holding_register", 100, config) == "%MW0"
    diags = Diagnostics()
    gen_v4.check(rmap, diags, config)
    moved = [s for s in rmap.signals if (iec_address(s) or "")[1:3] in ("MW", "MD")
             or (iec_address(s) or "")[1:3] == "QW" and s.address >= 100]    # %QW100.. no longer exist
    assert moved and len(diags.errors) == len(moved)
    first = moved[0]
    assert any(d.message.startswith(f"{first.name}: OpenPLC v4's Modbus slave") and iec_address(first) in d.message
               for d in diags.errors)


def test_a_unit_id_other_than_1_is_a_warning():
    rmap = copy.deepcopy(project_map())
    rmap.linuxcnc.slave_id = 2
    diags = Diagnostics()
    gen_v4.check(rmap, diags)
    assert [d.message for d in diags.warnings] == ["[linuxcnc] slave_id 2: OpenPLC v4's Modbus slave answers unit "
                                                   "id 1 only"]
    assert diags.errors == []
