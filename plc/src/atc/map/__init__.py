"""The register map: one source (modbus_map/map.toml + reason_codes.toml), everything else generated.

    model      load the TOML sources, with the line of every key (errors as file:line)
    check      validate signals and reason codes against the OpenPLC address map
    enums      enum state names from the ST TYPE declarations of st_src/
    gen_*      one generator per output file (ST declarations, HMI tags, LinuxCNC, doc, runtime config)
    generate   every output together, the drift check, `plc map check|generate`
"""
