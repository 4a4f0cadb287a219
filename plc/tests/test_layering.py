"""Two packages, one direction: the IEC toolchain (plc) imports nothing of the tool-changer application (atc).

The contract is import-linter's (pyproject.toml, [tool.importlinter]); it reads the real imports of every module,
those inside functions included.  Beside it: no import cycle between modules, no import of a project module inside
a function (none is left to break a cycle, none is needed for speed), and the bare toolchain works with no
application installed.
"""
from __future__ import annotations

import ast
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import grimp

from code_rules import c_names, c_tokens

PLC_DIR = Path(__file__).resolve().parents[1]
SRC = PLC_DIR / "src"
REPO = PLC_DIR.parent
LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")


def lint_imports(cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([str(LINT_IMPORTS), "--no-cache"], cwd=cwd, capture_output=True, text=True, timeout=120,
                          env=env)


def test_the_toolchain_imports_nothing_of_the_application():
    r = lint_imports(PLC_DIR)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Contracts: 1 kept, 0 broken." in r.stdout, r.stdout


def test_the_contract_catches_an_import_of_the_application_even_inside_a_function(tmp_path):
    """The same contract over two small packages where the toolchain imports the application in a function body:
    import-linter reports it broken, so the test above could fail."""
    (tmp_path / "plc").mkdir()
    (tmp_path / "atc").mkdir()
    (tmp_path / "plc" / "__init__.py").write_text("")
    (tmp_path / "atc" / "__init__.py").write_text("")
    (tmp_path / "plc" / "cli.py").write_text("def main():\n    from atc import plugin\n    return plugin\n")
    (tmp_path / "atc" / "plugin.py").write_text("import plc.cli\n")
    contract = (PLC_DIR / "pyproject.toml").read_text().split("[tool.importlinter]", 1)[1]
    (tmp_path / "pyproject.toml").write_text("[tool.importlinter]" + contract)
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    r = lint_imports(tmp_path, env)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "BROKEN" in r.stdout and "plc.cli -> atc.plugin" in r.stdout, r.stdout


def strongly_connected(edges: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components of the import graph (iterative: no recursion limit)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(edges[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                out.append(sorted(comp))
    return out


def test_strongly_connected_finds_a_cycle():
    assert [c for c in strongly_connected({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) if len(c) > 1] == \
        [["a", "b", "c"]]


def test_no_import_cycle_between_modules():
    """Before the split: 3 cycles, the largest through 16 modules (machine, map, seq, freshness, testrunner)."""
    graph = grimp.build_graph("plc", "atc")
    edges = {m: graph.find_modules_directly_imported_by(m) for m in graph.modules}
    cycles = [c for c in strongly_connected(edges) if len(c) > 1]
    assert len(edges) > 90
    assert cycles == []


def test_no_project_module_is_imported_inside_a_function():
    nested = []
    for path in sorted(SRC.rglob("*.py")):
        tree = ast.parse(path.read_text())
        top = {id(n) for n in tree.body}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and id(node) not in top:
                if node.level or (node.module or "").split(".")[0] in ("plc", "atc"):
                    nested.append(f"{path.relative_to(SRC)}:{node.lineno}: {ast.unparse(node)}")
            elif isinstance(node, ast.Import) and id(node) not in top:
                nested += [f"{path.relative_to(SRC)}:{node.lineno}: import {a.name}" for a in node.names
                           if a.name.split(".")[0] in ("plc", "atc")]
    assert nested == []


BARE = textwrap.dedent("""
    import sys
    sys.modules["atc"] = None          # any import of the application fails
    from plc import extensions
    extensions.load = lambda: extensions.Extensions()
    from plc.cli import main
    sys.exit(main(sys.argv[1:]))
""")


def bare_plc(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", BARE, *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_the_bare_toolchain_checks_builds_and_tests_a_program_of_its_own(tmp_path):
    (tmp_path / "st_src").mkdir()
    (tmp_path / "iec_tests").mkdir()
    (tmp_path / "st_src" / "Counter.st").write_text(textwrap.dedent("""\
        FUNCTION_BLOCK FB_Counter
        VAR_INPUT up : BOOL; END_VAR
        VAR_OUTPUT n : INT; END_VAR
        VAR edge : R_TRIG; END_VAR
        edge(CLK := up);
        IF edge.Q THEN n := n + 1; END_IF;
        END_FUNCTION_BLOCK
        PROGRAM Main
        VAR c : FB_Counter; END_VAR
        c(up := TRUE);
        END_PROGRAM
        CONFIGURATION Config0
          RESOURCE Res0 ON PLC
            TASK t(INTERVAL := T#10ms, PRIORITY := 0);
            PROGRAM inst0 WITH t : Main;
          END_RESOURCE
        END_CONFIGURATION
        """))
    (tmp_path / "iec_tests" / "TEST_Counter.st").write_text(textwrap.dedent("""\
        FUNCTION_BLOCK TEST_TheCounterCountsRisingEdges
        VAR_IN_OUT tc : ST_TestContext; END_VAR
        VAR c : FB_Counter; END_VAR
        c(up := TRUE); c(up := FALSE); c(up := TRUE);
        tc.Ok := AssertEqualINT(tc, 2, c.n, 'two rising edges');
        tc.Done := TRUE;
        END_FUNCTION_BLOCK
        """))
    helped = bare_plc("--help", cwd=tmp_path)
    assert helped.returncode == 0, helped.stderr
    commands = helped.stdout.split("positional arguments:")[1]
    assert "check" in commands and "monitor" in commands
    assert not any(f"    {name} " in commands for name in ("machine", "seq", "map", "host", "deploy", "hmi"))
    checked = bare_plc("check", "st_src", cwd=tmp_path)
    assert checked.returncode == 0 and "clean" in checked.stderr, checked.stderr
    built = bare_plc("build", "st_src", "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert built.returncode == 0 and (tmp_path / "out" / "program.o").is_file(), built.stderr
    tested = bare_plc("test", cwd=tmp_path)
    assert tested.returncode == 0 and tested.stdout.strip().endswith("1 passed, 0 failed"), \
        tested.stdout + tested.stderr
    unknown = bare_plc("machine", "check", cwd=tmp_path)
    assert unknown.returncode == 2 and "invalid choice: 'machine'" in unknown.stderr


def test_the_application_registers_its_commands_and_checks_through_the_hook():
    from plc import extensions
    ext = extensions.load()
    assert any(s.startswith("atc (atc.plugin:register)") for s in ext.sources)
    assert set(ext.commands) == {"seq", "map", "host", "tools", "deploy", "hmi"}
    assert ext.preflight and ext.run_setup and ext.parsers


def application_names_in_c(text: str, name: str, signals: set[str], addresses: set[str]) -> list[str]:
    """The application's signal names a C source uses as code (an identifier, a word of a string literal), and the
    signal addresses its string literals hold; comments are not code (C tokens, code_rules.c_tokens)."""
    tokens = c_tokens(text, name)
    strings = [t.text for t in tokens if t.kind == "string"]
    return [f"{name}: {n}" for n in sorted(signals & c_names(tokens))] + \
        [f"{name}: the address {a}" for a in sorted(addresses) if any(a in s for s in strings)]


def test_the_c_runtime_names_no_signal_of_the_application():
    """The runtime learns the application's signals from what `plc run` hands it (--events FILE, --sim-flag) and
    links the application's events from the application's package (atc/native/events.c)."""
    from atc.host.tags import load_map
    # ForcesActive is the runtime's own status input (runtime.h, FORCES_ACTIVE_BIT), which the map shows
    names = {s.name for s in load_map(REPO / "modbus_map" / "map.toml").signals} - {"ForcesActive"}
    sim = load_map(REPO / "modbus_map" / "map.toml").signal("SimulatedPlant")
    assert len(names) > 50 and sim is not None
    native = SRC / "plc" / "native"
    address = f"%IX{sim.address // 8}.{sim.address % 8}"
    found = []
    for path in sorted([*native.rglob("*.c"), *native.rglob("*.h")]):
        found += application_names_in_c(path.read_text(), str(path.relative_to(SRC)), names, {address})
    assert found == []
    assert (SRC / "atc" / "native" / "events.c").is_file()


def test_the_signal_rule_flags_a_signal_in_code_or_a_string_and_not_in_a_comment():
    c = ("/* ToolInSpindle and %IX49.7 are the application's; a comment may say so */\n"
         "static int ToolInSpindleCopy;   // a longer name is another name\n"
         'static const char *flag = "--sim-flag %IX49.7";\n'
         "static int ToolInSpindle;\n"
         'static void say(void) { log_msg("CarouselHomed went TRUE"); }\n')
    assert application_names_in_c(c, "x.c", {"ToolInSpindle", "CarouselHomed", "SimEStop"}, {"%IX49.7"}) == \
        ["x.c: CarouselHomed", "x.c: ToolInSpindle", "x.c: the address %IX49.7"]
    assert application_names_in_c(c.split("\n")[0], "x.c", {"ToolInSpindle"}, {"%IX49.7"}) == []
