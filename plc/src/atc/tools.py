"""`plc tools`: the PLC's tool table (docs/tools.md) over Modbus: list it, set a tool's row, reset its time used,
clear it, load it from a LinuxCNC tool table file (.tbl) and export it to one.

    plc tools list                       every row: tool, pocket, group, life, time used and left, probe, worn
    plc tools set T101 --pocket 3 [--group G] [--life MIN] [--used MIN[:SS]] [--probe | --no-probe] [--row R]
    plc tools reset T101                 time used back to 0 (after a regrind or a new tool)
    plc tools clear T101                 free its row
    plc tools load FILE.tbl              the table becomes the file's tools (T<n> P<p>; group, life, used and probe
                                         from an `atc:` part of the comment, else the tool's current values)
    plc tools export FILE.tbl [--offsets-from TBL]

Every change goes through the PLC's edit command (ToolEditRequest: the PLC checks it and answers), needs the
monitor's token file to be readable (the right a monitor write needs) and is appended to the audit log beside
it, one line per change with its answer, as the runtime logs a monitor write.

Exit status: 0 done; 1 the PLC refused an edit (its answer is printed); 2 usage, map, file, token or connection
problems.
"""
from __future__ import annotations

import argparse
import datetime
import os
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from plc import cliargs, runtime
from plc.modbus import LinkError, ModbusClient, ModbusException
from plc.project import add_view_options

from .host.tags import MapError, Tags, load_map
from .map.cli import default_map

EXIT_OK, EXIT_REFUSED, EXIT_USAGE = 0, 1, 2
COLUMNS = ("TableTool", "TablePocket", "TableGroup", "TableLife", "TableUsedMin", "TableUsedSec", "TableFlags")
EDIT_SET, EDIT_RESET, EDIT_CLEAR = 1, 2, 3
FLAG_PROBE = 1
ANSWERS = {1: "done", -1: "refused: the changer is busy (a change, prepare, homing or turn)",
           -2: "refused: row outside the table", -3: "refused: tool < 1 or held by another row",
           -4: "refused: pocket outside the carousel or held by another row",
           -5: "refused: a negative value or seconds above 59", -6: "refused: another tool is the probe tool",
           -7: "refused: the tool is in the spindle: unload it first", -8: "refused: unknown edit code"}
ATC_PART = re.compile(r"\batc:\s*(.*)$")


class ToolsError(Exception):
    """A problem the command reports in one sentence (exit 2)."""


@dataclass
class Row:
    row: int
    tool: int
    pocket: int
    group: int = 0
    life: int = 0
    used_min: int = 0
    used_sec: int = 0
    flags: int = 0

    @property
    def used_s(self) -> int:
        return self.used_min * 60 + self.used_sec

    @property
    def worn(self) -> bool:
        return self.life > 0 and self.used_min >= self.life

    def left(self) -> str:
        if self.life == 0:
            return "unlimited"
        s = max(0, self.life * 60 - self.used_s)
        return f"{s // 60}:{s % 60:02d}"

    def atc_part(self) -> str:
        probe = " probe" if self.flags & FLAG_PROBE else ""
        return f"atc: group={self.group} life={self.life} used={self.used_min}:{self.used_sec:02d}{probe}"


# ------------------------------------------------------------------------------------------------ tool files --
@dataclass
class TblTool:
    tool: int
    pocket: int
    line: int
    fields: str = ""                 # the other words (offsets, diameter...), as written
    comment: str = ""                # the comment without its atc: part
    group: int | None = None
    life: int | None = None
    used: tuple[int, int] | None = None
    probe: bool | None = None


def parse_used(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"(\d+)(?::(\d\d?))?", text)
    if not m or (m.group(2) is not None and int(m.group(2)) > 59):
        raise ValueError(f"time used '{text}': expected MINUTES or MINUTES:SS (seconds 0..59)")
    return int(m.group(1)), int(m.group(2) or 0)


def read_tbl(path: Path) -> list[TblTool]:
    """The tools of a LinuxCNC tool table: T<n> P<p> and the other words; ';' starts the comment, whose
    `atc: group=G life=M used=M:SS probe` part carries what LinuxCNC has no column for."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ToolsError(f"{path}: cannot read: {exc}") from None
    tools: list[TblTool] = []
    seen: dict[int, int] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        body, _, comment = raw.partition(";")
        if not body.strip():
            continue
        words = body.split()
        t = [w for w in words if re.fullmatch(r"[Tt]\d+", w)]
        p = [w for w in words if re.fullmatch(r"[Pp]\d+", w)]
        if len(t) != 1 or len(p) != 1:
            raise ToolsError(f"{path}:{number}: expected one T<n> and one P<p>")
        entry = TblTool(int(t[0][1:]), int(p[0][1:]), number,
                        " ".join(w for w in words if w not in (t[0], p[0])), comment.strip())
        if entry.tool in seen:
            raise ToolsError(f"{path}:{number}: T{entry.tool} again (first at line {seen[entry.tool]})")
        seen[entry.tool] = number
        m = ATC_PART.search(entry.comment)
        if m:
            entry.comment = entry.comment[:m.start()].strip()
            for item in m.group(1).split():
                key, _, value = item.partition("=")
                try:
                    if key == "group" and value:
                        entry.group = int(value)
                    elif key == "life" and value:
                        entry.life = int(value)
                    elif key == "used" and value:
                        entry.used = parse_used(value)
                    elif key == "probe" and not value:
                        entry.probe = True
                    else:
                        raise ValueError(f"unknown item '{item}' (group=G life=M used=M:SS probe)")
                except ValueError as exc:
                    raise ToolsError(f"{path}:{number}: atc: {exc}") from None
        tools.append(entry)
    return tools


def write_tbl(path: Path, rows: list[Row], offsets: dict[int, TblTool]) -> None:
    lines = []
    for r in sorted(rows, key=lambda r: r.pocket):
        other = offsets.get(r.tool)
        fields = other.fields if other and other.fields else "D0 Z0"
        comment = f"{other.comment} " if other and other.comment else ""
        lines.append(f"T{r.tool} P{r.pocket} {fields} ;{comment}{r.atc_part()}")
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
        os.replace(tmp, path)
    except OSError as exc:
        raise ToolsError(f"{path}: cannot write: {exc}") from None


# --------------------------------------------------------------------------------------------------- the PLC --
class Table:
    """The PLC's tool table on one Modbus connection: read it, and edit it through its edit command."""

    def __init__(self, tags: Tags, audit: Path, timeout: float = 5.0):
        self.tags = tags
        self.audit = audit
        self.timeout = timeout

    def rows(self) -> tuple[int, list[Row], int]:
        """(rows in use, the rows holding a tool, the tool in the spindle)."""
        n = int(self.tags.get("TableRows"))
        if not 0 <= n <= 50:
            raise ToolsError(f"the PLC reports {n} tool table rows (0..50 expected)")
        if n == 0:
            return 0, [], int(self.tags.get("ToolInSpindle"))
        names = [f"{c}{i}" for i in range(1, n + 1) for c in COLUMNS] + ["ToolInSpindle"]
        v = self.tags.read(*names)
        rows = [Row(i, *(int(v[f"{c}{i}"]) for c in COLUMNS)) for i in range(1, n + 1)]
        return n, [r for r in rows if r.tool > 0], int(v["ToolInSpindle"])

    def edit(self, code: int, row: int, what: str, values: Row | None = None) -> int:
        """One edit: the values, then a rising ToolEditRequest; the PLC's answer (ToolEditAnswer) once
        ToolEditCount moved. Audited with its answer."""
        before = int(self.tags.get("ToolEditCount"))
        if self.tags.get("ToolEditRequest"):
            self.tags.write(ToolEditRequest=False)
            self.scans_pass()
        v = values or Row(row, 0, 0)
        self.tags.write(ToolEditCode=code, ToolEditRow=row, ToolEditTool=v.tool, ToolEditPocket=v.pocket,
                        ToolEditGroup=v.group, ToolEditLife=v.life, ToolEditUsedMin=v.used_min,
                        ToolEditUsedSec=v.used_sec, ToolEditFlags=v.flags)
        self.tags.write(ToolEditRequest=True)
        deadline = time.monotonic() + self.timeout
        try:
            while True:
                s = self.tags.read("ToolEditCount", "ToolEditAnswer")
                if int(s["ToolEditCount"]) != before:
                    answer = int(s["ToolEditAnswer"])
                    break
                if time.monotonic() > deadline:
                    self.log(what, "no answer")
                    raise ToolsError(f"the PLC did not answer the edit within {self.timeout:g} s (is it running "
                                     f"this program, with the tool table?)")
                time.sleep(0.02)
        finally:
            self.tags.write(ToolEditRequest=False)
            self.scans_pass()
        self.log(what, ANSWERS.get(answer, f"answer {answer}"))
        return answer

    def scans_pass(self, scans: int = 2) -> None:
        """Wait until the PLC has scanned at least `scans` times (PlcHeartbeat counts its scans): it has seen the
        request line low, so the next edit's rising edge is one."""
        start = int(self.tags.get("PlcHeartbeat"))
        deadline = time.monotonic() + self.timeout
        while (int(self.tags.get("PlcHeartbeat")) - start) % 65536 < scans:
            if time.monotonic() > deadline:
                raise ToolsError(f"the PLC's heartbeat did not move within {self.timeout:g} s")
            time.sleep(0.005)

    def log(self, what: str, result: str) -> None:
        append_audit(self.audit, f"tools {what}", result)


def open_audit(path: Path) -> int:
    """The audit log opened for appending (created 0600), or ToolsError: a change that cannot be audited is not
    made."""
    try:
        return os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
    except OSError as exc:
        raise ToolsError(f"{path}: cannot append to the audit log: {exc}") from None


def append_audit(path: Path, what: str, result: str, fd: int | None = None) -> None:
    """One line in the audit log beside the monitor's token, as the runtime logs a monitor write: UTC time, the
    writer's uid and pid, what was changed and its outcome. `fd`: the log opened by open_audit (closed here)."""
    now = datetime.datetime.now(datetime.timezone.utc)
    line = (f"{now:%Y-%m-%dT%H:%M:%S}.{now.microsecond // 1000:03d}Z uid={os.getuid()} pid={os.getpid()} "
            f"{what} -> {result}\n")
    fd = open_audit(path) if fd is None else fd
    try:
        os.write(fd, line.encode())
    except OSError as exc:
        raise ToolsError(f"{path}: cannot append to the audit log: {exc}") from None
    finally:
        os.close(fd)


def describe(r: Row) -> str:
    return (f"T{r.tool} P{r.pocket} group {r.group} life {r.life or 'unlimited'} used {r.used_min}:{r.used_sec:02d}"
            f"{' probe' if r.flags & FLAG_PROBE else ''}")


def checked(answer: int, what: str, say) -> int:
    if answer == 1:
        say(f"{what}: done")
        return EXIT_OK
    say(f"{what}: {ANSWERS.get(answer, f'answer {answer}')}")
    return EXIT_REFUSED


def tool_number(text: str) -> int:
    m = re.fullmatch(r"[Tt]?(\d+)", text)
    if not m or int(m.group(1)) < 1:
        raise ToolsError(f"'{text}' is no tool number (T<n>, n >= 1)")
    return int(m.group(1))


def cmd_list(table: Table, say) -> int:
    n, rows, spindle = table.rows()
    say(f"{n} rows, {len(rows)} tools; spindle: {'empty' if spindle == 0 else f'T{spindle}'}")
    say(f"{'row':>3} {'tool':>5} {'pocket':>6} {'group':>5} {'life':>9} {'used':>8} {'left':>9}  flags")
    for r in rows:
        marks = [m for m, on in (("probe", r.flags & FLAG_PROBE), ("WORN", r.worn), ("in spindle", r.tool == spindle))
                 if on]
        say(f"{r.row:>3} {'T' + str(r.tool):>5} {r.pocket:>6} {r.group:>5} {r.life or 'unlimited':>9} "
            f"{r.used_min:>5}:{r.used_sec:02d} {r.left():>9}  {' '.join(marks)}")
    return EXIT_OK


def cmd_set(table: Table, args, say) -> int:
    tool = tool_number(args.tool)
    n, rows, _ = table.rows()
    mine = next((r for r in rows if r.tool == tool), None)
    if args.row is not None:
        row = args.row
    elif mine is not None:
        row = mine.row
    else:
        used = {r.row for r in rows}
        row = next((i for i in range(1, n + 1) if i not in used), 0)
        if row == 0:
            raise ToolsError(f"no free row for T{tool} (the table has {n} rows): clear one or give --row")
    base = mine if mine is not None and mine.row == row else \
        next((r for r in rows if r.row == row), Row(row, tool, 0))
    if args.pocket is None and (mine is None or mine.row != row):
        raise ToolsError(f"T{tool} is new in row {row}: give its --pocket")
    flags = base.flags
    if args.probe is not None:
        flags = flags | FLAG_PROBE if args.probe else flags & ~FLAG_PROBE
    used = parse_used(args.used) if args.used is not None else (base.used_min, base.used_sec)
    new = Row(row, tool, args.pocket if args.pocket is not None else base.pocket,
              args.group if args.group is not None else base.group,
              args.life if args.life is not None else base.life, *used, flags=flags)
    what = f"set row {row} {describe(new)}"
    return checked(table.edit(EDIT_SET, row, what, new), what, say)


def cmd_reset_or_clear(table: Table, args, code: int, say) -> int:
    tool = tool_number(args.tool)
    _, rows, _ = table.rows()
    mine = next((r for r in rows if r.tool == tool), None)
    if mine is None:
        raise ToolsError(f"T{tool} is in no row of the PLC's tool table (plc tools list)")
    what = f"{'reset' if code == EDIT_RESET else 'clear'} row {mine.row} T{tool}"
    return checked(table.edit(code, mine.row, what), what, say)


def cmd_load(table: Table, path: Path, say) -> int:
    wanted = read_tbl(path)
    n, rows, spindle = table.rows()
    if len(wanted) > n:
        raise ToolsError(f"{path}: {len(wanted)} tools, the PLC's table has {n} rows")
    have = {r.tool: r for r in rows}
    # the spindle tool keeps its row; every other row is freed first, so no tool or pocket is held twice meanwhile
    targets: dict[int, Row] = {}
    free = [i for i in range(1, n + 1)]
    if spindle in have and any(w.tool == spindle for w in wanted):
        free.remove(have[spindle].row)
    for w in wanted:
        old = have.get(w.tool)
        row = old.row if old is not None and w.tool == spindle else free.pop(0)
        used = w.used if w.used is not None else ((old.used_min, old.used_sec) if old else (0, 0))
        flags = (FLAG_PROBE if w.probe else 0) if w.probe is not None else (old.flags if old else 0)
        targets[row] = Row(row, w.tool, w.pocket, w.group if w.group is not None else (old.group if old else 0),
                           w.life if w.life is not None else (old.life if old else 0), *used, flags=flags)
    status = EXIT_OK
    for r in rows:
        if r.tool == spindle and r.row in targets and targets[r.row].tool == spindle:
            continue
        what = f"clear row {r.row} T{r.tool} (load {path.name})"
        answer = table.edit(EDIT_CLEAR, r.row, what)
        if answer != 1:
            status = checked(answer, what, say)
    lines = {w.tool: w.line for w in wanted}
    for row, new in sorted(targets.items()):
        what = f"set row {row} {describe(new)} (load {path.name}:{lines[new.tool]})"
        if checked(table.edit(EDIT_SET, row, what, new), what, say) != EXIT_OK:
            status = EXIT_REFUSED
    say(f"loaded {len(targets)} tools from {path}" if status == EXIT_OK else f"{path}: not every tool was taken")
    return status


def cmd_export(table: Table, path: Path, offsets_from: Path | None, say) -> int:
    _, rows, _ = table.rows()
    offsets = {t.tool: t for t in read_tbl(offsets_from)} if offsets_from else {}
    write_tbl(path, rows, offsets)
    say(f"wrote {len(rows)} tools to {path}")
    return EXIT_OK


# ----------------------------------------------------------------------------------------------- command line --
class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    epilog = "exit status: 0 done, 1 the PLC refused an edit, 2 usage, map, file, token or connection problem"
    p = _Parser(prog="plc tools", description="The PLC's tool table (docs/tools.md): list, set, reset the time "
                "used, clear, load from or export to a LinuxCNC tool table file. Every change is checked by the "
                "PLC, needs the monitor's token file and is written to the audit log.", epilog=epilog)
    p.add_argument("--host", default=None, help="PLC address (default: [linuxcnc] host of the map, 127.0.0.1)")
    p.add_argument("--port", type=int, default=None,
                   help="Modbus/TCP port (default: the machine's run configuration, else the map's 5020)")
    p.add_argument("--map", type=Path, default=None, metavar="FILE", help="register map (modbus_map/map.toml)")
    p.add_argument("--token-file", type=Path, default=None, metavar="FILE",
                   help=f"the monitor's token, needed for changes (default: the machine's, "
                        f"{runtime.DEFAULT_TOKEN_FILE} for the default machine)")
    p.add_argument("--audit", type=Path, default=None, metavar="FILE",
                   help="audit log the changes are appended to (default: audit.log beside the token file)")
    add_view_options(p)
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.add_parser("list", help="every row: tool, pocket, group, life, time used and left, probe, worn",
                   epilog=epilog)
    s = sub.add_parser("set", help="write a tool's row (values not given keep the row's)", epilog=epilog)
    s.add_argument("tool", metavar="T<n>")
    s.add_argument("--row", type=int, help="row to write (default: the tool's row, else the first free one)")
    s.add_argument("--pocket", type=int, help="pocket (needed for a tool new in its row)")
    s.add_argument("--group", type=int, help="group: tools of one group are identical (0 = none)")
    s.add_argument("--life", type=int, metavar="MIN", help="life in minutes of cutting (0 = unlimited)")
    s.add_argument("--used", metavar="MIN[:SS]", help="time used")
    s.add_argument("--probe", action="store_true", default=None, help="the probe tool (one at most)")
    s.add_argument("--no-probe", action="store_false", dest="probe", help="not the probe tool")
    for name, text in (("reset", "time used back to 0 (after a regrind or a new tool)"), ("clear", "free its row")):
        r = sub.add_parser(name, help=text, epilog=epilog)
        r.add_argument("tool", metavar="T<n>")
    ld = sub.add_parser("load", help="the table becomes the tools of a LinuxCNC tool table file", epilog=epilog)
    ld.add_argument("file", type=Path, metavar="FILE.tbl")
    ex = sub.add_parser("export", help="write the table as a LinuxCNC tool table file", epilog=epilog)
    ex.add_argument("file", type=Path, metavar="FILE.tbl")
    ex.add_argument("--offsets-from", type=Path, metavar="TBL",
                    help="copy each tool's other words (offsets, diameter) and comment from this tool table")
    return p


def main(argv: list[str]) -> int:
    parser = build_parser()
    args, code = cliargs.parse(parser, argv)
    if args is None:
        return code
    if args.command is None:
        parser.print_usage(sys.stderr)
        print("plc tools: error: a command is needed: list, set, reset, clear, load, export", file=sys.stderr)
        return EXIT_USAGE

    def say(text: str) -> None:
        print(text, flush=True)

    try:
        rmap = load_map(args.map or default_map())
    except MapError as exc:
        print(f"plc tools: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if rmap.signal("ToolEditRequest") is None or rmap.signal("TableRows") is None:
        print(f"plc tools: error: {rmap.path}: the register map has no tool table (TableRows, ToolEditRequest)",
              file=sys.stderr)
        return EXIT_USAGE
    machine_port, _, machine_token = runtime.project_endpoint(rmap.root)
    token_file = args.token_file or machine_token
    audit = args.audit or token_file.parent / runtime.DEFAULT_AUDIT_FILE.name
    if args.command not in ("list", "export"):
        try:
            if not token_file.read_text(encoding="utf-8").split():
                raise OSError("empty")
        except (OSError, UnicodeDecodeError) as exc:
            print(f"plc tools: error: changes need the monitor's token: {token_file}: {exc}", file=sys.stderr)
            return EXIT_USAGE
    host = args.host or rmap.linuxcnc.host
    port = args.port if args.port is not None else machine_port if machine_port is not None else rmap.linuxcnc.port
    client = ModbusClient(host, port, unit=rmap.linuxcnc.slave_id)
    try:
        client.connect()
    except LinkError as exc:
        print(f"plc tools: error: cannot reach the PLC at {host}:{port}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    table = Table(Tags(rmap, client), audit)
    try:
        if args.command == "list":
            return cmd_list(table, say)
        if args.command == "set":
            return cmd_set(table, args, say)
        if args.command in ("reset", "clear"):
            return cmd_reset_or_clear(table, args, EDIT_RESET if args.command == "reset" else EDIT_CLEAR, say)
        if args.command == "load":
            return cmd_load(table, args.file, say)
        return cmd_export(table, args.file, args.offsets_from, say)
    except (ToolsError, ValueError) as exc:
        print(f"plc tools: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except (LinkError, ModbusException) as exc:
        print(f"plc tools: error: the PLC at {host}:{port}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    finally:
        client.close()
