"""What every test of the suite shares: one build cache and one set of runtime objects for all the copies of the
project the tests make (both are keyed by content, so sharing changes no result, only how often the same C is
compiled: each copy would otherwise start cold).  A test that is about where a project keeps its cache removes
PLC_CACHE_DIR from the environment it gives `plc`."""
import os
from pathlib import Path

BUILD = Path(__file__).resolve().parents[2] / "build"
os.environ.setdefault("PLC_CACHE_DIR", str(BUILD / "plc-cache"))
os.environ.setdefault("PLC_RUNTIME_OBJECTS", str(BUILD / "runtime-objects"))
