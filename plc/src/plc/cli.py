"""The `plc` command: the integrator's front door.

Exit codes (EXIT_CODES, also in `plc --help`): 0 success, 1 the input has errors
(or tests failed), 2 usage or environment problems, 3 an internal compiler error.
User errors never print a Python traceback.
"""
from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from importlib import import_module
from pathlib import Path

from . import __version__, buildcache, extensions, retainfile, runtime, testrunner
from .diagnostics import InternalError
from .buildcache import paused_gc
from .driver import GeneratedCError, UserError, compile_c, compile_sources, print_diagnostics
from .project import add_view_options, choose_view, project_root, refused_by_preflight, where
from .project import run_config as project_run_config


def cmd_check(args) -> int:
    t0 = time.perf_counter()
    res = compile_sources(args.paths, portability=not args.no_portability, target=args.target, generate=False,
                          test_build="auto")
    print_diagnostics(res, quiet=args.quiet)
    n_err, n_warn = len(res.diags.errors), len(res.diags.warnings)
    # checking for a deploy target, a portability warning is what that target refuses or reads otherwise: the
    # program does not deploy there as written, so the check fails
    n_target = sum(1 for d in res.diags.warnings if (d.code or "").startswith("portability.")) if args.target else 0
    if not args.quiet:
        nfiles = len([f for f in res.files if not f.path.startswith("<plc>")])
        found = f"{n_err} error(s), {n_warn} warning(s)" if n_err or n_warn else "clean"
        if n_target:
            found += f"; {n_target} portability warning(s) for --target {args.target}: not deployable as written"
        print(f"checked {nfiles} file(s): {found} in {time.perf_counter() - t0:.2f}s", file=sys.stderr)
    return 1 if n_err or n_target else 0


def use_project_cache(root: Path | None) -> None:
    """Parse results and objects from the project's build cache (build/plc-cache/, shared by plc test)."""
    buildcache.use(buildcache.project_cache(root) if root is not None else None)


def cmd_build(args) -> int:
    use_project_cache(project_root())
    with paused_gc():
        res = compile_sources(args.paths, portability=not args.no_portability, target=args.target)
    print_diagnostics(res, quiet=args.quiet)
    if not res.ok:
        print(f"build failed: {len(res.diags.errors)} error(s)", file=sys.stderr)
        return 1
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    c_file = out / "program.c"
    c_file.write_text(res.c_text)
    obj = out / "program.o"
    compile_c(c_file, obj)
    if not args.quiet:
        cfg = res.program.configs[0].name if res.program.configs else "(no CONFIGURATION)"
        print(f"built {cfg}: {c_file} and {obj}", file=sys.stderr)
    return 0


def _inside(path: str, root: Path) -> bool:
    return where(Path(path)).is_relative_to(where(root))


def run_configuration(args, root: Path | None) -> Path | None:
    """The run configuration `plc run` uses, said on stderr: --config, else the project's when every path belongs
    to the project (the one an extension names, e.g. the machine's, else configs/runtime.toml), else none
    (built-in defaults). Sets args.state_dir, where the project's run keeps its state by default."""
    inside = root is not None and all(_inside(p, root) for p in args.paths)
    project_cfg, args.state_dir = project_run_config(root) if inside else (None, None)
    if args.config is not None:
        print(f"plc run: using {args.config}", file=sys.stderr)
        return args.config
    if project_cfg is not None:
        print(f"plc run: using {project_cfg} (the project's run configuration)", file=sys.stderr)
        return project_cfg
    why = "the sources are outside the project" if root is not None and not inside else "the project has none"
    state = args.state_dir / runtime.DEFAULT_RETAIN_FILE.name if args.state_dir else runtime.DEFAULT_RETAIN_FILE
    print(f"plc run: no run configuration ({why}): built-in defaults, retain file {args.retain or state}",
          file=sys.stderr)
    return None


def cmd_run(args) -> int:
    root = project_root()
    paths = args.paths or ([str(root / "st_src")] if root else [])
    if not paths:
        raise UserError("no ST sources given and no project st_src/ found from here")
    in_project = root is not None and all(_inside(p, root) for p in paths)
    use_project_cache(root)
    with paused_gc():
        if in_project and refused_by_preflight(root, "plc run"):
            return 1
        res = compile_sources(paths, portability=False)
    print_diagnostics(res, quiet=True)
    if not res.ok:
        print(f"plc run: the program does not compile ({len(res.diags.errors)} error(s))", file=sys.stderr)
        return 1
    if not res.program.configs:
        raise UserError("the sources have no CONFIGURATION: nothing to run")
    args.paths = paths
    if in_project and Path(args.build_dir) == runtime.DEFAULT_BUILD_DIR:
        args.build_dir = root / runtime.DEFAULT_BUILD_DIR       # the project's own (a view has its own)
    setup = _run_setup(root, Path(args.build_dir)) if in_project else extensions.RunSetup()
    args.config = run_configuration(args, root)
    args.run_setup = setup
    c_file = Path(args.build_dir) / "program" / "program.c"
    c_file.parent.mkdir(parents=True, exist_ok=True)
    if not c_file.exists() or c_file.read_text() != res.c_text:
        c_file.write_text(res.c_text)
    try:
        return runtime.run_command(args, c_file, generated=True)
    except runtime.RuntimeBuildError as e:
        if not e.program_refused:
            raise UserError(str(e)) from None
        log = c_file.with_suffix(".cc.log")
        log.write_text(f"$ {shlex.join(e.command)}\n{e.output}")
        raise GeneratedCError(c_file, log, e.output) from None
    except runtime.ConfigError as e:
        raise UserError(str(e)) from None


def _run_setup(root: Path, build_dir: Path) -> extensions.RunSetup:
    """What the first extension that knows this project adds to the runtime (nothing without one)."""
    for setup in extensions.load().run_setup:
        found = setup(root, build_dir)
        if found is not None:
            return found
    return extensions.RunSetup()


def cmd_retain_show(args) -> int:
    try:
        f = retainfile.read(args.file)
    except retainfile.RetainFileError as e:
        print(f"plc retain: error: {args.file}: {e}", file=sys.stderr)
        return 1
    if f.version == 1:
        print(f"{args.file}: format version 1 (one block of values without names: the runtime that reads it "
              f"names them), generation {f.generation}")
        return 0
    print(f"{args.file}: format version {f.version}, generation {f.generation}, {len(f.entries)} entries "
          f"({len(f.kept_aside())} kept aside)")
    for e in f.entries:
        print("  " + retainfile.describe(e))
    return 0


def add_compile_opts(p: argparse.ArgumentParser) -> None:
    p.add_argument("paths", nargs="+", metavar="PATH",
                   help=".st files, PLCopen .xml projects or directories (searched recursively)")
    p.add_argument("--no-portability", action="store_true", help="do not warn about constructs MATIEC rejects")
    p.add_argument("--target", choices=["openplc", "openplc-v4"],
                   help="also check what this deploy target requires: openplc (v3: CONFIGURATION Config0, RESOURCE "
                        "Res0), openplc-v4 (what its compiler STruC++ rejects or reads otherwise)")
    p.add_argument("-q", "--quiet", action="store_true", help="print errors only")


EXIT_CODES = ("Exit codes: 0 success; 1 the input has errors, or tests failed; 2 usage or environment problems "
              "(a missing file or C compiler, a port in use); 3 an internal compiler error, a bug of plc and not "
              "of the program (a compiler stage met a construct it does not handle, or the C compiler rejected "
              "the generated C, which is then kept with the C compiler's output).")


def parser() -> argparse.ArgumentParser:
    views = extensions.load().views
    ap = argparse.ArgumentParser(prog="plc", description="atc-plc toolchain: check, build, test and run "
                                 "IEC 61131-3 Structured Text for the soft-PLC and OpenPLC.",
                                 epilog=" ".join([*(f"{v.flag} {v.metavar}, given to a command of the project: "
                                                    f"{v.help}." for v in views), EXIT_CODES]))
    ap.add_argument("--version", action="version", version=f"plc {__version__}")
    sub = ap.add_subparsers(dest="cmd", metavar="COMMAND")
    p = sub.add_parser("check", help="report errors and portability warnings", description=
                       "Parse and check ST files; print diagnostics as file:line:col. Exit 0 when there is no error "
                       "(with --target, and no portability warning either: what the target refuses fails the check).")
    add_compile_opts(p)
    p.set_defaults(func=cmd_check)
    p = sub.add_parser("build", help="compile ST to C and an object file", description=
                       "Compile ST files into DIR/program.c (MATIEC-shaped C against plc_abi.h) and DIR/program.o.")
    add_compile_opts(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.set_defaults(func=cmd_build)
    testrunner.add_parser(sub)
    ext = extensions.load()
    for add_parser in ext.parsers:
        add_parser(sub)
    p = sub.add_parser("run", help="build and run the soft-PLC (Modbus/TCP, OpenPLC map)", description=
                       "Compile the ST program (default: the project's st_src/) and run it as a soft-PLC serving "
                       "Modbus/TCP with OpenPLC's address map. Ctrl-C stops it: outputs go safe, RETAIN data "
                       "is saved. The run configuration is --config, else the project's (its machine's, or "
                       "configs/runtime.toml) when the sources belong to the project; the one used is printed. "
                       "Modbus/TCP Security (a TLS listener beside the plain one, port 802 by default, each client's "
                       "role from its certificate): [modbus.tls] cert, key, ca, port, bind in the run configuration "
                       "(plc tls makes the certificates; README, \"Hardening the Modbus front end\").")
    p.add_argument("paths", nargs="*", metavar="PATH", help="ST files or directories (default: st_src/)")
    runtime.add_run_arguments(p)
    add_view_options(p)
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("retain", help="read a retained-data file: plc retain show FILE", description=
                       "Read a retained-data file of the runtime. Exit 0, or 1 when the file is damaged.")
    rsub = p.add_subparsers(dest="retain_cmd", metavar="show")
    rsub.required = True
    q = rsub.add_parser("show", help="list every saved value with its name, type and location",
                        description="Check a retained-data file (CRC, entry table) and list every saved value: "
                                    "name, type, location, value; values kept aside (saved by an earlier program "
                                    "version, not used by the present one) are marked.")
    q.add_argument("file", type=Path, metavar="FILE", help="the retain file (e.g. var/plc.retain)")
    q.set_defaults(func=cmd_retain_show)
    for name, (text, _) in TOOLCHAIN_DELEGATED.items():
        sub.add_parser(name, help=text, add_help=False)
    for command in ext.commands.values():
        sub.add_parser(command.name, help=command.help, add_help=False)
    return ap


# The toolchain's subcommands with their own argument parsers (each module has main(argv) -> int); an
# extension's subcommands are in extensions.load().commands.
TOOLCHAIN_DELEGATED = {
    "status": ("the soft-PLC's diagnostic block: state, scan times, Modbus counters (plc status --help)",
               "plc.hmi.status"),
    "monitor": ("watch, write and force variables of the running PLC (plc monitor --help)", "plc.hmi.cli"),
    "import": ("PLCopen XML or an Editor v4 folder to ST: plc import plcopen|openplc-editor PATH --out DIR",
               "plc.plcopen.importer"),
    "export": ("ST project to PLCopen XML: plc export plcopen --out FILE.xml", "plc.plcopen.exporter"),
    "tls": ("certificates of Modbus/TCP Security: a CA, the runtime's, clients' with a role (plc tls --help)",
            "plc.tlscerts"),
}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        choose_view(argv)
        if argv and argv[0] in TOOLCHAIN_DELEGATED:
            return import_module(TOOLCHAIN_DELEGATED[argv[0]][1]).main(argv[1:])
        command = extensions.load().commands.get(argv[0]) if argv else None
        if command is not None:
            return command.main(argv[1:])
        ap = parser()
        args = ap.parse_args(argv)
        if not getattr(args, "func", None):
            ap.print_help()
            return 2
        return args.func(args)
    except (UserError, extensions.ViewError) as e:
        print(f"plc: error: {e}", file=sys.stderr)
        return 2
    except InternalError as e:
        # a node kind a compiler stage does not handle: a bug of the compiler, never silent C
        print(f"{e}\nplc: this is a bug of the compiler, not of your program: please report it with the input",
              file=sys.stderr)
        return 3
    except GeneratedCError as e:
        # C generated from a program that checked clean does not compile: a bug of the compiler too
        print(f"plc: {e}\nplc: this is a bug of the compiler, not of your program: please report it with the "
              "input, the generated C and the C compiler's output", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print("plc: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader went away (plc ... | head): stop quietly, and keep Python from complaining at exit
        try:
            sys.stdout = open(os.devnull, "w")
        except OSError:
            pass
        return 1

if __name__ == "__main__":
    sys.exit(main())
