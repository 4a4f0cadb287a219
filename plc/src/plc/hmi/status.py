"""`plc status`: the runtime's diagnostic block (input registers 1024-1087) read over Modbus, with names.

The layout is runtime.h's enum diag_offset; a test reads that header and proves DIAG below agrees with it.
Works against our runtime only (OpenPLC has no input registers there: the read fails, exit 2).

Exit status: 0 the PLC runs, 1 it is faulted or stopping, 2 no connection or no diagnostic block.
"""
from __future__ import annotations

import argparse
import sys

from .. import cliargs, runtime
from ..project import add_view_options, project_root
from plc.modbus import LinkError, ModbusClient, ModbusException

DIAG_BASE, DIAG_COUNT = 1024, 64
# name: (offset, words); times in microseconds
DIAG = {
    "version": (0, 1), "state": (1, 1), "fault_kind": (2, 1), "fault_line": (3, 1), "fault_col": (4, 1),
    "flags": (5, 1), "base_tick_us": (6, 2), "scan_count": (8, 4), "scan_last_us": (12, 2),
    "scan_min_us": (14, 2), "scan_max_us": (16, 2), "scan_mean_us": (18, 2), "scan_p99_us": (20, 2),
    "wake_last_us": (22, 2), "wake_min_us": (24, 2), "wake_max_us": (26, 2), "wake_mean_us": (28, 2),
    "wake_p99_us": (30, 2), "overruns": (32, 2), "clients": (34, 1), "requests": (36, 2), "exceptions": (38, 2),
    "refused": (40, 2), "retain_saves": (42, 2), "scan_p50_us": (44, 2), "wake_p50_us": (46, 2),
    "uptime_s": (48, 2), "skipped": (50, 2), "dropped": (52, 2), "app_fault": (54, 1),
    "writes": (56, 2), "writes_refused": (58, 2),
}
SIGNED = {"app_fault"}
# the I/O device block (--io modbus): 8 words per remote I/O device in configuration order, its state first
IO_BASE, IO_WORDS, IO_MAX = DIAG_BASE + DIAG_COUNT, 8, 16
IO_STATES = {0: "unused", 1: "waiting", 2: "ok", 3: "LOST"}
IO_LOST = 3
STATES = {0: "STARTING", 1: "RUNNING", 2: "FAULTED (program stopped, outputs safe, Modbus serving)", 3: "STOPPING"}
FAULTS = {0: "none", 1: "integer division by zero", 2: "array index out of bounds", 3: "value outside its subrange",
          4: "assertion failed", 90: "scan watchdog", 99: "program fault"}
FLAGS = {0x01: "real-time scan", 0x02: "retained values restored", 0x04: "retain file rejected",
         0x08: "last retain save failed", 0x10: "simulated I/O", 0x20: "unused saved values kept aside"}


def decode(words: list[int]) -> dict[str, int]:
    out = {}
    for name, (off, n) in DIAG.items():
        v = 0
        for w in words[off:off + n]:
            v = (v << 16) | w
        if name in SIGNED and v >= 0x8000:
            v -= 0x10000
        out[name] = v
    return out


def read(client: ModbusClient) -> dict[str, int]:
    """The diagnostic block, with `io_states`: the state of each configured remote I/O device, in order."""
    d = decode(client.read_input_registers(DIAG_BASE, DIAG_COUNT))
    half = IO_WORDS * IO_MAX // 2           # a read is at most 125 registers (Modbus)
    io = client.read_input_registers(IO_BASE, half) + client.read_input_registers(IO_BASE + half, half)
    d["io_states"] = [io[i * IO_WORDS] for i in range(IO_MAX) if io[i * IO_WORDS] != 0]
    return d


def healthy(d: dict) -> bool:
    """Running, no application fault latched, no remote I/O device lost: what exit status 0 says."""
    return d["state"] == 1 and d.get("app_fault", 0) == 0 and IO_LOST not in d.get("io_states", [])


def render(d: dict[str, int]) -> list[str]:
    flags = [t for bit, t in FLAGS.items() if d["flags"] & bit]
    lines = [f"state       {STATES.get(d['state'], d['state'])}"]
    if d.get("app_fault"):
        lines.append(f"application fault {d['app_fault']} latched (the program runs; `plc host status` names it)")
    if d.get("io_states"):
        lost = [str(i + 1) for i, st in enumerate(d["io_states"]) if st == IO_LOST]
        lines.append(f"io devices  {len(d['io_states'])}: " + ", ".join(
            f"{i + 1} {IO_STATES.get(st, st)}" for i, st in enumerate(d["io_states"]))
            + (f" (device {', '.join(lost)} lost: its inputs are stale, its outputs safe)" if lost else ""))
    if d["fault_kind"]:
        lines.append(f"fault       {FAULTS.get(d['fault_kind'], d['fault_kind'])} (kind {d['fault_kind']}) at line "
                     f"{d['fault_line']}, column {d['fault_col']}")
    lines += [
        f"uptime      {d['uptime_s']} s, {d['scan_count']} scans of {d['base_tick_us'] / 1000:g} ms",
        f"scan        last {d['scan_last_us']} us, p50 {d['scan_p50_us']}, p99 {d['scan_p99_us']}, "
        f"max {d['scan_max_us']}, mean {d['scan_mean_us']}",
        f"wake-up     p50 {d['wake_p50_us']} us, p99 {d['wake_p99_us']}, max {d['wake_max_us']}; overruns "
        f"{d['overruns']}, skipped {d['skipped']}",
        f"modbus      {d['clients']} client(s), {d['requests']} requests, {d['exceptions']} exceptions, "
        f"{d['refused']} refused, {d['dropped']} dropped; writes {d['writes']} served, {d['writes_refused']} refused",
        f"retain      {d['retain_saves']} saves",
        f"flags       {', '.join(flags) if flags else 'none'}",
    ]
    return lines


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="plc status", description="Read the soft-PLC's diagnostic block (input "
                                "registers 1024-1087): state, fault, scan and wake-up times, Modbus counters.",
                                epilog="exit status: 0 running with no application fault and no remote I/O "
                                       "device lost, 1 faulted or stopping, an application fault latched or a "
                                       "device lost, 2 no connection or no diagnostic block")
    p.add_argument("--host", default="127.0.0.1", help="PLC address (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=None,
                   help="Modbus/TCP port (default: the project's run configuration's, else 5020)")
    p.add_argument("--json", action="store_true", help="print the raw fields as JSON")
    add_view_options(p)
    args, code = cliargs.parse(p, argv)
    if args is None:
        return code
    if args.port is None:
        args.port = runtime.project_endpoint(project_root())[0] or runtime.DEFAULT_PORT
    client = ModbusClient(args.host, args.port)
    try:
        client.connect()
        d = read(client)
    except (LinkError, ModbusException) as exc:
        print(f"plc status: error: {exc}", file=sys.stderr)
        return 2
    finally:
        client.close()
    if args.json:
        import json
        print(json.dumps(d, indent=1))
    else:
        print("\n".join(render(d)))
    return 0 if healthy(d) else 1
