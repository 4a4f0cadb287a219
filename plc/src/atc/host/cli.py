"""`plc host`: a small CNC host on the register map (the iov2 host end) for the soft-PLC or an OpenPLC runtime.

    plc host "T5 M6"            prepare tool 5, change, print the tool in the spindle
    plc host T5                 prepare only;  plc host M6: change to the prepared tool
    plc host abort [REASON]     emc-abort (default reason 8, TASK_ABORT)
    plc host clear              clear the fault latches (host's and PLC's)
    plc host confirm N          after an interrupted change and `home`: tool N is in the spindle (0 = empty)
    plc host home | status
    plc host M3 | M4 | M5       spindle on (either way) / off: the PLC counts the spindle tool's time (SpindleOn);
                                refused while the PLC inhibits the spindle (the probe tool is in it)
    plc host                    interactive prompt

The host serves the PLC's sequence mailbox (MbxHostActive): each MOVEABS, MOVETOEDGE, FEEDRATE, SPINDLE, MESSAGE or
DIALOG request is printed as a CNC would execute it and answered; DIALOG and MESSAGE ask the operator (OK/cancel)
unless --answer ok|cancel answers them (scripted use).  --no-mailbox leaves the answers to the PLC itself.

Exit status: 0 every command completed; 3 every command ran but a soft fault skipped a change (the G-code
program would continue, with #5600 = 1); 1 a command failed (hard fault, abort, timeout, lost link), the
commands after it did not run; 2 usage, map or connection problems.  Pocket = tool number unless --tool-table
gives another (LinuxCNC .tbl: T<n> P<p>).
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from plc import cliargs, runtime
from plc.modbus import LinkError, ModbusClient, ModbusException
from plc.project import add_view_options, where

from .. import project

from ..map.cli import default_map
from .mailbox import Mailbox, mailbox_in_map, message_texts
from .session import HostError, Session, Timeouts
from .tags import MapError, load_map

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_SKIPPED = 0, 1, 2, 3
PROMPT_HELP = """  Tn            prepare tool n (pocket n, or the tool table's)
  M6            change to the prepared tool
  M3, M4 / M5   spindle on / off (the PLC counts the spindle tool's time; refused while it inhibits the spindle)
  T5 M6         both; several commands per line run in order
  abort [N]     emc-abort with reason N (default 8, TASK_ABORT)
  clear         clear the PLC's fault and the host's fault latch
  home          home the carousel (and the changer: arm back, collet closed)
  confirm N     tool N is in the spindle (0 = empty), when the PLC asks after an interrupted change
  status        tool, pocket, link, states, fault
  quit          leave (Ctrl-D too)"""
COMMANDS = "Tn, M6, M3, M5, abort [REASON], clear, home, confirm N, status"
TOKEN = re.compile(r"^(T\d+|M0*[3-6]|ABORT|CLEAR|CONFIRM|STATUS|HOME|HELP|QUIT|EXIT|\d+)$", re.IGNORECASE)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="plc host", description="A CNC host for the atc-plc register map: the CNC end of LinuxCNC's "
                "iov2 protocol over Modbus/TCP. Commands: Tn (prepare tool n), M6 (change), M3/M4/M5 (spindle on/off), "
                "abort [REASON], "
                "clear, home, confirm N (tool N in the spindle after an interrupted change), status; several per "
                "call (\"T5 M6\"); without commands an interactive prompt.",
                epilog="exit status: 0 done, 3 done but a soft fault skipped a change, 1 a command failed, "
                       "2 usage, map or connection problem")
    p.add_argument("commands", nargs="*", metavar="COMMAND", help="e.g. \"T5 M6\", T0, M6, abort 8, clear")
    p.add_argument("--host", default=None, help="PLC address (default: [linuxcnc] host of the map, 127.0.0.1)")
    p.add_argument("--port", type=int, default=None,
                   help="Modbus/TCP port (default: the machine's run configuration, else the map's 5020)")
    p.add_argument("--map", type=Path, default=None, metavar="FILE", help="register map (modbus_map/map.toml)")
    p.add_argument("--tool-table", type=Path, metavar="FILE", help="LinuxCNC tool table giving each tool's pocket")
    p.add_argument("--timeout", type=float, default=60.0, metavar="S",
                   help="longest wait for a prepare or a change (default 60)")
    p.add_argument("--no-start-change", action="store_true",
                   help="skip the start-change handshake (iov2 without -support-start-change)")
    p.add_argument("--no-mailbox", action="store_true",
                   help="do not serve the sequence mailbox: the PLC acknowledges moves and dialogs itself")
    p.add_argument("--answer", choices=("ask", "ok", "cancel"), default="ask",
                   help="DIALOG/MESSAGE answer: ask the operator (default), or answer OK / cancel automatically")
    p.add_argument("--edge", choices=("reached", "none"), default="reached",
                   help="what a MOVETOEDGE finds: the edge (default) or none over the whole distance")
    p.add_argument("--sequences", type=Path, metavar="FILE",
                   help="sequence set whose MESSAGE/DIALOG texts are shown (default: configs/sequences/"
                        "sequences.toml beside the map's folder, when it exists)")
    p.add_argument("-q", "--quiet", action="store_true", help="print only the result and errors")
    add_view_options(p)
    return p


def read_tool_table(path: Path) -> dict[int, int]:
    """tool -> pocket from a LinuxCNC tool table (T<n> P<p> ...; ';' starts a comment)."""
    pockets: dict[int, int] = {}
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        line = line.split(";", 1)[0].strip()
        if not line:
            continue
        t = re.search(r"\bT(\d+)\b", line, re.IGNORECASE)
        p = re.search(r"\bP(\d+)\b", line, re.IGNORECASE)
        if not t or not p:
            raise ValueError(f"{path}:{number}: expected T<n> P<p>")
        pockets[int(t.group(1))] = int(p.group(1))
    return pockets


def tokens(words: list[str]) -> list[str]:
    """Split 'T5 M6' and 'T5M6' alike into commands; ValueError for anything else."""
    out = []
    for word in " ".join(words).split():
        for part in re.findall(r"[TtMm]\d+|[A-Za-z]+|\d+", word) or [word]:
            if not TOKEN.match(part):
                raise ValueError(f"unknown command '{part}' ({COMMANDS})")
            out.append(part.upper())
        if "".join(re.findall(r"[TtMm]\d+|[A-Za-z]+|\d+", word)) != word:
            raise ValueError(f"cannot read '{word}' ({COMMANDS})")
    return out


def run_commands(session: Session, words: list[str], pockets: dict[int, int], say) -> int:
    """Execute commands in order; stop at the first that fails.  Returns the exit status."""
    status = EXIT_OK
    try:
        todo = tokens(words)
    except ValueError as exc:
        say(f"error: {exc}")
        return EXIT_USAGE
    i = 0
    while i < len(todo):
        cmd = todo[i]
        i += 1
        if cmd.startswith("T"):
            tool = int(cmd[1:])
            outcome = session.prepare(tool, pockets.get(tool, tool))
        elif cmd.startswith("M") and int(cmd[1:]) == 6:
            outcome = session.change()
        elif cmd.startswith("M"):
            outcome = session.spindle(int(cmd[1:]) != 5)
        elif cmd == "ABORT":
            reason = 8
            if i < len(todo) and todo[i].isdigit():
                reason, i = int(todo[i]), i + 1
            outcome = session.abort(reason)
        elif cmd == "CLEAR":
            outcome = session.clear()
        elif cmd == "HOME":
            outcome = session.home()
        elif cmd == "CONFIRM":
            if i >= len(todo) or not todo[i].isdigit():
                say("error: confirm needs the tool in the spindle: confirm N (0 = empty)")
                return EXIT_USAGE
            outcome = session.confirm(int(todo[i]))
            i += 1
        elif cmd == "STATUS":
            for line in session.status():
                say(line)
            continue
        elif cmd.isdigit():
            say(f"error: a number must follow abort (got '{cmd}')")
            return EXIT_USAGE
        else:
            say(f"error: '{cmd.lower()}' is only for the interactive prompt")
            return EXIT_USAGE
        say(outcome.text)
        if not outcome.ok:
            return EXIT_FAILED
        if outcome.reason > 0:
            status = EXIT_SKIPPED
    return status


def interactive(session: Session, pockets: dict[int, int], say) -> int:
    say("atc-plc host: Tn, M6, abort [REASON], clear, home, confirm N, status, quit (the host heartbeat keeps running)")
    status = EXIT_OK
    while True:
        try:
            line = input("atc> ")
        except EOFError:
            print()
            return status
        words = line.split()
        if not words:
            continue
        if words[0].lower() in ("quit", "exit"):
            return status
        if words[0].lower() == "help":
            say(PROMPT_HELP)
            continue
        try:
            status = max(status, run_commands(session, words, pockets, say))
        except HostError as exc:
            say(f"error: {exc}")
            status = EXIT_FAILED
            if "link" in str(exc).lower() or "stopped" in str(exc).lower():
                return status


def main(argv: list[str]) -> int:
    parser = build_parser()
    args, code = cliargs.parse(parser, argv)
    if args is None:
        return code

    def say(text: str) -> None:
        print(text, flush=True)

    def quiet_say(text: str) -> None:
        if text.startswith(("error", "M6", "toolchanger fault", "tool ")):
            print(text, flush=True)

    out = quiet_say if args.quiet else say
    try:
        rmap = load_map(args.map or default_map())
    except MapError as exc:
        print(f"plc host: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    pockets: dict[int, int] = {}
    if args.tool_table:
        try:
            pockets = read_tool_table(args.tool_table)
        except (OSError, ValueError) as exc:
            print(f"plc host: error: {exc}", file=sys.stderr)
            return EXIT_USAGE
    if args.commands:
        try:
            tokens(args.commands)
        except ValueError as exc:
            print(f"plc host: error: {exc}", file=sys.stderr)
            return EXIT_USAGE
    texts: dict[int, str] = {}
    if not args.no_mailbox:
        root = where(args.map or default_map()).parent.parent
        index = args.sequences or root / project.sequence_index(root)
        if args.sequences or index.exists():
            try:
                texts = message_texts(index)
            except (OSError, ValueError) as exc:
                print(f"plc host: error: {index}: {exc}", file=sys.stderr)
                return EXIT_USAGE
    host = args.host or rmap.linuxcnc.host
    machine_port, _, _ = runtime.project_endpoint(rmap.root)
    port = args.port if args.port is not None else machine_port if machine_port is not None else rmap.linuxcnc.port
    client = ModbusClient(host, port, unit=rmap.linuxcnc.slave_id)
    try:
        client.connect()
    except LinkError as exc:
        print(f"plc host: error: {exc} (is `plc run` running?)", file=sys.stderr)
        return EXIT_USAGE
    session = Session(rmap, client, say=out, timeouts=Timeouts(request=args.timeout),
                      start_change=not args.no_start_change)
    mailbox = None
    if not args.no_mailbox and mailbox_in_map(session.tags):
        mailbox = Mailbox(session.tags, say=out, answer=args.answer, edge=args.edge == "reached", texts=texts)
        try:
            session.attach_mailbox(mailbox)
        except ValueError as exc:
            print(f"plc host: error: {exc}", file=sys.stderr)
            return EXIT_USAGE
    status = EXIT_FAILED
    try:
        s = session.start()
        if not args.quiet:
            say(f"connected to {host}:{port}: tool {session.tool_number} in spindle"
                + (f", fault latched ({session.fault_reason})" if session.faulted else ""))
        if mailbox is not None:
            mailbox.announce()
        if args.commands:
            status = run_commands(session, args.commands, pockets, out)
        else:
            status = interactive(session, pockets, say)
        if status in (EXIT_OK, EXIT_SKIPPED):
            print(f"tool {int(session.tags.get('ToolInSpindle'))} in spindle", flush=True)
        del s
    except HostError as exc:
        print(f"plc host: error: {exc}", file=sys.stderr)
        status = EXIT_FAILED
    except ModbusException as exc:
        print(f"plc host: error: the PLC refused a request: {exc}", file=sys.stderr)
        status = EXIT_FAILED
    except LinkError as exc:
        print(f"plc host: error: {exc}", file=sys.stderr)
        status = EXIT_FAILED
    except KeyboardInterrupt:
        print("plc host: interrupted: aborting", file=sys.stderr)
        try:
            session.abort()
        except Exception as exc:          # the link may be the reason for the interrupt
            print(f"plc host: the abort failed too: {exc}", file=sys.stderr)
        status = 130
    finally:
        session.stop()
        if mailbox is not None:
            try:
                mailbox.retire()
            except Exception:                 # the link may be gone: the PLC's default is FALSE after a restart
                pass
        client.close()
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
