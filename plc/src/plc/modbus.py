"""A small Modbus/TCP client on a plain socket: the function codes the register map needs, nothing more.

Each request is one MBAP frame (transaction id, protocol 0, length, unit id) and waits for its own answer;
a lock makes the client safe to share between the heartbeat thread and the command loop.  Errors are
exceptions with a sentence for the operator: LinkError (connection or framing), ModbusException (the server
answered with an exception code).
"""
from __future__ import annotations

import socket
import struct
import threading

EXCEPTIONS = {1: "illegal function", 2: "illegal data address (not on the map, or not host-writable)",
              3: "illegal data value", 4: "server device failure", 6: "server busy"}


class LinkError(Exception):
    """No connection, a broken connection, a timeout or a malformed answer."""


class ModbusException(Exception):
    def __init__(self, function: int, code: int, address: int):
        self.function, self.code, self.address = function, code, address
        text = EXCEPTIONS.get(code, f"exception {code}")
        super().__init__(f"function {function} at address {address}: {text}")


class ModbusClient:
    def __init__(self, host: str, port: int, timeout: float = 2.0, unit: int = 1):
        self.host, self.port, self.timeout, self.unit = host, port, timeout, unit
        self._sock: socket.socket | None = None
        self._tid = 0
        self._lock = threading.Lock()

    # ------------------------------------------------------------ connection --
    def connect(self) -> None:
        try:
            self._sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
        except OSError as exc:
            raise LinkError(f"cannot connect to {self.host}:{self.port}: {exc.strerror or exc}") from None
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def close(self) -> None:
        with self._lock:
            if self._sock is not None:
                try:
                    self._sock.close()
                finally:
                    self._sock = None

    def __enter__(self) -> "ModbusClient":
        self.connect()
        return self

    def __exit__(self, *_exc) -> None:
        self.close()

    # -------------------------------------------------------------- requests --
    def _recv(self, n: int) -> bytes:
        assert self._sock is not None
        data = b""
        while len(data) < n:
            try:
                chunk = self._sock.recv(n - len(data))
            except socket.timeout:
                raise LinkError(f"no answer from {self.host}:{self.port} within {self.timeout} s") from None
            except OSError as exc:
                raise LinkError(f"connection to {self.host}:{self.port} failed: {exc.strerror or exc}") from None
            if not chunk:
                raise LinkError(f"{self.host}:{self.port} closed the connection")
            data += chunk
        return data

    def request(self, pdu: bytes, address: int = 0) -> bytes:
        """Send one PDU, return the answer's PDU (function code included); raise on exceptions."""
        with self._lock:
            if self._sock is None:
                raise LinkError("not connected")
            self._tid = (self._tid + 1) & 0xFFFF
            frame = struct.pack(">HHHB", self._tid, 0, len(pdu) + 1, self.unit) + pdu
            try:
                self._sock.sendall(frame)
            except OSError as exc:
                raise LinkError(f"connection to {self.host}:{self.port} failed: {exc.strerror or exc}") from None
            while True:
                tid, proto, length, _unit = struct.unpack(">HHHB", self._recv(7))
                if proto != 0 or not 2 <= length <= 254:
                    raise LinkError(f"malformed answer from {self.host}:{self.port} (protocol {proto}, "
                                    f"length {length})")
                body = self._recv(length - 1)
                if tid == self._tid:
                    break           # answers to requests we gave up on are skipped
        if body[0] == pdu[0] | 0x80:
            raise ModbusException(pdu[0], body[1] if len(body) > 1 else 0, address)
        if body[0] != pdu[0]:
            raise LinkError(f"answer with function {body[0]} to function {pdu[0]}")
        return body

    def read_bits(self, function: int, address: int, count: int) -> list[bool]:
        body = self.request(struct.pack(">BHH", function, address, count), address)
        data = body[2:2 + body[1]]
        if len(data) * 8 < count:
            raise LinkError(f"short answer to function {function}: {len(data)} bytes for {count} bits")
        return [bool(data[i // 8] >> (i % 8) & 1) for i in range(count)]

    def read_registers(self, function: int, address: int, count: int) -> list[int]:
        body = self.request(struct.pack(">BHH", function, address, count), address)
        if body[1] != 2 * count or len(body) < 2 + 2 * count:
            raise LinkError(f"short answer to function {function}: {body[1]} bytes for {count} registers")
        return list(struct.unpack(f">{count}H", body[2:2 + 2 * count]))

    def read_coils(self, address: int, count: int) -> list[bool]:
        return self.read_bits(1, address, count)

    def read_discrete_inputs(self, address: int, count: int) -> list[bool]:
        return self.read_bits(2, address, count)

    def read_holding(self, address: int, count: int) -> list[int]:
        return self.read_registers(3, address, count)

    def read_input_registers(self, address: int, count: int) -> list[int]:
        return self.read_registers(4, address, count)

    def write_coil(self, address: int, value: bool) -> None:
        self.request(struct.pack(">BHH", 5, address, 0xFF00 if value else 0), address)

    def write_register(self, address: int, value: int) -> None:
        self.request(struct.pack(">BHH", 6, address, value & 0xFFFF), address)

    def write_coils(self, address: int, values: list[bool]) -> None:
        packed = bytearray((len(values) + 7) // 8)
        for i, v in enumerate(values):
            if v:
                packed[i // 8] |= 1 << (i % 8)
        self.request(struct.pack(">BHHB", 15, address, len(values), len(packed)) + bytes(packed), address)

    def write_registers(self, address: int, values: list[int]) -> None:
        data = b"".join(struct.pack(">H", v & 0xFFFF) for v in values)
        self.request(struct.pack(">BHHB", 16, address, len(values), len(data)) + data, address)
