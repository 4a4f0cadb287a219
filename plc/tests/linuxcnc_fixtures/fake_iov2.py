"""Stand-in for iov2 under halrun (system python3, LinuxCNC's `hal` module): it creates the iocontrol.0.*
toolchanger pins and drives them the way iov2 does (number and request bit in the same instant) through the
generated atc_iov2.hal and mb2hal to the echo PLC of test_map_linuxcnc.py.  One line per finding in
result.txt ("ok ..." / "FAIL ..."); `phase1` tells the test to stop the PLC for the link-loss step."""
import os
import random
import time

import hal

BIT, S32, OUT, IN = hal.HAL_BIT, hal.HAL_S32, hal.HAL_OUT, hal.HAL_IN
io = hal.component("fakeiov2", "iocontrol.0")
for name, kind, direction in [
        ("tool-prepare", BIT, OUT), ("tool-prep-number", S32, OUT), ("tool-prep-pocket", S32, OUT),
        ("tool-prepared", BIT, IN), ("tool-change", BIT, OUT), ("tool-number", S32, OUT),
        ("tool-changed", BIT, IN), ("start-change", BIT, OUT), ("start-change-ack", BIT, IN),
        ("emc-abort", BIT, OUT), ("emc-reason", S32, OUT), ("emc-abort-ack", BIT, IN),
        ("toolchanger-fault", BIT, IN), ("toolchanger-reason", S32, IN), ("toolchanger-fault-ack", BIT, OUT),
        ("toolchanger-faulted", BIT, OUT), ("toolchanger-clear-fault", BIT, IN),
        ("user-enable-out", BIT, OUT), ("emc-enable-in", BIT, IN), ("user-request-enable", BIT, OUT)]:
    io.newpin(name, kind, direction)
probe = hal.component("fakeprobe")
probe.newpin("fault-reason", S32, IN)
io.ready()
probe.ready()
log = open("result.txt.tmp", "w")


def say(text):
    log.write(text + "\n")
    log.flush()


def wait(cond, timeout, what):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if cond():
            return time.time() - t0
        time.sleep(0.005)
    say(f"FAIL timeout waiting for {what}")
    raise SystemExit(1)


def handshake(req, ack, what):
    io[req] = True
    dt = wait(lambda: io[ack], 5, f"{ack} ({what})")
    io[req] = False
    wait(lambda: not io[ack], 5, f"{ack} to drop ({what})")
    return dt


try:
    io["user-enable-out"] = True
    say(f"ok link watch up after {wait(lambda: io['emc-enable-in'], 15, 'emc-enable-in'):.2f} s")
    n = int(os.environ.get("PREPARES", "60"))
    wrong = stale = 0
    for i in range(n):
        tool, pocket = 200 + i, 1000 + i
        time.sleep(random.uniform(0, 0.02))       # any phase of the mb2hal pass
        io["tool-prep-number"], io["tool-prep-pocket"], io["tool-prepare"] = tool, pocket, True
        wait(lambda: io["tool-prepared"], 5, "tool-prepared")
        stale += probe["fault-reason"] != pocket
        time.sleep(0.06)                          # > one pass: now the register read is current
        wrong += probe["fault-reason"] != pocket   # the PLC latched the previous request's numbers
        io["tool-prepare"] = False
        wait(lambda: not io["tool-prepared"], 5, "tool-prepared to drop")
    # a measurement, not a verdict: whether the settle delay covers mb2hal's pace depends on the machine's load
    # (scripts/bench-mb2hal-settle); that every prepare was answered is checked by the waits above
    say(f"measure {n} prepares: numbers latched with their request {n - wrong}/{n}; "
        f"number already current when tool-prepared arrived {n - stale}/{n}")
    say(f"ok change handshake ({handshake('tool-change', 'tool-changed', 'M6'):.3f} s)")
    for tool, want in ((99, -206), (98, 106)):
        io["tool-prep-number"], io["tool-prep-pocket"], io["tool-prepare"] = tool, 1, True
        wait(lambda: io["toolchanger-fault"], 5, f"toolchanger-fault (T{tool})")
        reason = io["toolchanger-reason"]
        say(("ok" if reason == want else "FAIL") + f" toolchanger-reason {reason}, expected {want}")
        io["toolchanger-fault-ack"] = True
        wait(lambda: not io["toolchanger-fault"], 5, "toolchanger-fault to drop")
        io["toolchanger-fault-ack"] = False
        wait(lambda: io["tool-prepared"], 5, "tool-prepared after the fault")
        io["tool-prepare"] = False
        wait(lambda: not io["tool-prepared"], 5, "tool-prepared to drop")
    io["tool-prep-number"], io["tool-prep-pocket"], io["tool-prepare"] = 97, 1, True
    wait(lambda: io["tool-prepared"], 5, "tool-prepared (T97)")
    time.sleep(0.1)
    say(("ok" if probe["fault-reason"] == -32768 else "FAIL") + f" FaultReason -32768 arrives as "
        f"{probe['fault-reason']}")
    io["tool-prepare"] = False
    io["emc-reason"] = 8
    say(f"ok abort handshake ({handshake('emc-abort', 'emc-abort-ack', 'abort 8'):.3f} s)")
    open("phase1", "w").close()
    dt = wait(lambda: not io["emc-enable-in"], 5, "emc-enable-in to drop after the PLC stopped")
    say(f"ok E-stop {dt:.2f} s after the PLC stopped")
finally:
    log.close()
    os.rename("result.txt.tmp", "result.txt")
