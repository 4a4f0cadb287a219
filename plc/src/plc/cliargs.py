"""What every `plc` subcommand does with its command line: one set of exit codes, one way to parse."""
from __future__ import annotations

import argparse

EXIT_OK, EXIT_FINDINGS, EXIT_USAGE = 0, 1, 2


def parse(parser: argparse.ArgumentParser, argv: list[str]) -> tuple[argparse.Namespace | None, int]:
    """(the arguments, EXIT_OK), or (None, the exit code) when there is nothing to run: 0 after --help,
    EXIT_USAGE after a usage error.  argparse has printed the help or the error either way."""
    try:
        return parser.parse_args(argv), EXIT_OK
    except SystemExit as exc:
        return None, int(exc.code) if isinstance(exc.code, int) else EXIT_USAGE
