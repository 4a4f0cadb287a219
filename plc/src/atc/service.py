"""`plc deploy service|upgrade|rollback`: the soft-PLC installed on the machine's PC as a systemd service.

A deployment is one folder (installed as PREFIX, default /opt/atc-plc):

    NAME.service        systemd unit: Type=notify, Restart=always, WatchdogSec, real-time and memory-lock
                        limits, StateDirectory=NAME (the retained file lives in /var/lib/NAME)
    install.sh          copies the folder to PREFIX, installs and starts the unit
    uninstall.sh        stops and removes the unit and PREFIX (the state directory stays unless --purge)
    README.md           the same steps for the integrator
    current -> releases/ID     the version the service runs
    previous -> releases/ID    the version before the last upgrade (rollback)
    releases/ID/        one program version: plc-runtime (built for the program), run (its command line),
                        runtime.toml (its run configuration), retain-layout.txt (its retained entries and
                        located variables, from `plc-runtime --describe-retain`), program.c, lib/ (libmodbus),
                        VERSION

`upgrade` builds a new release beside the running one, compares the two retain layouts (a saved value the new
version would not restore is a refusal, each one named, unless --force), points `current` at it, `previous`
at the old one, and restarts the service: the old runtime makes its outputs safe and saves its retained data,
the new one restores them and scans.  The switch-over time (outputs safe -> first scan of the new version) is
read from the two runtimes' log lines, which carry the system's monotonic clock.
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from plc.cliargs import EXIT_FINDINGS, EXIT_OK
from plc.driver import compile_sources, print_diagnostics
from plc.extensions import RunSetup
from plc.project import add_view_options, project_root, where

from plc import runtime

from . import project
from .runsetup import runtime_setup

DEFAULT_NAME = "atc-plc"
DEFAULT_WATCHDOG_SEC = 3
RETAIN_FILE = "plc.retain"
OUTPUTS_SAFE = re.compile(r"outputs safe .* at monotonic ([\d.]+) s")
FIRST_SCAN = re.compile(r"first scan done at monotonic ([\d.]+) s")


class DeployError(Exception):
    """A problem the user must fix; str() says what (no traceback)."""


# ------------------------------------------------------------------------ layouts

@dataclasses.dataclass(frozen=True)
class RetainItem:
    path: str
    type: str
    where: str            # "" for a variable, "%MW0" for registers
    size: int


@dataclasses.dataclass(frozen=True)
class LocatedItem:
    address: str
    path: str
    type: str
    retain: bool


@dataclasses.dataclass
class Layout:
    retained: list[RetainItem]
    located: list[LocatedItem]


def parse_layout(text: str) -> Layout:
    """Read the output of `plc-runtime --describe-retain`."""
    out = Layout([], [])
    for n, line in enumerate(text.splitlines(), 1):
        f = line.split("\t")
        if f[0] == "retain" and len(f) == 5:
            out.retained.append(RetainItem(f[1], f[2], "" if f[3] == "-" else f[3], int(f[4])))
        elif f[0] == "located" and len(f) == 5:
            out.located.append(LocatedItem(f[1], f[2], f[3], f[4] == "RETAIN"))
        elif line.strip():
            raise DeployError(f"retain layout line {n}: cannot read {line!r}")
    return out


@dataclasses.dataclass
class Comparison:
    lost: list[str]          # saved values the new version would not restore (refusal unless forced)
    notes: list[str]         # moves, new entries, register map changes (information)


def compare(old: Layout, new: Layout) -> Comparison:
    """What an upgrade from `old` to `new` does to the retained values, by the runtime's matching rules
    (name and type; a register whose name is gone by address and type)."""
    lost, notes = [], []
    new_by_path = {r.path: r for r in new.retained}
    old_paths = {r.path for r in old.retained}
    taken: set[RetainItem] = set()
    for r in old.retained:
        n = new_by_path.get(r.path)
        if n is not None and n.type == r.type and n.size == r.size:
            taken.add(n)
            if n.where != r.where:
                notes.append(f"{r.path} ({r.type}) moves from {r.where or 'memory'} to {n.where or 'memory'}")
    for r in old.retained:
        n = new_by_path.get(r.path)
        if n is not None and n in taken and n.type == r.type:
            continue
        by_address = next((m for m in new.retained if m not in taken and r.where and m.where == r.where
                           and m.type == r.type and m.size == r.size and m.path not in old_paths), None)
        if by_address is not None and n is None:
            taken.add(by_address)
            notes.append(f"{by_address.path} ({r.type}) takes the value of {r.path} by its address {r.where}")
        elif n is not None:
            lost.append(f"{r.path} changes type from {r.type} to {n.type}: its value would be kept aside, "
                        f"the variable starts from its initial value")
        else:
            lost.append(f"{r.path} ({r.type}{' at ' + r.where if r.where else ''}) is no longer retained: its "
                        "value would be kept aside")
    for n in new.retained:
        if n not in taken and n.path not in old_paths:
            notes.append(f"{n.path} ({n.type}) is new: it starts from its initial value")
    old_loc = {(x.address, x.path): x for x in old.located}
    new_loc = {(x.address, x.path): x for x in new.located}
    for key in sorted(old_loc.keys() - new_loc.keys()):
        notes.append(f"register map: {key[1]} no longer at {key[0]}")
    for key in sorted(new_loc.keys() - old_loc.keys()):
        notes.append(f"register map: {key[1]} now at {key[0]}")
    for key in sorted(old_loc.keys() & new_loc.keys()):
        if old_loc[key].type != new_loc[key].type:
            notes.append(f"register map: {key[1]} at {key[0]} changes type from {old_loc[key].type} to "
                         f"{new_loc[key].type}")
    return Comparison(lost, notes)


# ----------------------------------------------------------------------- releases

def _libmodbus(binary: Path) -> Path | None:
    """The libmodbus the binary is linked with (copied into the release so the folder stands alone)."""
    try:
        out = subprocess.run(["ldd", str(binary)], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.TimeoutExpired):
        return None
    m = re.search(r"libmodbus\.so[.\d]*\s+=>\s+(\S+)", out)
    return Path(m.group(1)) if m else None


def runtime_argv(cfg: runtime.RunConfig) -> list[str]:
    """The runtime's options for a service (no binary). The retain file and the monitor's files are set by the
    run script, in the service's own directories, and the TLS files in the release's tls/: nothing points back
    into the checkout it was built from."""
    argv = runtime.runtime_argv(Path("plc-runtime"), cfg)[1:]
    for option in ("--retain", "--monitor", "--monitor-token", "--audit", "--tls-cert", "--tls-key", "--tls-ca"):
        if option in argv:
            i = argv.index(option)
            del argv[i:i + 2]
    return argv + ["--status", "log"]


# the monitor channel of a service: socket in $RUNTIME_DIRECTORY (/run/NAME), token and audit log in
# $STATE_DIRECTORY (/var/lib/NAME); the token is created (random, mode 0600) at the first start
MONITOR_RUN = """run=${RUNTIME_DIRECTORY:-$state}
if [ ! -f "$state/monitor.token" ]; then
    (umask 077 && od -An -N16 -tx1 /dev/urandom | tr -d ' \\n' >"$state/monitor.token" && echo >>"$state/monitor.token")
fi
"""
MONITOR_ARGS = ' --monitor "$run/plc.monitor" --monitor-token "$state/monitor.token" --audit "$state/audit.log"'


RUN_SCRIPT = """#!/bin/sh
# Generated by `plc deploy`: the command line of this program version.  systemd runs it through
# PREFIX/current/run; exec keeps the process id, so the runtime itself talks to systemd.
# The retained data live in $STATE_DIRECTORY (set by systemd from StateDirectory=).
here=$(dirname "$(readlink -f "$0")")
state=${{STATE_DIRECTORY:-/var/lib/{name}}}
{monitor}LD_LIBRARY_PATH="$here/lib${{LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}}" exec "$here/plc-runtime" \\
    --retain "$state/{retain}"{monitor_args} {args} "$@"
"""


EVENTS_ARGS = ' --events "$here/events.txt"'
# [modbus.tls]: the run configuration's certificate, key and CA, copied into the release (the key mode 0600)
TLS_FILES = (("tls_cert", "server.pem", 0o644), ("tls_key", "server.key", 0o600), ("tls_ca", "ca.pem", 0o644))
TLS_ARGS = ' --tls-cert "$here/tls/server.pem" --tls-key "$here/tls/server.key" --tls-ca "$here/tls/ca.pem"'


def _application_setup(sources: list[Path], work: Path) -> RunSetup:
    """The application's events and simulation flag from the register map of the project deployed from (the one
    `plc deploy` runs in, else the sources'); the description goes into the release as events.txt. Nothing
    without a register map."""
    root = project_root() or (project_root(sources[0].resolve()) if sources else None)
    map_path = root / "modbus_map" / "map.toml" if root is not None else None
    if map_path is None or not map_path.is_file():
        return RunSetup()
    return runtime_setup(map_path, work)


def load_run_config(config: Path | None) -> runtime.RunConfig:
    """The run configuration (the built-in defaults without one), its mistakes as a DeployError."""
    try:
        cfg = runtime.load_config(config) if config else runtime.RunConfig()
    except runtime.ConfigError as exc:
        raise DeployError(str(exc)) from None
    return cfg


def build_release(prefix: Path, sources: list[Path], config: Path | None, cfg: runtime.RunConfig, name: str,
                  quiet: bool = False) -> Path:
    """Compile the sources and build a release folder under prefix/releases; return it."""
    res = compile_sources([str(s) for s in sources], portability=False)
    print_diagnostics(res, quiet=True)
    if not res.ok:
        raise DeployError(f"the program does not compile ({len(res.diags.errors)} error(s))")
    if not res.program.configs:
        raise DeployError("the sources have no CONFIGURATION: nothing to run")
    digest = hashlib.sha256(res.c_text.encode()).hexdigest()[:10]
    rel_id = time.strftime("%Y%m%dT%H%M%S") + "-" + digest
    releases = prefix / "releases"
    release = releases / rel_id
    n = 1
    while release.exists():
        n += 1
        release = releases / f"{rel_id}.{n}"
    work = releases / (release.name + ".partial")
    shutil.rmtree(work, ignore_errors=True)
    (work / "lib").mkdir(parents=True)
    (work / "program.c").write_text(res.c_text)
    setup = _application_setup(sources, work)
    try:
        runtime.apply_application(cfg, setup, config or "the run configuration")
    except runtime.ConfigError as exc:
        shutil.rmtree(work, ignore_errors=True)
        raise DeployError(str(exc)) from None
    try:
        with tempfile.TemporaryDirectory(prefix="plc-deploy-") as build:
            binary = runtime.build_runtime(work / "program.c", Path(build), observer=setup.observer)
            shutil.copy2(binary, work / "plc-runtime")
    except runtime.RuntimeBuildError as exc:
        shutil.rmtree(work, ignore_errors=True)
        raise DeployError(str(exc)) from None
    lib = _libmodbus(work / "plc-runtime")
    if lib is not None:
        shutil.copy2(lib, work / "lib" / lib.name)
    if cfg.tls_cert is not None:
        try:
            (work / "tls").mkdir()
            for field, fname, mode in TLS_FILES:
                shutil.copyfile(getattr(cfg, field), work / "tls" / fname)
                os.chmod(work / "tls" / fname, mode)
        except OSError as exc:
            shutil.rmtree(work, ignore_errors=True)
            raise DeployError(f"[modbus.tls]: cannot copy {exc.filename} into the release: {exc.strerror}") from None
    args = runtime_argv(cfg)
    monitor = cfg.monitor
    (work / "run").write_text(RUN_SCRIPT.format(name=name, retain=RETAIN_FILE,
                                                monitor=MONITOR_RUN if monitor else "",
                                                monitor_args=(MONITOR_ARGS if monitor else "") +
                                                (EVENTS_ARGS if setup.events_file is not None else "") +
                                                (TLS_ARGS if cfg.tls_cert is not None else ""),
                                                args=" ".join(shlex.quote(a) for a in args)))
    os.chmod(work / "run", 0o755)
    if config:
        shutil.copy2(config, work / "runtime.toml")
    else:
        (work / "runtime.toml").write_text("# built-in defaults (no run configuration given)\n")
    describe = subprocess.run([str(work / "plc-runtime"), *args, "--describe-retain"], capture_output=True,
                              text=True, timeout=60)
    if describe.returncode != 0:
        shutil.rmtree(work, ignore_errors=True)
        raise DeployError(f"plc-runtime --describe-retain failed: {describe.stderr.strip()}")
    (work / "retain-layout.txt").write_text(describe.stdout)
    srcs = ", ".join(str(s) for s in sources)
    (work / "VERSION").write_text(f"release {release.name}\nbuilt {time.strftime('%Y-%m-%d %H:%M:%S %z')}\n"
                                  f"program {res.program.configs[0].name} from {srcs}\n"
                                  f"run configuration {config or 'built-in defaults'}\n")
    work.rename(release)
    if not quiet:
        print(f"plc deploy: built release {release}", file=sys.stderr)
    return release


def release_of(link: Path) -> Path | None:
    return link.resolve() if link.is_symlink() and link.resolve().is_dir() else None


def point(link: Path, target: Path) -> None:
    """Make link point at target, atomically (a new symlink renamed over the old one)."""
    tmp = link.with_name(link.name + ".new")
    if tmp.is_symlink() or tmp.exists():
        tmp.unlink()
    tmp.symlink_to(os.path.relpath(target, link.parent))
    os.replace(tmp, link)


def layout_of(release: Path) -> Layout:
    return parse_layout((release / "retain-layout.txt").read_text())


# -------------------------------------------------------------------------- files

UNIT = """# Generated by `plc deploy service`: the atc-plc soft-PLC as a systemd service.
[Unit]
Description=atc-plc soft-PLC (program {config}, Modbus/TCP {bind}:{port}){simulated_unit}
Documentation=file://{prefix}/README.md
After=network-online.target
Wants=network-online.target
# a runtime that keeps crashing is given up after 10 starts in 60 s (systemctl reset-failed {name})
StartLimitIntervalSec=60
StartLimitBurst=10

[Service]
# READY=1 after the first scan; WATCHDOG=1 while the scans run (sd_notify protocol, NOTIFY_SOCKET)
Type=notify
NotifyAccess=main
ExecStart={prefix}/current/run
Restart=always
RestartSec=1
# no ping for this long (the scan is stuck): systemd kills the runtime and starts it again; the
# runtime's own --watchdog has made the outputs safe long before
WatchdogSec={watchdog}
TimeoutStartSec=30
# SIGTERM: outputs safe, retained data saved, exit 0
TimeoutStopSec=15
# the retained file lives in /var/lib/{name} ($STATE_DIRECTORY), kept across upgrades and uninstalls
StateDirectory={name}
StateDirectoryMode=0750
# the monitor's socket lives in /run/{name} ($RUNTIME_DIRECTORY); its token and audit log beside the retained file
RuntimeDirectory={name}
RuntimeDirectoryMode=0750
WorkingDirectory=/var/lib/{name}
# SCHED_FIFO for the scan thread and memory locked (mlockall)
LimitRTPRIO={rt_limit}
LimitMEMLOCK=infinity
{user}# log lines carry their priority (<3> error, <4> warning, <6> info) into the journal
StandardError=journal
SyslogIdentifier={name}
NoNewPrivileges=yes
ProtectSystem=full
ProtectHome=yes
PrivateTmp=yes

[Install]
WantedBy=multi-user.target
"""

INSTALL = """#!/bin/sh
# Install the {name} service from this folder (run as root): copies the folder to {prefix} (unless it is
# already there), installs {name}.service, enables it at boot and starts it.
set -eu
here=$(cd "$(dirname "$0")" && pwd -P)
prefix={prefix}
if [ "$here" != "$prefix" ]; then
    mkdir -p "$prefix"
    cp -a "$here/." "$prefix/"
fi
missing=$(LD_LIBRARY_PATH="$prefix/current/lib" ldd "$prefix/current/plc-runtime" | grep 'not found' || true)
if [ -n "$missing" ]; then
    echo "install: libraries missing for plc-runtime:" >&2
    echo "$missing" >&2
    exit 1
fi
install -m 0644 "$prefix/{name}.service" /etc/systemd/system/{name}.service
systemctl daemon-reload
systemctl enable --now {name}.service
systemctl --no-pager status {name}.service || true
"""

UNINSTALL = """#!/bin/sh
# Stop and remove the {name} service and {prefix}.  The retained data in /var/lib/{name} stay (the tool
# in the spindle, the pocket table) unless --purge is given.
set -eu
systemctl disable --now {name}.service 2>/dev/null || true
rm -f /etc/systemd/system/{name}.service
systemctl daemon-reload
rm -rf {prefix}
if [ "${{1:-}}" = "--purge" ]; then
    rm -rf /var/lib/{name}
fi
"""

README = """# {name}: the atc-plc soft-PLC as a systemd service

Generated by `plc deploy service`. This folder holds the runtime built for the program (`current/`), its run
configuration and the systemd unit `{name}.service`.
{simulated_readme}
## Install
    sudo ./install.sh            # copies this folder to {prefix}, installs, enables and starts the unit
    systemctl status {name}
    journalctl -u {name} -f      # the runtime's log, with its priorities (journalctl -p warning)

The machine needs `libmodbus` (copied into `releases/*/lib/`), OpenSSL's `libssl3` (Debian's, the runtime's
TLS listener links it) and glibc; no compiler. The retained data (tool
in the spindle, pocket table) live in `/var/lib/{name}/{retain}`.

The monitor channel (`plc monitor`, `plc hmi`) is the socket `/run/{name}/plc.monitor`; writes and forces need the
token `/var/lib/{name}/monitor.token` (random, mode 0600, created at the first start), and every one of them is
logged in `/var/lib/{name}/audit.log`:

    sudo plc monitor --socket /run/{name}/plc.monitor --token-file /var/lib/{name}/monitor.token forces

## What the unit does
- starts at boot (`WantedBy=multi-user.target`) once the network is up; `Type=notify`: ready after the first
  scan;
- `Restart=always`: after a crash (or `kill -9`) the runtime starts again 1 s later and restores the retained
  data of the last completed save; the outputs stay off meanwhile (no process drives them);
- `WatchdogSec={watchdog}`: the runtime pings systemd while its scans run; a program stuck in a loop stops the
  pings and systemd restarts the runtime (its own scan watchdog has made the outputs safe already);
- `LimitRTPRIO` (the scan's priority + 1: the watchdog runs one above the scan), `LimitMEMLOCK=infinity`: SCHED_FIFO
  scan thread with locked memory.

## Upgrade the program on the running machine
From an atc-plc checkout on this machine (`scripts/setup` installs the toolchain: gcc, libmodbus-dev, Python):

    plc deploy upgrade --prefix {prefix} [--src st_src] [--config machines/NAME/runtime.toml] [--force]

builds the new version into `releases/`, compares its retained variables and register map with the running one
(a saved value the new version would not restore stops the upgrade and is named; `--force` goes on and the
runtime keeps such values aside in the retained file), switches `current` to it (`previous` keeps the old one),
and restarts the service: outputs safe, retained data saved, new version started, retained data restored. It
prints the switch-over time (outputs safe -> first scan of the new version).

    plc deploy rollback --prefix {prefix}    # back to `previous`

## Uninstall
    sudo ./uninstall.sh          # stops and removes the unit and {prefix}; --purge also removes /var/lib/{name}
"""


SIMULATED_README = """
**This service runs the simulated plant** (`[io] layer = "sim"`, deployed with `--simulated`): the program's
plant models stand in for the machine, so it answers every tool change as done while nothing moves. It is for
demonstrations and tests, never for a machine; deploy a run configuration with the machine's I/O layer instead.
"""


def service_io(config: Path | None, cfg: runtime.RunConfig, simulated: bool, what: str) -> runtime.RunConfig:
    """The I/O layer of a service: the run configuration's; with none named, the simulated plant when asked
    (--simulated), else no I/O ("none": the program runs, nothing moves, no change is answered as done, said on
    stderr). A configuration naming "sim" is refused unless asked: the service would answer M6 as done while
    nothing moves."""
    if not cfg.io_chosen:
        if simulated:
            return dataclasses.replace(cfg, io="sim", io_chosen=True)
        print(f"plc deploy: warning: {config or 'the built-in defaults'} names no I/O layer ([io] layer): the "
              f"service runs with none (nothing moves); give the machine's ([io] layer = \"modbus\" and its "
              f"[[io.device]] tables), or --simulated for a demonstration {what}", file=sys.stderr)
        return dataclasses.replace(cfg, io="none", io_chosen=True)
    if cfg.io == "sim" and not simulated:
        raise DeployError(f"{config or 'the built-in defaults'}: [io] layer = \"sim\": the service would run the "
                          f"simulated plant and answer every tool change as done while nothing moves; give a run "
                          f"configuration with the machine's I/O layer (--config FILE), or --simulated for a "
                          f"demonstration {what}: nothing written")
    return cfg


def write_deployment(out: Path, release: Path, cfg: runtime.RunConfig, program: str, name: str, prefix: Path,
                     watchdog: int, user: str | None) -> None:
    simulated = cfg.io == "sim"
    fill = dict(name=name, prefix=prefix, config=program, bind=cfg.bind, port=cfg.port, watchdog=watchdog,
                rt_limit=max(cfg.rt_priority, 1) + 1, retain=RETAIN_FILE,
                user=f"User={user}\n" if user else "",
                simulated_unit=" - SIMULATED PLANT, no machine I/O" if simulated else "",
                simulated_readme=SIMULATED_README if simulated else "")
    files = {f"{name}.service": (UNIT.format(**fill), 0o644), "install.sh": (INSTALL.format(**fill), 0o755),
             "uninstall.sh": (UNINSTALL.format(**fill), 0o755), "README.md": (README.format(**fill), 0o644)}
    for fname, (text, mode) in files.items():
        (out / fname).write_text(text)
        os.chmod(out / fname, mode)
    point(out / "current", release)


# ------------------------------------------------------------------------ switching

def switch_over_ms(lines: list[str]) -> float | None:
    """Outputs safe (the old runtime's last such line) -> the first scan of the next runtime, in ms."""
    safe = None
    for line in lines:
        m = OUTPUTS_SAFE.search(line)
        if m:
            safe = float(m.group(1))
            continue
        m = FIRST_SCAN.search(line)
        if m and safe is not None:
            return (float(m.group(1)) - safe) * 1000.0
    return None


def restart(command: str, log: Path | None, name: str, since: float, timeout: float) -> float | None:
    """Run the restart command, wait for the new version's first scan in the log; return the switch-over."""
    offset = log.stat().st_size if log is not None and log.exists() else 0
    try:
        result = subprocess.run(command, shell=True, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise DeployError(f"restart command {command!r} did not finish within {timeout:g} s") from None
    if result.returncode != 0:
        raise DeployError(f"restart command {command!r} failed ({result.returncode}): {result.stderr.strip()}")
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if log is not None:      # only what the log got after the restart began
            with open(log, "rb") as f:
                f.seek(offset)
                text = f.read().decode(errors="replace")
        else:
            try:
                text = subprocess.run(["journalctl", "-u", f"{name}.service", "-o", "cat", "--no-pager",
                                       "--since", f"@{int(since) - 1}"], capture_output=True, text=True,
                                      timeout=30).stdout
            except (OSError, subprocess.TimeoutExpired):
                return None
        ms = switch_over_ms(text.splitlines())
        if ms is not None and ms >= 0:
            return ms
        time.sleep(0.05)
    return None


# ---------------------------------------------------------------------- commands

def _sources(args) -> list[Path]:
    root = project_root()
    src = args.src or ([root / "st_src"] if root else [])
    if not src or not all(Path(d).exists() for d in src):
        raise DeployError("no ST sources (give --src DIR or run inside the project)")
    return [Path(s) for s in src]


def _config(args, sources: list[Path]) -> Path | None:
    if args.config is not None:
        return args.config
    root = project_root()
    cfg = project.run_config(root) if root else None
    inside = root is not None and all(where(s).is_relative_to(where(root)) for s in sources)
    if cfg is not None and inside:
        return cfg
    return None


def service_name(args) -> str:
    """--name, else atc-plc for the project's default machine and atc-plc-NAME for another one (two machines of a
    project deploy as two services without clashing)."""
    if args.name:
        return args.name
    root = project_root()
    if root is None or project.source_root(root) == root:
        return DEFAULT_NAME
    return f"{DEFAULT_NAME}-{project.default_name(root)}"


def cmd_service(args) -> int:
    sources = _sources(args)
    config = _config(args, sources)
    cfg = service_io(config, load_run_config(config), args.simulated, "service")
    if cfg.tls_cert is not None and args.user:
        # the key is root's (mode 0600) and port 802 is below 1024: a service user could read neither
        raise DeployError(f"{config}: [modbus.tls] with --user {args.user}: not done yet (the service user would "
                          "need the TLS key and, below port 1024, CAP_NET_BIND_SERVICE); deploy it as root: "
                          "nothing written")
    out: Path = args.out.resolve()
    prefix = (args.prefix or Path("/opt") / args.name).resolve()
    if (out / "current").exists():
        raise DeployError(f"{out} already holds a deployment (use plc deploy upgrade --prefix {out})")
    out.mkdir(parents=True, exist_ok=True)
    if not args.quiet:
        print(f"plc deploy: run configuration {config or 'built-in defaults (none found)'}", file=sys.stderr)
    release = build_release(out, sources, config, cfg, args.name, quiet=args.quiet)
    program = re.search(r"^program (\S+)", (release / "VERSION").read_text(), re.M).group(1)
    write_deployment(out, release, cfg, program, args.name, prefix, args.watchdog_sec, args.user)
    if not args.quiet:
        if cfg.io == "sim":
            print("plc deploy: warning: --simulated: this service runs the simulated plant (no machine I/O); "
                  "the unit's description and README say so", file=sys.stderr)
        n = len(layout_of(release).retained)
        print(f"plc deploy: wrote {out} ({args.name}.service for {prefix}, {n} retained entries); install with "
              f"sudo {out}/install.sh", file=sys.stderr)
    return EXIT_OK


def _restart_command(args) -> str:
    return args.restart_command if args.restart_command is not None else f"systemctl restart {args.name}.service"


def cmd_upgrade(args) -> int:
    prefix: Path = args.prefix.resolve()
    running = release_of(prefix / "current")
    if running is None:
        raise DeployError(f"{prefix} has no current release (deploy with plc deploy service first)")
    sources = _sources(args)
    config = _config(args, sources)
    cfg = service_io(config, load_run_config(config), args.simulated, "upgrade")
    new = build_release(prefix, sources, config, cfg, args.name, quiet=args.quiet)
    result = compare(layout_of(running), layout_of(new))
    for note in result.notes:
        print(f"plc deploy: {note}", file=sys.stderr)
    if result.lost and not args.force:
        for line in result.lost:
            print(f"plc deploy: error: {line}", file=sys.stderr)
        shutil.rmtree(new)
        print(f"plc deploy: upgrade refused: {len(result.lost)} retained value(s) would not be restored "
              "(--force to upgrade anyway; the runtime keeps them aside in the retained file)", file=sys.stderr)
        return EXIT_FINDINGS
    for line in result.lost:
        print(f"plc deploy: warning (--force): {line}", file=sys.stderr)
    return _switch(args, prefix, new, running, "upgrade")


def _switch(args, prefix: Path, new: Path, old: Path, what: str) -> int:
    before = release_of(prefix / "previous")
    point(prefix / "previous", old)
    point(prefix / "current", new)
    print(f"plc deploy: {what}: current -> {new.name}, previous -> {old.name}", file=sys.stderr)
    command = _restart_command(args)
    if not command:
        print(f"plc deploy: restart the service to run {new.name} (systemctl restart {args.name})",
              file=sys.stderr)
        return EXIT_OK
    try:
        ms = restart(command, args.log, args.name, time.time(), args.timeout)
    except DeployError as exc:               # the service was not restarted: the links go back
        point(prefix / "current", old)
        if before is not None:
            point(prefix / "previous", before)
        raise DeployError(f"{exc}; current -> {old.name} again") from None
    if ms is None:
        print("plc deploy: restarted; switch-over time not found in the log (see journalctl -u "
              f"{args.name})", file=sys.stderr)
    else:
        print(f"plc deploy: switch-over {ms:.1f} ms (outputs safe -> first scan of {new.name})")
    return EXIT_OK


def cmd_rollback(args) -> int:
    prefix: Path = args.prefix.resolve()
    running, previous = release_of(prefix / "current"), release_of(prefix / "previous")
    if running is None or previous is None:
        raise DeployError(f"{prefix} has no previous release to go back to")
    result = compare(layout_of(running), layout_of(previous))
    for line in result.lost:   # the runtime keeps them aside: going forward again finds them
        print(f"plc deploy: note: {line}", file=sys.stderr)
    return _switch(args, prefix, previous, running, "rollback")


def add_parsers(sub) -> None:
    s = sub.add_parser("service", help="a folder to install the soft-PLC as a systemd service",
                       description="Build the runtime for the program and write a self-contained deployment "
                                   "folder: the runtime, its run configuration, a systemd unit, install and "
                                   "uninstall scripts and a README.")
    s.add_argument("--out", required=True, type=Path, metavar="DIR", help="the folder to write")
    s.add_argument("--prefix", type=Path, metavar="DIR", help=f"where install.sh puts it (default "
                   f"/opt/{DEFAULT_NAME})")
    s.add_argument("--watchdog-sec", type=int, default=DEFAULT_WATCHDOG_SEC, metavar="S",
                   help=f"systemd WatchdogSec (default {DEFAULT_WATCHDOG_SEC})")
    s.add_argument("--user", metavar="USER", help="run as this user (default root)")
    for p in [s] + [sub.add_parser(n, help=h, description=d) for n, h, d in (
            ("upgrade", "switch a deployment to a new program version",
             "Build the new version into PREFIX/releases, compare its retained variables and register map with "
             "the running one (refused when a saved value would not be restored, unless --force), switch "
             "PREFIX/current to it, keep the old one as PREFIX/previous and restart the service. Prints the "
             "switch-over time."),
            ("rollback", "switch a deployment back to its previous version",
             "Point PREFIX/current at PREFIX/previous (and previous at the version left) and restart the "
             "service."))]:
        if p is not s:
            p.add_argument("--prefix", required=True, type=Path, metavar="DIR", help="the deployment folder")
            p.add_argument("--restart-command", metavar="CMD",
                           help="how to restart the service (default: systemctl restart NAME.service; '' = "
                                "switch only)")
            p.add_argument("--log", type=Path, metavar="FILE",
                           help="the runtime's log file, for the switch-over time (default: the journal)")
            p.add_argument("--timeout", type=float, default=60.0, metavar="S",
                           help="longest wait for the new version's first scan (default 60)")
        if p.prog.endswith("upgrade"):
            p.add_argument("--force", action="store_true", help="upgrade even when retained values would "
                           "not be restored (they are kept aside in the retained file)")
        if not p.prog.endswith("rollback"):
            p.add_argument("--src", type=Path, action="append", metavar="DIR",
                           help="ST sources (default: st_src/ of the project; repeatable)")
            p.add_argument("--config", type=Path, metavar="FILE",
                           help="run configuration (default: the machine's, machines/NAME/runtime.toml)")
            p.add_argument("--simulated", action="store_true",
                           help="allow a run configuration with the simulated plant ([io] layer = \"sim\"): a "
                                "demonstration service, never a machine's (refused without it)")
        p.add_argument("--name", default=None, help=f"service name (default {DEFAULT_NAME}; {DEFAULT_NAME}-NAME for "
                       "another machine than the project's default, --machine NAME)")
        p.add_argument("-q", "--quiet", action="store_true", help="print errors only")
        add_view_options(p)
    sub.choices["service"].set_defaults(func=cmd_service)
    sub.choices["upgrade"].set_defaults(func=cmd_upgrade)
    sub.choices["rollback"].set_defaults(func=cmd_rollback)
