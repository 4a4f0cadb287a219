"""The toolchanger page in a real browser (Debian's chromium + chromium-driver, driven by selenium).

The real application runs on our runtime with the simulated carousel and its monitor; `plc hmi` serves the page
on a free loopback port.  Checked as an operator would see it: the page loads with the carousel drawn from the
map and machines/default/machine.toml; during T3 M6 the carousel turns (motion shown) to pocket 3 and tool 3 arrives in
the spindle; a forced input (the simulated plant switched off: the application then sees the open E-stop
chain) changes the program's behaviour, shows as forced, and the fault appears with its text, cause and
remedy; without the token every command and force is refused and nothing reaches the PLC.  A screenshot is
kept in build/artifacts/hmi-toolchanger.png.

Without chromium, chromium-driver or selenium the test is skipped with the reason printed (scripts/setup
installs them); a browser that is present but fails is a failure.
"""
from __future__ import annotations

import contextlib
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import rt_harness as h
from plc import driver, runtime
from plc.hmi.monitor import Monitor
from plc.modbus import ModbusClient
from atc.host.session import Session, Timeouts
from atc.host.tags import Tags, load_map
from atc.runsetup import runtime_setup
from atc.tools import Row, Table

REPO = Path(__file__).resolve().parents[2]
ARTIFACTS = REPO / "build" / "artifacts"
TOKEN = "browser-test-token-0123456789"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")

try:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By
    HAVE_SELENIUM = True
except ImportError:
    HAVE_SELENIUM = False

MISSING = [what for what, ok in (("chromium", CHROMIUM), ("chromium-driver", DRIVER), ("selenium", HAVE_SELENIUM))
           if not ok]
if MISSING:
    print(f"\ntest_hmi_browser: SKIPPED: {', '.join(MISSING)} not installed (scripts/setup installs them)",
          file=sys.stderr)
pytestmark = pytest.mark.skipif(bool(MISSING), reason=f"{', '.join(MISSING)} not installed (run scripts/setup)")


@pytest.fixture(scope="module")
def plant(tmp_path_factory):
    """The application on our runtime, its monitor, and `plc hmi` in front of it."""
    with served_plant(tmp_path_factory.mktemp("hmi")) as served:
        yield served


@contextlib.contextmanager
def served_plant(tmp: Path):
    """The application on our runtime (simulated plant, monitor, token) and `plc hmi` in front of it, in `tmp`;
    yields url, rt (the rt_harness.Runtime), sock and tmp; stops both at the end, the runtime checked clean."""
    result = driver.compile_sources([REPO / "st_src"], portability=False)
    assert result.ok
    (tmp / "program.c").write_text(result.c_text)
    setup = runtime_setup(REPO / "modbus_map" / "map.toml", tmp)     # what `plc run` of the project adds
    binary = runtime.build_runtime(tmp / "program.c", h.CACHE, sanitize=h.SANITIZE, observer=setup.observer)
    (tmp / "token").write_text(TOKEN + "\n")
    sock = tmp / "m.sock"
    rt = h.Runtime(binary, "--no-rt", "--sim-flag", setup.sim_flag, "--monitor", str(sock),
                   "--monitor-token", str(tmp / "token"), "--writable-registers", "512-8191").start()
    hmi = subprocess.Popen([sys.executable, "-m", "plc.cli", "hmi", "--port", "0", "--plc-port", str(rt.port),
                            "--monitor", str(sock), "--token-file", str(tmp / "token"), "--alarms",
                            str(tmp / "alarms.jsonl"), "--map", str(REPO / "modbus_map" / "map.toml")],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    line = hmi.stdout.readline()
    m = re.search(r"(http://127\.0\.0\.1:\d+)/", line)
    assert m, f"plc hmi did not start: {line}{hmi.stdout.read() if hmi.poll() is not None else ''}"
    try:
        yield {"url": m.group(1), "rt": rt, "sock": sock, "tmp": tmp}
    except BaseException:            # a test that failed inside `with served_plant(...)`: leave nothing running
        hmi.kill()
        hmi.wait(10)
        rt.kill()
        raise
    hmi.send_signal(signal.SIGINT)
    try:
        hmi.wait(10 * h.SLOW)
    except subprocess.TimeoutExpired:
        hmi.kill()
    rc = rt.stop()
    rt.assert_clean_exit(rc)


def browser():
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1400,900"):
        opts.add_argument(arg)
    return webdriver.Chrome(service=Service(DRIVER), options=opts)


def text(b, element_id: str) -> str:
    return b.find_element(By.ID, element_id).text


# Installed in the page: records the five fields' texts on every change the page makes to any of them.
WATCH_FIELDS = """
const ids = ["current-pocket", "motion", "target-pocket", "spindle-tool", "changer-state"];
const snap = () => ids.map(id => document.getElementById(id).textContent.trim());
window.__atcSeen = [snap()];
const observer = new MutationObserver(() => {
    const now = snap(), last = window.__atcSeen[window.__atcSeen.length - 1];
    if (now.some((v, i) => v !== last[i])) { window.__atcSeen.push(now); }
});
for (const id of ids) {
    observer.observe(document.getElementById(id), {childList: true, characterData: true, subtree: true});
}
"""


def wait_page(b, predicate, timeout: float, what: str):
    return h.wait_until(lambda: predicate(b), timeout, what, step=0.05)


def test_the_page_shows_a_tool_change_a_forced_input_and_its_fault_and_refuses_without_token(plant, tmp_path):
    url = plant["url"]
    b = browser()
    try:
        b.get(url + "/")
        assert "toolchanger" in b.title
        wait_page(b, lambda b: text(b, "plc-link") == "connected", 10, "the page to reach the PLC")
        pockets = b.find_elements(By.CSS_SELECTOR, ".pocket")
        assert len(pockets) == 6, "machines/default/machine.toml: 6 pockets"
        wait_page(b, lambda b: text(b, "spindle-tool") == "T0", 10, "the empty spindle")
        assert b.find_elements(By.CSS_SELECTOR, "#iolines tr[data-signal=ToolPrepare]"), "iov2 lines from the map"

        # --- T3 M6 from a host, the page watched every 50 ms
        rmap = load_map(REPO / "modbus_map" / "map.toml")
        client = ModbusClient("127.0.0.1", plant["rt"].port, timeout=5 * h.SLOW)
        client.connect()
        session = Session(rmap, client, say=lambda _t: None, timeouts=Timeouts(request=60 * h.SLOW))
        outcome = {}

        def host():
            session.start()
            outcome["prepare"] = session.prepare(3, 3)
            outcome["change"] = session.change()

        # every state the page shows is recorded by the page itself (a MutationObserver on the five fields), not by
        # polling it from here: a busy machine slows WebDriver's round trips, never what the page displayed
        b.execute_script(WATCH_FIELDS)
        t = threading.Thread(target=host)
        t.start()
        t.join(120 * h.SLOW)
        assert not t.is_alive(), "the host's T3 M6 did not end"
        seen = [tuple(v) for v in b.execute_script("return window.__atcSeen;")]
        assert outcome["prepare"].ok and outcome["change"].ok, outcome
        wait_page(b, lambda b: text(b, "spindle-tool") == "T3", 10, "tool 3 in the spindle on the page")
        pockets_seen = [s[0] for s in seen]
        assert any(s[1].startswith("turning") for s in seen), f"the carousel never showed motion: {seen[:5]}"
        assert "3" in pockets_seen and pockets_seen.index("3") > 0, f"pocket 3 never reached: {pockets_seen}"
        assert any(s[2] == "3" for s in seen), "the target pocket 3 was shown"
        assert pockets_seen[0] != "3", "the carousel started elsewhere"
        assert any("AtcGetting" in s[4] for s in seen), "the changer state by name"
        current = b.find_element(By.CSS_SELECTOR, ".pocket.current")
        assert current.get_attribute("data-pocket") == "3"

        # --- the tool table (docs/tools.md): every tool with its time left; a worn tool marked there and on the ring
        wait_page(b, lambda b: len(b.find_elements(By.CSS_SELECTOR, "#tools tbody tr")) == 6, 10, "the tool table")
        assert not b.find_elements(By.CSS_SELECTOR, ".pocket.worn")
        edits = Table(Tags(rmap, client), tmp_path / "audit.log")
        assert edits.edit(1, 5, "set T5 worn", Row(5, 5, 5, life=1, used_min=1)) == 1
        assert edits.edit(1, 4, "set T4 with time left", Row(4, 4, 4, life=2, used_min=1, used_sec=30)) == 1
        wait_page(b, lambda b: b.find_elements(By.CSS_SELECTOR, "#tools tr.worn[data-tool='5']"), 10,
                  "T5 marked worn in the tool table")
        assert b.find_elements(By.CSS_SELECTOR, ".pocket.worn[data-pocket='5']"), "pocket 5 marked worn"
        row4 = [td.text for td in b.find_elements(By.CSS_SELECTOR, "#tools tr[data-tool='4'] td")]
        assert row4[:5] == ["T4", "4", "-", "2 min", "0:30"], row4
        assert len(b.find_elements(By.CSS_SELECTOR, ".pocket.worn")) == 1     # T5 stays worn: the page resets it
        # T3 (in the spindle) flagged the probe tool: the PLC inhibits the spindle and the page says why
        assert text(b, "spindle-inhibit") == "free"
        assert edits.edit(1, 3, "T3 the probe", Row(3, 3, 3, flags=1)) == 1
        wait_page(b, lambda b: text(b, "spindle-inhibit").startswith("inhibited: the probe tool T3 is in it"), 10,
                  "the spindle inhibit and its reason")
        assert edits.edit(1, 3, "T3 no probe", Row(3, 3, 3)) == 1
        wait_page(b, lambda b: text(b, "spindle-inhibit") == "free", 10, "the inhibit gone")
        session.stop()
        client.close()

        # --- unlock, force an input from the watch panel: the program faults, the page shows it
        b.find_element(By.ID, "token").send_keys(TOKEN)
        b.find_element(By.ID, "token-set").click()
        wait_page(b, lambda b: "unlocked" in text(b, "token-state"), 10, "the token accepted")
        b.find_element(By.ID, "watch-path").send_keys("%IX49.7")
        b.find_element(By.ID, "watch-add").click()
        row = "#watch tr[data-path='CONFIG0.RES0.ATC.SIMULATEDPLANT']"
        wait_page(b, lambda b: b.find_elements(By.CSS_SELECTOR, row), 10, "the watched input's row")
        b.find_element(By.CSS_SELECTOR, row + " input.val").send_keys("FALSE")
        b.find_element(By.CSS_SELECTOR, row + " button[data-action=force]").click()
        wait_page(b, lambda b: "forced" in b.find_element(By.CSS_SELECTOR, row).get_attribute("class"), 10,
                  "the row marked forced")
        wait_page(b, lambda b: text(b, "fault").startswith("-101 ESTOP"), 10, "the fault on the page")
        assert "E-stop chain opened" in text(b, "fault-text")
        assert text(b, "fault-cause").startswith("cause:") and text(b, "fault-remedy").startswith("remedy:")
        assert b.find_elements(By.CSS_SELECTOR, "#alarms tr.alarm[data-code='-101']"), "in the alarm history"
        assert text(b, "force-count") == "1"
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        shot = ARTIFACTS / "hmi-toolchanger.png"
        b.save_screenshot(str(shot))
        print(f"\nscreenshot: {shot}")
        b.find_element(By.CSS_SELECTOR, row + " button[data-action=unforce-restore]").click()
        wait_page(b, lambda b: "forced" not in b.find_element(By.CSS_SELECTOR, row).get_attribute("class"), 10,
                  "the force ended")
        b.find_element(By.ID, "cmd-clear").click()
        wait_page(b, lambda b: text(b, "fault") == "none", 30, "the fault cleared by the page's command")

        # --- the tool table's reset from the page (token unlocked): T5's time back to 0, audited
        b.find_element(By.CSS_SELECTOR, "#tools button.tool-reset[data-tool='5']").click()
        wait_page(b, lambda b: "T5: time used reset to 0" in text(b, "message"), 30, "the reset answered")
        wait_page(b, lambda b: not b.find_elements(By.CSS_SELECTOR, ".pocket.worn"), 10, "T5 reset: no worn mark")
        assert "tools reset row 5 T5 (page) -> done" in (plant["tmp"] / "audit.log").read_text()

        # --- the user procedures (issue 31): listed from the sequence set, which ships them disabled (no switch
        # can enable them); commissioned through the monitor (FB_AtcMachine's ProcUseDefs / ProcDefs: the alarm
        # light's compiled definition, enabled) the page's switch disables it through ProcDisabled (the page cannot
        # enable it again: the set has it disabled; the test clears ProcDisabled) and the program-stopped line runs
        # the mode-3 alarm, whose result and time the page shows
        wait_page(b, lambda b: len(b.find_elements(By.CSS_SELECTOR, "#procs tbody tr")) == 2, 10, "two procedures")
        lube, alarm = "#procs tr[data-slot='1']", "#procs tr[data-slot='2']"
        wait_page(b, lambda b: b.find_element(By.CSS_SELECTOR, lube).text.startswith(
            "0 lube every 240000 ms disabled (sequence set)"), 10, "the lube row: shipped disabled")
        assert not b.find_element(By.CSS_SELECTOR, lube + " button.proc-switch").is_displayed(), "no switch"
        compiled = "ATC.MACHINE.PROCS.PROCDEFS[2]."
        fields = ("DEFINED", "ID", "MODE", "SEQUENCE", "STOPONERROR", "CANSTOPGCODE", "ERRMSG")   # mode 3: no interval
        with Monitor(plant["sock"], timeout=5 * h.SLOW) as m:
            m.auth(TOKEN)
            values = m.read(*(compiled + f for f in fields))
            shipped = {f: values["CONFIG0.RES0." + compiled + f] for f in fields}
            assert (shipped["DEFINED"], shipped["ID"], shipped["MODE"]) == (True, 3, 3), shipped
            for f in fields:
                m.write("ATC.MACHINE.PROCDEFS[2]." + f, shipped[f])
            m.write("ATC.MACHINE.PROCDEFS[2].ENABLED", True)
            m.write("ATC.MACHINE.PROCUSEDEFS", True)
        wait_page(b, lambda b: b.find_element(By.CSS_SELECTOR, alarm).text.startswith(
            "3 alarm light on error or stop enabled"), 10, "the alarm commissioned")
        b.find_element(By.CSS_SELECTOR, alarm + " button.proc-switch").click()
        wait_page(b, lambda b: "procedure 3 (alarm light) disabled" in text(b, "message"), 30, "the switch answered")
        wait_page(b, lambda b: "disabled (sequence set)" in b.find_element(By.CSS_SELECTOR, alarm).text, 10,
                  "alarm disabled")
        assert not b.find_element(By.CSS_SELECTOR, alarm + " button.proc-switch").is_displayed(), "no way back"
        with ModbusClient("127.0.0.1", plant["rt"].port, timeout=5 * h.SLOW) as line:
            assert line.read_holding(rmap.signal("ProcDisabled").address, 1) == [2], "the switch set bit 1 (slot 2)"
            line.write_register(rmap.signal("ProcDisabled").address, 0)
            wait_page(b, lambda b: b.find_element(By.CSS_SELECTOR, alarm).text.startswith(
                "3 alarm light on error or stop enabled"), 10, "the alarm enabled again")
            line.write_coil(rmap.signal("ProgramStopped").address, True)
            wait_page(b, lambda b: text(b, "proc-last").startswith("last: procedure 3 DONE (1), ran "), 30,
                      "the alarm's result on the page")
            assert re.search(r"ended \d+ s ago; failures since start 0", text(b, "proc-last")), text(b, "proc-last")
            line.write_coil(rmap.signal("ProgramStopped").address, False)

        # --- a page without the token: refused, and nothing reaches the PLC
        b.execute_script("sessionStorage.clear()")
        b.get(url + "/")
        wait_page(b, lambda b: text(b, "plc-link") == "connected", 10, "the page again")
        b.find_element(By.ID, "cmd-home").click()
        wait_page(b, lambda b: "refused" in text(b, "message"), 10, "home refused")
        assert "token" in text(b, "message")
        b.find_element(By.ID, "watch-path").send_keys("%IX49.7")
        b.find_element(By.ID, "watch-add").click()
        wait_page(b, lambda b: b.find_elements(By.CSS_SELECTOR, row), 10, "the row")
        b.find_element(By.CSS_SELECTOR, row + " input.val").send_keys("FALSE")
        b.find_element(By.CSS_SELECTOR, row + " button[data-action=force]").click()
        wait_page(b, lambda b: "refused" in text(b, "watch-message"), 10, "force refused in the watch panel")
        with Monitor(plant["sock"], timeout=5 * h.SLOW) as m:
            assert m.forces() == []
            assert m.read("%IX49.7")["CONFIG0.RES0.ATC.SIMULATEDPLANT"] is True
        assert text(b, "fault") == "none"
    finally:
        b.quit()


def unlocked_page(url: str):
    b = browser()
    b.get(url + "/")
    wait_page(b, lambda b: text(b, "plc-link") == "connected", 10, "the page to reach the PLC")
    b.find_element(By.ID, "token").clear()
    b.find_element(By.ID, "token").send_keys(TOKEN)
    b.find_element(By.ID, "token-set").click()
    wait_page(b, lambda b: "unlocked" in text(b, "token-state"), 10, "the token accepted")
    return b


def page_command(b, button: str, expect: str, timeout: float = 60) -> str:
    """Click a command button; the page's answer once it is no longer 'sent'."""
    b.execute_script("document.getElementById('message').textContent = ''")
    b.find_element(By.ID, button).click()
    wait_page(b, lambda b: text(b, "message") and not text(b, "message").endswith(": sent"), timeout * h.SLOW,
              f"the answer to {button}")
    answer = text(b, "message")
    assert re.search(expect, answer), f"{button}: {answer!r} (expected {expect!r})"
    return answer


def host_session(port: int) -> tuple[Session, ModbusClient]:
    client = ModbusClient("127.0.0.1", port, timeout=5 * h.SLOW)
    client.connect()
    return Session(load_map(REPO / "modbus_map" / "map.toml"), client, say=lambda _t: None,
                   timeouts=Timeouts(request=60 * h.SLOW)), client


def test_go_to_pocket_and_the_recovery_steps_from_the_page_with_a_tool_in_the_spindle(plant):
    """With T3 in the spindle, "+1 pocket" and "go to pocket 5" end with the carousel at the pocket the page named
    (the positioner's own target shown on the way, no other), tool 3 still in the spindle; a pocket that is not on
    the carousel is refused on the page with the PLC's reason. Then a T5 M6 aborted while Put Tool has the collet
    open: the page shows the recovery still asked after the clear, homes from the page, and confirms the tool the
    simulated spindle holds (typed by the operator); the recovery ends and the page shows that tool."""
    session, client = host_session(plant["rt"].port)
    tags = session.tags
    b = unlocked_page(plant["url"])
    try:
        session.start()
        if tags.get("FaultReason"):
            assert session.clear().ok
        if int(tags.get("ToolInSpindle")) != 3:
            assert session.prepare(3, 3).ok and session.change().ok
        session.stop()
        wait_page(b, lambda b: text(b, "spindle-tool") == "T3", 10, "T3 in the spindle on the page")
        b.execute_script(WATCH_FIELDS)

        current = int(text(b, "current-pocket"))
        nxt = current % 6 + 1
        answer = page_command(b, "cmd-plus", rf"go to pocket {nxt}: pocket {nxt} at the change position")
        s = tags.read("CurrentPocket", "ToolInSpindle", "CarouselTarget", "GotoAnswer")
        assert s["CurrentPocket"] == nxt and s["ToolInSpindle"] == 3 and s["CarouselTarget"] == 0, (answer, s)
        wait_page(b, lambda b: text(b, "current-pocket") == str(nxt), 10, f"pocket {nxt} on the page")
        seen = [tuple(v) for v in b.execute_script("return window.__atcSeen;")]
        targets = {v[2] for v in seen}
        assert targets <= {"-", str(nxt)}, f"+1 pocket: the page showed targets {targets}"
        assert str(nxt) in targets or nxt == current, f"the positioner's target {nxt} was shown: {seen}"

        b.execute_script(WATCH_FIELDS)
        goal = 5 if nxt != 5 else 2
        b.find_element(By.ID, "goto-pocket").clear()
        b.find_element(By.ID, "goto-pocket").send_keys(str(goal))
        page_command(b, "cmd-goto", rf"go to pocket {goal}: pocket {goal} at the change position")
        assert tags.get("CurrentPocket") == goal and tags.get("ToolInSpindle") == 3
        wait_page(b, lambda b: text(b, "current-pocket") == str(goal), 10, f"pocket {goal} on the page")
        targets = {v[2] for v in b.execute_script("return window.__atcSeen;")}
        assert targets == {"-", str(goal)}, f"go to pocket {goal}: the page showed targets {targets}"
        assert b.find_element(By.CSS_SELECTOR, ".pocket.current").get_attribute("data-pocket") == str(goal)

        b.find_element(By.ID, "goto-pocket").clear()
        b.find_element(By.ID, "goto-pocket").send_keys("9")
        page_command(b, "cmd-goto", r"the PLC refused: pocket 9 is not on the carousel \(1\.\.6\)")
        assert tags.get("CurrentPocket") == goal

        # --- T5 M6 aborted at Put Tool step 16 (collet open): this test is the host's mailbox and leaves that
        # step's move unanswered, then aborts as a second host would (test_host_system does the same)
        tags.write(MbxHostActive=True)
        session, client2 = host_session(plant["rt"].port)
        result = {}

        def host():
            session.start()
            result["prepare"] = session.prepare(5, 5)
            result["change"] = session.change()

        t = threading.Thread(target=host)
        t.start()
        try:
            deadline = time.monotonic() + 120 * h.SLOW
            while time.monotonic() < deadline:
                s = tags.read("SeqKind", "SeqStep", "MbxRequestPending", "MbxRequestId", "MbxOpcode", "MbxAxisMask",
                              "MbxX", "MbxY", "MbxZ")
                if s["SeqKind"] == 3 and s["SeqStep"] == 16:
                    break
                if s["MbxRequestPending"]:
                    if s["MbxOpcode"] == 1:          # MOVEABS: the host is where it was asked to go
                        tags.write(**{f"HostPos{a}": round(s[f"Mbx{a}"] / 100) for i, a in enumerate("XYZ")
                                      if s["MbxAxisMask"] & (1 << i)})
                    tags.write(MbxAnswerResult=1)
                    tags.write(MbxAnswerId=s["MbxRequestId"])
                time.sleep(0.005)
            else:
                raise AssertionError("Put Tool never reached step 16: "
                                     f"{tags.read('FaultReason', 'SeqKind', 'SeqStep')}")
            tags.write(EmcReason=8)
            tags.write(EmcAbort=True)
            h.wait_until(lambda: tags.get("EmcAbortAck"), 30 * h.SLOW, "emc-abort-ack")
            tags.write(EmcAbort=False)
            t.join(60 * h.SLOW)
            assert not t.is_alive(), "the aborted M6 did not end"
        finally:
            tags.write(MbxHostActive=False)
            session.stop()
            client2.close()
        assert not result["change"].ok, result
        s = tags.read("FaultReason", "Recovery", "UncertainTool")
        assert s["FaultReason"] == -103 and s["Recovery"] == 3 and s["UncertainTool"] == 3, s

        # --- the recovery, from the page only
        wait_page(b, lambda b: text(b, "fault").startswith("-103"), 10, "the interrupted change on the page")
        page_command(b, "cmd-clear", r"clear: no fault")
        wait_page(b, lambda b: text(b, "fault") == "none", 10, "the fault cleared")
        assert text(b, "recovery").startswith("pending: home the changer"), text(b, "recovery")
        assert "pending" in b.find_element(By.ID, "recovery-box").get_attribute("class")
        b.find_element(By.ID, "goto-pocket").clear()
        b.find_element(By.ID, "goto-pocket").send_keys("1")
        page_command(b, "cmd-goto", r"the PLC refused: an interrupted change left a recovery to do")
        page_command(b, "cmd-home", r"home: carousel homed.*tool 3 is in the spindle or in its pocket")
        wait_page(b, lambda b: text(b, "recovery").startswith("pending: confirm the tool: T3"), 10,
                  "the confirmation asked on the page")
        assert b.find_element(By.ID, "cmd-confirm").is_displayed()
        seen_tool = int(tags.get("SimSpindleTool"))           # what the operator sees in the spindle
        assert seen_tool in (0, 3), seen_tool
        b.find_element(By.ID, "confirm-tool").send_keys(str(seen_tool))
        page_command(b, "cmd-confirm", rf"confirm: tool {seen_tool} in the spindle")
        wait_page(b, lambda b: text(b, "recovery") == "none", 10, "no recovery left on the page")
        wait_page(b, lambda b: text(b, "spindle-tool") == f"T{seen_tool}", 10, "the confirmed tool on the page")
        s = tags.read("Recovery", "ToolInSpindle", "FaultReason")
        assert s == {"Recovery": 0, "ToolInSpindle": seen_tool, "FaultReason": 0}, s
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        b.save_screenshot(str(ARTIFACTS / "hmi-recovery.png"))
    finally:
        b.quit()
        client.close()
