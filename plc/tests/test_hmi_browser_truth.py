"""What the toolchanger page says is true (issue 27, point 6, the page's "smaller untruths"), in a real browser.

Each test names what an operator reads on the page and checks it against the PLC itself (its Modbus lines, its
diagnostic block, its monitor): values read before the PLC was lost are greyed and say when they were read, and
come back live; the inputs nothing drives in simulation read "not simulated", not an open E-stop; an active
fault line is drawn red, a healthy one is not; an alarm carries the PLC's time; a refusal for want of the token
goes when the page is unlocked; watch and force answers stay in their panel.  The fixtures and helpers are those
of test_hmi_browser.py (skipped the same way without chromium, chromium-driver or selenium).
"""
from __future__ import annotations

import os
import re
import signal
import time

import pytest
import rt_harness as h
from atc.host.tags import Tags, load_map
from plc.hmi import status
from plc.hmi.monitor import Monitor
from plc.modbus import ModbusClient
from test_hmi_browser import (  # noqa: F401
    REPO,
    TOKEN,
    browser,
    pytestmark,
    served_plant,
    text,
    unlocked_page,
    wait_page,
)

try:
    from selenium.webdriver.common.by import By
except ImportError:          # pytestmark (test_hmi_browser's) skips every test and says why
    By = None

RED = "rgba(254, 202, 202, 1)"       # index.html: tr.faultline.on (#fecaca)
GREEN = "rgba(187, 247, 208, 1)"     # index.html: .on (#bbf7d0)
SIM_PLANT = "CONFIG0.RES0.ATC.SIMULATEDPLANT"      # %IX49.7, the simulation flag


@pytest.fixture(scope="module")
def plant(tmp_path_factory):
    """The application on our runtime with the simulated plant, and `plc hmi` in front of it (this module's)."""
    with served_plant(tmp_path_factory.mktemp("hmi-truth")) as served:
        yield served


def plc_tags(port: int) -> tuple[Tags, ModbusClient]:
    client = ModbusClient("127.0.0.1", port, timeout=5 * h.SLOW)
    client.connect()
    return Tags(load_map(REPO / "modbus_map" / "map.toml"), client), client


def line(b, name: str):
    return b.find_element(By.CSS_SELECTOR, f"#iolines tr[data-signal={name}]")


def line_value(b, name: str) -> str:
    return line(b, name).find_element(By.CSS_SELECTOR, ".v").text


def classes(element) -> set[str]:
    return set((element.get_attribute("class") or "").split())


def acknowledge_and_clear(tags: Tags) -> None:
    """As iov2 and the operator would: acknowledge the reported fault line, latch and then clear the fault."""
    if tags.get("ToolchangerFault"):
        tags.write(ToolchangerFaulted=True, ToolchangerFaultAck=True)
        h.wait_until(lambda: not tags.get("ToolchangerFault"), 30, "the fault line to drop on its acknowledgement")
    tags.write(ToolchangerFaultAck=False)
    tags.write(ClearFault=False)
    tags.write(ClearFault=True)
    try:
        h.wait_until(lambda: tags.get("FaultReason") == 0, 30, "the PLC to clear its fault")
    finally:
        tags.write(ClearFault=False)
    tags.write(ToolchangerFaulted=False)


def newest_alarm(b) -> dict:
    """The top row of the alarm history (the newest), read in one go: the page redraws the table on a change."""
    return b.execute_script(
        "const tr = document.querySelector('#alarms tr.alarm'); if (!tr) return {};"
        "return {code: tr.dataset.code, cells: Array.from(tr.cells, (td) => td.textContent)};")


def seconds_shown(b, t0: float, t1: float) -> set[str]:
    """The page's own rendering (toLocaleTimeString) of every wall-clock second from t0 to t1."""
    return set(b.execute_script(
        "const out = []; for (let s = Math.floor(arguments[0]); s <= Math.ceil(arguments[1]); s++) "
        "out.push(new Date(s * 1000).toLocaleTimeString()); return out;", t0, t1))


def test_values_read_before_the_plc_was_lost_are_greyed_with_their_time_and_come_back_live(tmp_path):
    """A runtime of its own, paused (SIGSTOP) under a live page: the page greys every section, says in a banner
    that the values are as last read and when (a second between the last live observation and the pause), keeps
    that after an unlock; resumed (SIGCONT), the values are live again and unmarked; stopped (SIGTERM), stale
    again."""
    with served_plant(tmp_path) as own:
        rt = own["rt"]
        b = unlocked_page(own["url"])
        paused = False
        try:
            wait_page(b, lambda b: text(b, "spindle-tool") == "T0", 10, "live values on the page")
            section = b.find_element(By.CSS_SELECTOR, "#page section")
            assert "stale" not in classes(b.find_element(By.ID, "page")) and text(b, "stale") == ""
            assert float(section.value_of_css_property("opacity")) == 1.0
            # a push after this moment proves the page live up to it; its poll time is the earliest the banner
            # may name
            first = b.execute_script("return window.lastPolledAt;")
            wait_page(b, lambda b: b.execute_script("return window.lastPolledAt;") > first, 10, "a later push")
            live_at = b.execute_script("return window.lastPolledAt;") / 1000
            os.kill(rt.proc.pid, signal.SIGSTOP)
            paused, paused_at = True, time.time()

            wait_page(b, lambda b: text(b, "plc-link").startswith("lost:"), 30, "the page to lose the PLC")
            assert "stale" in classes(b.find_element(By.ID, "page"))
            assert float(section.value_of_css_property("opacity")) < 1.0, "the values are greyed"
            assert text(b, "spindle-tool") == "T0", "the last values stay, marked"
            banner = text(b, "stale")
            m = re.fullmatch(r"PLC lost: every value below is as last read at (.+) \(stale\)", banner)
            assert m, banner
            polled = b.execute_script("return window.lastPolledAt;") / 1000
            assert live_at <= polled <= paused_at + 1.0, (live_at, polled, paused_at)
            assert m.group(1) in seconds_shown(b, live_at, paused_at + 1.0), (banner, live_at, paused_at)

            b.execute_script("document.getElementById('token-state').textContent = ''")
            b.find_element(By.ID, "token-set").click()         # unlocking again must not un-grey a lost page
            wait_page(b, lambda b: "unlocked" in text(b, "token-state"), 10, "the unlock answered")
            assert "stale" in classes(b.find_element(By.ID, "page")), "an unlock un-greyed the values of a lost PLC"
            assert text(b, "stale") == banner

            os.kill(rt.proc.pid, signal.SIGCONT)
            paused = False
            wait_page(b, lambda b: text(b, "plc-link") == "connected", 30, "the PLC back on the page")
            assert "stale" not in classes(b.find_element(By.ID, "page")) and text(b, "stale") == ""
            assert float(section.value_of_css_property("opacity")) == 1.0
            assert b.execute_script("return window.lastPolledAt;") / 1000 > paused_at, "values read after the pause"

            rc = rt.stop(signal.SIGTERM)
            rt.assert_clean_exit(rc)
            wait_page(b, lambda b: text(b, "plc-link").startswith("lost:"), 30, "the page to lose the stopped PLC")
            assert "stale" in classes(b.find_element(By.ID, "page"))
            assert text(b, "stale").startswith("PLC lost: every value below is as last read at ")
        finally:
            if paused:
                os.kill(rt.proc.pid, signal.SIGCONT)
            b.quit()


def test_the_inputs_the_simulation_does_not_drive_read_not_simulated_and_real_inputs_without_it(plant):
    """With the simulated plant the E-stop chain, door, air, spindle and sensor inputs read 0 on their wires
    (nothing drives them): the page shows "not simulated", neither "0" nor a lit line; with the simulation flag
    forced off they are the machine's inputs again and show their 0."""
    tags, client = plc_tags(plant["rt"].port)
    b = unlocked_page(plant["url"])
    try:
        wait_page(b, lambda b: line_value(b, "SimulatedPlant") == "1", 10, "the simulation flag on the page")
        free = b.execute_script("return info.not_simulated;")
        assert {"EStopOk", "GuardDoorClosed", "AirPressureOk", "SpindleStopped"} <= set(free), free
        wires = tags.read(*free)
        assert not any(wires.values()), f"inputs the simulation drives after all: {wires}"
        for name in free:
            row = line(b, name)
            assert line_value(b, name) == "not simulated", f"{name}: {line_value(b, name)!r}"
            assert "nosim" in classes(row) and "on" not in classes(row), (name, classes(row))
        assert "ESTOP" not in text(b, "fault"), "an E-stop on the page while the simulated chain is closed"

        with Monitor(plant["sock"], timeout=5 * h.SLOW) as m:
            m.auth(TOKEN)
            m.force(SIM_PLANT, "FALSE")
            try:
                wait_page(b, lambda b: line_value(b, "SimulatedPlant") == "0", 10, "the simulation off on the page")
                for name in free:
                    assert line_value(b, name) == "0", f"{name} without the simulation: {line_value(b, name)!r}"
                    assert "nosim" not in classes(line(b, name))
            finally:
                m.unforce(SIM_PLANT, restore=True)
        h.wait_until(lambda: tags.get("SimulatedPlant"), 10, "the simulation flag back")
        acknowledge_and_clear(tags)            # the program saw the real, open E-stop chain meanwhile
        wait_page(b, lambda b: line_value(b, "EStopOk") == "not simulated" and text(b, "fault") == "none", 10,
                  "the simulation back on the page")
    finally:
        b.quit()
        client.close()


def test_an_active_fault_line_is_drawn_as_a_fault_and_healthy_when_it_drops(plant):
    """The simulated E-stop opened with the changer idle: the PLC latches -101 and raises toolchanger-fault; its
    line on the page is red (not the green of an active healthy line such as SimulatedPlant); acknowledged as
    iov2 does, it drops and is drawn healthy; iov2's own latch (ToolchangerFaulted) is red until cleared."""
    tags, client = plc_tags(plant["rt"].port)
    b = unlocked_page(plant["url"])
    try:
        wait_page(b, lambda b: line_value(b, "ToolchangerFault") == "0" and text(b, "fault") == "none", 10,
                  "a healthy changer on the page")
        for name in ("ToolchangerFault", "ToolchangerFaulted", "SimulatedPlant"):
            assert line(b, name).value_of_css_property("background-color") != RED, name
        assert "faultline" in classes(line(b, "ToolchangerFault")), "the page knows it as a fault line"
        assert line(b, "SimulatedPlant").value_of_css_property("background-color") == GREEN, "a healthy active line"

        tags.write(SimEStop=True)
        try:
            h.wait_until(lambda: tags.get("ToolchangerFault"), 30, "the PLC to raise toolchanger-fault")
            assert tags.get("FaultReason") == -101
            wait_page(b, lambda b: line_value(b, "ToolchangerFault") == "1", 10, "the fault line on the page")
            row = line(b, "ToolchangerFault")
            assert {"faultline", "on"} <= classes(row), classes(row)
            assert row.value_of_css_property("background-color") == RED, "an active fault line drawn green"
            assert text(b, "fault").startswith("-101 ESTOP")

            tags.write(ToolchangerFaulted=True, ToolchangerFaultAck=True)     # iov2 latches and acknowledges
            h.wait_until(lambda: not tags.get("ToolchangerFault"), 30, "the fault line to drop on its ack")
            wait_page(b, lambda b: line_value(b, "ToolchangerFault") == "0"
                      and line_value(b, "ToolchangerFaulted") == "1", 10, "the ack on the page")
            assert line(b, "ToolchangerFault").value_of_css_property("background-color") != RED
            assert "on" not in classes(line(b, "ToolchangerFault"))
            assert line(b, "ToolchangerFaulted").value_of_css_property("background-color") == RED, "iov2's latch"
        finally:
            tags.write(SimEStop=False)
        acknowledge_and_clear(tags)
        wait_page(b, lambda b: line_value(b, "ToolchangerFaulted") == "0" and text(b, "fault") == "none", 10,
                  "the cleared fault on the page")
        for name in ("ToolchangerFault", "ToolchangerFaulted"):
            assert line(b, name).value_of_css_property("background-color") != RED, name
    finally:
        b.quit()
        client.close()


def test_a_refusal_for_want_of_the_token_goes_on_unlocking_and_watch_answers_stay_in_their_panel(plant):
    """A page without the token: home is refused under the carousel; a watch of an unknown variable and a force
    are refused in the watch panel, the carousel's message untouched; unlocking clears both refusals; unlocked,
    a force panel answer is again in the watch panel, none under the carousel."""
    b = browser()
    try:
        b.get(plant["url"] + "/")
        wait_page(b, lambda b: text(b, "plc-link") == "connected", 10, "the page to reach the PLC")
        b.find_element(By.ID, "cmd-home").click()
        wait_page(b, lambda b: text(b, "message").startswith("refused"), 10, "home refused")
        refused_home = text(b, "message")
        assert "token" in refused_home, refused_home

        b.find_element(By.ID, "watch-path").send_keys("ATC.NO_SUCH_VARIABLE")
        b.find_element(By.ID, "watch-add").click()
        wait_page(b, lambda b: text(b, "watch-message").startswith("refused: watch ATC.NO_SUCH_VARIABLE"), 10,
                  "the watch refused in the watch panel")
        assert text(b, "message") == refused_home, "a watch answer under the carousel"
        b.find_element(By.ID, "watch-path").clear()
        b.find_element(By.ID, "watch-path").send_keys("%IX49.7")
        b.find_element(By.ID, "watch-add").click()
        row = f"#watch tr[data-path='{SIM_PLANT}']"
        wait_page(b, lambda b: b.find_elements(By.CSS_SELECTOR, row) and text(b, "watch-message")
                  == "watching %IX49.7", 10, "the watched input")
        b.find_element(By.CSS_SELECTOR, row + " input.val").send_keys("FALSE")
        b.find_element(By.CSS_SELECTOR, row + " button[data-action=force]").click()
        wait_page(b, lambda b: text(b, "watch-message").startswith("refused"), 10, "the force refused")
        assert "token" in text(b, "watch-message"), text(b, "watch-message")
        assert text(b, "message") == refused_home, "a force answer under the carousel"
        with Monitor(plant["sock"], timeout=5 * h.SLOW) as m:
            assert m.forces() == [], "a refused force reached the PLC"

        b.find_element(By.ID, "token").send_keys(TOKEN)
        b.find_element(By.ID, "token-set").click()
        wait_page(b, lambda b: "unlocked" in text(b, "token-state"), 10, "the token accepted")
        assert text(b, "message") == "", f"still shown after unlocking: {text(b, 'message')!r}"
        assert text(b, "watch-message") == "", f"still shown after unlocking: {text(b, 'watch-message')!r}"

        b.find_element(By.CSS_SELECTOR, row + " input.val").clear()
        b.find_element(By.CSS_SELECTOR, row + " button[data-action=write]").click()    # no value: refused
        wait_page(b, lambda b: text(b, "watch-message") != "", 10, "the write's answer")
        assert text(b, "watch-message").startswith("refused: "), text(b, "watch-message")
        assert "token" not in text(b, "watch-message"), "unlocked, yet refused for the token"
        assert text(b, "message") == "", "a write's answer under the carousel"
    finally:
        b.quit()


def test_an_alarm_carries_the_plcs_time_from_its_scan_count(plant):
    """An E-stop fault raised and cleared: its alarm row gives the PLC's time (seconds since its start, from the
    scan count) between the PLC's own scan counts read just before and just after, the page server's clock
    beside it, and the legend says which clock is which; the same for the time it was cleared."""
    tags, client = plc_tags(plant["rt"].port)
    b = unlocked_page(plant["url"])
    try:
        wait_page(b, lambda b: text(b, "fault") == "none", 10, "no fault on the page")

        def plc_seconds() -> float:
            d = status.read(client)
            return d["scan_count"] * d["base_tick_us"] / 1e6

        tick = status.read(client)["base_tick_us"] / 1e6
        wall0, plc0 = time.time(), plc_seconds()
        tags.write(SimEStop=True)
        try:
            h.wait_until(lambda: tags.get("FaultReason") == -101, 30, "the PLC to latch -101")
            wait_page(b, lambda b: newest_alarm(b).get("code") == "-101" and newest_alarm(b)["cells"][-1] == "active",
                      10, "the alarm row")
            plc1, wall1 = plc_seconds(), time.time()
        finally:
            tags.write(SimEStop=False)
        when = newest_alarm(b)["cells"][0]
        m = re.fullmatch(r"PLC (\d+\.\d{3}) s, (.+)", when)
        assert m, f"the alarm time: {when!r}"
        raised = float(m.group(1))
        assert plc0 - 2 * tick <= raised <= plc1 + 2 * tick, (plc0, raised, plc1)
        assert m.group(2) in seconds_shown(b, wall0, wall1), (when, wall0, wall1)
        assert text(b, "alarm-clock") == \
            "time: the PLC's (seconds since its start, from its scan count), then the page server's clock"

        plc2 = plc_seconds()
        acknowledge_and_clear(tags)
        wait_page(b, lambda b: newest_alarm(b)["cells"][-1].startswith("cleared"), 10, "the alarm cleared")
        plc3 = plc_seconds()
        alarm = newest_alarm(b)
        assert alarm["code"] == "-101" and alarm["cells"][0] == when, alarm
        cleared = alarm["cells"][-1]
        m = re.fullmatch(r"cleared PLC (\d+\.\d{3}) s, .+", cleared)
        assert m, cleared
        assert plc2 - 2 * tick <= float(m.group(1)) <= plc3 + 2 * tick, (plc2, m.group(1), plc3)
    finally:
        b.quit()
        client.close()
