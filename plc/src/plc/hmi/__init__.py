"""Seeing and driving the running PLC: the map's names for every signal (mapinfo), the monitoring channel's
client (monitor), `plc status` (the diagnostic block), and the live toolchanger page `plc hmi` (server)."""
