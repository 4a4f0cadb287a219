"""`plc host`: a CNC host client speaking the register map (the iov2 host end) over raw Modbus/TCP.

    modbus    the Modbus/TCP client (socket, MBAP framing, the function codes the map needs)
    tags      signals by name: batched typed reads, grouped writes
    session   the iov2 host end: four-phase handshakes, fault handling, heartbeat, link watch
    cli       commands, the interactive prompt, exit codes
"""
