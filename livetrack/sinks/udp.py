"""UDP pose stream: one datagram per target per processed frame (schema in docs/pose-stream.md).

The socket is non-blocking and connected to the destination, so the kernel reports ICMP errors (nobody
listening, network unreachable) on later sends: every failed send is counted by its errno name in ``stats``,
never raised. A full socket buffer drops the datagram (counted as ``would_block``).
"""

from __future__ import annotations

import errno
import logging
import socket
from typing import Any, Literal

from livetrack.frames import Mounting
from livetrack.sinks.base import TrackedFrame
from livetrack.sinks.pose_message import Encoding, messages_for_tracked_frame

log = logging.getLogger(__name__)


def parse_host_port(text: str, what: str = "address") -> tuple[str, int]:
    """``HOST:PORT`` (IPv6 as ``[::1]:PORT``) -> (host, port); ValueError naming the problem."""
    host, sep, port_text = text.rpartition(":")
    if not sep or not host or not port_text:
        raise ValueError(f"{what} must be HOST:PORT, got {text!r}")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    try:
        port = int(port_text)
    except ValueError:
        raise ValueError(f"{what}: port must be an integer, got {port_text!r}") from None
    if not 1 <= port <= 65535:
        raise ValueError(f"{what}: port must be in 1..65535, got {port}")
    return host, port


class UdpSink:
    """Sends each target of each TrackedFrame as one datagram to ``host:port``."""

    consumes: Literal["results"] = "results"

    def __init__(self, host: str, port: int, encoding: Encoding = "binary", name: str = "udp",
                 mounting: Mounting | None = None):
        self.name = name
        self.mounting = mounting  # set: version 2 messages with the vehicle frames (docs/pose-stream.md)
        self.host = host
        self.port = port
        self.encoding: Encoding = encoding
        self._sock: socket.socket | None = None
        self._address: Any = None
        self._connected = False
        self._sequence = 0
        self._sent = 0
        self._errors: dict[str, int] = {}

    def open(self) -> None:
        infos = socket.getaddrinfo(self.host, self.port, type=socket.SOCK_DGRAM)
        family, _, _, _, address = infos[0]
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        self._sock.setblocking(False)
        self._address = address
        log.info("UDP pose stream to %s:%d (%s)", self.host, self.port, self.encoding)

    def handle(self, item: TrackedFrame) -> None:
        messages = messages_for_tracked_frame(item, self._sequence, self.mounting)
        self._sequence += len(messages)
        for message in messages:
            self._send(message.encode(self.encoding))

    def _send(self, payload: bytes) -> None:
        assert self._sock is not None
        try:
            if not self._connected:
                self._sock.connect(self._address)
                self._connected = True
            self._sock.send(payload)
            self._sent += 1
        except BlockingIOError:
            self._count("would_block")
        except OSError as exc:
            self._count(errno.errorcode.get(exc.errno or 0, type(exc).__name__))
            if sum(self._errors.values()) in (1, 10, 100, 1000):
                log.warning("UDP %s:%d: %s (%d send errors so far)", self.host, self.port, exc,
                            sum(self._errors.values()))

    def _count(self, key: str) -> None:
        self._errors[key] = self._errors.get(key, 0) + 1

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    @property
    def stats(self) -> dict[str, Any]:
        return {"sent": self._sent, "errors": sum(self._errors.values()), "errors_by_kind": dict(self._errors)}
