"""`plc seq`: check tool-change sequences and compile them into ST tables.

    plc seq check FILES...                      line-numbered errors, all of them, in one run
    plc seq compile INDEX --out FILE.st         write the generated ST tables
    plc seq compile INDEX --out FILE.st --check-drift    exit 1 if FILE.st is not what INDEX generates

Exit status: 0 = clean (warnings allowed unless --werror), 1 = errors in the sequences or drift,
2 = the command could not run (bad arguments, unreadable input, output not writable).
"""

from __future__ import annotations

import argparse
import difflib
import sys
from pathlib import Path

from plc import cliargs
from plc.cliargs import EXIT_FINDINGS, EXIT_OK, EXIT_USAGE

from .assemble import check_files, check_set, display_path
from .diagnostics import Diagnostics
from .encoding import MAX_TOOLS, Kind
from .stgen import generate, stable_name


class _Parser(argparse.ArgumentParser):
    """argparse that exits with status 2 and a one-line message, never a traceback."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def _build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="plc seq", description="Check and compile Logosol-style tool-change sequences "
                                                 "(Put Tool, Get Tool, Toolchanger Home, Length Measurement).")
    sub = parser.add_subparsers(dest="command", metavar="{check,compile}", parser_class=_Parser)
    sub.required = True

    check = sub.add_parser("check", help="check sequence files or whole sets; report every error with its line",
                           description="Check sequence files (*.seq) and sequence-set indexes (*.toml). A sequence "
                                       "file is checked against --index, or the sequences.toml beside it, with the "
                                       "kind and tools that index gives it; a file no index names is checked as "
                                       "--kind for --tool.")
    check.add_argument("files", nargs="+", type=Path, metavar="FILE", help="*.seq sequence files or *.toml indexes")
    check.add_argument("--index", type=Path, help="index giving I/O map, axes, tools and P/Q values for *.seq files")
    check.add_argument("--kind", choices=[k.key for k in Kind], default=Kind.PUT.key,
                       help="kind of a sequence file that no index names (default: put)")
    check.add_argument("--tool", type=int, default=1, help="tool a Put/Get file that no index names runs for "
                                                           "(default: 1)")
    _common(check)

    compile_ = sub.add_parser("compile", help="compile a sequence set into generated ST tables",
                              description="Check a sequence set and write its ST step tables. The output depends "
                                          "only on the inputs: compiling twice gives the same bytes.")
    compile_.add_argument("index", type=Path, metavar="INDEX", help="the set's index, e.g. "
                                                                    "configs/sequences/sequences.toml")
    compile_.add_argument("--out", type=Path, required=True, metavar="FILE.st", help="generated ST file")
    compile_.add_argument("--check-drift", action="store_true",
                          help="write nothing; exit 1 if FILE.st differs from what INDEX generates")
    _common(compile_)
    return parser


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-q", "--quiet", action="store_true", help="print errors only, no warnings or summary")
    parser.add_argument("-v", "--verbose", action="store_true", help="say what was checked or written")
    parser.add_argument("--werror", action="store_true", help="treat warnings as errors")


def _report(diags: Diagnostics, args: argparse.Namespace) -> bool:
    """Print the diagnostics to stderr; True when the run is clean."""
    for diagnostic in diags.sorted():
        if args.quiet and diagnostic not in diags.errors:
            continue
        print(diagnostic.render(), file=sys.stderr)
    failed = bool(diags.errors) or (args.werror and bool(diags.warnings))
    if not args.quiet and (diags.errors or diags.warnings):
        print(f"{len(diags.errors)} error(s), {len(diags.warnings)} warning(s)", file=sys.stderr)
    return not failed


def _missing(paths: list[Path]) -> int:
    missing = [p for p in paths if not p.is_file()]
    for path in missing:
        print(f"plc seq: error: no such file: {path}", file=sys.stderr)
    return EXIT_USAGE if missing else EXIT_OK


def _check(args: argparse.Namespace) -> int:
    if not 1 <= args.tool <= MAX_TOOLS:
        print(f"plc seq check: error: --tool must be 1..{MAX_TOOLS}", file=sys.stderr)
        return EXIT_USAGE
    status = _missing(list(args.files) + ([args.index] if args.index else []))
    if status:
        return status
    diags = Diagnostics()
    check_files(list(args.files), diags, index=args.index, kind=Kind.from_key(args.kind), tool=args.tool)
    clean = _report(diags, args)
    if clean and args.verbose:
        print(f"checked {len(args.files)} file(s): no errors", file=sys.stderr)
    return EXIT_OK if clean else EXIT_FINDINGS


def _compile(args: argparse.Namespace) -> int:
    status = _missing([args.index])
    if status:
        return status
    diags = Diagnostics()
    assembly = check_set(args.index, diags)
    if not _report(diags, args) or assembly is None:
        return EXIT_FINDINGS
    text = generate(assembly, stable_name(args.index), stable_name(args.out))
    try:
        current = args.out.read_text(encoding="utf-8") if args.out.exists() else None
    except (OSError, UnicodeDecodeError) as exc:
        print(f"plc seq compile: error: cannot read {args.out}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if args.check_drift:
        return _drift(args, current, text)
    if current != text:
        try:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(text, encoding="utf-8", newline="\n")
        except OSError as exc:
            print(f"plc seq compile: error: cannot write {args.out}: {exc.strerror or exc}", file=sys.stderr)
            return EXIT_USAGE
    if args.verbose:
        state = "unchanged" if current == text else "written"
        print(f"{display_path(args.out)}: {state} ({len(assembly.sequences)} sequences)", file=sys.stderr)
    return EXIT_OK


def _drift(args: argparse.Namespace, current: str | None, text: str) -> int:
    if current == text:
        if args.verbose:
            print(f"{display_path(args.out)}: up to date", file=sys.stderr)
        return EXIT_OK
    out = display_path(args.out)
    reason = "does not exist" if current is None else "differs from what the sequences generate"
    print(f"plc seq compile: drift: {out} {reason}", file=sys.stderr)
    if current is not None and not args.quiet:
        diff = list(difflib.unified_diff(current.splitlines(), text.splitlines(), f"{out} (on disk)",
                                         f"{out} (generated)", lineterm="", n=1))
        for line in diff[:40]:
            print(line, file=sys.stderr)
        if len(diff) > 40:
            print(f"... {len(diff) - 40} more diff lines", file=sys.stderr)
    print(f"  run: plc seq compile {display_path(args.index)} --out {out}", file=sys.stderr)
    return EXIT_FINDINGS


def main(argv: list[str]) -> int:
    """Entry point for `plc seq ...`; argv excludes the program name and the word `seq`."""
    parser = _build_parser()
    args, code = cliargs.parse(parser, argv)
    if args is None:
        return code
    if args.command == "check":
        return _check(args)
    return _compile(args)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
