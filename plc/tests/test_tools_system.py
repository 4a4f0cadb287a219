"""System tests of the PLC's tool table (docs/tools.md): `plc run` with the real application and the simulated
carousel, `plc tools` and `plc host` as separate processes over Modbus/TCP, as an integrator runs them. Loopback
only; every wait is bounded and waits for a state, never for a time."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from test_host_system import REPO, Plc, ok


class ToolsPlc(Plc):
    def tools(self, *words: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-m", "plc.cli", "tools", "--port", str(self.port), "--token-file",
               str(self.tmp / "tools.token"), "--audit", str(self.tmp / "tools-audit.log"), *words]
        return subprocess.run(cmd, cwd=REPO / "plc", capture_output=True, text=True, timeout=timeout)

    def table(self) -> dict[int, dict[str, int]]:
        """tool -> its row's values, from the map's registers."""
        client, tags = self.tags()
        with client:
            n = int(tags.get("TableRows"))
            cols = ("TableTool", "TablePocket", "TableGroup", "TableLife", "TableUsedMin", "TableUsedSec", "TableFlags")
            v = tags.read(*(f"{c}{i}" for i in range(1, n + 1) for c in cols))
        rows = {}
        for i in range(1, n + 1):
            if v[f"TableTool{i}"]:
                rows[int(v[f"TableTool{i}"])] = {"row": i, **{c[5:].lower(): int(v[f"{c}{i}"]) for c in cols[1:]}}
        return rows

    def read(self, *names: str) -> dict:
        client, tags = self.tags()
        with client:
            return tags.read(*names)

    def write(self, **values) -> None:
        client, tags = self.tags()
        with client:
            tags.write(**values)


@pytest.fixture(scope="module")
def plc(tmp_path_factory):
    p = ToolsPlc(tmp_path_factory.mktemp("tools"))
    p.start()
    (p.tmp / "tools.token").write_text("test-token\n")      # the right to change the table (plc tools --help)
    yield p
    p.stop()


def refused(result: subprocess.CompletedProcess) -> str:
    assert result.returncode == 1, f"exit {result.returncode}\n{result.stdout}\n{result.stderr}"
    return result.stdout


def test_a_fresh_table_holds_tool_n_in_pocket_n(plc):
    out = ok(plc.tools("list"))
    assert out.splitlines()[0].startswith("6 rows, 6 tools")
    assert {t: r["pocket"] for t, r in plc.table().items()} == {n: n for n in range(1, 7)}


def test_t101_set_into_pocket_3_changes_in_and_out(plc):
    out = ok(plc.tools("set", "T101", "--row", "3", "--pocket", "3"))
    assert "set row 3 T101 P3" in out and out.rstrip().endswith("done")
    assert plc.table()[101]["pocket"] == 3
    assert 3 not in plc.table()
    assert plc.read("PocketTool3")["PocketTool3"] == 101          # the pocket table relabelled by the edit
    # the host names no pocket for T101 (it would say 101): the PLC takes the pocket from its table
    assert ok(plc.host("clear", "T101 M6")).splitlines()[-1] == "tool 101 in spindle"
    values = plc.read("ToolInSpindle", "PreparedTool", "PocketTool3", "CurrentPocket", "FaultReason")
    assert values == {"ToolInSpindle": 101, "PreparedTool": 101, "PocketTool3": 0, "CurrentPocket": 3,
                      "FaultReason": 0}
    assert ok(plc.host("T0 M6")).splitlines()[-1] == "tool 0 in spindle"
    assert plc.read("ToolInSpindle", "PocketTool3") == {"ToolInSpindle": 0, "PocketTool3": 101}
    audit = (plc.tmp / "tools-audit.log").read_text()
    assert "tools set row 3 T101 P3 group 0 life unlimited used 0:00 -> done" in audit


def test_edits_the_plc_refuses_exit_1_with_its_reason_and_are_audited(plc):
    out = refused(plc.tools("set", "T5", "--pocket", "4"))
    assert "refused: pocket outside the carousel or held by another row" in out
    assert plc.table()[5]["pocket"] == 5
    out = refused(plc.tools("set", "T5", "--pocket", "9"))
    assert "refused: pocket outside the carousel" in out
    assert "tools set row 5 T5 P4 group 0 life unlimited used 0:00 -> refused: pocket" \
        in (plc.tmp / "tools-audit.log").read_text()


def test_changes_need_the_token_and_bad_input_is_a_sentence(plc, tmp_path):
    cmd = [sys.executable, "-m", "plc.cli", "tools", "--port", str(plc.port), "--token-file",
           str(tmp_path / "none.token"), "reset", "T1"]
    r = subprocess.run(cmd, cwd=REPO / "plc", capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "changes need the monitor's token" in r.stderr and "Traceback" not in r.stderr
    r = plc.tools("set", "Tx")
    assert r.returncode == 2 and "'Tx' is no tool number" in r.stderr
    r = plc.tools("set", "T77")
    assert r.returncode == 2 and "no free row for T77 (the table has 6 rows)" in r.stderr
    r = plc.tools("set", "T77", "--row", "6")
    assert r.returncode == 2 and "T77 is new in row 6: give its --pocket" in r.stderr
    bad = tmp_path / "bad.tbl"
    bad.write_text("T1 P1 D0\nT2 Z0.5 ;no pocket\n")
    r = plc.tools("load", str(bad))
    assert r.returncode == 2 and f"{bad}:2: expected one T<n> and one P<p>" in r.stderr


def test_a_worn_tool_gets_its_sister_and_the_time_survives_a_restart(plc):
    ok(plc.tools("set", "T2", "--group", "1", "--life", "1", "--used", "0:59"))
    ok(plc.tools("set", "T4", "--group", "1"))
    assert ok(plc.host("clear", "T2 M6")).splitlines()[-1] == "tool 2 in spindle"
    plc.write(SpindleOn=True)                 # the CNC's spindle turns: T2 cuts until its minute is used
    deadline = time.monotonic() + 60
    while plc.table()[2]["usedmin"] < 1:
        assert time.monotonic() < deadline, f"T2 never reached its life: {plc.table()[2]}"
        time.sleep(0.1)
    plc.write(SpindleOn=False)
    used = plc.table()[2]
    assert "WORN" in ok(plc.tools("list"))
    ok(plc.host("T0 M6"))
    out = ok(plc.host("T2 M6"))               # the host asks T2: the PLC loads its sister T4, the host takes it
    assert "M6: T2 is worn out: its sister T4 in spindle" in out and out.splitlines()[-1] == "tool 4 in spindle"
    assert plc.read("ToolInSpindle", "PreparedTool", "CurrentPocket") == \
        {"ToolInSpindle": 4, "PreparedTool": 4, "CurrentPocket": 4}
    assert plc.table()[4]["usedmin"] == 0
    ok(plc.host("T0 M6"))
    plc.stop()
    plc.start()
    after = plc.table()
    assert (after[2]["usedmin"], after[2]["usedsec"]) == (used["usedmin"], used["usedsec"])
    assert after[101]["pocket"] == 3 and after[2]["life"] == 1 and after[4]["group"] == 1
    ok(plc.tools("reset", "T2"))
    assert plc.table()[2]["usedmin"] == 0 and plc.table()[2]["usedsec"] == 0


def test_a_group_with_no_time_left_is_refused_with_109(plc):
    ok(plc.tools("set", "T6", "--life", "1", "--used", "1:00"))
    r = plc.host("clear", "T6 M6")
    assert r.returncode == 3, f"exit {r.returncode}\n{r.stdout}\n{r.stderr}"     # soft: the program goes on
    assert "109" in r.stdout and "no tool of its group has time left" in r.stdout
    assert plc.read("ToolInSpindle")["ToolInSpindle"] == 0
    ok(plc.host("clear"))
    ok(plc.tools("reset", "T6"))


def test_the_probe_in_the_spindle_inhibits_the_spindle(plc):
    ok(plc.tools("set", "T5", "--probe"))
    assert refused(plc.tools("set", "T1", "--probe")).rstrip().endswith("refused: another tool is the probe tool")
    ok(plc.host("clear", "T5 M6"))
    assert plc.read("SpindleInhibit")["SpindleInhibit"] is True
    r = plc.host("M3")
    assert r.returncode == 1, f"exit {r.returncode}\n{r.stdout}\n{r.stderr}"
    assert "M3: the spindle stays off: the PLC inhibits it (SpindleInhibit: the probe tool T5 is in the spindle)" \
        in r.stdout
    assert plc.read("SpindleOn")["SpindleOn"] is False
    ok(plc.host("T0 M6"))
    assert plc.read("SpindleInhibit")["SpindleInhibit"] is False
    assert "spindle on" in ok(plc.host("M3")).splitlines()
    assert plc.read("SpindleOn")["SpindleOn"] is True
    ok(plc.host("T1 M6"))                     # M6 stops the spindle first
    assert plc.read("SpindleOn")["SpindleOn"] is False
    ok(plc.host("M4", "M5", "T0 M6"))


def test_export_then_load_gives_the_same_table(plc, tmp_path: Path):
    before = plc.table()
    out = tmp_path / "tools.tbl"
    ok(plc.tools("export", str(out)))
    text = out.read_text()
    assert "T101 P3 D0 Z0 ;atc: group=0 life=0 used=0:00" in text
    assert "T5 P5 D0 Z0 ;atc: group=0 life=0 used=0:00 probe" in text
    ok(plc.tools("clear", "T6"))
    ok(plc.tools("load", str(out)))
    assert {t: {k: v for k, v in r.items() if k != "row"} for t, r in plc.table().items()} == \
        {t: {k: v for k, v in r.items() if k != "row"} for t, r in before.items()}


def tooldb(plc, offsets: Path, talk: str) -> subprocess.CompletedProcess:
    """configs/linuxcnc/bin/atc-tooldb as LinuxCNC runs it (DB_PROGRAM), told `talk` on its stdin; it exits 0."""
    cmd = [sys.executable, str(REPO / "configs" / "linuxcnc" / "bin" / "atc-tooldb"), "--port", str(plc.port),
           "--offsets", str(offsets)]
    r = subprocess.run(cmd, input=talk, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    return r


def test_the_tool_database_program_serves_the_plcs_table(plc, tmp_path: Path):
    """configs/linuxcnc/bin/atc-tooldb as LinuxCNC runs it (DB_PROGRAM): the version, then g, p, l, u."""
    offsets = tmp_path / "offsets.tbl"
    r = tooldb(plc, offsets, "g\np T101 P3 Z1.5 D6 ;drill 6\nl T101 P0\nu T0 P0\nbogus\ng\n")
    lines = r.stdout.splitlines()
    assert lines[0] == "v2.1"
    first = lines[1:lines.index("FINI")]
    pockets = {int(t[1:]): int(p[1:]) for t, p, *_ in (line.split() for line in first)}
    assert pockets == {t: r["pocket"] for t, r in plc.table().items()}
    assert "T101 P3 D0 Z0" in first
    rest = lines[lines.index("FINI") + 1:]
    assert rest[0] == "FINI (update recvd) T101 P3 Z1.5 D6 ;drill 6"
    assert rest[1] == "FINI (update recvd) T101 P0" and rest[2] == "FINI (update recvd) T0 P0"
    assert rest[3] == "NAK unknown command <bogus>"
    assert "T101 P3 Z1.5 D6 ;drill 6" in rest[4:]              # the second g serves the offsets kept by p
    assert rest[-1] == "FINI"
    assert offsets.read_text() == "T101 P0 Z1.5 D6 ;drill 6\n"


def test_a_tool_database_put_with_another_pocket_is_a_table_edit(plc, tmp_path: Path):
    """A `p` line whose pocket differs from the PLC's row becomes the PLC's edit command: done when the pocket is
    free (the table and the pocket table follow), NAK with the PLC's reason when it is refused; the offsets are
    kept either way, and both answers are logged."""
    ok(plc.tools("clear", "T6"))                                     # pocket 6 free
    offsets = tmp_path / "offsets.tbl"
    r = tooldb(plc, offsets, "p T101 P6 Z2 D6 ;moved\np T101 P5 Z3 D6 ;onto T5\np T101 P6 Z4 D6 ;same pocket\n")
    lines = r.stdout.splitlines()
    refusal = "NAK the PLC refused T101 in pocket 5: refused: pocket outside the carousel or held by another row"
    assert lines == ["v2.1", "FINI (update recvd) T101 P6 Z2 D6 ;moved", refusal,
                     "FINI (update recvd) T101 P6 Z4 D6 ;same pocket"]
    assert "atc-tooldb: p: T101 to pocket 6: the PLC's table row 3 set -> done" in r.stderr
    assert "T101 to pocket 5: the PLC's table row 3 set -> refused: pocket outside the carousel" in r.stderr
    assert r.stderr.count("row 3 set") == 2                           # the same pocket is no edit
    table = plc.table()
    assert table[101]["pocket"] == 6 and table[5]["pocket"] == 5
    assert plc.read("PocketTool6", "PocketTool3") == {"PocketTool6": 101, "PocketTool3": 0}
    assert offsets.read_text() == "T101 P0 Z4 D6 ;same pocket\n"
    ok(plc.tools("set", "T101", "--pocket", "3"))
    ok(plc.tools("set", "T6", "--row", "6", "--pocket", "6"))
