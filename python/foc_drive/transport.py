"""Byte transports: TCP (the simulator, QEMU's serial port) and serial ports."""

from __future__ import annotations

import select
import socket
from typing import Optional

__all__ = ["Transport", "TcpTransport", "SerialTransport"]


class Transport:
    """A bidirectional byte stream with read timeouts (the interface)."""

    def write(self, data: bytes) -> None:  # pragma: no cover - interface
        """Send all bytes."""
        raise NotImplementedError

    def read(self, max_bytes: int, timeout: float) -> bytes:  # pragma: no cover
        """What is available (at most ``max_bytes``), waiting at most
        ``timeout`` seconds; ``b""`` when nothing arrived. A closed
        connection raises :class:`ConnectionError`."""
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - interface
        """Release the connection."""
        raise NotImplementedError


class TcpTransport(Transport):
    """TCP transport (``TCP_NODELAY``)."""

    def __init__(self, sock: socket.socket) -> None:
        self._sock: Optional[socket.socket] = sock
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(True)

    @classmethod
    def connect(cls, host: str, port: int, connect_timeout: float = 5.0) -> "TcpTransport":
        """Connect to ``host:port``."""
        sock = socket.create_connection((host, port), timeout=connect_timeout)
        sock.settimeout(None)
        return cls(sock)

    def _socket(self) -> socket.socket:
        if self._sock is None:
            raise ConnectionError("the connection is closed")
        return self._sock

    def write(self, data: bytes) -> None:
        self._socket().sendall(data)

    def read(self, max_bytes: int, timeout: float) -> bytes:
        s = self._socket()
        ready, _, _ = select.select([s], [], [], max(timeout, 0.0))
        if not ready:
            return b""
        data = s.recv(max_bytes)
        if not data:
            raise ConnectionError("connection closed by the device")
        return data

    def close(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            finally:
                self._sock = None


class SerialTransport(Transport):
    """Serial port through pyserial (``pip install foc-drive[serial]``)."""

    def __init__(self, path: str, baud: int = 115200) -> None:
        try:
            import serial  # type: ignore[import-not-found]
        except ImportError as e:  # pragma: no cover - depends on the machine
            raise ImportError(
                "serial ports need pyserial: pip install pyserial "
                "(or pip install 'foc-drive[serial]')"
            ) from e
        self._port = serial.Serial(path, baudrate=baud, timeout=0)

    def write(self, data: bytes) -> None:
        self._port.write(data)
        self._port.flush()

    def read(self, max_bytes: int, timeout: float) -> bytes:
        self._port.timeout = max(timeout, 0.001)
        first = self._port.read(1)
        if not first:
            return b""
        waiting = min(self._port.in_waiting, max_bytes - 1)
        return first + (self._port.read(waiting) if waiting > 0 else b"")

    def close(self) -> None:
        self._port.close()
