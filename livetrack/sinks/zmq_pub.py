"""ZeroMQ PUB pose stream: two-frame messages ``[topic, payload]``, topic ``livetrack/pose/<target id>``.

The payload is the same message as the UDP stream (docs/pose-stream.md). The socket is created, used and closed
by the sink's own thread (ZeroMQ sockets are not thread-safe), binds to localhost by default, and has a send
high-water mark: a subscriber that reads slowly fills its queue up to SNDHWM messages, after which PUB drops
messages for it (ZeroMQ's PUB never blocks); sends never wait (``NOBLOCK``), failures are counted.
"""

from __future__ import annotations

import logging
from typing import Any, Literal

import zmq

from livetrack.frames import Mounting
from livetrack.sinks.base import TrackedFrame
from livetrack.sinks.pose_message import Encoding, messages_for_tracked_frame

log = logging.getLogger(__name__)

TOPIC_PREFIX = b"livetrack/pose/"


def topic_for(target_id: int) -> bytes:
    return TOPIC_PREFIX + str(int(target_id)).encode("ascii")


class ZmqPubSink:
    """Publishes each target of each TrackedFrame on ``endpoint`` (bound, e.g. ``tcp://127.0.0.1:5556``)."""

    consumes: Literal["results"] = "results"

    def __init__(self, endpoint: str, encoding: Encoding = "binary", sndhwm: int = 100, name: str = "zmq",
                 context: zmq.Context | None = None, mounting: Mounting | None = None):
        self.name = name
        self.mounting = mounting  # set: version 2 messages with the vehicle frames (docs/pose-stream.md)
        self.endpoint = endpoint
        self.encoding: Encoding = encoding
        self.sndhwm = sndhwm
        self._context = context
        self._own_context = context is None
        self._sock: zmq.Socket | None = None
        self.bound_endpoint: str | None = None
        self._sequence = 0
        self._sent = 0
        self._errors: dict[str, int] = {}

    def open(self) -> None:
        if self._context is None:
            self._context = zmq.Context()
        sock = self._context.socket(zmq.PUB)
        sock.setsockopt(zmq.SNDHWM, self.sndhwm)
        sock.setsockopt(zmq.LINGER, 0)
        try:
            sock.bind(self.endpoint)
        except zmq.ZMQError:
            sock.close()
            raise
        self._sock = sock
        self.bound_endpoint = sock.getsockopt(zmq.LAST_ENDPOINT).decode()
        log.info("ZeroMQ pose stream on %s (SNDHWM %d, %s)", self.bound_endpoint, self.sndhwm, self.encoding)

    def handle(self, item: TrackedFrame) -> None:
        assert self._sock is not None
        messages = messages_for_tracked_frame(item, self._sequence, self.mounting)
        self._sequence += len(messages)
        for message in messages:
            try:
                self._sock.send_multipart([topic_for(message.target_id), message.encode(self.encoding)],
                                          flags=zmq.NOBLOCK)
                self._sent += 1
            except zmq.Again:
                self._count("would_block")
            except zmq.ZMQError as exc:
                self._count(zmq.strerror(exc.errno))

    def _count(self, key: str) -> None:
        self._errors[key] = self._errors.get(key, 0) + 1

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close(linger=0)
            self._sock = None
        if self._own_context and self._context is not None:
            self._context.term()
            self._context = None

    @property
    def stats(self) -> dict[str, Any]:
        return {"sent": self._sent, "errors": sum(self._errors.values()), "errors_by_kind": dict(self._errors),
                "endpoint": self.bound_endpoint or self.endpoint}
