"""`plc host` against a server that applies FC15 the way OpenPLC v3 does: whole bytes from the start address, the
padding bits of the last data byte included (tests/host_fake_plc.py, whole_bytes=True).  The host writes each
coil with its own FC5, so the change, abort and fault handshakes complete there too, no coil changes that the
host did not mean to change, a coil another host dropped is never written back, and a host waiting for a change
stops at once when another host aborts it."""
from __future__ import annotations

import threading
from pathlib import Path

from host_fake_plc import Addr, Behaviour, FakePlc
from atc.host import cli
from atc.host.tags import load_map

REPO = Path(__file__).resolve().parents[2]
MAP = REPO / "modbus_map" / "map.toml"
RMAP = load_map(MAP)
ADDR = Addr(coil={s.name: s.address for s in RMAP.signals if s.table == "coil"},
            reg={s.name: s.address for s in RMAP.signals if s.table == "holding_register"})
HOST_COILS = {s.address: s.name for s in RMAP.signals if s.table == "coil" and s.host_writable}


def run(fake: FakePlc, capsys, *words: str) -> tuple[int, str]:
    status = cli.main(["--port", str(fake.port), "--map", str(MAP), *words])
    out = capsys.readouterr()
    return status, out.out + out.err


def sets(fake: FakePlc, name: str) -> list[tuple[int, int]]:
    """(log position, value) of every change of a coil."""
    a = ADDR.coil[name]
    return [(i, e[2]) for i, e in enumerate(fake.log) if e[0] == "set" and e[1] == a]


def test_every_coil_write_is_one_fc5_of_a_host_command(capsys):
    with FakePlc(ADDR, whole_bytes=True) as fake:
        status, out = run(fake, capsys, "T5 M6", "abort", "clear", "status")
    assert status == 0, out
    writes = [e for e in fake.log if e[0] == "write" and e[1] in (5, 15)]
    assert writes, "the host wrote no coil"
    for _w, fc, address, values in writes:
        assert fc == 5 and address in HOST_COILS and len(values) == 1, (fc, address, values)
    changed = {e[1] for e in fake.log if e[0] == "set" and e[1] >= 400}
    assert changed <= set(HOST_COILS), f"coils changed outside the host commands: {changed - set(HOST_COILS)}"


def test_a_coil_another_host_dropped_is_not_written_back():
    """The lost update a read-modify-write of a shared byte made (a second host's emc-abort stayed up, and its
    acknowledgement with it, after that host had dropped it): host B holds EmcAbort; host A writes another coil
    of the same byte (ToolchangerFaulted, as a host does on a fault) and B drops EmcAbort at the worst moment,
    right after any read A makes to write (or right after A's write, if A reads nothing). EmcAbort must end
    FALSE, set and dropped by B only."""
    from plc.modbus import ModbusClient
    from atc.host.tags import Tags

    class Interleaved(ModbusClient):
        then = None

        def read_coils(self, address: int, count: int) -> list[bool]:
            values = super().read_coils(address, count)
            if self.then is not None:
                then, self.then = self.then, None
                then()
            return values

    with FakePlc(ADDR, whole_bytes=True) as fake:
        ca, cb = Interleaved("127.0.0.1", fake.port), ModbusClient("127.0.0.1", fake.port)
        ca.connect()
        cb.connect()
        a, b = Tags(RMAP, ca), Tags(RMAP, cb)
        try:
            b.write(EmcAbort=True)
            ca.then = lambda: b.write(EmcAbort=False)
            a.write(ToolchangerFaulted=True)
            if ca.then is not None:
                ca.then()
                ca.then = None
            assert a.get("ToolchangerFaulted") is True
            assert b.get("EmcAbort") is False, "host A wrote back the emc-abort host B had dropped"
        finally:
            ca.close()
            cb.close()
    assert [v for _i, v in sets(fake, "EmcAbort")] == [1, 0], sets(fake, "EmcAbort")


def test_change_completes_against_whole_byte_fc15(capsys):
    with FakePlc(ADDR, whole_bytes=True) as fake:
        status, out = run(fake, capsys, "T5 M6")
    assert status == 0, out
    assert out.strip().splitlines()[-1] == "tool 5 in spindle"
    assert fake.index("prepare latched tool 5 pocket 5") < fake.index("change started")


def test_abort_handshake_holds_emc_abort_until_its_ack(capsys):
    with FakePlc(ADDR, Behaviour(change_scans=10 ** 6), whole_bytes=True) as fake:
        status, out = run(fake, capsys, "T3", "abort")
    assert status == 0, out
    assert "acknowledged" in out
    raised = [i for i, v in sets(fake, "EmcAbort") if v == 1]
    dropped = [i for i, v in sets(fake, "EmcAbort") if v == 0]
    acked = fake.index("abort reason 8")
    assert raised and raised[0] < acked
    assert not [i for i in dropped if raised[0] < i < acked], "emc-abort dropped before the PLC acknowledged it"


def test_fault_during_change_aborts_with_reason_101_and_completes(capsys):
    with FakePlc(ADDR, Behaviour(fault_on_change=-201), whole_bytes=True) as fake:
        status, out = run(fake, capsys, "T5 M6")
    assert status == 1, out
    assert "toolchanger fault -201" in out and "timeout" not in out, out
    assert fake.index("fault -201 in change") < fake.index("abort reason 101")
    assert fake.index("fault acked") < fake.index("abort reason 101") or "fault acked" in fake.events


def test_another_hosts_abort_ends_the_first_hosts_wait_at_once(capsys):
    """The first host waits for a change the fake never completes (a 600 s timeout: only a bug waits for it);
    a second host aborts it; the PLC latches -103 as the application does. The first host must end with the
    abort or the fault, never with its timeout. The thread join only bounds a hang."""
    behaviour = Behaviour(ack_change=False, fault_on_abort=-103)
    with FakePlc(ADDR, behaviour, whole_bytes=True) as fake:
        result: dict[str, object] = {}

        def first() -> None:
            result["status"] = cli.main(["--port", str(fake.port), "--map", str(MAP), "--timeout", "600", "T5 M6"])

        t = threading.Thread(target=first, daemon=True)
        t.start()
        waited = 0.0
        while "change started" not in fake.events and waited < 120:
            threading.Event().wait(0.05)
            waited += 0.05
        assert "change started" in fake.events, "the first host never started its change"
        status2 = cli.main(["--port", str(fake.port), "--map", str(MAP), "abort"])
        t.join(timeout=120)
        out = capsys.readouterr()
        assert not t.is_alive(), "the first host still waits after another host aborted its change"
    text = out.out + out.err
    assert status2 == 0, text
    assert result["status"] == 1, text
    assert "timeout" not in text, text
    assert "-103" in text or "another host" in text, text
