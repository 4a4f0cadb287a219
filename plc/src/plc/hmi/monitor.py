"""Client of the runtime's monitoring channel (monitor.c): a Unix socket, one request per line, one JSON answer.

    with Monitor("var/plc.monitor") as m:
        m.read("ATC.MACHINE.ROTARY.TARGET")          # {"CONFIG0.RES0.ATC.MACHINE.ROTARY.TARGET": 5}
        m.auth(token); m.force("%IX0.3", "TRUE"); m.unforce("%IX0.3", restore=True)
        for scan, values in m.subscribe(50, "ATC.TOOLINSPINDLE"): ...

A refused request raises MonitorError with the runtime's sentence.  The channel is synchronous: subscription
lines that arrive while a request waits for its answer are kept for subscribe()'s iterator.
"""
from __future__ import annotations

import json
import os
import socket
from collections import deque
from pathlib import Path


class MonitorError(Exception):
    """The runtime refused a request (str() is its reason) or the channel failed."""


def read_token(path: Path) -> str:
    try:
        return Path(path).read_text(encoding="utf-8").split()[0]
    except (OSError, IndexError) as exc:
        raise MonitorError(f"cannot read the token from {path}: {getattr(exc, 'strerror', None) or exc}") from None


class Monitor:
    def __init__(self, path: str | os.PathLike, timeout: float = 10.0):
        self.path = str(path)
        self.timeout = timeout
        self._sock: socket.socket | None = None
        self._buf = b""
        self._pushed: deque[dict] = deque()

    def connect(self) -> "Monitor":
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(self.timeout)
        try:
            sock.connect(self.path)
        except OSError as exc:
            sock.close()
            raise MonitorError(f"cannot connect to the monitor at {self.path}: {exc.strerror or exc} "
                               "(is `plc run` running, with its monitor?)") from None
        self._sock = sock
        return self

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> "Monitor":
        return self.connect() if self._sock is None else self

    def __exit__(self, *_exc) -> None:
        self.close()

    # ------------------------------------------------------------- lines --
    def _line(self) -> dict:
        assert self._sock is not None
        while b"\n" not in self._buf:
            try:
                chunk = self._sock.recv(65536)
            except socket.timeout:
                raise MonitorError(f"no answer from the monitor within {self.timeout} s") from None
            except OSError as exc:
                raise MonitorError(f"monitor connection failed: {exc.strerror or exc}") from None
            if not chunk:
                raise MonitorError("the monitor closed the connection")
            self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        try:
            return json.loads(line)
        except ValueError:
            raise MonitorError(f"malformed answer from the monitor: {line[:200]!r}") from None

    def send_raw(self, text: str) -> None:
        if self._sock is None:
            self.connect()
        assert self._sock is not None
        self._sock.sendall(text.encode())

    def request(self, line: str) -> dict:
        """Send one request line, return its answer (MonitorError when refused)."""
        if "\n" in line:
            raise MonitorError("a request is one line")
        self.send_raw(line + "\n")
        while True:
            answer = self._line()
            if "sub" in answer and "ok" not in answer:          # a subscription's line, not our answer
                self._pushed.append(answer)
                continue
            if not answer.get("ok"):
                raise MonitorError(answer.get("error", "refused"))
            return answer

    # ---------------------------------------------------------- requests --
    def hello(self) -> dict:
        return self.request("hello")

    def list(self, prefix: str = "") -> list[dict]:
        return self.request(f"list {prefix}".strip())["vars"]

    def read_scan(self, *paths: str) -> tuple[int, dict]:
        answer = self.request("read " + " ".join(paths))
        return answer["scan"], answer["values"]

    def read(self, *paths: str) -> dict:
        return self.read_scan(*paths)[1]

    def auth(self, token: str) -> None:
        self.request(f"auth {token}")

    def write(self, path: str, value) -> int:
        return self.request(f"write {path} {_text(value)}")["scan"]

    def force(self, path: str, value) -> int:
        return self.request(f"force {path} {_text(value)}")["scan"]

    def unforce(self, path: str, restore: bool = False) -> int:
        return self.request(f"unforce {path} {'restore' if restore else 'keep'}")["scan"]

    def unforce_all(self) -> int:
        return self.request("unforce-all")["scan"]

    def forces(self) -> list[dict]:
        return self.request("forces")["forces"]

    def subscribe(self, period_ms: int, *paths: str) -> int:
        return self.request(f"sub {period_ms} " + " ".join(paths))["sub"]

    def unsubscribe(self, sub: int) -> None:
        self.request(f"unsub {sub}")

    def next_update(self) -> dict:
        """The next subscription line: {"sub": id, "scan": n, "values": {...}}."""
        if self._pushed:
            return self._pushed.popleft()
        while True:
            answer = self._line()
            if "sub" in answer and "ok" not in answer:
                if "error" in answer:
                    raise MonitorError(answer.get("error", "subscription failed"))
                return answer


def _text(value) -> str:
    if isinstance(value, bool):
        return "TRUE" if value else "FALSE"
    return str(value)
