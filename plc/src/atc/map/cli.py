"""`plc map`: validate the register map and generate everything that derives from it.

    plc map check      validate modbus_map/map.toml and reason_codes.toml, and fail on drift of any
                       generated file (exit 1 on any problem)
    plc map generate   write the generated files (only those whose content changes)

Exit status: 0 clean (warnings allowed), 1 problems in the map or drift, 2 the command could not run.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from plc import cliargs
from plc.cliargs import EXIT_FINDINGS, EXIT_OK, EXIT_USAGE
from plc.diagnostics import Diagnostics
from plc.project import add_view_options, project_root

from .generate import drift, load_and_check, outputs, write

DEFAULT_MAP = Path("modbus_map") / "map.toml"


def source_checkout() -> Path | None:
    """The repository this package was installed from (editable install), if it is one: None for a wheel."""
    for parent in Path(__file__).resolve().parents:
        if all((parent / m).is_dir() for m in ("st_src", "modbus_map")):
            return parent
    return None


def default_map() -> Path:
    """modbus_map/map.toml of the project (the one `--machine` chose, else the one around here), else of the
    current directory, else of the repository this package lives in."""
    root = project_root()
    if root is not None and (root / DEFAULT_MAP).is_file():
        return root / DEFAULT_MAP
    if DEFAULT_MAP.is_file():
        return DEFAULT_MAP
    repo = source_checkout()
    return (repo / DEFAULT_MAP) if repo is not None else DEFAULT_MAP


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="plc map", description="Validate the register map (modbus_map/) and generate the "
                     "PROGRAM's located declarations, HMI tags, LinuxCNC files, the map document and the "
                     "runtime configuration from it.")
    sub = parser.add_subparsers(dest="command", metavar="{check,generate}", parser_class=_Parser)
    sub.required = True
    for name, text in (("check", "validate the map and fail on drift of any generated file"),
                       ("generate", "write every generated file (reproducible, byte for byte)")):
        p = sub.add_parser(name, help=text, description=text[0].upper() + text[1:] + ".")
        p.add_argument("--map", type=Path, default=None, metavar="FILE",
                       help="the map (default: modbus_map/map.toml)")
        p.add_argument("-q", "--quiet", action="store_true", help="print errors only")
        p.add_argument("-v", "--verbose", action="store_true", help="list the files checked or written")
        add_view_options(p)
    return parser


def _report(diags: Diagnostics, quiet: bool) -> None:
    for d in diags.sorted():
        if quiet and d.severity != "error":
            continue
        print(d.render(), file=sys.stderr)


def main(argv: list[str]) -> int:
    parser = build_parser()
    args, code = cliargs.parse(parser, argv)
    if args is None:
        return code
    map_path = args.map or default_map()
    if not map_path.is_file():
        print(f"plc map: error: no such file: {map_path}", file=sys.stderr)
        return EXIT_USAGE
    diags = Diagnostics()
    loaded = load_and_check(map_path, diags)
    if loaded is None:
        _report(diags, args.quiet)
        return EXIT_FINDINGS
    if args.command == "check":
        stale = drift(loaded, diags) if not diags.has_errors() else []
        _report(diags, args.quiet)
        n_err = len(diags.errors)
        if not args.quiet:
            files = len(outputs(loaded))
            print(f"plc map check: {len(loaded.rmap.signals)} signals, {len(loaded.rmap.reasons)} reason codes, "
                  f"{files} generated files ({len(stale)} drifted): {n_err} error(s), "
                  f"{len(diags.warnings)} warning(s)", file=sys.stderr)
        return EXIT_FINDINGS if n_err else EXIT_OK
    _report(diags, args.quiet)
    if diags.has_errors():
        print("plc map generate: nothing written: fix the errors first", file=sys.stderr)
        return EXIT_FINDINGS
    try:
        written = write(loaded)
    except OSError as exc:
        print(f"plc map generate: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if args.verbose:
        for rel in outputs(loaded):
            print(f"{rel}: {'written' if rel in written else 'unchanged'}", file=sys.stderr)
    elif not args.quiet:
        print(f"plc map generate: {len(written)} file(s) written, {len(outputs(loaded)) - len(written)} "
              "unchanged", file=sys.stderr)
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
