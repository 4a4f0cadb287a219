"""Seeing and driving the running PLC: the monitoring channel's client (monitor), `plc monitor` (cli) and
`plc status` (the diagnostic block)."""
