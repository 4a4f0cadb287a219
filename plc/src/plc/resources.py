"""Where the toolchain finds the files it ships: the one place that knows the package layout.

Everything below is package data (see pyproject.toml), so an installed `plc` (wheel or editable) finds the
ST standard library, the ABI headers and the runtime's C sources beside its own modules; nothing reaches
outside the package with relative `parents[...]` hops.
"""
from __future__ import annotations

from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
STDLIB = PACKAGE / "stdlib"                      # ST and C of the standard library, the ST test library
STANDARD_FBS = STDLIB / "standard_fbs.st"        # the standard function blocks (TON, R_TRIG, CTU, ...) in ST
TESTLIB = STDLIB / "testing"                     # what a `plc test` build adds: ST_TestContext, the ASSERT_ functions
DATA = PACKAGE / "data"                          # reference lists (OpenPLC's reserved identifiers, ...)
NATIVE = PACKAGE / "native"
INCLUDE = NATIVE / "include"                     # plc_abi.h: the contract between generated C and every host
RUNTIME_SRC = NATIVE / "runtime"                 # the soft-PLC runtime's C sources
