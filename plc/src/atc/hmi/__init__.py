"""The live toolchanger page `plc hmi` (server, static/) and the register map's names for every signal
(mapinfo), on top of the toolchain's monitoring client (plc.hmi)."""
