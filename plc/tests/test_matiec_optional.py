"""Optional cross-check: does the real MATIEC accept our ST, run the way OpenPLC v3 runs it?

Our compiler is meant to accept exactly the portable subset of ST (docs/matiec.md).  These tests hand the
project's ST to the reference compiler when the user has one installed, so a portability slip shows up here and
not on a customer's OpenPLC:

    IEC2C=/path/to/iec2c                         OpenPLC_v3's fork of MATIEC (utils/matiec_src), built locally
    IEC2C_LIB=/path/to/OpenPLC_v3/webserver/lib  the IEC library iec2c reads (ieclib.txt and friends)
    IEC2C_CINCLUDE=/path/to/OpenPLC_v3/webserver/core/lib   optional: also compile the generated C like OpenPLC

Without IEC2C the tests are skipped and say why (see `pytest -rs`).  Nothing from MATIEC or OpenPLC is stored
in this repository; the tests only run a compiler the user points at.

How OpenPLC v3 compiles (webserver/scripts/compile_program.sh): one .st file, from the directory that holds the
library folder `lib/`, with `iec2c -f -l -p -r -R -a <file>`; it then needs Config0.c and Res0.c and builds them
with `g++ -std=gnu++11 -I ./lib -c <file> -w` inside webserver/core.  We do the same in a temporary directory.
"""

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
ST_SRC = REPO / "st_src"
SRC = REPO / "plc" / "src"
IEC_TESTS = REPO / "iec_tests"
IEC2C_FLAGS = ["-f", "-l", "-p", "-r", "-R", "-a"]
PROGRAM_PATH = "./st_files/program.st"
TIMEOUT_S = 120

# OpenPLC needs exactly Config0/Res0.  Added only when the sources have no CONFIGURATION of their own, so that
# iec2c emits Config0.c and Res0.c (every POU body is generated whether or not it is instantiated).
STUB_CONFIGURATION = """
PROGRAM MatiecOracleStub
VAR
    toggle : BOOL;
END_VAR
toggle := NOT toggle;
END_PROGRAM

CONFIGURATION Config0
    RESOURCE Res0 ON PLC
        TASK MainTask(INTERVAL := T#4ms, PRIORITY := 0);
        PROGRAM OracleStubInstance WITH MainTask : MatiecOracleStub;
    END_RESOURCE
END_CONFIGURATION
"""

ASSERT_TYPES = ["BOOL", "SINT", "INT", "DINT", "LINT", "USINT", "UINT", "UDINT", "BYTE", "WORD", "DWORD", "TIME"]


def _reference_compiler():
    """(iec2c, library dir) from the environment, or skip with the reason."""
    iec2c = os.environ.get("IEC2C")
    if not iec2c:
        pytest.skip("IEC2C not set: point IEC2C at OpenPLC_v3's iec2c and IEC2C_LIB at OpenPLC_v3/webserver/lib "
                    "to cross-check st_src/ against the real MATIEC")
    library = os.environ.get("IEC2C_LIB")
    if not library:
        pytest.skip("IEC2C_LIB not set: it must name OpenPLC_v3/webserver/lib (the folder holding ieclib.txt)")
    iec2c_path, library_path = Path(iec2c), Path(library)
    if not (iec2c_path.is_file() and os.access(iec2c_path, os.X_OK)):
        pytest.fail(f"IEC2C={iec2c} is not an executable file")
    if not (library_path / "ieclib.txt").is_file():
        pytest.fail(f"IEC2C_LIB={library} has no ieclib.txt; expected OpenPLC_v3/webserver/lib")
    return iec2c_path, library_path


def _st_files(*folders):
    """The sources of the folders: ST, and the PLCopen XML our compiler translates (a ladder FB)."""
    files = []
    for folder in folders:
        files.extend(sorted(p for p in folder.rglob("*") if p.suffix.lower() in (".st", ".xml")))
    return files


def _strip_comments(text):
    return re.sub(r"\(\*.*?\*\)", " ", text, flags=re.S)


def _has_configuration(text):
    return re.search(r"^\s*CONFIGURATION\b", _strip_comments(text), flags=re.M | re.I) is not None


class CombinedSource:
    """Several .st files joined into one program text, remembering where each line came from."""

    def __init__(self):
        self.text = ""
        self.origins = []          # origins[n - 1] = (file label, line in that file) for combined line n

    def add(self, label, text, first_line=1):
        if not text.endswith("\n"):
            text += "\n"
        for number in range(first_line, first_line + text.count("\n")):
            self.origins.append((label, number))
        self.text += text

    def explain(self, message):
        """Rewrite iec2c's `program.st:LINE-COL..LINE-COL` positions as `file:line:col` (the start)."""
        def where(match):
            line, column = int(match.group(1)), match.group(2)
            if 1 <= line <= len(self.origins):
                label, original = self.origins[line - 1]
                return f"{label}:{original}:{column}"
            return match.group(0)
        return re.sub(r"\S*program\.st:(\d+)-(\d+)(?:\.\.\d+-\d+)?", where, message)


def _combine(files, prelude=None):
    """The files as one program the way `plc deploy openplc` joins them (atc.deploy: PLCopen XML translated to ST,
    TYPEs first, each after the types it uses, then the POUs), each line remembering its file and line."""
    from atc.deploy import order, split_items
    from plc.diagnostics import Diagnostics
    from plc.driver import SourceSet, load_user_file
    source = CombinedSource()
    if prelude:
        source.add("<stub test prelude>", prelude)
    items = []
    for path in files:
        diags = Diagnostics()
        name, text, _translation = load_user_file(path, diags, SourceSet())
        assert text is not None and not diags.has_errors(), [d.render() for d in diags.sorted()]
        items += [(it, str(path.relative_to(REPO))) for it in split_items(name, text, Diagnostics())]
    by_item = {id(it): label for it, label in items}
    for it in order([it for it, _label in items]):
        source.add(by_item[id(it)], it.text, first_line=it.first_line)
    if not _has_configuration(source.text):
        source.add("<stub configuration>", STUB_CONFIGURATION)
    return source


def _run_iec2c(source, workdir):
    """Run iec2c as OpenPLC does; return (completed process, folder holding the generated files)."""
    iec2c, library = _reference_compiler()
    (workdir / "st_files").mkdir(parents=True)
    (workdir / "st_files" / "program.st").write_text(source.text, encoding="utf-8")
    os.symlink(library, workdir / "lib", target_is_directory=True)
    result = subprocess.run([str(iec2c), *IEC2C_FLAGS, PROGRAM_PATH], cwd=workdir, capture_output=True,
                            text=True, timeout=TIMEOUT_S)
    return result, workdir


def _assert_accepted(result, source):
    output = source.explain((result.stdout + result.stderr).strip())
    if result.returncode < 0:
        pytest.fail(f"iec2c crashed (signal {-result.returncode}) on the combined sources:\n{output}")
    assert result.returncode == 0, f"iec2c rejected the combined sources:\n{output}"


def _compile_generated_c(workdir):
    """Compile Config0.c and Res0.c with OpenPLC's headers and flags; skip when they are not available."""
    include = os.environ.get("IEC2C_CINCLUDE")
    if not include:
        pytest.skip("IEC2C_CINCLUDE not set: point it at OpenPLC_v3/webserver/core/lib to compile the generated C")
    if not (Path(include) / "iec_std_lib.h").is_file():
        pytest.fail(f"IEC2C_CINCLUDE={include} has no iec_std_lib.h; expected OpenPLC_v3/webserver/core/lib")
    compiler = shutil.which("g++")
    if compiler is None:
        pytest.skip("g++ not found: OpenPLC compiles the generated code with g++ -std=gnu++11")
    core = workdir / "core"
    core.mkdir()
    for name in ("POUS.c", "POUS.h", "LOCATED_VARIABLES.h", "VARIABLES.csv", "Config0.c", "Config0.h", "Res0.c"):
        assert (workdir / name).is_file(), f"iec2c did not write {name} (OpenPLC moves it into core/)"
        shutil.move(workdir / name, core / name)
    os.symlink(include, core / "lib", target_is_directory=True)
    # OpenPLC's headers include "../c_blocks.h", an empty placeholder in OpenPLC's core/ folder.
    (core / "c_blocks.h").write_text("")
    for unit in ("Config0.c", "Res0.c"):
        result = subprocess.run([compiler, "-std=gnu++11", "-I", "./lib", "-c", unit, "-w"], cwd=core,
                                capture_output=True, text=True, timeout=TIMEOUT_S)
        errors = "\n".join(line for line in result.stderr.splitlines() if "error" in line)
        assert result.returncode == 0, f"g++ rejected the C that iec2c generated from {unit}:\n{errors}"


def _stub_test_prelude():
    """ST_TestContext and the assertion functions as COMMON.md describes them, for when the repository does not
    ship them as ST (the test runner may provide them itself).  Only their interfaces matter to iec2c."""
    parts = ["""TYPE
    ST_TestContext : STRUCT
        Scan : UDINT;
        Now : TIME;
        CycleTime : TIME := T#4ms;
        Budget : UDINT := 100000;
        Advance : TIME;
        Done : BOOL;
        Ok : BOOL := TRUE;
        Failures : UDINT;
        Message : STRING;
    END_STRUCT;
END_TYPE
"""]

    def assertion(name, passed, inputs):
        return (f"FUNCTION {name} : BOOL\nVAR_IN_OUT\n    tc : ST_TestContext;\nEND_VAR\n"
                f"VAR_INPUT\n    {inputs}\n    msg : STRING;\nEND_VAR\n{name} := {passed};\n"
                f"IF NOT {name} THEN\n    tc.Failures := tc.Failures + 1;\n    tc.Message := msg;\nEND_IF;\n"
                f"END_FUNCTION\n")

    parts.append(assertion("AssertTrue", "cond", "cond : BOOL;"))
    parts.append(assertion("AssertFalse", "NOT cond", "cond : BOOL;"))
    for type_name in ASSERT_TYPES:
        parts.append(assertion(f"AssertEqual{type_name}", "expected = actual",
                               f"expected : {type_name}; actual : {type_name};"))
    for type_name in ("REAL", "LREAL"):
        parts.append(assertion(f"AssertNear{type_name}", "ABS(expected - actual) <= tolerance",
                               f"expected : {type_name}; actual : {type_name}; tolerance : {type_name};"))
    parts.append("FUNCTION Fail : BOOL\nVAR_IN_OUT\n    tc : ST_TestContext;\nEND_VAR\nVAR_INPUT\n    msg : STRING;\n"
                 "END_VAR\ntc.Failures := tc.Failures + 1;\ntc.Message := msg;\nFail := FALSE;\nEND_FUNCTION\n")
    return "\n".join(parts)


def _enum_asserts(files):
    """The AssertEqual_<Enum> functions `plc test` generates for the enumerations of these files."""
    from plc.diagnostics import Diagnostics
    from plc.driver import enum_asserts
    from plc.parser import parse
    trees = [parse(path.read_text(encoding="utf-8"), str(path), Diagnostics())
             for path in files if path.suffix == ".st"]
    return enum_asserts(trees)


def _repository_defines_test_context(files):
    pattern = re.compile(r"\bST_TestContext\s*:\s*STRUCT\b", re.I)
    return any(pattern.search(_strip_comments(path.read_text(encoding="utf-8"))) for path in files)


def test_reference_compiler_is_strict_like_openplc(tmp_path):
    """Guard: the configured iec2c must reject a FUNCTION call used as a statement, as OpenPLC's fork does with
    these flags; otherwise an 'accepted' below would prove nothing."""
    source = CombinedSource()
    source.add("<probe>", """FUNCTION F_Probe : BOOL
VAR_INPUT
    a : INT;
END_VAR
F_Probe := a > 0;
END_FUNCTION
""" + STUB_CONFIGURATION.replace("toggle := NOT toggle;", "toggle := NOT toggle;\nF_Probe(1);"))
    result, _ = _run_iec2c(source, tmp_path)
    output = result.stdout + result.stderr
    assert result.returncode != 0, "iec2c accepted a function call used as a statement; is this OpenPLC's MATIEC?"
    assert "not allowed outside an expression" in output, output


def test_st_src_is_accepted_by_openplc_matiec(tmp_path):
    files = _st_files(ST_SRC)
    assert files, f"no .st files under {ST_SRC}"
    source = _combine(files)
    result, _ = _run_iec2c(source, tmp_path)
    _assert_accepted(result, source)


def test_st_src_generated_c_compiles_like_openplc(tmp_path):
    files = _st_files(ST_SRC)
    assert files, f"no .st files under {ST_SRC}"
    source = _combine(files)
    result, workdir = _run_iec2c(source, tmp_path)
    _assert_accepted(result, source)
    _compile_generated_c(workdir)


def test_iec_tests_are_accepted_by_openplc_matiec(tmp_path):
    library_files = _st_files(ST_SRC)
    test_files = _st_files(IEC_TESTS)
    if not test_files:
        pytest.skip(f"no .st files under {IEC_TESTS}")
    # as `plc test` builds them: the toolchain's testing library and one typed assert per enumeration
    testing = sorted((SRC / "plc" / "stdlib" / "testing").glob("*.st"))
    files = library_files + test_files + testing
    prelude = None if _repository_defines_test_context(files) else _stub_test_prelude()
    source = _combine(files, (prelude or "") + _enum_asserts(files))
    result, workdir = _run_iec2c(source, tmp_path)
    _assert_accepted(result, source)
    if os.environ.get("IEC2C_CINCLUDE"):
        _compile_generated_c(workdir)


MACHINES = sorted(p.parent.name for p in (REPO / "machines").glob("*/machine.toml"))


@pytest.mark.parametrize("machine", MACHINES)
def test_every_machines_openplc_bundle_is_accepted_by_openplc_matiec(machine, tmp_path):
    """Issue 26: `plc deploy openplc --machine NAME` of every machine of the project, as an OpenPLC user uploads
    it, is accepted by the real MATIEC (and its C compiles like OpenPLC's when IEC2C_CINCLUDE is given)."""
    _reference_compiler()
    bundle = tmp_path / f"{machine}.st"
    deployed = subprocess.run([sys.executable, "-m", "plc.cli", "deploy", "openplc", "--machine", machine, "--out",
                               str(bundle)], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert deployed.returncode == 0, deployed.stderr
    source = CombinedSource()
    source.add(bundle.name, bundle.read_text(encoding="utf-8"))
    result, workdir = _run_iec2c(source, tmp_path / "iec2c")
    _assert_accepted(result, source)
    if os.environ.get("IEC2C_CINCLUDE"):
        _compile_generated_c(workdir)
