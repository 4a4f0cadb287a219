"""The compiler's stage contract: the AST declares its fields and annotations, the visitors walk the declared
children, and a node kind a pass does not handle stops the build with an internal error at its position
instead of becoming silent C."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import pytest

from harness import compile_st
from plc import ast as A
from plc.codegen import generate
from plc.diagnostics import Diagnostics, InternalError
from plc.driver import analyze, compile_sources
from plc.parser import parse

SRC = """PROGRAM Main
VAR
    n : INT;
    go : BOOL;
END_VAR
IF go THEN
    n := n + 1;
END_IF;
n := ABS(n);
END_PROGRAM
"""


@dataclass(eq=False)
class Goto(A.Stmt):
    """A statement kind no pass knows: what a new parser rule without its passes would produce."""
    label: str = ""


def main_pou(files: list[A.SourceFile]) -> A.Pou:
    return next(item for f in files for item in f.items if isinstance(item, A.Pou) and item.name == "MAIN")


def test_annotations_are_declared_fields_outside_the_constructor():
    for kind, names in ((A.Name, {"ty", "sym"}), (A.Binary, {"ty", "sym"}), (A.Arg, {"param"}),
                        (A.Call, {"ty", "sym", "target", "site", "std_args", "time_arith"})):
        annotations = {f.name for f in dataclasses.fields(kind) if A.is_annotation(f)}
        assert annotations == names, kind
        assert all(not f.init for f in dataclasses.fields(kind) if f.name in names)
    call = A.Call(A.Pos("t.st", 1, 1), "ABS", [])
    assert (call.ty, call.target, call.site, call.std_args, call.time_arith) == (None, None, -1, [], False)


def test_semantic_passes_fill_the_annotations_code_generation_reads():
    res = compile_st(SRC, name="t.st", generate=False)
    assert res.ok, [d.message for d in res.diags.sorted()]
    body = main_pou(res.files).body
    assign = body[1]
    call = assign.value
    assert call.target is not None and call.target.name == "ABS"
    assert call.std_args == [call.args[0].value]
    assert call.ty is not None and call.ty.name == "INT"
    assert assign.target.sym.name == "N"


def test_the_generic_visitor_walks_declared_children_and_skips_annotations():
    diags = Diagnostics()
    f = parse(SRC, "t.st", diags)

    class Names(A.NodeVisitor):
        def __init__(self):
            self.seen = []

        def visit_Name(self, node):
            self.seen.append((node.name, node.pos.line))

    v = Names()
    v.visit(f)
    assert v.seen == [("GO", 6), ("N", 7), ("N", 7), ("N", 9), ("N", 9)]
    kinds = [type(n).__name__ for n in A.walk(main_pou([f]))]
    assert kinds.count("Assign") == 2 and kinds.index("If") < kinds.index("Assign")


def test_dispatch_on_the_node_kind_names_the_unhandled_kind_and_its_position():
    class OnlyPous:
        def d_Pou(self, node):
            return node.name

    pou = main_pou([parse(SRC, "t.st", Diagnostics())])
    assert A.handler(OnlyPous(), "d_", pou, "the declarations pass")(pou) == "MAIN"
    with pytest.raises(InternalError) as exc:
        A.handler(OnlyPous(), "d_", Goto(A.Pos("t.st", 3, 5)), "the declarations pass", "the item")
    assert str(exc.value) == "t.st:3:5: internal compiler error: the declarations pass does not handle the item Goto"


def test_every_statement_and_expression_kind_has_its_method_in_each_pass_that_dispatches_on_it():
    """What `handler` would stop a build for at run time, found here for the kinds ast.py declares."""
    from plc.codegen import Gen
    from plc.passes.expressions import ExpressionTyping
    from plc.passes.statements import StatementPass
    kinds = [c for c in vars(A).values() if isinstance(c, type) and issubclass(c, A.Node)]
    stmts = [c for c in kinds if issubclass(c, A.Stmt) and c is not A.Stmt]
    exprs = [c for c in kinds if issubclass(c, A.Expr) and c is not A.Expr]
    # semantic analysis refuses these with an error, so the C generator never meets them
    refused = {"Deref", "Direct"}
    missing = [(cls.__name__, prefix + k.__name__)
               for cls, prefix, family in ((StatementPass, "s_", stmts), (Gen, "s_", stmts),
                                           (ExpressionTyping, "t_", exprs), (Gen, "x_", exprs))
               for k in family if not hasattr(cls, prefix + k.__name__)
               and not (cls is Gen and k.__name__ in refused)]
    assert len(stmts) >= 10 and len(exprs) >= 15
    assert missing == []


def test_names_and_calls_resolve_to_the_typed_symbols_of_symbols_py():
    from plc.stdfuncs import StdFunc
    from plc.symbols import CURRENT_TIME, EN, ENO, BuiltinSym, ConversionSym, EnumValueSym, FuncSym, VarSym
    src = ("TYPE E_Mode : (Idle, Moving); END_TYPE\n"
           "FUNCTION F_Next : E_Mode\nVAR_INPUT m : E_Mode; END_VAR\n"
           "IF m = E_Mode#Idle THEN F_Next := Moving; ELSE F_Next := Idle; END_IF;\nENO := TRUE;\nEND_FUNCTION\n"
           "FUNCTION_BLOCK FB_Gate\nVAR_INPUT go : BOOL; END_VAR\nVAR_OUTPUT open : BOOL; END_VAR\n"
           "open := go AND EN;\nEND_FUNCTION_BLOCK\n"
           "PROGRAM Main\nVAR m : E_Mode; d : DINT; n : INT; g : FB_Gate; END_VAR\n"
           "m := F_Next(m);\nd := INT_TO_DINT(ABS(n));\ng(go := m = Moving);\nEND_PROGRAM\n")
    res = compile_st(src, name="t.st", generate=False)
    assert res.ok, [d.message for d in res.diags.sorted()]
    nodes = [n for f in res.files for n in A.walk(f)]
    syms = [n.sym for n in nodes if isinstance(n, A.Expr) and n.sym is not None]
    targets = [n.target for n in nodes if isinstance(n, A.Call) and n.target is not None]
    assert {type(s) for s in syms} == {VarSym, FuncSym, EnumValueSym, BuiltinSym}
    assert {type(t) for t in targets} == {FuncSym, StdFunc, ConversionSym, VarSym}
    builtins = [s for s in syms if isinstance(s, BuiltinSym)]
    assert {id(s) for s in builtins} == {id(EN), id(ENO), id(CURRENT_TIME)}      # one object each
    values = {(s.type.name, s.value, s.index) for s in syms if isinstance(s, EnumValueSym)}
    assert {("E_MODE", "IDLE", 0), ("E_MODE", "MOVING", 1)} <= values
    (conv,) = [t for t in targets if isinstance(t, ConversionSym)]
    assert (conv.src.name, conv.dst.name) == ("INT", "DINT")


def test_an_unhandled_statement_kind_stops_semantic_analysis_at_its_position():
    diags = Diagnostics()
    files = [parse(SRC, "t.st", diags)]
    main_pou(files).body.append(Goto(A.Pos("t.st", 9, 1)))
    with pytest.raises(InternalError) as exc:
        analyze(files, diags)
    assert exc.value.pos == A.Pos("t.st", 9, 1)
    assert "does not handle the statement Goto" in str(exc.value)


def test_an_unhandled_statement_kind_stops_code_generation_instead_of_compiling_to_nothing():
    res = compile_st(SRC, name="t.st", generate=False)
    assert res.ok
    main_pou(res.files).body.insert(0, Goto(A.Pos("t.st", 6, 1)))
    with pytest.raises(InternalError) as exc:
        generate(res.program)
    assert exc.value.pos == A.Pos("t.st", 6, 1)
    assert "the C generator does not handle the statement Goto" in str(exc.value)


def test_an_unresolved_expression_stops_code_generation_instead_of_compiling_to_zero():
    res = compile_st(SRC, name="t.st", generate=False)
    assert res.ok
    cond = main_pou(res.files).body[0].branches[0][0]
    cond.sym = None                         # what a pass that forgot to resolve the name would leave
    with pytest.raises(InternalError) as exc:
        generate(res.program)
    assert exc.value.pos == A.Pos("t.st", 6, 4)
    assert "name GO reached the C generator unresolved" in str(exc.value)


def test_every_standard_function_carries_its_c_emitter_beside_its_signature():
    from plc.stdfuncs import STD_FUNCS
    missing = [name for name, f in STD_FUNCS.items() if f.emit is None]
    assert missing == []


def test_a_standard_function_without_an_emitter_stops_code_generation_at_the_call():
    res = compile_st(SRC, name="t.st", generate=False)
    assert res.ok
    call = main_pou(res.files).body[1].value
    call.target = dataclasses.replace(call.target, emit=None)
    with pytest.raises(InternalError) as exc:
        generate(res.program)
    assert exc.value.pos == A.Pos("t.st", 9, 6)
    assert "standard function ABS has no C emitter" in str(exc.value)


def test_a_recorded_portability_fact_becomes_the_rules_warning():
    res = compile_st("PROGRAM Main\nVAR t : TIME; END_VAR\nt := T#5us;\nEND_PROGRAM\n", name="t.st", generate=False)
    (w,) = [d for d in res.diags.warnings if d.code == "portability.time-unit"]
    assert (w.pos.line, w.pos.col) == (3, 6)
    assert w.message == "portability: 'us'/'ns' units in TIME literals are rejected by OpenPLC's MATIEC"
    assert w.hint == "write fractions of ms, e.g. T#1.5ms"


# positional calls of a FUNCTION and an FB, conversions with EN/ENO, TIME literals: what the passes once rewrote
REBOUND = """FUNCTION F_Scale : INT
VAR_INPUT k : INT; f : INT; END_VAR
F_Scale := k * f;
END_FUNCTION
PROGRAM P_Rebound
VAR
    n : INT;
    d : DINT;
    ok : BOOL;
    t : TIME := T#1s500ms;
    tmr : TON;
END_VAR
n := F_Scale(3, n);
d := INT_TO_DINT(ENO => ok, EN := n > 0, IN := n);
tmr(n > 2, T#20ms);
t := t + T#2ms;
END_PROGRAM
"""


def syntax_of(files: list[A.SourceFile]) -> list[tuple[A.Node, tuple]]:
    """Every node with what its syntax fields hold (child nodes by identity)."""
    def held(v):
        if isinstance(v, A.Node):
            return id(v)
        if isinstance(v, (list, tuple)):
            return type(v).__name__, tuple(held(x) for x in v)
        return v
    def kept(f: A.SourceFile, v) -> bool:
        return not (isinstance(v, A.Pos) and f.path.lower().endswith(".xml#st"))
    return [(n, tuple((k, held(v)) for k, v in A.child_fields(n) if kept(f, v))) for f in files for n in A.walk(f)]


def test_after_the_parser_no_stage_writes_a_syntax_field_or_an_undeclared_attribute(tmp_path, monkeypatch):
    """Compiling the project's library and its tests (and REBOUND) to C: the semantic passes, the portability
    pass and the C generator fill annotations only, the syntax fields stay as the parser wrote them (but for
    the positions of a PLCopen project, moved into its XML: ast.py says so), and no node carries an attribute
    its class does not declare."""
    from pathlib import Path

    from plc import driver
    root = Path(__file__).resolve().parents[2]
    (tmp_path / "rebound.st").write_text(REBOUND)
    parsed = []
    analyze = driver.analyze

    def analyze_after_noting_the_syntax(files, *args, **kw):
        parsed.extend(syntax_of(files))
        return analyze(files, *args, **kw)

    monkeypatch.setattr(driver, "analyze", analyze_after_noting_the_syntax)
    res = compile_sources([root / "st_src", root / "iec_tests", tmp_path / "rebound.st"], test_build=True)
    assert res.ok and res.c_text
    now = dict((id(n), fields) for n, fields in syntax_of(res.files))
    changed = [(type(n).__name__, n.pos, fields, now.get(id(n))) for n, fields in parsed if now.get(id(n)) != fields]
    assert changed == []
    assert len(now) == len(parsed) > 10_000
    assert any(isinstance(n, A.TimeLit) and n.value == 1_500_000_000 for n, _f in parsed)
    undeclared = set()
    for f in res.files:
        for node in A.walk(f):
            declared = {fl.name for fl in dataclasses.fields(node)}
            undeclared |= {(type(node).__name__, k) for k in vars(node) if k not in declared}
    assert undeclared == set()


def test_an_internal_error_reaches_the_command_line_as_exit_3_with_its_position_and_no_traceback(
        tmp_path, monkeypatch, capsys):
    from plc import cli, driver

    def broken(*_args, **_kw):
        raise InternalError(A.Pos("t.st", 4, 2), "the C generator does not handle the statement Goto")

    monkeypatch.setattr(driver, "compile_sources", broken)
    monkeypatch.setattr(cli, "compile_sources", broken)
    src = tmp_path / "t.st"
    src.write_text(SRC)
    assert cli.main(["check", str(src)]) == 3
    err = capsys.readouterr().err
    assert err.startswith("t.st:4:2: internal compiler error: the C generator does not handle the statement Goto")
    assert "bug of the compiler" in err and "Traceback" not in err


GOOD = SRC + ("CONFIGURATION Config0\nRESOURCE Res0 ON PLC\nTASK t0(INTERVAL := T#4ms, PRIORITY := 0);\n"
               "PROGRAM i0 WITH t0 : Main;\nEND_RESOURCE\nEND_CONFIGURATION\n")


def test_c_that_the_c_compiler_rejects_is_an_internal_error_exit_3_keeping_the_c_and_the_compiler_output(
        tmp_path, monkeypatch, capsys):
    """plc build runs $CC on the C it generated; a failure there is a bug of plc, not a problem of the program."""
    from plc import cli
    fake_cc = tmp_path / "fake-cc"
    fake_cc.write_text("#!/bin/sh\necho 'program.c:7:3: error: the fake compiler refuses this' >&2\nexit 1\n")
    fake_cc.chmod(0o755)
    monkeypatch.setenv("CC", str(fake_cc))
    src, out = tmp_path / "t.st", tmp_path / "out"
    src.write_text(GOOD)
    assert cli.main(["build", str(src), "--out", str(out)]) == 3
    err = capsys.readouterr().err
    c_file, log = out / "program.c", out / "program.cc.log"
    assert err.startswith("plc: internal compiler error: the C compiler rejected the C generated for the program:\n"
                          "  program.c:7:3: error: the fake compiler refuses this\n")
    assert f"the generated C is kept in {c_file}, the C compiler's output in {log}" in err
    assert "bug of the compiler, not of your program" in err and "Traceback" not in err
    assert "plc_program" in c_file.read_text()
    kept = log.read_text()
    assert kept.startswith(f"$ {fake_cc} ") and str(c_file) in kept.splitlines()[0]
    assert "the fake compiler refuses this" in kept
    assert not (out / "program.o").exists()


def test_the_c_generator_writes_the_unit_in_its_final_order():
    """The C of a build is the generator's buffer as written, nothing edited afterwards: the assertion hook of a
    test build right after the include, every file-scope definition `static PLC_UNUSED` (or `static inline`),
    the site table last, once every site is numbered."""
    from plc.codegen import Gen
    src = GOOD.replace("go : BOOL;", "go : BOOL;\n    a : ARRAY[0..3] OF INT;").replace("n := ABS(n);",
                                                                                      "n := ABS(n);\na[n] := 1;")
    unit = compile_st(src, name="t.st", test_build=True).c_text
    res = compile_st(src, name="t.st", generate=False, test_build=True)
    gen = Gen(res.program, test_build=True)
    assert gen.generate() == unit == "\n".join(gen.out) + "\n"
    lines = unit.splitlines()
    assert lines[lines.index('#include "plc_rt.h"') + 1].startswith("static inline uint8_t plc_assert_done(")
    assert [ln for ln in lines if ln.startswith("static ")
            and not ln.startswith(("static inline ", "static PLC_UNUSED "))] == []
    sites = res.program.sites
    assert any(s.pos.file == "t.st" for s in sites)            # a[n]: an index the C checks at run time
    assert lines[-1] == f"const uint32_t plc_n_sites = {len(sites)}u;"


def test_plc_help_names_the_exit_codes(capsys):
    from plc import cli
    help_text = " ".join(cli.parser().format_help().split())
    assert "Exit codes: 0 success; 1 the input has errors, or tests failed; 2 usage or environment" in help_text
    assert "3 an internal compiler error, a bug of plc" in help_text


def test_the_stages_record_facts_and_only_the_portability_pass_warns():
    """Lexer, parser and semantic passes record portability facts; the warnings appear in the portability pass."""
    from plc import portability
    text = ("// a comment MATIEC rejects\nVAR_GLOBAL g : INT; END_VAR\n"
            "PROGRAM Main\nVAR t : TIME; END_VAR\nt := T#5us;\nEND_PROGRAM\n")
    diags = Diagnostics()
    tree = parse(text, "t.st", diags)
    assert [(f.rule, f.pos.line, f.pos.col) for f in tree.facts] == [("comment-line", 1, 1), ("global", 2, 1)]
    prog = analyze([tree], diags)
    assert [(f.rule, f.pos.line, f.pos.col) for f in prog.facts] == [("time-unit", 5, 6)]
    assert diags.warnings == [], "no stage before the portability pass writes a warning"
    portability.lint([tree], prog, diags, set())
    got = [(d.code, d.pos.line, d.pos.col) for d in diags.warnings]
    assert got[:3] == [("portability.comment-line", 1, 1), ("portability.global", 2, 1),
                       ("portability.time-unit", 5, 6)]


def test_each_semantic_pass_is_a_class_of_its_own_module_run_by_name():
    """No mixin analyzer: driver.SEMANTIC_PASSES names the passes, each a Pass subclass in its own module,
    sharing one SemanticState."""
    from plc import driver, sema
    from plc.passes.context import Pass, SemanticState
    assert list(driver.SEMANTIC_PASSES) == list(sema.PASSES)
    classes = [*sema.PASSES.values(), *sema.HELPERS.values()]
    assert all(cls.__bases__ == (Pass,) for cls in classes)
    assert len({cls.__module__ for cls in classes}) == len(classes)
    diags = Diagnostics()
    files = [parse("PROGRAM Main\nVAR n : INT; END_VAR\nn := n + 1;\nEND_PROGRAM\n", "t.st", diags)]
    prog = sema.analyze(files, diags, driver.SEMANTIC_PASSES)
    assert not diags.items and prog.pous["MAIN"].scope.vars["N"].type.name == "INT"
    # the passes' shared state is one object; a pass's own working state stays with the pass
    st = SemanticState(files, Diagnostics())
    assert not hasattr(st, "resolving") and not hasattr(st, "loop")


def test_plc_run_c_that_the_c_compiler_rejects_in_the_program_is_an_internal_error_exit_3(
        tmp_path, monkeypatch, capsys):
    """plc run compiles the runtime with the C plc generated: an error the C compiler places in that program.c is
    plc's bug (exit 3, the C and the output kept); an error elsewhere (a missing libmodbus) stays exit 1/2."""
    from plc import cli
    fake_cc = tmp_path / "fake-cc"
    fake_cc.write_text("#!/bin/sh\n"
                       "case \"$*\" in *--version*|*-MM*) exec gcc \"$@\";; esac\n"
                       "for a in \"$@\"; do case \"$a\" in *program.c) prog=$a;; esac; done\n"
                       "[ -n \"$prog\" ] || exec gcc \"$@\"\n"
                       "echo \"$prog:5:2: error: the fake compiler refuses this\" >&2\nexit 1\n")
    fake_cc.chmod(0o755)
    monkeypatch.setenv("CC", str(fake_cc))
    monkeypatch.chdir(tmp_path)
    src, out = tmp_path / "t.st", tmp_path / "out"
    src.write_text(GOOD)
    assert cli.main(["run", str(src), "--build-dir", str(out)]) == 3
    err = capsys.readouterr().err
    c_file = out / "program" / "program.c"
    assert "internal compiler error: the C compiler rejected the C generated for the program" in err, err
    assert f"{c_file}:5:2: error: the fake compiler refuses this" in err
    assert "bug of the compiler, not of your program" in err and "Traceback" not in err
    log = c_file.with_suffix(".cc.log")
    assert log.read_text().startswith(f"$ {fake_cc} ") and "the fake compiler refuses this" in log.read_text()


def test_plc_run_a_build_error_outside_the_program_is_not_called_a_compiler_bug(tmp_path, monkeypatch, capsys):
    from plc import cli
    fake_cc = tmp_path / "fake-cc"
    fake_cc.write_text("#!/bin/sh\n"
                       "case \"$*\" in *--version*|*-MM*) exec gcc \"$@\";; esac\n"
                       "echo 'main.c:1:10: fatal error: modbus.h: No such file or directory' >&2\nexit 1\n")
    fake_cc.chmod(0o755)
    monkeypatch.setenv("CC", str(fake_cc))
    monkeypatch.chdir(tmp_path)
    src = tmp_path / "t.st"
    src.write_text(GOOD)
    assert cli.main(["run", str(src), "--build-dir", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "modbus.h: No such file" in err and "hint: install the Debian packages" in err
    assert "bug of the compiler" not in err and "Traceback" not in err
