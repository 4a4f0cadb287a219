"""atc-plc toolchain: a MATIEC-compatible Structured Text compiler, test runner and runtime front end."""

__version__ = "0.1.0"
