"""Modbus/TCP Security (MBAPS): the runtime's TLS listener, with pymodbus' TLS client and Python's ssl module as
the independent clients (issue 35 points 2 to 4).

A test PKI is made with plc.tlscerts (what `plc tls` writes): a CA, the runtime's certificate, one client
certificate per role, and the ones the runtime must refuse: none at all, another CA's, an expired one, none or an
unknown value in the role extension, a role that is not a UTF8String. The role matrix of test_runtime_roles runs
again with the role taken from the certificate; the audit lines carry the certificate's common name; the
regression corpus of the Modbus front end is replayed over TLS, then a bounded run of mutated frames goes over
TLS (scripts/test reruns this file against the ASan/UBSan build). No verdict depends on the machine's speed: what
must not have happened is checked after whole scans (h.wait_scans).
"""

from __future__ import annotations

import datetime as dt
import random
import re
import socket
import ssl
import struct
import subprocess
import sys
from pathlib import Path

import pytest

import modbus_fuzz as fz
import rt_harness as h

pytest.importorskip("cryptography", reason="cryptography is a dependency of plc (scripts/setup installs it)")
pytest.importorskip("pymodbus", reason="pymodbus is a test dependency (pip install -e 'plc[test]')")
from pymodbus import FramerType
from pymodbus.client import ModbusTlsClient

from plc import tlscerts

COMMAND_COIL, COMMAND_REGISTER = 400, 520             # in the host ranges below
ENGINEERING_COIL, ENGINEERING_REGISTER = 700, 1024 + 300
FRAME_TIMEOUT_MS = 500                                # the corpus's incomplete frames, and a handshake, within this
MUTATED_FRAMES = 600                                  # the bounded fuzzing over TLS


@pytest.fixture(scope="module")
def pki(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("pki")
    ca = tlscerts.make_ca("test CA")
    tlscerts.write_pair(ca, d / "ca.pem", d / "ca.key")
    tlscerts.write_pair(tlscerts.make_leaf(ca, "plc", server=True, ips=["127.0.0.1"]), d / "server.pem",
                        d / "server.key")
    for role in tlscerts.ROLES:
        tlscerts.write_pair(tlscerts.make_leaf(ca, f"{role}-client", role=role), d / f"{role}.pem", d / f"{role}.key")
    past = dt.datetime.now(dt.timezone.utc) - dt.timedelta(days=2)
    refused = {
        "expired": tlscerts.make_leaf(ca, "expired", role="host", not_before=past - dt.timedelta(days=30),
                                      not_after=past),
        "other-ca": tlscerts.make_leaf(tlscerts.make_ca("another CA"), "stranger", role="engineer"),
        "no-role": tlscerts.make_leaf(ca, "no-role-" + "x" * 56),       # 64 characters: the longest CN
        "unknown-role": tlscerts.make_leaf(ca, "admin", role="admin"),
        "not-utf8": tlscerts.make_leaf(ca, "octets", role_value=b"\x04\x04host"),      # an OCTET STRING
    }
    for name, issued in refused.items():
        tlscerts.write_pair(issued, d / f"{name}.pem", d / f"{name}.key")
    return d


def tls_args(pki: Path) -> list[str]:
    return ["--tls-port", "0", "--tls-cert", str(pki / "server.pem"), "--tls-key", str(pki / "server.key"),
            "--tls-ca", str(pki / "ca.pem")]


def start(pki: Path, *more: str) -> h.Runtime:
    rt = h.Runtime(h.runtime_binary(), "--no-rt", *tls_args(pki), "--host-coils", "400-407", "--host-registers",
                   "512-527", "--frame-timeout", str(FRAME_TIMEOUT_MS), *more).start()
    rt.tls_port = int(rt.wait_for(r"modbus: TLS \(Modbus/TCP Security\) on [\d.]+:(\d+)").group(1))
    return rt


def context(pki: Path, name: str | None, maximum: ssl.TLSVersion | None = None,
            check_hostname: bool = True) -> ssl.SSLContext:
    """A client's: the runtime's certificate verified against the CA (and 127.0.0.1 in it), `name`'s presented."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = check_hostname
    ctx.load_verify_locations(pki / "ca.pem")
    if name:
        ctx.load_cert_chain(pki / f"{name}.pem", pki / f"{name}.key")
    if maximum:
        ctx.maximum_version = maximum
    return ctx


def tls_socket(pki: Path, name: str | None, port: int, timeout: float = 3.0) -> ssl.SSLSocket:
    raw = socket.create_connection(("127.0.0.1", port), timeout=timeout * h.SLOW)
    return context(pki, name).wrap_socket(raw, server_hostname="127.0.0.1")


class TlsClient(h.Client):
    """rt_harness' hand-made MBAP frames over a TLS connection with the certificate `name`."""

    def __init__(self, pki: Path, name: str, port: int):
        self.sock = tls_socket(pki, name, port)
        self.tid = 0


def pymodbus_client(pki: Path, name: str, port: int) -> ModbusTlsClient:
    # pymodbus wraps its socket without a server name: the CA is checked, the address in the certificate is not
    c = ModbusTlsClient("127.0.0.1", port=port, sslctx=context(pki, name, check_hostname=False), framer=FramerType.TLS,
                        timeout=3 * h.SLOW, retries=0)
    assert c.connect(), f"pymodbus could not connect with the certificate {name}"
    return c


def exception_code(response) -> int | None:
    return response.exception_code if response.isError() else None


@pytest.fixture(scope="module")
def rt(pki, tmp_path_factory):
    audit = tmp_path_factory.mktemp("audit") / "audit.log"
    runtime = start(pki, "--audit", str(audit))
    runtime.audit = audit
    try:
        yield runtime
    finally:
        runtime.assert_clean_exit(runtime.stop())


@pytest.fixture
def plain(rt):
    """The plain listener (no --allow: an engineer), for reading back and the diagnostic counters."""
    with h.Client(rt.port) as c:
        yield c


def audit_text(rt, pattern: str) -> str:
    """The audit file once a line matches `pattern` (the audit thread writes it a moment after the answer)."""
    def found() -> str:
        text = rt.audit.read_text() if rt.audit.exists() else ""
        return text if re.search(pattern, text, re.M) else ""
    return h.wait_until(found, 5, f"an audit line matching {pattern!r}")


# ------------------------------------------------------------------- the role matrix over TLS

def test_a_read_certificate_reads_and_its_writes_are_refused_with_exception_01(rt, pki, plain):
    before = h.read_diag(plain)
    c = pymodbus_client(pki, "read", rt.tls_port)
    try:
        assert c.read_holding_registers(1024 + 30).registers == [4242]      # %MW30, set by the program
        assert len(c.read_input_registers(h.DIAG_BASE, count=4).registers) == 4
        assert exception_code(c.write_register(COMMAND_REGISTER, 77)) == h.MODBUS_EXCEPTION_ILLEGAL_FUNCTION
        assert exception_code(c.write_coils(COMMAND_COIL, [True, True])) == h.MODBUS_EXCEPTION_ILLEGAL_FUNCTION
        assert exception_code(c.write_registers(ENGINEERING_REGISTER, [1, 2])) == h.MODBUS_EXCEPTION_ILLEGAL_FUNCTION
    finally:
        c.close()
    h.wait_scans(plain)
    assert plain.read_holding(COMMAND_REGISTER) == [0] and plain.read_coils(COMMAND_COIL, 2) == [False, False]
    after = h.read_diag(plain)
    assert after["writes_refused"] - before["writes_refused"] == 3 and after["writes"] == before["writes"]
    rt.wait_for(r"client 127\.0\.0\.1:\d+ authenticated over TLS \[TLSv1\.3, cn \"read-client\", role read\]"
                r"|more clients authenticated over TLS .*cn \"read-client\", role read")
    rt.wait_for(r"client 127\.0\.0\.1:\d+ write refused \[role read, fc=6 register 520 count=1: exception 01, "
                r"role read writes nothing\]")
    text = audit_text(rt, r'cn="read-client" role=read fc=16 registers 1324-1325')
    assert re.search(r'^\S+Z modbus peer=127\.0\.0\.1:\d+ tls cn="read-client" role=read fc=6 register 520 count=1 '
                     r'-> refused: exception 01 ILLEGAL FUNCTION \(role read writes nothing\)$', text, re.M), text


def test_a_host_certificate_writes_the_host_signals_only_and_an_engineer_writes_everything(rt, pki, plain):
    host = pymodbus_client(pki, "host", rt.tls_port)
    try:
        assert exception_code(host.write_coil(COMMAND_COIL, True)) is None
        assert exception_code(host.write_registers(COMMAND_REGISTER, [11, 12])) is None
        assert exception_code(host.write_register(ENGINEERING_REGISTER, 5)) == h.MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS
        assert exception_code(host.write_coil(ENGINEERING_COIL, True)) == h.MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS
        assert exception_code(host.write_registers(526, [21, 22, 23])) == h.MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS
    finally:
        host.close()
    h.wait_scans(plain)
    assert plain.read_coils(COMMAND_COIL) == [True] and plain.read_holding(COMMAND_REGISTER, 2) == [11, 12]
    assert plain.read_holding(ENGINEERING_REGISTER) == [0] and plain.read_coils(ENGINEERING_COIL) == [False]
    assert plain.read_holding(526, 3) == [0, 0, 0]                # refused whole

    engineer = pymodbus_client(pki, "engineer", rt.tls_port)
    try:
        assert exception_code(engineer.write_register(ENGINEERING_REGISTER, 32)) is None
        assert exception_code(engineer.write_coils(ENGINEERING_COIL, [True, True])) is None
        assert exception_code(engineer.write_registers(526, [21, 22, 23])) is None
    finally:
        engineer.close()
    h.wait_scans(plain)
    assert plain.read_holding(ENGINEERING_REGISTER) == [32] and plain.read_coils(ENGINEERING_COIL, 2) == [True, True]
    assert plain.read_holding(526, 3) == [21, 22, 23]
    text = audit_text(rt, r'cn="engineer-client" role=engineer fc=16 registers 526-528 count=3 -> ok$')
    for pattern in (r'tls cn="host-client" role=host fc=5 coil 400 count=1 -> ok$',
                    r'tls cn="host-client" role=host fc=16 registers 520-521 count=2 -> ok$',
                    r'tls cn="host-client" role=host fc=6 register 1324 count=1 -> refused: exception 02 ILLEGAL '
                    r"DATA ADDRESS \(outside the host ranges: an engineer's\)$",
                    r'tls cn="engineer-client" role=engineer fc=6 register 1324 count=1 -> ok$'):
        assert re.search(pattern, text, re.M), f"{pattern!r} not in the audit file:\n{text}"


def test_tls_1_2_is_served_too(rt, pki):
    raw = socket.create_connection(("127.0.0.1", rt.tls_port), timeout=3 * h.SLOW)
    s = context(pki, "read", maximum=ssl.TLSVersion.TLSv1_2).wrap_socket(raw, server_hostname="127.0.0.1")
    c = h.Client.__new__(h.Client)
    c.sock, c.tid = s, 0
    with c:
        assert s.version() == "TLSv1.2"
        assert c.read_holding(1024 + 30) == [4242]


# ------------------------------------------------------------------- refused at the handshake

def refused(pki: Path, name: str | None, port: int) -> str:
    """Connect with the certificate `name` (None: none) and send a read; the server must answer nothing. Returns
    how the client saw the refusal."""
    try:
        s = tls_socket(pki, name, port)
    except (ssl.SSLError, ConnectionError) as exc:       # TLS 1.2: the alert ends the handshake itself
        return f"handshake: {exc}"
    with s:
        try:
            s.sendall(struct.pack(">HHHBBHH", 1, 0, 6, 1, 3, 1024 + 30, 1))
            data = s.recv(64)
        except (ssl.SSLError, ConnectionError) as exc:   # TLS 1.3: the server's alert comes after the client's Finished
            return f"after the handshake: {exc}"
        assert data == b"", f"the server answered a refused client: {data.hex()}"
        return "closed"


REFUSALS = {   # the certificate, and what the runtime's log says
    None: r"peer did not return a certificate",
    "other-ca": r"certificate: unable to get local issuer certificate",
    "expired": r"certificate: certificate has expired",
    "no-role": r'cn "no-role-x{56}": its certificate has no role extension \(OID 1\.3\.6\.1\.4\.1\.50316\.802\.1\)\]',
    "unknown-role": r"cn \"admin\": its role 'admin' is not read, host or engineer",
    "not-utf8": r'cn "octets": its role extension is not one UTF8String',
}


@pytest.mark.parametrize("name", list(REFUSALS), ids=[str(n) for n in REFUSALS])
def test_a_client_without_a_valid_certificate_with_a_known_role_is_refused(pki, name):
    with start(pki) as rt, h.Client(rt.port) as plain:
        before = h.read_diag(plain)["refused"]
        how = refused(pki, name, rt.tls_port)
        rt.wait_for(r"client 127\.0\.0\.1:\d+ refused: TLS handshake failed or no known role in its certificate "
                    r"\[" + REFUSALS[name])
        assert h.read_diag(plain)["refused"] == before + 1, how
        assert h.read_diag(plain)["requests"] > 0                    # the plain listener goes on serving


def test_a_plain_client_on_the_tls_port_and_a_silent_one_are_dropped(pki):
    with start(pki) as rt:
        with socket.create_connection(("127.0.0.1", rt.tls_port), timeout=10 * h.SLOW) as s:
            s.sendall(struct.pack(">HHHBBHH", 1, 0, 6, 1, 3, 1024 + 30, 1))           # Modbus without TLS
            try:
                assert s.recv(64) == b""
            except ConnectionResetError:
                pass
        rt.wait_for(r"refused: TLS handshake failed or no known role in its certificate \[")
        with socket.create_connection(("127.0.0.1", rt.tls_port), timeout=10 * h.SLOW) as s:   # sends nothing
            try:
                assert s.recv(64) == b""
            except ConnectionResetError:
                pass
        rt.wait_for(rf"dropped: TLS handshake not done within the frame timeout \[after {FRAME_TIMEOUT_MS} ms\]")


def test_tls_clients_take_the_slots_of_max_clients_with_the_plain_ones(pki):
    with start(pki, "--max-clients", "2") as rt, h.Client(rt.port) as plain:
        assert plain.read_holding(1024 + 30) == [4242]             # served: it keeps its slot
        with TlsClient(pki, "read", rt.tls_port) as tls:
            assert tls.read_holding(1024 + 30) == [4242]           # the second slot, served over TLS
            refused(pki, "engineer", rt.tls_port)                  # a third: no slot left
            rt.wait_for(r"client 127\.0\.0\.1:\d+ refused: every slot holds a served client \[limit of 2 clients")
            assert tls.read_holding(1024 + 30) == [4242] and plain.read_holding(1024 + 30) == [4242]


# ------------------------------------------------------------------- the fuzz corpus over TLS

CORPUS = fz.load_corpus()


@pytest.fixture(scope="module")
def corpus_rt(pki):
    rt = start(pki)
    try:
        yield rt
    finally:
        rt.assert_clean_exit(rt.stop())


@pytest.mark.parametrize("entry", CORPUS, ids=[e.name for e in CORPUS])
def test_the_corpus_entry_gets_its_recorded_outcome_over_tls(corpus_rt, pki, entry):
    assert fz.replay(corpus_rt.tls_port, entry, connect=lambda port, t: tls_socket(pki, "engineer", port, t)) is None


def mutate(rng: random.Random, data: bytes) -> bytes:
    """A corpus frame with a few bytes flipped, cut short or doubled."""
    b = bytearray(data)
    for _ in range(rng.randint(1, 3)):
        kind = rng.randrange(4)
        if kind == 0 and b:
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        elif kind == 1 and b:
            b[rng.randrange(len(b))] = rng.randrange(256)
        elif kind == 2 and len(b) > 1:
            del b[rng.randrange(1, len(b)):]
        else:
            b += data
    return bytes(b)


def framing(stream: bytes) -> tuple[int, bool, int]:
    """What the server makes of a byte stream (modbus_server.c take_frames): the complete frames it answers, whether
    a header that is not Modbus/TCP then makes it close the connection, and the bytes left of an incomplete one."""
    frames, at = 0, 0
    while len(stream) - at >= 7:
        protocol, length = struct.unpack(">HH", stream[at + 2:at + 6])
        if protocol != 0 or not 2 <= length <= 254:
            return frames, True, 0
        if len(stream) - at < 6 + length:
            break
        frames, at = frames + 1, at + 6 + length
    return frames, False, len(stream) - at


def test_mutated_corpus_frames_over_tls_are_answered_or_closed_as_over_tcp(pki):
    """MUTATED_FRAMES frames over TLS, each on the connection of the one before while that one stays open: every
    complete frame is answered, a header that is not Modbus/TCP closes the connection, an incomplete frame is left
    by the client (which opens another). Then the corpus gets its recorded outcomes and the runtime exits 0 without
    a sanitizer report (the ASan rerun)."""
    rng = random.Random(35)
    answered = reconnects = 0
    with start(pki) as rt:
        s = tls_socket(pki, "engineer", rt.tls_port, timeout=10)
        try:
            for n in range(MUTATED_FRAMES):
                data = mutate(rng, rng.choice(CORPUS).data)
                frames, closes, left = framing(data)
                s.sendall(data)
                for _ in range(frames):
                    assert fz._recv_frame(s) is not None, f"frame {n} {data.hex()}: no answer"
                    answered += 1
                if closes:
                    assert fz._recv_frame(s) is None, f"frame {n} {data.hex()}: not closed"
                if closes or left:
                    s.close()
                    s = tls_socket(pki, "engineer", rt.tls_port, timeout=10)
                    reconnects += 1
        finally:
            s.close()
        print(f"{MUTATED_FRAMES} mutated frames over TLS: {answered} answers, {reconnects} connections anew")
        assert answered > MUTATED_FRAMES // 2
        with h.Client(rt.port) as plain:
            assert h.read_diag(plain)["requests"] >= answered
        for entry in CORPUS[:12]:                        # well-formed and coalesced: answered as before
            assert fz.replay(rt.tls_port, entry, connect=lambda port, t: tls_socket(pki, "engineer", port, t)) is None


# ------------------------------------------------------------------- configuration and start-up

def test_a_certificate_or_key_that_does_not_load_stops_the_start_with_the_file_named(pki, tmp_path):
    wrong_key = ["--tls-cert", str(pki / "server.pem"), "--tls-key", str(pki / "host.key"), "--tls-ca",
                 str(pki / "ca.pem")]
    missing = ["--tls-cert", str(tmp_path / "none.pem"), "--tls-key", str(pki / "server.key"), "--tls-ca",
               str(pki / "ca.pem")]
    cases = {tuple(wrong_key): f"modbus: TLS: cannot load the private key (PEM) {pki / 'host.key'}: key values "
                               "mismatch",
             tuple(missing): "modbus: TLS: cannot load the server certificate (PEM) " + str(tmp_path / "none.pem")}
    for args, message in cases.items():
        result = subprocess.run([str(h.runtime_binary()), "--no-rt", "--port", "0", "--tls-port", "0", *args,
                                 "--retain", str(tmp_path / "plc.retain")], capture_output=True, text=True,
                                timeout=30 * h.SLOW, env={**h.os.environ, **h.SANITIZER_ENV})
        assert result.returncode == 1, result.stderr
        assert message in result.stderr, result.stderr
        assert not (tmp_path / "plc.retain").exists()                   # nothing written
    result = subprocess.run([str(h.runtime_binary()), "--tls-cert", "x.pem"], capture_output=True, text=True,
                            timeout=30 * h.SLOW)
    assert result.returncode == 2 and "--tls-cert, --tls-key and --tls-ca go together" in result.stderr


def test_the_run_configuration_names_the_tls_files_and_reports_a_bad_one_at_its_key(pki, tmp_path):
    from plc import runtime
    good = tmp_path / "good.toml"
    good.write_text(f'[modbus]\nport = 5020\n\n[modbus.tls]\ncert = "{pki}/server.pem"\nkey = "{pki}/server.key"\n'
                    f'ca = "{pki}/ca.pem"\nbind = "0.0.0.0"\n')
    argv = runtime.runtime_argv(Path("plc-runtime"), runtime.load_config(good))
    i = argv.index("--tls-cert")
    assert argv[i:i + 10] == ["--tls-cert", f"{pki}/server.pem", "--tls-key", f"{pki}/server.key", "--tls-ca",
                              f"{pki}/ca.pem", "--tls-port", "802", "--tls-bind", "0.0.0.0"]
    assert argv[argv.index("--bind") + 1] == "127.0.0.1"                 # the plain listener stays on loopback
    (tmp_path / "junk.pem").write_text("not PEM\n")
    bad = tmp_path / "bad.toml"
    bad.write_text(f'[modbus]\nport = 5020\n\n[modbus.tls]\ncert = "{pki}/server.pem"\nkey = "{pki}/host.key"\n'
                   f'ca = "junk.pem"\nport = 5020\n')
    with pytest.raises(runtime.ConfigError) as e:
        runtime.load_config(bad)
    assert e.value.problems == [
        f"{bad}:6:1: error: [modbus.tls] key: {pki}/host.key is not the private key of {pki}/server.pem",
        f"{bad}:7:1: error: [modbus.tls] ca: {tmp_path}/junk.pem holds no PEM certificate",
        f"{bad}:8:1: error: [modbus.tls] port: 5020 is the plain listener's port too ([modbus] port)"]
    missing = tmp_path / "missing.toml"
    missing.write_text('[modbus.tls]\ncert = "tls/server.pem"\nkey = "tls/server.key"\n')
    with pytest.raises(runtime.ConfigError) as e:
        runtime.load_config(missing)
    assert e.value.problems == [
        f"{missing}:1:1: error: [modbus.tls] ca is required (the CA certificate(s) that sign the clients' "
        "certificates (PEM))",
        f"{missing}:2:1: error: [modbus.tls] cert: cannot read {tmp_path}/tls/server.pem: No such file or directory",
        f"{missing}:3:1: error: [modbus.tls] key: cannot read {tmp_path}/tls/server.key: No such file or directory"]


# ------------------------------------------------------------------- plc tls

def plc_tls(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "plc.cli", "tls", *args], capture_output=True, text=True, timeout=120)


def test_plc_tls_makes_a_ca_a_server_and_a_client_certificate_with_its_role(tmp_path):
    from cryptography import x509
    d = tmp_path / "tls"
    for args in (["ca", str(d)], ["server", str(d), "--ip", "192.168.1.10"],
                 ["client", str(d), "--name", "hmi", "--role", "host"]):
        result = plc_tls(*args)
        assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in d.iterdir()) == ["ca.key", "ca.pem", "hmi.key", "hmi.pem", "server.key",
                                                   "server.pem"]
    assert all((d / n).stat().st_mode & 0o077 == 0 for n in ("ca.key", "hmi.key", "server.key"))
    cert = x509.load_pem_x509_certificate((d / "hmi.pem").read_bytes())
    ext = cert.extensions.get_extension_for_oid(x509.ObjectIdentifier(tlscerts.ROLE_OID))
    assert not ext.critical and ext.value.value == b"\x0c\x04host"       # a DER UTF8String "host"
    assert cert.subject.rfc4514_string() == "CN=hmi"
    server = x509.load_pem_x509_certificate((d / "server.pem").read_bytes())
    assert [str(a) for a in server.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
            .get_values_for_type(x509.IPAddress)] == ["192.168.1.10"]
    # the runtime's own check accepts what plc tls wrote
    from plc import runtime
    assert runtime.tls_file_problems({"cert": d / "server.pem", "key": d / "server.key", "ca": d / "ca.pem"}) == {}

    again = plc_tls("client", str(d), "--name", "hmi", "--role", "read")
    assert again.returncode == 1 and f"{d}/hmi.pem exists (--force replaces it)" in again.stderr
    assert plc_tls("client", str(d), "--name", "hmi", "--role", "read", "--force").returncode == 0
    no_ca = plc_tls("client", str(tmp_path / "empty"), "--name", "x", "--role", "read")
    assert no_ca.returncode == 1 and "make the CA first" in no_ca.stderr and "Traceback" not in no_ca.stderr
    bad = plc_tls("client", str(d), "--name", "a b", "--role", "read")
    assert bad.returncode == 2 and "is not a name" in bad.stderr
    assert plc_tls("client", str(d), "--name", "x", "--role", "admin").returncode == 2
    helped = plc_tls("--help")
    assert helped.returncode == 0 and "Exit status: 0 the files were written" in helped.stdout


def test_a_service_release_carries_the_tls_files_and_its_run_script_names_them_there(pki, tmp_path):
    """plc deploy service copies [modbus.tls]'s three files into the release (the key mode 0600) and the release's
    run script names them there: the runtime started from it serves TLS with nothing pointing back here."""
    config = tmp_path / "runtime.toml"
    config.write_text(f'[modbus]\nport = 5020\n\n[modbus.tls]\ncert = "{pki}/server.pem"\nkey = "{pki}/server.key"\n'
                      f'ca = "{pki}/ca.pem"\nport = 8802\n')
    out, src = tmp_path / "deploy", tmp_path / "src"          # a small program outside the project: built fast
    src.mkdir()
    (src / "main.st").write_text("PROGRAM Main\nVAR n AT %QW0 : INT; END_VAR\nn := n + 1;\nEND_PROGRAM\n"
                                 + h.MAIN_EVERY_4MS)
    deploy = [sys.executable, "-m", "plc.cli", "deploy", "service", "--src", str(src), "--config", str(config),
              "--simulated"]
    refused = subprocess.run([*deploy, "--out", str(tmp_path / "other"), "--user", "plc"], cwd=tmp_path,
                             capture_output=True, text=True, timeout=300 * h.SLOW)
    assert refused.returncode == 2 and "[modbus.tls] with --user plc: not done yet" in refused.stderr
    assert not (tmp_path / "other").exists()
    result = subprocess.run([*deploy, "--out", str(out), "--prefix", str(out)], cwd=tmp_path, capture_output=True,
                            text=True, timeout=300 * h.SLOW)
    assert result.returncode == 0, result.stderr
    release = (out / "current").resolve()
    assert {f.name: f.stat().st_mode & 0o777 for f in (release / "tls").iterdir()} == {
        "server.pem": 0o644, "server.key": 0o600, "ca.pem": 0o644}
    assert (release / "tls" / "server.key").read_bytes() == (pki / "server.key").read_bytes()
    script = (release / "run").read_text()
    assert '--tls-cert "$here/tls/server.pem" --tls-key "$here/tls/server.key" --tls-ca "$here/tls/ca.pem"' in script
    assert "--tls-port 8802" in script and str(pki) not in script
    state = tmp_path / "state"
    state.mkdir()
    rt = h.Runtime(release / "run", "--port", "0", "--tls-port", "0", "--no-rt", "--status", "log", raw=True,
                   env={"STATE_DIRECTORY": str(state), "RUNTIME_DIRECTORY": str(state)})
    try:
        rt.wait_for(r"modbus: TLS \(Modbus/TCP Security\) on 127\.0\.0\.1:\d+: TLS 1\.2 or later, client "
                    rf"certificates signed by {re.escape(str(release / 'tls' / 'ca.pem'))}")
    finally:
        rt.stop()
