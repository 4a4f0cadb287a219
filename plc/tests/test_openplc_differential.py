"""Optional differential: our build and OpenPLC v3's build of the same deploy file, scan for scan.

`plc deploy openplc` writes the file an integrator uploads to OpenPLC v3.  Here it is built twice: by `plc build`
(our C against plc_abi.h, stepped by differential/abi_driver.c) and by the real MATIEC (iec2c, then g++ with
OpenPLC's own headers, stepped by differential/matiec_driver.cpp the way OpenPLC's main loop steps it).  One
deterministic host script drives each build through the register map (modbus_map/map.toml): the simulated plant,
the iov2 handshake of LinuxCNC, the heartbeat, tool changes, aborts at many points of a change, E-stops in the
middle of a change, a soft fault and the documented recovery (clear, home, confirm).  Every scan, every located
variable of both builds is recorded; the test fails on the first scan where they differ.

It needs what test_matiec_optional.py needs (IEC2C, IEC2C_LIB and IEC2C_CINCLUDE: OpenPLC_v3's iec2c, its
webserver/lib and webserver/core/lib) and is skipped with the reason otherwise (`pytest -rs`).  It runs a little
over 20,000 scans per build; the scans are counted, never timed.
"""

import os
import shutil
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

from test_matiec_optional import IEC2C_FLAGS, PROGRAM_PATH, _reference_compiler

REPO = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
DRIVERS = HERE / "differential"
INCLUDE = REPO / "plc" / "src" / "plc" / "native" / "include"
TIMEOUT_S = 900
MIN_SCANS = 20_000
HEARTBEAT_EVERY = 25          # scans (100 ms at the 4 ms task): well inside the host link time-out
ABORT_REASON = 8              # iov2's emc-reason for a task abort (atc.host.session.REASON_TASK_ABORT)
POCKETS = 6                   # machines/default: pocket n holds tool n

# The script, episode by episode; it repeats until MIN_SCANS have run.  ("abort", tool, n): abort n scans after
# tool-change rises; ("estop", tool, n): open the simulated E-stop chain n scans after it; ("soft", tool): an M6 of a
# tool in no row of the tool table with a pocket outside the carousel (soft fault 106, the program goes on);
# ("worn", tool): its row edited worn out (life 1 min, 1 min used), an M6 of it (soft fault 109), the row reset.
PLAN = [
    ("change", 3), ("change", 5), ("abort", 2, 5), ("change", 2), ("abort", 6, 60), ("change", 6),
    ("estop", 1, 120), ("change", 1), ("soft", 99), ("change", 4), ("worn", 5), ("change", 5),
    ("abort", 3, 250), ("change", 3),
    ("estop", 5, 400), ("change", 5), ("abort", 2, 500), ("change", 2), ("estop", 6, 30), ("change", 6),
    ("abort", 1, 700), ("change", 1), ("estop", 4, 650), ("change", 4), ("abort", 6, 120), ("home",),
]


class Build:
    """One build of the deploy file behind its driver: write before a scan, read every located variable after."""

    def __init__(self, exe: Path):
        self.proc = subprocess.Popen([str(exe)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                     bufsize=1)
        self.addresses = []
        for line in self.proc.stdout:
            if line.startswith("ready"):
                break
            self.addresses.append(line.split()[1])
        self.order = sorted(range(len(self.addresses)), key=lambda i: self.addresses[i])

    def scan(self, writes: dict[str, int]) -> tuple:
        self.proc.stdin.write(" ".join(f"{a}={v}" for a, v in writes.items()) + "\n")
        line = self.proc.stdout.readline().split()
        if not line or line[0] != "o":
            raise AssertionError(f"the driver answered {' '.join(line) or 'nothing'}")
        values = line[1:]
        return tuple(int(values[i]) for i in self.order)

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=60)


class Host:
    """The deterministic host: what LinuxCNC's iov2 and an operator do, scan by scan, reacting to this build's own
    outputs (so two builds that agree take the same path)."""

    def __init__(self, build: Build, addresses: dict[str, str]):
        self.build, self.addresses = build, addresses
        self.column = {name: build.order.index(build.addresses.index(addr)) for name, addr in addresses.items()
                       if addr in build.addresses}
        self.pending: dict[str, int] = {}
        self.scans: list[tuple] = []
        self.out: dict[str, int] = {}
        self.beat = 0
        self.events = Counter()

    def write(self, **values) -> None:
        for name, value in values.items():
            self.pending[self.addresses[name]] = int(value)

    def step(self) -> None:
        if len(self.scans) % HEARTBEAT_EVERY == 0:
            self.beat = self.beat % 60000 + 1
            self.write(HostHeartbeat=self.beat)
        row = self.build.scan(self.pending)
        self.pending = {}
        self.scans.append(row)
        self.out = {name: row[col] for name, col in self.column.items()}

    def until(self, cond, limit: int) -> bool:
        for _ in range(limit):
            self.step()
            if cond(self.out):
                return True
        return False

    def hold(self, scans: int) -> None:
        for _ in range(scans):
            self.step()

    # ---- iov2, as LinuxCNC drives it (atc.host.session does the same over Modbus, in seconds)
    def prepare(self, tool: int, pocket: int) -> None:
        self.write(ToolPrepNumber=tool, ToolPrepPocket=pocket, ToolPrepare=1)
        self.until(lambda s: s["ToolPrepared"], 3000)
        self.write(ToolPrepare=0)
        self.until(lambda s: not s["ToolPrepared"], 100)

    def start_change(self) -> bool:
        self.write(StartChange=1)
        self.until(lambda s: s["StartChangeAck"] or s["ToolchangerFault"], 3000)
        self.write(StartChange=0)
        self.until(lambda s: not s["StartChangeAck"], 100)
        return not self.out["ToolchangerFault"]

    def change(self, tool: int) -> None:
        self.prepare(tool, tool)
        if not self.start_change():
            return self.fault()
        self.write(ToolNumber=self.out["ToolInSpindle"], ToolChange=1)
        done = self.until(lambda s: s["ToolChanged"] or s["ToolchangerFault"], 6000)
        self.write(ToolChange=0)
        if done and self.out["ToolChanged"]:
            self.events["changes"] += 1
            self.until(lambda s: not s["ToolChanged"], 100)
        else:
            self.fault()

    def abort(self) -> None:
        self.write(EmcReason=ABORT_REASON, EmcAbort=1, ToolPrepare=0, ToolChange=0, StartChange=0)
        if self.until(lambda s: s["EmcAbortAck"], 500):
            self.events["aborts"] += 1
        self.write(EmcAbort=0)
        self.until(lambda s: not s["EmcAbortAck"], 100)

    def interrupted(self, tool: int, after: int, estop: bool) -> None:
        self.prepare(tool, tool)
        if not self.start_change():
            return self.fault()
        self.write(ToolNumber=self.out["ToolInSpindle"], ToolChange=1)
        if self.until(lambda s: s["ToolChanged"] or s["ToolchangerFault"], after):
            self.write(ToolChange=0)
            self.events["finished before the interruption"] += 1
            return self.fault() if self.out["ToolchangerFault"] else None
        if estop:
            self.write(SimEStop=1)
            self.hold(50)
            self.events["e-stops"] += 1
            self.abort()
            self.write(SimEStop=0)
            self.hold(25)
        else:
            self.abort()
        self.fault()

    def edit_row(self, **values) -> None:
        """One tool table edit (docs/tools.md): the values, then a rising ToolEditRequest until it is answered."""
        count = self.out["ToolEditCount"]
        self.write(ToolEditRequest=0, **{f"ToolEdit{k}": v for k, v in values.items()})
        self.step()
        self.write(ToolEditRequest=1)
        if self.until(lambda s: s["ToolEditCount"] != count, 50) and self.out["ToolEditAnswer"] == 1:
            self.events["tool table edits"] += 1
        self.write(ToolEditRequest=0)
        self.step()

    def worn(self, tool: int) -> None:
        """A worn tool without a sister: its M6 is refused with soft fault 109, the program goes on."""
        self.edit_row(Code=1, Row=tool, Tool=tool, Pocket=tool, Group=0, Life=1, UsedMin=1, UsedSec=0, Flags=0)
        self.soft_fault(tool, tool)
        self.edit_row(Code=2, Row=tool)

    def soft_fault(self, tool: int, pocket: int = POCKETS + 3) -> None:
        """An M6 the PLC skips with a soft fault (> 0): a pocket outside the carousel (106), a worn tool (109)."""
        self.prepare(tool, pocket)
        if self.start_change():
            self.write(ToolNumber=self.out["ToolInSpindle"], ToolChange=1)
            self.until(lambda s: s["ToolChanged"] or s["ToolchangerFault"], 3000)
            self.write(ToolChange=0)
        if self.out["FaultReason"] > 0:
            self.events[f"soft faults {self.out['FaultReason']}"] += 1
        self.fault()

    def fault(self) -> None:
        """LinuxCNC's fault handshake, then the operator: clear, home and confirm as Recovery asks."""
        if self.out["ToolchangerFault"]:
            self.write(ToolchangerFaulted=1, ToolchangerFaultAck=1)
            self.hold(3)
            self.write(ToolchangerFaultAck=0)
        self.write(ClearFault=0)
        self.step()
        self.write(ClearFault=1)
        if self.until(lambda s: s["FaultReason"] == 0 and not s["ToolchangerFault"], 200):
            self.events["faults cleared"] += 1
        self.write(ClearFault=0, ToolchangerFaulted=0)
        self.step()
        if self.out["Recovery"] & 1:
            self.home()
            self.events["recoveries: homed"] += 1
        if self.out["Recovery"] & 2:
            self.write(ConfirmToolNumber=self.out["UncertainTool"], ConfirmTool=0)
            self.step()
            self.write(ConfirmTool=1)
            if self.until(lambda s: s["Recovery"] == 0, 200):
                self.events["recoveries: tool confirmed"] += 1
            self.write(ConfirmTool=0)
            self.step()

    def home(self) -> None:
        self.write(HomeRequest=0)
        self.step()
        self.write(HomeRequest=1)
        self.until(lambda s: s["ChangerBusy"], 50)
        self.until(lambda s: not s["ChangerBusy"], 6000)
        self.write(HomeRequest=0)
        self.step()

    def run(self, min_scans: int = MIN_SCANS) -> None:
        """The plan, episode by episode, again until min_scans have run (1: the plan once)."""
        self.write(SimulatedPlant=1, EStopOk=1, GuardDoorClosed=1, AirPressureOk=1, SpindleStopped=1,
                   MbxHostActive=0)
        self.until(lambda s: s["CarouselHomed"] and not s["ChangerBusy"], 6000)
        while True:
            for episode in PLAN:
                kind = episode[0]
                if kind == "change":
                    self.change(episode[1])
                elif kind in ("abort", "estop"):
                    self.interrupted(episode[1], episode[2], estop=kind == "estop")
                elif kind == "soft":
                    self.soft_fault(episode[1])
                elif kind == "worn":
                    self.worn(episode[1])
                else:
                    self.home()
                    self.events["homings asked"] += 1
                self.hold(10)
            if len(self.scans) >= min_scans:
                break


def _signal_addresses() -> dict[str, str]:
    from atc.host.tags import load_map
    from atc.map.model import iec_address
    rmap = load_map(REPO / "modbus_map" / "map.toml")
    return {s.name: iec_address(s) for s in rmap.signals if iec_address(s)}


def _run(cmd, cwd, what, env=None):
    result = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT_S, env=env)
    assert result.returncode == 0, f"{what} failed:\n{(result.stdout + result.stderr)[-4000:]}"


def build_ours(deploy: Path, out: Path, cflags: tuple[str, ...] = ("-O2",), source: Path = REPO) -> Path:
    """`plc build` of the deploy file, compiled with gcc (cflags) and stepped by abi_driver.c: the driver.
    `source`: the tree whose plc package and plc_abi.h build it (scripts/bench_scan.py --baseline: an earlier
    commit's, exported from the history); the driver is always this tree's."""
    env = None if source == REPO else dict(os.environ, PYTHONPATH=str(source / "plc" / "src"))
    _run([sys.executable, "-m", "plc.cli", "build", "-q", str(deploy), "--out", str(out)], source, "plc build", env)
    _run(["gcc", "-std=c99", *cflags, "-Wall", "-Wextra", "-Werror",
          f"-I{source / INCLUDE.relative_to(REPO)}", "program.c", str(DRIVERS / "abi_driver.c"), "-lm", "-o", "prog"],
         out, "gcc (our build)")
    return out / "prog"


def build_matiec(deploy: Path, work: Path, iec2c: Path, library: Path, include: Path,
                 cflags: tuple[str, ...] = ()) -> Path:
    """iec2c of the deploy file as OpenPLC runs it, then g++ with OpenPLC's headers (no -O, as OpenPLC builds it,
    unless cflags say otherwise), stepped by matiec_driver.cpp: the driver."""
    (work / "st_files").mkdir(parents=True)
    shutil.copy(deploy, work / "st_files" / "program.st")
    os.symlink(library, work / "lib", target_is_directory=True)
    _run([str(iec2c), *IEC2C_FLAGS, PROGRAM_PATH], work, "iec2c")
    core = work / "core"
    core.mkdir()
    for name in ("POUS.c", "POUS.h", "LOCATED_VARIABLES.h", "Config0.c", "Config0.h", "Res0.c"):
        shutil.move(work / name, core / name)
    os.symlink(include, core / "lib", target_is_directory=True)
    (core / "c_blocks.h").write_text("")       # OpenPLC's empty placeholder, included as "../c_blocks.h"
    shutil.copy(DRIVERS / "matiec_driver.cpp", core)
    _run(["g++", "-std=gnu++11", *cflags, "-I", "./lib", "-w", "Config0.c", "Res0.c", "matiec_driver.cpp", "-o",
          "prog"], core, "g++ (MATIEC's build, OpenPLC's headers)")
    return core / "prog"


def deploy_file(out: Path) -> Path:
    """The file an integrator uploads to OpenPLC v3 (`plc deploy openplc`)."""
    _run([sys.executable, "-m", "plc.cli", "deploy", "openplc", "-q", "--out", str(out)], REPO, "plc deploy openplc")
    return out


def _builds(tmp_path: Path) -> tuple[Path, Path]:
    iec2c, library = _reference_compiler()
    include = os.environ.get("IEC2C_CINCLUDE")
    if not include:
        pytest.skip("IEC2C_CINCLUDE not set: point it at OpenPLC_v3/webserver/core/lib to build MATIEC's C")
    if not (Path(include) / "iec_std_lib.h").is_file():
        pytest.fail(f"IEC2C_CINCLUDE={include} has no iec_std_lib.h; expected OpenPLC_v3/webserver/core/lib")
    for compiler in ("gcc", "g++"):
        if shutil.which(compiler) is None:
            pytest.skip(f"{compiler} not found")
    deploy = deploy_file(tmp_path / "deploy.st")
    return build_ours(deploy, tmp_path / "ours"), build_matiec(deploy, tmp_path / "matiec", iec2c, library,
                                                               Path(include))


def test_our_build_and_openplc_matiec_agree_scan_for_scan(tmp_path):
    ours_exe, matiec_exe = _builds(tmp_path)
    addresses = _signal_addresses()
    hosts = []
    for exe in (ours_exe, matiec_exe):
        build = Build(exe)
        host = Host(build, addresses)
        try:
            host.run()
        finally:
            build.close()
        hosts.append(host)
    ours, matiec = hosts
    assert sorted(ours.build.addresses) == sorted(matiec.build.addresses), "the builds locate other variables"
    names = sorted(ours.build.addresses)
    differing = [n for n, (a, b) in enumerate(zip(ours.scans, matiec.scans, strict=False)) if a != b]
    summary = (f"{len(ours.scans)} scans (ours) / {len(matiec.scans)} (MATIEC), {len(differing)} differ; "
               f"script: {dict(ours.events)}")
    print(summary)
    if differing:
        n = differing[0]
        pairs = zip(ours.scans[n], matiec.scans[n], strict=True)
        detail = [f"{names[i]}: ours {a}, MATIEC {b}" for i, (a, b) in enumerate(pairs) if a != b]
        pytest.fail(f"{summary}\nfirst difference at scan {n}: " + "; ".join(detail))
    assert len(ours.scans) == len(matiec.scans) >= MIN_SCANS
    # the script did what it says (a host that never got past homing would agree too)
    assert ours.events["changes"] >= 20, summary
    assert ours.events["aborts"] >= 10, summary
    assert ours.events["e-stops"] >= 4, summary
    assert ours.events["soft faults 106"] >= 1 and ours.events["soft faults 109"] >= 1, summary
    assert ours.events["recoveries: homed"] >= 1, summary
    assert ours.events == matiec.events, summary
