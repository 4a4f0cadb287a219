"""atc-plc, the tool-changer application on top of the plc toolchain.

    machine    the machine description (machines/default/machine.toml) and everything generated from it
    map        the register map (modbus_map/): checks and generators
    seq        the tool-change sequence language: parser, checker, ST step tables
    host       `plc host`: a CNC host client speaking the register map (the iov2 host end)
    hmi        `plc hmi`: the live toolchanger page
    deploy     `plc deploy openplc|service|upgrade|rollback`
    service    the systemd service release (built by deploy)
    freshness  generated files against their sources, before `plc run` and `plc test`
    plugin     what this package adds to the `plc` command (the toolchain's plc.extensions hook)

This package imports the toolchain (plc); the toolchain never imports it (tests/test_layering.py).
"""
