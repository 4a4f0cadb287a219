"""`plc monitor`: watch, write and force variables of the running soft-PLC over its monitoring channel.

    plc monitor vars [PREFIX]              every variable (path, type)
    plc monitor read PATH...               values of one scan
    plc monitor watch PATH... [--period MS] [--count N]   a line per update, tagged with the scan number
    plc monitor write PATH VALUE           once, before the next scan's program
    plc monitor force PATH VALUE           held every scan until unforced
    plc monitor unforce PATH [--restore]   end a force (keep the value, or restore the one from before)
    plc monitor forces                     the active forces

Paths: full (CONFIG0.RES0.ATC.MACHINE.ROTARY.TARGET), a unique tail (ATC.MACHINE.ROTARY.TARGET), struct fields
and array elements (ATC.MACHINE.RUNNER.STEPS[3].LINE), or a located address (%IX0.3).  Writes need the token
(--token-file, default var/monitor.token, written by `plc run`).  Every write and force is in the audit log.

Exit status: 0 done, 1 the runtime refused the request (the reason is printed), 2 usage or no connection.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .. import cliargs, runtime
from .monitor import Monitor, MonitorError, read_token
from ..project import add_view_options, project_root


PERIOD_MS = (10, 10000)        # the update periods the runtime's subscriptions serve (monitor.c, `sub MS`)


def period_ms(text: str) -> int:
    """--period: a whole number of milliseconds the runtime can serve (argparse names the option on an error)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of milliseconds") from None
    if not PERIOD_MS[0] <= value <= PERIOD_MS[1]:
        raise argparse.ArgumentTypeError(f"{value} ms: the update period is {PERIOD_MS[0]}..{PERIOD_MS[1]} ms")
    return value


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="plc monitor", description="Watch, write and force variables of the running "
                                "soft-PLC (its monitoring channel, never the Modbus port).",
                                epilog="exit status: 0 done, 1 refused by the runtime, 2 usage or no connection")
    p.add_argument("--socket", type=Path, default=None,
                   help="the runtime's monitor socket (default: the project's run's, beside its retained file; "
                        f"{runtime.DEFAULT_MONITOR_SOCKET} without a project)")
    p.add_argument("--token-file", type=Path, default=None,
                   help=f"the token for writes (default: beside the socket; {runtime.DEFAULT_TOKEN_FILE} without a "
                        "project)")
    add_view_options(p)
    sub = p.add_subparsers(dest="cmd", metavar="COMMAND", required=True)
    q = sub.add_parser("vars", help="list the variables")
    q.add_argument("prefix", nargs="?", default="", help="only paths containing this")
    q = sub.add_parser("read", help="values of one scan")
    q.add_argument("paths", nargs="+", metavar="PATH")
    q = sub.add_parser("watch", help="values as they change, every --period ms")
    q.add_argument("paths", nargs="+", metavar="PATH")
    q.add_argument("--period", type=period_ms, default=100, metavar="MS",
                   help=f"update period, {PERIOD_MS[0]}..{PERIOD_MS[1]} ms (default 100)")
    q.add_argument("--count", type=int, default=0, metavar="N", help="stop after N updates (default: Ctrl-C)")
    for name, text in (("write", "set once, before the next scan's program"), ("force", "hold a value")):
        q = sub.add_parser(name, help=text)
        q.add_argument("path", metavar="PATH")
        q.add_argument("value", metavar="VALUE", help="TRUE/FALSE, a number, T#2s, an enum value name")
    q = sub.add_parser("unforce", help="end a force")
    q.add_argument("path", metavar="PATH", nargs="?")
    q.add_argument("--restore", action="store_true", help="restore the value from before the force")
    q.add_argument("--all", action="store_true", help="end every force (values kept)")
    sub.add_parser("forces", help="the active forces")
    return p


AMBIGUOUS = "names more than one variable"    # the runtime's sentence for a tail several paths end with (varpath.c)
CANDIDATES_SHOWN = 10


def tail_length(path: str, tail: str) -> int:
    """How much of `tail` names `path` the way the runtime resolves a tail (0: none): `path` ends, at a dot, with
    the start of `tail` up to a field or an index (the rest selects inside the variable)."""
    for i in [-1] + [i for i, c in enumerate(path) if c == "."]:
        end = path[i + 1:]
        if tail == end or tail.startswith((end + ".", end + "[")):
            return len(end)
    return 0


def ambiguity(m: Monitor, tail: str) -> str:
    """The variables an ambiguous tail names (those it matches longest, as the runtime compares them): the first
    CANDIDATES_SHOWN of them and how many more."""
    tail = tail.upper()
    first = tail.split(".", 1)[0].split("[", 1)[0]      # in every path the tail names
    lengths = {v["path"]: tail_length(v["path"], tail) for v in m.list(first)}
    best = max(lengths.values(), default=0)
    found = [path for path, n in lengths.items() if n and n == best]
    if not found:
        return ""
    shown = ", ".join(found[:CANDIDATES_SHOWN])
    more = f" and {len(found) - CANDIDATES_SHOWN} more (plc monitor vars {first})" \
        if len(found) > CANDIDATES_SHOWN else ""
    return f"; it names {len(found)}: {shown}{more}"


def run(args, m: Monitor) -> int:
    try:
        return _run(args, m)
    except MonitorError as exc:
        if AMBIGUOUS not in str(exc):
            raise
        tail = str(exc).split("'")[1]
        raise MonitorError(f"{exc}{ambiguity(m, tail)}") from None


def _run(args, m: Monitor) -> int:
    if args.cmd in ("write", "force", "unforce"):
        m.auth(read_token(args.token_file))
    if args.cmd == "vars":
        for v in m.list(args.prefix):
            extra = f"  {v['address']}" if "address" in v else ""
            flags = " CONSTANT" if v.get("constant") else ""
            print(f"{v['path']}  {v['type']}{extra}{flags}")
    elif args.cmd == "read":
        scan, values = m.read_scan(*args.paths)
        for path, value in values.items():
            print(f"{path} = {json.dumps(value)}")
        print(f"(scan {scan})")
    elif args.cmd == "watch":
        m.subscribe(args.period, *args.paths)
        last = None
        n = 0
        while args.count == 0 or n < args.count:
            update = m.next_update()
            n += 1
            if update["values"] != last:
                print(f"scan {update['scan']}: " + "  ".join(f"{p} = {json.dumps(v)}" for p, v in
                                                           update["values"].items()), flush=True)
                last = update["values"]
    elif args.cmd == "write":
        print(f"{args.path} := {args.value} at scan {m.write(args.path, args.value)}")
    elif args.cmd == "force":
        print(f"{args.path} forced to {args.value} from scan {m.force(args.path, args.value)}")
    elif args.cmd == "unforce":
        if args.all:
            print(f"every force ended at scan {m.unforce_all()}")
        elif not args.path:
            print("plc monitor: error: unforce PATH, or --all", file=sys.stderr)
            return 2
        else:
            scan = m.unforce(args.path, restore=args.restore)
            print(f"{args.path} unforced at scan {scan} ({'value restored' if args.restore else 'value kept'})")
    elif args.cmd == "forces":
        forces = m.forces()
        for f in forces:
            print(f"{f['path']} = {f['value']}  (since scan {f['since_scan']})")
        if not forces:
            print("no forces")
    return 0


def main(argv: list[str]) -> int:
    parser = build_parser()
    args, code = cliargs.parse(parser, argv)
    if args is None:
        return code
    _, sock, token = runtime.project_endpoint(project_root())
    args.socket = args.socket or sock
    args.token_file = args.token_file or token
    m = Monitor(args.socket)
    try:
        m.connect()
    except MonitorError as exc:
        print(f"plc monitor: error: {exc}", file=sys.stderr)
        return 2
    try:
        return run(args, m)
    except MonitorError as exc:
        print(f"plc monitor: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    finally:
        m.close()
