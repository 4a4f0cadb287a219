"""`plc import plcopen FILE.xml --out DIR` and `plc import openplc-editor FOLDER --out DIR`: a PLCopen project
or an OpenPLC Editor v4 project folder as readable ST, one declaration per file.

For integrators who leave ladder behind: every TYPE, POU and the CONFIGURATION is written to
DIR/<name>.st; LD and FBD bodies come out as the ST the compiler runs (docs/ladder.md), each rung or
network under a comment naming its elements.  The files are checked with the compiler before the
command reports success.

An Editor v4 folder (docs/openplc-editor.md) is translated and checked before anything is written: with
an error nothing is written, and every diagnostic names the editor's file, POU and rung/node.

Exit codes: 0 written and checked clean of errors, 1 the project has errors, 2 usage problems.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .. import cliargs
from ..cliargs import EXIT_FINDINGS, EXIT_OK, EXIT_USAGE
from ..diagnostics import Diagnostics, SourceSet
from ..driver import UserError, compile_sources, decode, display_name, print_diagnostics, read_bytes
from . import editor4, translate


def unit_files(tr) -> dict[str, str]:
    """File name -> ST text for every unit of a translation."""
    out: dict[str, str] = {}
    for u in tr.units:
        head = f"(* imported from {tr.xml_name} by `plc import plcopen`"
        head += f"; {u.language} body, {u.networks} network(s) *)" if u.language != "ST" and u.kind not in (
            "TYPE", "CONFIGURATION") else " *)"
        name = f"{u.name}.st"
        n = 2
        while name in out:
            name = f"{u.name}_{n}.st"
            n += 1
        out[name] = head + "\n" + "\n".join(text for text, _o in u.lines) + "\n"
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="plc import", description="Bring a project from another format in as ST.")
    sub = p.add_subparsers(dest="format", metavar="{plcopen,openplc-editor}")
    sub.required = True
    o = sub.add_parser("plcopen", help="PLCopen TC6 XML (OpenPLC Editor, Beremiz) to ST files",
                       description="Write every TYPE, POU and CONFIGURATION of a PLCopen TC6 0201 project as "
                                   "one ST file each in DIR; LD/FBD bodies are translated (docs/ladder.md). "
                                   "Exit 0 written, 1 project errors, 2 usage.")
    o.add_argument("file", type=Path, metavar="FILE.xml", help="the PLCopen project")
    o.add_argument("--out", required=True, type=Path, metavar="DIR", help="directory for the .st files")
    o.add_argument("-q", "--quiet", action="store_true", help="print errors only")
    e = sub.add_parser("openplc-editor", help="an OpenPLC Editor v4 project folder to ST files",
                       description="Write every data type, POU and the configuration of an OpenPLC Editor v4 "
                                   "project folder (project.json, pous/<kind>/<Name>.st|.ld|.fbd) as one ST file "
                                   "each in DIR; LD/FBD bodies are translated as PLCopen ones are "
                                   "(docs/ladder.md, docs/openplc-editor.md). Nothing is written when the project "
                                   "has errors. Exit 0 written, 1 project errors (nothing written), 2 usage.")
    e.add_argument("folder", type=Path, metavar="FOLDER", help="the project folder (holds project.json)")
    e.add_argument("--out", required=True, type=Path, metavar="DIR", help="directory for the .st files")
    e.add_argument("--no-configuration", action="store_true",
                   help="leave project.json's configuration out (types and POUs only), for a build whose "
                        "CONFIGURATION is in ST")
    e.add_argument("-q", "--quiet", action="store_true", help="print errors only")
    return p


def import_editor_folder(args) -> int:
    if not editor4.looks_like_project(args.folder):
        print(f"plc import: error: {args.folder}: not an OpenPLC Editor v4 project folder (no project.json)",
              file=sys.stderr)
        return EXIT_USAGE
    diags = Diagnostics()
    sources = SourceSet()
    for f in sorted(args.folder.rglob("*")):
        if f.is_file() and f.suffix.lower() in (".json", ".st", ".ld", ".fbd"):
            try:
                sources.add(display_name(f), f.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError):
                pass
    units = editor4.read_folder(args.folder, diags)
    if units is None:
        for d in diags.sorted():
            if not args.quiet or d.severity == "error":
                print(d.render(sources), file=sys.stderr)
        print("plc import: nothing written", file=sys.stderr)
        return EXIT_FINDINGS
    if args.no_configuration:
        units = [u for u in units if u.kind != "CONFIGURATION"]
    texts = editor4.unit_texts(units, "plc import openplc-editor")
    generated = {display_name(args.out / name): (name, text, table) for name, (text, table) in texts.items()}
    res = compile_sources([], generate=False, extra_texts=[(g, text) for g, (_n, text, _t) in generated.items()])
    editor4.remap(res.diags, {g: table for g, (_n, _text, table) in generated.items()})
    res.diags.items[:0] = diags.items
    for d in res.diags.sorted():
        if not args.quiet or d.severity == "error":
            print(d.render(sources), file=sys.stderr)
    if res.diags.has_errors():
        print(f"plc import: {len(res.diags.errors)} error(s): nothing written", file=sys.stderr)
        return EXIT_FINDINGS
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        for name, text, _t in generated.values():
            (args.out / name).write_text(text, encoding="utf-8", newline="\n")
    except OSError as e:
        print(f"plc import: error: cannot write to {args.out}: {e.strerror or e}", file=sys.stderr)
        return EXIT_USAGE
    if not args.quiet:
        print(f"plc import: wrote {len(generated)} file(s) to {args.out}: 0 error(s), "
              f"{len(res.diags.warnings)} warning(s)", file=sys.stderr)
    return EXIT_OK


def main(argv: list[str]) -> int:
    args, code = cliargs.parse(build_parser(), argv)
    if args is None:
        return code
    if args.format == "openplc-editor":
        return import_editor_folder(args)
    if editor4.looks_like_project(args.file):
        print(f"plc import: error: {args.file} is an OpenPLC Editor v4 project folder: use "
              f"plc import openplc-editor {args.file} --out DIR", file=sys.stderr)
        return EXIT_USAGE
    try:
        data = read_bytes(args.file)
    except UserError as e:
        print(f"plc import: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    diags = Diagnostics()
    name = display_name(args.file)
    sources = SourceSet()
    sources.add(name, decode(data))
    tr = translate(name, data, diags)
    if tr is None:
        for d in diags.sorted():
            print(d.render(sources), file=sys.stderr)
        print("plc import: nothing written", file=sys.stderr)
        return EXIT_FINDINGS
    files = unit_files(tr)
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        for fname, text in files.items():
            (args.out / fname).write_text(text, encoding="utf-8", newline="\n")
    except OSError as e:
        print(f"plc import: error: cannot write to {args.out}: {e.strerror or e}", file=sys.stderr)
        return EXIT_USAGE
    res = compile_sources([args.out / f for f in files], generate=False)
    print_diagnostics(res, quiet=args.quiet)
    if not args.quiet:
        print(f"plc import: wrote {len(files)} file(s) to {args.out}: {len(res.diags.errors)} error(s), "
              f"{len(res.diags.warnings)} warning(s)", file=sys.stderr)
    return EXIT_FINDINGS if res.diags.has_errors() else EXIT_OK
