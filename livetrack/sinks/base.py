"""What the pipeline hands to its outputs, and the small protocol every output (sink) implements.

A sink is owned by one thread (``livetrack.pipeline.SinkRunner``): ``open()``, ``handle()`` and ``close()`` are
all called from that thread, so a sink needs no locks and may own thread-affine resources (ZeroMQ sockets, a
Rerun stream, a recording writer). The one exception: an optional ``prepare(item)`` runs in the submitting thread
(``SinkRunner.submit``), for work that must be done before the item is queued (the recorder's spooling). The
runner feeds it through a bounded queue that drops the oldest item when the sink falls behind: a slow sink never
blocks tracking.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

from livetrack.estimator.tracker import FrameResult
from livetrack.sources.base import Frame


@dataclass(frozen=True)
class TrackedFrame:
    """One processed frame as handed to the result sinks.

    sequence: consecutive count of processed frames in this run (0, 1, 2, ...); a gap in ``frame.frame_id``
        with consecutive ``sequence`` means frames were dropped before processing.
    frame: the acquired frame (image shared, read-only by convention: sinks must not modify it).
    result: ``Tracker.process`` output for the frame.
    stage_ms: per-stage times in milliseconds: ``queue_ms`` (host arrival to processing start), ``detect_ms``,
        ``pose_ms``, ``track_ms`` (the whole ``Tracker.process`` call, ``perf_counter_ns``), ``track_cpu_ms`` (its
        CPU time on the processing thread, ``thread_time_ns``).
    handoff_ns: ``time.time_ns()`` when the record was handed to the sinks.
    latency_ms: host latency, ``handoff_ns - frame.host_timestamp_ns``.
    device_latency_ms: ``handoff_ns - frame.timestamp_ns`` when the device clock is the host's Unix clock
        (within 10 s of it), else None.
    """

    sequence: int
    frame: Frame
    result: FrameResult
    stage_ms: dict[str, float]
    handoff_ns: int
    latency_ms: float
    device_latency_ms: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)


class Sink(Protocol):
    """One output. ``consumes`` says what it is fed: ``"results"`` (TrackedFrame, after processing) or
    ``"frames"`` (every acquired Frame, straight from the acquisition thread, e.g. the recorder).

    ``open()`` may raise (bad path, port in use): the pipeline reports it at start. ``handle()`` must not raise
    for expected trouble (unreachable network, viewer gone): count it in ``stats`` instead; an unexpected
    exception is caught, counted and logged by the runner. ``close()`` releases everything; it is called once,
    also after a failed ``open()``.
    """

    name: str
    consumes: Literal["results", "frames"]

    def open(self) -> None: ...

    def handle(self, item: Any) -> None: ...

    def close(self) -> None: ...

    @property
    def stats(self) -> dict[str, Any]: ...
