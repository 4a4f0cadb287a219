"""The soft-PLC runtime, Python side: build the C runtime with a program, and `plc run`.

``build_runtime(program_c, out_dir)`` compiles the runtime sources in ``plc/src/plc/native/runtime/``
together with one program C file (written against ``plc/src/plc/native/include/plc_abi.h``) into an
executable, cached by the content of everything that goes into it.

``run_command(args, program_c)`` implements ``plc run``: it reads the optional TOML
configuration, applies the command-line options on top, builds if needed and replaces
the current process with the runtime (which then owns the terminal and the signals).

Configuration file (every key optional; paths relative to the file's directory)::

    [modbus]
    bind = "127.0.0.1"              # IPv4 address to listen on
    port = 5020
    max_clients = 32
    frame_timeout_ms = 2000         # a request begun must be complete (and responses read) within this
    read_only = false               # true: every write function code answered with exception 01
    allow = ["127.0.0.1", "192.168.1.0/24"]   # role engineer; no allow and no [[modbus.client]]: any client
    writable_coils = ["400-799"]              # what an engineer may write; [] = none
    writable_registers = ["512-8191"]
    host_coils = ["400-407"]                  # of those, what a host may write (default: the application's
    host_registers = ["512-534"]              # host-writable ranges, else every writable one)

    [[modbus.client]]                         # a client (or network) with a role: read, host or engineer
    address = "192.168.1.20"                  # the longest prefix holding a client's address decides its role
    role = "host"

    [modbus.tls]                    # Modbus/TCP Security (MBAPS): a TLS listener beside the plain one
    cert = "tls/server.pem"         # the runtime's certificate, its key, the CA of the clients' certificates
    key = "tls/server.key"          #   (PEM; `plc tls` makes them); the role is the client certificate's
    ca = "tls/ca.pem"               #   role extension; --allow and [[modbus.client]] are the plain listener's
    port = 802                      # the default (below 1024: root or CAP_NET_BIND_SERVICE); 0 = any free port
    bind = "0.0.0.0"                # default: [modbus] bind (keep that one 127.0.0.1 for mb2hal)

    [io]
    layer = "sim"                   # "sim", "none" or "modbus"
    # [[io.device]] tables: the remote I/O devices of layer "modbus" (see plc/src/plc/io_config.py)

    [retain]
    file = "var/plc.retain"
    interval_ms = 200               # minimum time between two saves
    registers = ["1024-1039"]       # holding registers saved with the RETAIN variables

    [monitor]                       # watch, write and force (plc monitor, plc hmi): a Unix socket, mode 0600
    enabled = true                  # the three files default to the retain file's directory (var/)
    socket = "var/plc.monitor"
    token_file = "var/monitor.token"   # created (random, mode 0600) when missing; writes need it
    audit_file = "var/audit.log"       # every write, force and refused token

    [scan]
    realtime = true                 # ask for SCHED_FIFO
    rt_priority = 50                # 1..98: the watchdog thread runs one level above
    # cpu = 1                       # pin the scan thread (only it) to this CPU (default: not pinned)
    # cpu_latency_us = 0            # no CPU idle state slower to wake than this while running (PM QoS)
    status_interval_s = 10          # status log line period when not on a terminal
    watchdog_ms = 1000              # longest run() call before outputs are forced safe (0 = off)
"""

from __future__ import annotations

import argparse
import dataclasses
import errno
import hashlib
import ipaddress
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Sequence

from . import buildcache, io_config, project, tomlconf
from .diagnostics import Diagnostic
from .tomlconf import Bool, Check, Field, Int, Invalid, OneOf, Table, ipv4
from .extensions import RunSetup
from .resources import INCLUDE as INCLUDE_DIR, RUNTIME_SRC as RUNTIME_DIR

NO_EVENTS = "events_none.c"       # the runtime without application events; an observer's C source replaces it

BINARY_NAME = "plc-runtime"

COILS = 800                 # %QX0.0 .. %QX99.7
HOLDING_REGISTERS = 8192    # %QW, %MW, %MD, %ML
DEFAULT_PORT = 5020
DEFAULT_TLS_PORT = 802      # Modbus/TCP Security's registered port
DEFAULT_RETAIN_FILE = Path("var") / "plc.retain"
DEFAULT_BUILD_DIR = Path("build") / "runtime"
DEFAULT_MONITOR_SOCKET = Path("var") / "plc.monitor"
DEFAULT_TOKEN_FILE = Path("var") / "monitor.token"
DEFAULT_AUDIT_FILE = Path("var") / "audit.log"

WARNINGS = ["-std=c11", "-Wall", "-Wextra", "-Werror"]
OPTIMISE = ["-O2", "-g"]
SANITIZE = ["-O1", "-g", "-fno-omit-frame-pointer", "-fsanitize=address,undefined",
            "-fno-sanitize-recover=undefined"]

IO_LAYERS = ("sim", "none", "modbus")
MAX_CPU = 1023              # CPU_SETSIZE - 1 of glibc: the highest CPU number --cpu accepts

APT_HINT = "install the Debian packages gcc, make, pkg-config, libmodbus-dev and libssl-dev"


class RuntimeBuildError(Exception):
    """The runtime could not be built; str() is a message for the user (no traceback needed).

    `program_refused`: the C compiler reported an error in the program's C file itself (not in the runtime or a
    missing library); `output` is everything it printed.  For C that plc generated that is a bug of plc."""

    def __init__(self, message: str, program_refused: bool = False, output: str = "",
                 command: Sequence[str] = ()) -> None:
        super().__init__(message)
        self.program_refused, self.output, self.command = program_refused, output, list(command)


class ConfigError(Exception):
    """The run configuration is invalid; str() says where and why (`problems`: one positioned line each)."""

    def __init__(self, message: str, problems: Sequence[str] = ()) -> None:
        super().__init__(message)
        self.problems = list(problems) or [message]


# --------------------------------------------------------------------------- build

def _library_flags(package: str, name: str, header: str, cflags: list[str],
                   libs: list[str]) -> tuple[list[str], list[str]]:
    """A library's compiler and linker flags from pkg-config, else the given ones when its header is installed."""
    if shutil.which("pkg-config"):
        found = [subprocess.run(["pkg-config", flag, package], capture_output=True, text=True)
                 for flag in ("--cflags", "--libs")]
        if all(r.returncode == 0 for r in found):
            return found[0].stdout.split(), found[1].stdout.split()
    if Path(header).exists():
        return cflags, libs
    raise RuntimeBuildError(f"{name} not found: {APT_HINT}")


def _modbus_flags() -> tuple[list[str], list[str]]:
    return _library_flags("libmodbus", "libmodbus", "/usr/include/modbus/modbus.h", ["-I/usr/include/modbus"],
                          ["-lmodbus"])


def _openssl_flags() -> tuple[list[str], list[str]]:
    """OpenSSL's compiler and linker flags (the TLS listener, modbus_server.c)."""
    return _library_flags("openssl", "OpenSSL", "/usr/include/openssl/ssl.h", [], ["-lssl", "-lcrypto"])


def _compiler() -> str:
    cc = os.environ.get("CC", "gcc")
    if shutil.which(cc) is None:
        raise RuntimeBuildError(f"C compiler '{cc}' not found: {APT_HINT}")
    return cc


def _dependencies(cc: str, program_c: Path, cppflags: list[str]) -> list[Path]:
    """The program file and every non-system header it includes (gcc -MM)."""
    result = subprocess.run([cc, "-MM", *cppflags, str(program_c)], capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeBuildError(f"cannot read the includes of {program_c}:\n{_trim(result.stderr)}")
    text = result.stdout.replace("\\\n", " ")
    deps = text.split(":", 1)[1].split() if ":" in text else []
    return [Path(d) for d in deps]


def _trim(text: str, lines: int = 60) -> str:
    parts = text.strip().splitlines()
    if len(parts) > lines:
        parts = parts[:lines] + [f"... ({len(parts) - lines} more lines)"]
    return "\n".join(parts)


def build_runtime(program_c: Path, out_dir: Path, sanitize: bool = False,
                  include_dirs: Sequence[Path] = (), observer: Path | None = None) -> Path:
    """Compile the runtime with `program_c`; return the executable (reused when nothing changed).

    `observer` is the C source of an application's events (monitor.h), linked in place of events_none.c.

    The cache key covers the compiler version, the flags, the runtime sources and
    headers, and the program file with every header it includes.  `sanitize` builds
    with AddressSanitizer and UndefinedBehaviorSanitizer.  Raises RuntimeBuildError.
    """
    program_c = Path(program_c)
    out_dir = Path(out_dir)
    if not program_c.is_file():
        raise RuntimeBuildError(f"program C file {program_c} does not exist")
    sources = sorted(RUNTIME_DIR.glob("*.c"))
    if not sources:
        raise RuntimeBuildError(f"runtime sources not found in {RUNTIME_DIR}")
    if observer is not None:
        if not Path(observer).is_file():
            raise RuntimeBuildError(f"the application's events source {observer} does not exist")
        sources = [s for s in sources if s.name != NO_EVENTS] + [Path(observer)]
    cc = _compiler()
    modbus_cflags, modbus_libs = _modbus_flags()
    ssl_cflags, ssl_libs = _openssl_flags()
    cppflags = ["-I" + str(RUNTIME_DIR), "-I" + str(INCLUDE_DIR)]
    cppflags += ["-I" + str(Path(d).resolve()) for d in include_dirs] + modbus_cflags + ssl_cflags
    cflags = WARNINGS + (SANITIZE if sanitize else OPTIMISE)
    libs = modbus_libs + ssl_libs + ["-lpthread", "-lm"]

    version = subprocess.run([cc, "--version"], capture_output=True, text=True).stdout.splitlines()[:1]
    digest = hashlib.sha256()
    for item in [cc, *version, *cflags, *cppflags, *libs]:
        digest.update(item.encode() + b"\0")
    inputs = sources + sorted(RUNTIME_DIR.glob("*.h")) + [INCLUDE_DIR / "plc_abi.h"]
    program_deps = _dependencies(cc, program_c, cppflags)
    for path in inputs + program_deps:
        digest.update(str(path.name).encode() + b"\0")
        digest.update(path.read_bytes())
    name = f"{BINARY_NAME}-{digest.hexdigest()[:16]}" + ("-asan" if sanitize else "")
    target = out_dir / name
    if target.is_file() and os.access(target, os.X_OK):
        return target

    out_dir.mkdir(parents=True, exist_ok=True)
    # the runtime's own sources as objects reused by every program (PLC_RUNTIME_OBJECTS: one directory for many
    # build directories, as the test suite sets it), compiled in parallel; the program compiled alone
    shared = os.environ.get("PLC_RUNTIME_OBJECTS")
    obj_dir = Path(shared) if shared else out_dir / "objects"
    head = "\0".join([cc, *version, *cflags, *cppflags])
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        objects = list(pool.map(lambda src: _runtime_object(cc, cflags, cppflags, src, obj_dir, head), sources))
    fd, program_o = tempfile.mkstemp(prefix=name + ".", suffix=".o", dir=out_dir)
    os.close(fd)
    fd, tmp_name = tempfile.mkstemp(prefix=name + ".", dir=out_dir)
    os.close(fd)
    try:
        command = [cc, *cflags, *cppflags, "-c", str(program_c), "-o", program_o]
        cache = buildcache.active()
        if cache is None:
            result = subprocess.run(command, capture_output=True, text=True)
        else:       # the program's object from the build cache plc build and plc test share, keyed by its text
            try:
                unit = buildcache.Unit(program_c.stem, program_c.read_text())
                (cached,) = buildcache.compile_units(cache, [unit], cc, [*cflags, *cppflags],
                                                     program_deps[1:], program_c.parent)
                shutil.copyfile(cached, program_o)
                result = subprocess.CompletedProcess(command, 0, "", "")
            except buildcache.UnitError as e:
                command = e.command
                result = subprocess.CompletedProcess(command, 1, "", e.output)
        if result.returncode == 0:
            command = [cc, *cflags, *map(str, objects), program_o, "-o", tmp_name, *libs]
            result = subprocess.run(command, capture_output=True, text=True)
        if result.returncode != 0:
            hint = f"\nhint: {APT_HINT}" if "modbus.h" in result.stderr or "openssl/" in result.stderr else ""
            # gcc and clang name the file of each error first: "FILE:LINE:COL: error: ..."
            refused = any(line.startswith(f"{program_c}:") and ": error:" in line
                          for line in result.stderr.splitlines())
            raise RuntimeBuildError(f"building the runtime with {program_c} failed:\n"
                                    f"{_trim(result.stderr)}{hint}", refused, result.stdout + result.stderr, command)
        os.chmod(tmp_name, 0o755)
        os.replace(tmp_name, target)
    finally:
        for leftover in (program_o, tmp_name):
            if os.path.exists(leftover):
                os.unlink(leftover)
    return target


def _runtime_object(cc: str, cflags: list[str], cppflags: list[str], source: Path, obj_dir: Path,
                    head: str) -> Path:
    """`source` (a runtime source, or an application's events source) compiled to an object in `obj_dir`, named
    by a hash of the compiler, the flags, the source and every header it includes: reused when present."""
    digest = hashlib.sha256(head.encode())
    for path in _dependencies(cc, source, cppflags):
        digest.update(str(path.name).encode() + b"\0")
        digest.update(path.read_bytes())
    obj = obj_dir / f"{source.stem}-{digest.hexdigest()[:20]}.o"
    if obj.is_file():
        return obj
    obj_dir.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=obj.name + ".", suffix=".o", dir=obj_dir)
    os.close(fd)
    command = [cc, *cflags, *cppflags, "-c", str(source), "-o", tmp]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        os.unlink(tmp)
        hint = f"\nhint: {APT_HINT}" if "modbus.h" in result.stderr or "openssl/" in result.stderr else ""
        raise RuntimeBuildError(f"building the runtime ({source.name}) failed:\n{_trim(result.stderr)}{hint}",
                                False, result.stdout + result.stderr, command)
    os.replace(tmp, obj)
    return obj


# -------------------------------------------------------------------------- config

@dataclasses.dataclass
class RunConfig:
    bind: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    max_clients: int = 32
    frame_timeout_ms: int = 2000
    read_only: bool = False
    allow: list[str] = dataclasses.field(default_factory=list)      # "ADDR/BITS" (engineer) or "ADDR/BITS=ROLE"
    writable_coils: list[str] | None = None          # None: the runtime's default
    writable_registers: list[str] | None = None
    host_coils: list[str] | None = None              # None: the application's host ranges, else the writable ones
    host_registers: list[str] | None = None
    io: str = "sim"                                  # the default: outputs loop back to inputs
    io_chosen: bool = False                          # the layer was asked for (--io, [io] layer), not the default
    io_devices: list[str] = dataclasses.field(default_factory=list)   # --io-device specs ([[io.device]])
    devices: list[io_config.IoDevice] = dataclasses.field(default_factory=list)   # the same, as checked
    retain_file: Path | None = None                  # None: DEFAULT_RETAIN_FILE
    retain_interval_ms: int = 200
    retain_registers: list[str] = dataclasses.field(default_factory=list)
    realtime: bool = True
    rt_priority: int = 50
    cpu: int | None = None                           # None: the scan thread is not pinned
    cpu_latency_us: int | None = None                # None: the kernel's idle states (no PM QoS request)
    status_interval_s: float = 10.0
    watchdog_ms: int = 1000
    monitor: bool = True
    monitor_socket: Path | None = None               # None: beside the retain file (plc.monitor)
    token_file: Path | None = None                   # None: beside the retain file (monitor.token)
    audit_file: Path | None = None                   # None: beside the retain file (audit.log)
    events_file: Path | None = None                  # set by `plc run` from the application (plc.extensions)
    sim_flag: str | None = None                      # [io] sim_flag / --sim-flag: %IXa.b held TRUE by --io sim
    tls_cert: Path | None = None                     # [modbus.tls]: None: no TLS listener
    tls_key: Path | None = None
    tls_ca: Path | None = None
    tls_port: int = DEFAULT_TLS_PORT
    tls_bind: str | None = None                      # None: bind


def _ranges(limit: int) -> Check:
    """Addresses and ranges "FIRST-LAST" of 0..limit-1 (one string or a list), normalised to "FIRST-LAST"."""
    def check(value: Any) -> list[str]:
        if isinstance(value, str):
            value = [value]
        if not isinstance(value, list):
            raise Invalid(f"expected a list of ranges like [\"400-799\"], got {value!r}")
        out = []
        for item in value:
            text = str(item).strip() if isinstance(item, (str, int)) and not isinstance(item, bool) else None
            lo_text, _, hi_text = (text or "").partition("-")
            if text is None or not lo_text.strip().isdigit() or (hi_text and not hi_text.strip().isdigit()):
                raise Invalid(f"{item!r} is not an address or a range 'FIRST-LAST'")
            lo = int(lo_text)
            hi = int(hi_text) if hi_text else lo
            if lo > hi or hi >= limit:
                raise Invalid(f"range {item!r} is outside 0-{limit - 1}")
            out.append(f"{lo}-{hi}")
        return out
    return Check(check, f"ranges of 0-{limit - 1}")


def _network(value: Any) -> str:
    try:
        return str(ipaddress.IPv4Network(value, strict=False))
    except (ipaddress.AddressValueError, ipaddress.NetmaskValueError, ValueError, TypeError):
        raise Invalid(f"{value!r} is not an IPv4 address or ADDR/BITS") from None


def _allow_list(value: Any) -> list[str]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list):
        raise Invalid("expected a list of addresses")
    if len(value) > 32:
        raise Invalid("at most 32 entries")
    return [_network(a) for a in value]


def _discrete_input(value: Any) -> str:
    """A discrete input of OpenPLC's map written %IXa.b (a 0..99, b 0..7)."""
    m = re.fullmatch(r"%IX(\d{1,2})\.([0-7])", value) if isinstance(value, str) else None
    if m is None:
        raise Invalid(f"expected a discrete input %IX0.0..%IX99.7, got {value!r}")
    return value


def _file_name(value: Any) -> Path:
    if not isinstance(value, str) or not value:
        raise Invalid("expected a file name")
    return Path(value)


def _seconds(value: Any) -> float:
    if not isinstance(value, (int, float)) or isinstance(value, bool) or value < 0.1:
        raise Invalid("expected a number of seconds >= 0.1")
    return float(value)


IPV4, DISCRETE_INPUT, FILE_NAME = Check(ipv4, "an IPv4 address"), Check(_discrete_input), Check(_file_name)

# The run configuration's schema: section -> its keys.  Where a key sets a RunConfig field of another name,
# _FIELD_OF says which; a file name is relative to the configuration's directory.
RUN_CONFIG = {
    "modbus": Table((
        Field("bind", IPV4, "IPv4 address to listen on"),
        Field("port", Int(0, 65535), "Modbus/TCP port"),
        Field("max_clients", Int(1, 256)),
        Field("frame_timeout_ms", Int(1, 3600000), "a request begun must be complete within this"),
        Field("read_only", Bool(), "every write function code answered with exception 01"),
        Field("allow", Check(_allow_list), "client addresses or networks (empty: any client)"),
        Field("writable_coils", _ranges(COILS), "coils a client may write"),
        Field("writable_registers", _ranges(HOLDING_REGISTERS), "holding registers a client may write"),
        Field("host_coils", _ranges(COILS), "of the writable coils, those a client of role host may write"),
        Field("host_registers", _ranges(HOLDING_REGISTERS), "of the writable registers, those a host may write"),
        Field("client", Check(lambda v: v), "[[modbus.client]]: a client address with its role"),
        Field("tls", Check(lambda v: v), "[modbus.tls]: Modbus/TCP Security, a TLS listener"))),
    "io": Table((
        Field("layer", OneOf(IO_LAYERS), "the I/O layer"),
        Field("device", Check(lambda v: v), "[[io.device]]: the remote I/O of layer modbus (io_config)"),
        Field("sim_flag", DISCRETE_INPUT, "%IXa.b held TRUE by --io sim"))),
    "retain": Table((
        Field("file", FILE_NAME, "the retained data"),
        Field("interval_ms", Int(0, 3600000), "minimum time between two saves"),
        Field("registers", _ranges(HOLDING_REGISTERS), "holding registers saved with the RETAIN variables"))),
    "scan": Table((
        Field("realtime", Bool(), "ask for SCHED_FIFO"),
        Field("rt_priority", Int(1, 98), "1..98: the watchdog thread runs one level above"),
        # the machine that runs it may not be this one: the runtime checks the CPU is online
        Field("cpu", Int(0, MAX_CPU), "pin the scan thread to this CPU"),
        Field("cpu_latency_us", Int(0, 2000000000), "PM QoS: no CPU idle state slower to wake than this"),
        Field("status_interval_s", Check(_seconds), "status log line period when not on a terminal"),
        Field("watchdog_ms", Int(0, 3600000), "longest run() call before outputs are forced safe (0 = off)"))),
    "monitor": Table((
        Field("enabled", Bool(), "watch, write and force over a Unix socket"),
        Field("socket", FILE_NAME), Field("token_file", FILE_NAME), Field("audit_file", FILE_NAME))),
}
_FIELD_OF = {("io", "layer"): "io", ("retain", "file"): "retain_file", ("retain", "interval_ms"): "retain_interval_ms",
             ("retain", "registers"): "retain_registers", ("monitor", "enabled"): "monitor",
             ("monitor", "socket"): "monitor_socket"}
_NOT_FIELDS = {("io", "device"), ("modbus", "client"), ("modbus", "tls")}

ROLES = ("read", "host", "engineer")
MAX_ALLOW = 32              # RT_MAX_ALLOW of the runtime: allow entries and [[modbus.client]] tables together
CLIENT = Table((
    Field("address", Check(_network), "an IPv4 address or ADDR/BITS", required=True),
    Field("role", OneOf(ROLES), "read, host or engineer", required=True)))


def check_clients(doc: tomlconf.Document, entries: Any, allow: list[str]) -> list[str]:
    """The `[[modbus.client]]` tables of a run configuration as allowlist entries "ADDR/BITS=ROLE", after the
    engineers of `allow`; every problem into doc (one network given two roles: at the second one)."""
    base = ("modbus", "client")
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        doc.error(base, "modbus.client: write each client as a [[modbus.client]] table with address and role")
        return []
    roles = {a: ("engineer", "[modbus] allow") for a in allow}
    out = []
    for n, entry in enumerate(entries):
        where = f"[[modbus.client]] {n + 1}"
        checked = CLIENT.check(doc, base + (n,), entry, where + ":")
        if not checked.ok:
            continue
        net, role = checked["address"], checked["role"]
        if net in roles and roles[net][0] != role:
            doc.error(base + (n, "address"), f"{where}: {net} has the role {roles[net][0]} already "
                      f"({roles[net][1]}): one role per address")
            continue
        roles[net] = (role, where)
        out.append(f"{net}={role}")
    if len(allow) + len(out) > MAX_ALLOW:
        doc.error(base, f"[modbus] allow and [[modbus.client]]: at most {MAX_ALLOW} entries together, "
                  f"{len(allow) + len(out)} given")
    return out


TLS = Table((
    Field("cert", FILE_NAME, "the runtime's certificate (PEM)", required=True),
    Field("key", FILE_NAME, "the private key of cert (PEM, not encrypted)", required=True),
    Field("ca", FILE_NAME, "the CA certificate(s) that sign the clients' certificates (PEM)", required=True),
    Field("port", Int(0, 65535), f"the TLS port (default {DEFAULT_TLS_PORT}; 0: any free port)"),
    Field("bind", IPV4, "IPv4 address of the TLS listener (default: [modbus] bind)")))


def check_tls(doc: tomlconf.Document, value: Any, cfg: RunConfig, base: Path) -> None:
    """`[modbus.tls]` into cfg: the files relative to `base` (the configuration's directory), each read as the
    runtime will (a certificate, a key that belongs to it, CA certificates); every problem into doc at its key."""
    path = ("modbus", "tls")
    checked = TLS.check(doc, path, value, "[modbus.tls]")
    files = {k: Path(os.path.normpath(base / checked[k])) for k in ("cert", "key", "ca") if k in checked}
    cfg.tls_port = checked.get("port", DEFAULT_TLS_PORT)
    cfg.tls_bind = checked.get("bind")
    if "port" in checked and cfg.tls_port != 0 and cfg.tls_port == cfg.port and (cfg.tls_bind or cfg.bind) == cfg.bind:
        doc.error(path + ("port",), f"[modbus.tls] port: {cfg.tls_port} is the plain listener's port too "
                  "([modbus] port)")
    for key, problem in tls_file_problems(files).items():
        doc.error(path + (key,), f"[modbus.tls] {key}: {problem}")
    if checked.ok:
        cfg.tls_cert, cfg.tls_key, cfg.tls_ca = files["cert"], files["key"], files["ca"]


def tls_file_problems(files: dict[str, Path]) -> dict[str, str]:
    """What is wrong with the TLS files (keys cert, key, ca) as the runtime will read them: key -> problem."""
    out: dict[str, str] = {}
    data: dict[str, bytes] = {}
    for key, f in files.items():
        try:
            data[key] = f.read_bytes()
        except OSError as exc:
            out[key] = f"cannot read {f}: {exc.strerror or exc}"
    try:
        from cryptography import x509
        from cryptography.exceptions import UnsupportedAlgorithm
        from cryptography.hazmat.primitives import serialization
    except ImportError:                                 # the runtime checks them at its start
        return out
    certs: dict[str, list] = {}
    for key in ("cert", "ca"):
        if key in data:
            try:
                certs[key] = x509.load_pem_x509_certificates(data[key])
            except ValueError:
                out[key] = f"{files[key]} holds no PEM certificate"
    if "key" in data:
        try:
            private = serialization.load_pem_private_key(data["key"], password=None)
        except TypeError:
            out["key"] = f"{files['key']} is encrypted: the runtime reads a key without a password"
        except (ValueError, UnsupportedAlgorithm):
            out["key"] = f"{files['key']} holds no PEM private key"
        else:
            if certs.get("cert") and private.public_key().public_bytes(
                    serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo) != \
                    certs["cert"][0].public_key().public_bytes(serialization.Encoding.DER,
                                                               serialization.PublicFormat.SubjectPublicKeyInfo):
                out["key"] = f"{files['key']} is not the private key of {files['cert']}"
    return out


def load_config(path: Path) -> RunConfig:
    """Read and check a TOML run configuration; raise ConfigError naming every problem of every table at once,
    each as `file:line:col: error: message`."""
    path = Path(path)
    try:
        doc = tomlconf.read(path)
    except tomlconf.TomlError as exc:
        d = exc.diagnostic
        raise ConfigError(f"{path}: {d.message}" if d.line == 0 else one_line(d)) from None
    cfg = RunConfig()
    checked = tomlconf.check_sections(doc, RUN_CONFIG)
    for section, values in checked.items():
        for key, value in values.values.items():
            if (section, key) in _NOT_FIELDS:
                continue
            if isinstance(value, Path) and not value.is_absolute():
                value = Path(os.path.normpath(path.parent / value))
            setattr(cfg, _FIELD_OF.get((section, key), key), value)
    modbus = doc.data.get("modbus") if isinstance(doc.data.get("modbus"), dict) else {}
    if "client" in modbus:
        cfg.allow = cfg.allow + check_clients(doc, modbus["client"], cfg.allow)
    if "tls" in modbus:
        check_tls(doc, modbus["tls"], cfg, path.parent)
    io = doc.data.get("io") if isinstance(doc.data.get("io"), dict) else {}
    cfg.io_chosen = "layer" in io
    if "device" in io:
        before = len(doc.errors)
        devices = io_config.check_devices(doc, io["device"])
        if len(doc.errors) == before:
            cfg.io_devices = io_config.device_specs(devices)
            cfg.devices = devices
    if cfg.io == "modbus" and "device" not in io:
        doc.error(("io", "layer"), "[io] layer: layer \"modbus\" needs at least one [[io.device]]")
    if doc.errors:
        problems = [one_line(d) for d in doc.in_file_order()]
        raise ConfigError(f"{len(problems)} problem(s) in the run configuration {path}:\n" + "\n".join(problems),
                          problems)
    return cfg


def one_line(d: Diagnostic) -> str:
    """A problem of the run configuration as one line, `file:line:col: error: message (hint)`."""
    return f"{d.where()}: {d.severity}: {d.message}" + (f" ({d.hint})" if d.hint else "")


def option(where: str, kind: tomlconf.Kind, value: Any) -> Any:
    """A command-line option checked as its configuration key is: ConfigError `--port: expected ...`."""
    try:
        return kind.check(value)
    except Invalid as exc:
        raise ConfigError(f"{where}: {exc}") from None


def apply_application(cfg: RunConfig, setup: RunSetup, where: object) -> None:
    """Lay what an application adds (plc.extensions.RunSetup) under a run configuration: its simulation flag,
    the ranges its program implies (host-writable coils and registers, retained registers), each unless the
    configuration or the command line says; a remote I/O layer must stop the application's output lines on their
    stop levels (ConfigError naming every coil that would not)."""
    if cfg.sim_flag is None:
        cfg.sim_flag = setup.sim_flag
    if cfg.writable_coils is None:
        cfg.writable_coils = setup.writable_coils
    if cfg.writable_registers is None:
        cfg.writable_registers = setup.writable_registers
    if cfg.host_coils is None:
        cfg.host_coils = setup.writable_coils         # a host writes the application's command signals
    if cfg.host_registers is None:
        cfg.host_registers = setup.writable_registers
    if not cfg.retain_registers:
        cfg.retain_registers = list(setup.retain_registers)
    wrong = stop_level_problems(cfg, setup.stop_levels) if cfg.io == "modbus" else []
    if wrong:
        raise ConfigError("\n".join([f"{where}: the remote I/O would not stop the machine when the runtime stops:",
                                      *wrong]))


def stop_level_problems(cfg: RunConfig, levels: dict[int, tuple[bool, str]]) -> list[str]:
    """Every coil of a remote I/O device whose `safe` value (what the device gets when the runtime stops, faults or
    loses its scan) differs from the level the application prescribes for it; one line each."""
    out = []
    for dev in cfg.devices:
        for r in dev.ranges:
            if not (r.kind.output and r.kind.bits):
                continue
            for k in range(r.count):
                bit = r.image + k
                if bit not in levels:
                    continue
                level, why = levels[bit]
                safe = bool(r.safe[k]) if r.safe else False
                if safe != level:
                    out.append(f"  [[io.device]] {dev.index} ({dev.name}) {r.kind.key} {r.nth + 1}: "
                               f"%QX{bit // 8}.{bit % 8} (device coil {r.address + k}) is "
                               f"{'true' if safe else 'false'} when stopped, but {why}: its stop level is "
                               f"{'true' if level else 'false'}; set its `safe` value")
    return out


def ensure_token(path: Path) -> None:
    """Create the monitor token file (random, mode 0600) when it does not exist yet."""
    import secrets
    path = Path(path)
    if path.exists():
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(secrets.token_hex(16) + "\n")


def monitor_files(cfg: RunConfig) -> tuple[Path, Path, Path]:
    """The monitor's socket, token and audit files: configured, else beside the retain file."""
    retain = cfg.retain_file if cfg.retain_file is not None else DEFAULT_RETAIN_FILE
    here = retain.parent
    return (cfg.monitor_socket or here / DEFAULT_MONITOR_SOCKET.name, cfg.token_file or here / DEFAULT_TOKEN_FILE.name,
            cfg.audit_file or here / DEFAULT_AUDIT_FILE.name)


def project_endpoint(root: Path | None) -> tuple[int | None, Path, Path]:
    """Where the project's run is reached: its Modbus port (None when the project has no run configuration), its
    monitor socket and token (beside its retained file), what `plc status`, `plc monitor` and the application's
    clients use by default."""
    config, state = project.run_config(root)
    cfg = RunConfig()
    if config is not None:
        try:
            cfg = load_config(config)
        except ConfigError:
            pass                    # `plc run` reports it; the defaults stand meanwhile
    if cfg.retain_file is None and state is not None:
        cfg.retain_file = state / DEFAULT_RETAIN_FILE.name
    sock, token, _ = monitor_files(cfg)
    return (cfg.port if config is not None else None), sock, token


def runtime_argv(binary: Path, cfg: RunConfig) -> list[str]:
    """The command line of the C runtime for a configuration."""
    retain = cfg.retain_file if cfg.retain_file is not None else DEFAULT_RETAIN_FILE
    argv = [str(binary), "--bind", cfg.bind, "--port", str(cfg.port), "--io", cfg.io,
            "--max-clients", str(cfg.max_clients), "--frame-timeout", str(cfg.frame_timeout_ms),
            "--retain", str(retain),
            "--retain-interval", str(cfg.retain_interval_ms),
            "--status-interval", str(cfg.status_interval_s), "--watchdog", str(cfg.watchdog_ms)]
    if cfg.allow:
        argv += ["--allow", ",".join(cfg.allow)]
    if cfg.writable_coils is not None:
        argv += ["--writable-coils", ",".join(cfg.writable_coils) or "none"]
    if cfg.writable_registers is not None:
        argv += ["--writable-registers", ",".join(cfg.writable_registers) or "none"]
    if cfg.host_coils is not None:
        argv += ["--host-coils", ",".join(cfg.host_coils) or "none"]
    if cfg.host_registers is not None:
        argv += ["--host-registers", ",".join(cfg.host_registers) or "none"]
    if cfg.retain_registers:
        argv += ["--retain-registers", ",".join(cfg.retain_registers)]
    if cfg.realtime:
        argv += ["--rt-priority", str(cfg.rt_priority)]
    else:
        argv.append("--no-rt")
    if cfg.cpu is not None:
        argv += ["--cpu", str(cfg.cpu)]
    if cfg.cpu_latency_us is not None:
        argv += ["--cpu-latency", str(cfg.cpu_latency_us)]
    if cfg.read_only:
        argv.append("--read-only")
    if cfg.io == "modbus":
        for spec in cfg.io_devices:
            argv += ["--io-device", spec]
    if cfg.monitor:
        sock, token, audit = monitor_files(cfg)
        argv += ["--monitor", str(sock), "--monitor-token", str(token), "--audit", str(audit)]
    if cfg.events_file is not None:
        argv += ["--events", str(cfg.events_file)]
    if cfg.tls_cert is not None:
        argv += ["--tls-cert", str(cfg.tls_cert), "--tls-key", str(cfg.tls_key), "--tls-ca", str(cfg.tls_ca),
                 "--tls-port", str(cfg.tls_port), "--tls-bind", cfg.tls_bind or cfg.bind]
    if cfg.io == "sim" and cfg.io_chosen and cfg.sim_flag is not None:
        argv += ["--sim-flag", cfg.sim_flag]        # the program's simulated plant runs only when asked
    return argv


# ------------------------------------------------------------------------- command

def add_run_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `plc run` (the caller adds the ST sources argument)."""
    parser.add_argument("--config", type=Path, metavar="FILE", help="TOML run configuration")
    parser.add_argument("--bind", metavar="ADDR", help="IPv4 address to serve Modbus on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, metavar="N", help=f"Modbus/TCP port (default {DEFAULT_PORT})")
    parser.add_argument("--io", choices=IO_LAYERS,
                        help="I/O layer (default sim; modbus: the [[io.device]] remote I/O of --config)")
    parser.add_argument("--sim-flag", metavar="%IXa.b",
                        help="with --io sim: the discrete input held TRUE to tell the program its plant models run "
                             "(default: the application's, e.g. SimulatedPlant of the register map; none without one)")
    parser.add_argument("--read-only", action="store_true", default=None,
                        help="serve reads only: every Modbus write is answered with exception 01")
    parser.add_argument("--retain", type=Path, metavar="FILE",
                        help=f"file keeping RETAIN data (default {DEFAULT_RETAIN_FILE})")
    parser.add_argument("--no-monitor", action="store_true",
                        help="no monitoring channel (watch, write, force; plc hmi's watch panel)")
    parser.add_argument("--sanitize", action="store_true",
                        help="run an AddressSanitizer/UBSan build of the runtime")
    parser.add_argument("--build-dir", type=Path, default=DEFAULT_BUILD_DIR, metavar="DIR",
                        help=f"where built runtimes are cached (default {DEFAULT_BUILD_DIR})")


def prepare_run(args: argparse.Namespace, program_c: Path) -> list[str]:
    """Check the configuration, build the runtime; return the command to execute."""
    cfg = load_config(args.config) if args.config else RunConfig()
    if args.bind is not None:
        cfg.bind = option("--bind", IPV4, args.bind)
    if args.port is not None:
        cfg.port = option("--port", Int(0, 65535), args.port)
    if args.io is not None:
        cfg.io, cfg.io_chosen = args.io, True
    if cfg.io == "modbus" and not cfg.io_devices:
        raise ConfigError("--io modbus needs the remote I/O devices: [[io.device]] tables in the run "
                          "configuration (--config FILE)")
    if args.read_only:
        cfg.read_only = True
    if args.retain is not None:
        cfg.retain_file = args.retain
    state = getattr(args, "state_dir", None)         # the project's, where its configuration names no retain file
    if cfg.retain_file is None and state is not None:
        cfg.retain_file = Path(state) / DEFAULT_RETAIN_FILE.name
    if getattr(args, "no_monitor", False):
        cfg.monitor = False
    if getattr(args, "sim_flag", None) is not None:
        cfg.sim_flag = option("--sim-flag", DISCRETE_INPUT, args.sim_flag)
    setup = getattr(args, "run_setup", None) or RunSetup()
    cfg.events_file = setup.events_file
    apply_application(cfg, setup, args.config or "the run configuration")
    if not cfg.io_chosen:
        simulated = " (the program's simulated plant is off: --io sim runs it)" if cfg.sim_flag else ""
        print(f"plc run: I/O layer sim by default: outputs loop back to inputs{simulated}", file=sys.stderr)
    retain = cfg.retain_file if cfg.retain_file is not None else DEFAULT_RETAIN_FILE
    binary = build_runtime(program_c, args.build_dir, sanitize=args.sanitize, observer=setup.observer)
    probe_listen(cfg.bind, cfg.port)                 # before anything is written: a taken port leaves nothing
    if cfg.tls_cert is not None:
        probe_listen(cfg.tls_bind or cfg.bind, cfg.tls_port)
    try:
        retain.parent.mkdir(parents=True, exist_ok=True)
        if cfg.monitor:
            sock, token, audit = monitor_files(cfg)
            sock.parent.mkdir(parents=True, exist_ok=True)
            audit.parent.mkdir(parents=True, exist_ok=True)
            ensure_token(token)
    except OSError as exc:
        raise ConfigError(f"cannot prepare the run directory (retain file {retain}, monitor files): {exc}") from None
    return runtime_argv(binary, cfg)


class AddressInUse(Exception):
    """The Modbus address cannot be bound (another process listens there): an environment problem, exit 2."""


def probe_listen(bind: str, port: int) -> None:
    """AddressInUse when bind:port cannot be bound now (as the runtime binds it, SO_REUSEADDR)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((bind, port))
        except OSError as exc:
            why = ("a port below 1024 needs root or CAP_NET_BIND_SERVICE" if exc.errno == errno.EACCES else
                   "another PLC runs there? give another --port or stop it")
            raise AddressInUse(f"cannot listen on {bind}:{port}: {exc.strerror or exc} ({why}); nothing was "
                               "written") from None


def run_command(args: argparse.Namespace, program_c: Path, generated: bool = False) -> int:
    """`plc run`: build if needed, then become the runtime (returns only on an error).

    `generated`: plc wrote `program_c`; the C compiler refusing it then raises RuntimeBuildError to the caller
    (an internal error of the compiler, not the user's)."""
    try:
        argv = prepare_run(args, program_c)
    except AddressInUse as exc:
        print(f"plc run: error: {exc}", file=sys.stderr)
        return 2
    except RuntimeBuildError as exc:
        if generated and exc.program_refused:
            raise
        print(f"plc run: error: {exc}", file=sys.stderr)
        return 1
    except ConfigError as exc:
        print(f"plc run: error: {exc}", file=sys.stderr)
        return 1
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        os.execv(argv[0], argv)
    except OSError as exc:
        print(f"plc run: error: cannot start {argv[0]}: {exc}", file=sys.stderr)
    return 1


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m plc.runtime PROGRAM.c [options]`: `plc run` for an already compiled program."""
    parser = argparse.ArgumentParser(prog="python -m plc.runtime",
                                     description="Build the soft-PLC runtime with a program C file and run it.")
    parser.add_argument("program_c", type=Path, metavar="PROGRAM.c", help="program C file (plc_abi.h)")
    parser.add_argument("--build-only", action="store_true", help="build, print the executable's path, exit")
    add_run_arguments(parser)
    args = parser.parse_args(argv)
    if args.build_only:
        try:
            print(build_runtime(args.program_c, args.build_dir, sanitize=args.sanitize))
        except RuntimeBuildError as exc:
            print(f"plc run: error: {exc}", file=sys.stderr)
            return 1
        return 0
    return run_command(args, args.program_c)


if __name__ == "__main__":
    sys.exit(main())
