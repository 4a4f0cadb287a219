"""The Modbus fuzzing of the runtime, shared by tests/test_runtime_fuzz.py (a short run, every
change) and scripts/fuzz-modbus (the long run of the benchmark).

A session: start the runtime (the ASan/UBSan build unless told otherwise), replay the
regression corpus (modbus_corpus.txt: every entry must have exactly its recorded outcome),
fire N mutated frames at it with mbfuzz.c, replay the corpus again, check a valid request
is still answered, stop it with SIGTERM and check the exit status and the log for
sanitizer reports.  With `tls` the runtime also serves Modbus/TCP Security, and the corpus
is replayed over TLS too, before and after the frames (an engineer's client certificate).
"""

from __future__ import annotations

import json
import socket
import ssl
import struct
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import rt_harness as h
from plc.runtime import build_runtime

CORPUS = h.FIXTURES / "modbus_corpus.txt"
FRAME_TIMEOUT_MS = 300                        # the corpus's incomplete frames are dropped after this
SANITIZER_MARKERS = ("ERROR: AddressSanitizer", "ERROR: LeakSanitizer", "runtime error:")
LAYOUT_VERSION = (h.DIAG_BASE, 1)             # an input register no write can change, and its value


@dataclass
class CorpusEntry:
    name: str
    outcomes: list[str]
    data: bytes
    line: int


def load_corpus(path: Path = CORPUS) -> list[CorpusEntry]:
    entries = []
    for number, text in enumerate(path.read_text().splitlines(), 1):
        if not text.strip() or text.lstrip().startswith("#"):
            continue
        name, outcomes, rest = text.split(None, 2)
        hex_text = rest.replace("|", "").replace(" ", "")
        try:
            data = bytes.fromhex(hex_text)
        except ValueError as exc:
            raise ValueError(f"{path}:{number}: {name}: bad hex: {exc}") from None
        entries.append(CorpusEntry(name, outcomes.split(","), data, number))
    return entries


def _recv_exact(s: socket.socket, n: int) -> bytes | None:
    data = b""
    while len(data) < n:
        chunk = s.recv(n - len(data))
        if not chunk:
            return None
        data += chunk
    return data


def _recv_frame(s: socket.socket) -> bytes | None:
    """One response ADU, or None when the server closed the connection."""
    try:
        head = _recv_exact(s, 7)
        if head is None:
            return None
        rest = _recv_exact(s, struct.unpack(">H", head[4:6])[0] - 1)
        return None if rest is None else head + rest
    except (ConnectionResetError, ssl.SSLError):          # a TLS connection reset or cut mid-record: closed too
        return None


def replay(port: int, entry: CorpusEntry, timeout: float = 10.0,
           connect: Callable[[int, float], socket.socket] | None = None) -> str | None:
    """Send one corpus entry on a fresh connection (`connect(port, timeout)`, e.g. a TLS one; default: plain
    TCP); None when the server acted as recorded, else what differed."""
    where = f"{CORPUS.name}:{entry.line} {entry.name}"
    opened = connect(port, timeout * h.SLOW) if connect else socket.create_connection(("127.0.0.1", port),
                                                                                       timeout=timeout * h.SLOW)
    with opened as s:
        s.sendall(entry.data)
        for outcome in entry.outcomes:
            kind, *args = outcome.split(":")
            if kind in ("ok", "exc"):
                rsp = _recv_frame(s)
                fc = int(args[0], 16)
                want = bytes([fc]) if kind == "ok" else bytes([(fc + 0x80) & 0xFF, int(args[1], 16)])
                if rsp is None:
                    return f"{where}: closed, expected {outcome}"
                if rsp[7:7 + len(want)] != want or (kind == "exc" and len(rsp) != 9):
                    return f"{where}: got {rsp.hex()}, expected {outcome}"
            elif kind == "open":
                s.sendall(struct.pack(">HHHBBHH", 0x7777, 0, 6, 1, h.MODBUS_FC_READ_INPUT_REGISTERS,
                                      LAYOUT_VERSION[0], 1))
                rsp = _recv_frame(s)
                if rsp is None or rsp[:2] != b"\x77\x77" or rsp[7:] != struct.pack(">BBH", 4, 2, LAYOUT_VERSION[1]):
                    return f"{where}: not open and in step (got {rsp.hex() if rsp else 'a close'})"
            elif kind == "closed":
                rsp = _recv_frame(s)
                if rsp is not None:
                    return f"{where}: got {rsp.hex()}, expected a close"
            else:
                return f"{where}: unknown outcome {outcome!r}"
    return None


def mbfuzz_binary() -> Path:
    return h.tool_binary("mbfuzz")


@dataclass
class FuzzReport:
    sanitized: bool
    frames: int = 0
    seconds: float = 0.0
    frames_per_s: float = 0.0
    connections: int = 0
    answered: int = 0                          # requests the server answered (diagnostic counter)
    exceptions: int = 0
    dropped: int = 0                           # connections the server closed
    corpus_entries: int = 0
    corpus_failures: list[str] = field(default_factory=list)
    tls_replays: int = 0                       # corpus entries replayed over TLS (0: no TLS listener)
    valid_request_after: bool = False
    exit_status: int | None = None
    sanitizer_findings: int = 0
    log_tail: str = ""

    @property
    def ok(self) -> bool:
        return (not self.corpus_failures and self.valid_request_after and self.exit_status == 0
                and self.sanitizer_findings == 0)


def tls_files(directory: Path) -> dict[str, Path]:
    """A CA, the runtime's certificate and an engineer's client certificate (plc.tlscerts), made once."""
    from plc import tlscerts
    names = {n: directory / f"{n}.pem" for n in ("ca", "server", "client")}
    names.update(server_key=directory / "server.key", client_key=directory / "client.key")
    if not names["client_key"].exists():
        ca = tlscerts.make_ca("fuzz CA")
        tlscerts.write_pair(ca, names["ca"], directory / "ca.key", force=True)
        tlscerts.write_pair(tlscerts.make_leaf(ca, "plc", server=True, ips=["127.0.0.1"]), names["server"],
                            names["server_key"], force=True)
        tlscerts.write_pair(tlscerts.make_leaf(ca, "fuzz", role="engineer"), names["client"], names["client_key"],
                            force=True)
    return names


def tls_connect(files: dict[str, Path]) -> Callable[[int, float], socket.socket]:
    """replay()'s `connect` for a TLS connection with the client certificate of `files`."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.load_verify_locations(files["ca"])
    ctx.load_cert_chain(files["client"], files["client_key"])

    def connect(port: int, timeout: float) -> socket.socket:
        raw = socket.create_connection(("127.0.0.1", port), timeout=timeout)
        return ctx.wrap_socket(raw, server_hostname="127.0.0.1")
    return connect


def fuzz_session(frames: int, seed: int = 1, connections: int = 4, sanitize: bool = True,
                 hang_limit_s: float = 3600, tls: bool = False) -> FuzzReport:
    binary = build_runtime(h.BASIC, h.CACHE, sanitize=sanitize)
    report = FuzzReport(sanitized=sanitize)
    args = ["--no-rt", "--frame-timeout", str(FRAME_TIMEOUT_MS)]
    connect = None
    if tls:
        files = tls_files(h.CACHE / "fuzz-tls")
        args += ["--tls-port", "0", "--tls-cert", str(files["server"]), "--tls-key", str(files["server_key"]),
                 "--tls-ca", str(files["ca"])]
        connect = tls_connect(files)
    rt = h.Runtime(binary, *args).start()
    tls_port = int(rt.wait_for(r"modbus: TLS \(Modbus/TCP Security\) on [\d.]+:(\d+)").group(1)) if tls else 0
    try:
        corpus = load_corpus()
        report.corpus_entries = len(corpus)
        for entry in corpus:
            if (problem := replay(rt.port, entry)):
                report.corpus_failures.append(problem)
            if tls and (problem := replay(tls_port, entry, connect=connect)):
                report.corpus_failures.append("over TLS: " + problem)
            report.tls_replays += tls
        if frames > 0:
            result = subprocess.run([str(mbfuzz_binary()), "--port", str(rt.port), "--frames", str(frames),
                                     "--seed", str(seed), "--connections", str(connections)],
                                    capture_output=True, text=True, timeout=hang_limit_s)
            if result.returncode != 0 or not result.stdout.strip():
                raise RuntimeError(f"mbfuzz failed ({result.returncode}): {result.stderr}{result.stdout}")
            out = json.loads(result.stdout)
            report.frames, report.seconds = out["frames"], out["seconds"]
            report.frames_per_s, report.connections = out["frames_per_s"], out["connections"]
        for entry in corpus:                   # the same answers after the storm
            if (problem := replay(rt.port, entry)):
                report.corpus_failures.append("after fuzzing: " + problem)
            if tls and (problem := replay(tls_port, entry, connect=connect)):
                report.corpus_failures.append("after fuzzing, over TLS: " + problem)
            report.tls_replays += tls
        try:
            with h.Client(rt.port) as c:
                report.valid_request_after = c.read_input(LAYOUT_VERSION[0]) == [LAYOUT_VERSION[1]]
                d = h.read_diag(c)
                report.answered, report.exceptions, report.dropped = d["requests"], d["exceptions"], d["dropped"]
        except (OSError, AssertionError, h.ModbusError):
            report.valid_request_after = False
        report.exit_status = rt.stop()
    finally:
        if rt.proc.poll() is None:
            rt.kill()
    log = rt.log
    report.sanitizer_findings = sum(log.count(m) for m in SANITIZER_MARKERS)
    report.log_tail = "\n".join(log.splitlines()[-40:])
    return report
