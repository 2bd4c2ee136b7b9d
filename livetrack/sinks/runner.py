"""Bounded hand-offs between threads, and the thread that owns each sink.

``DropSlot``: a deque of at most N items plus a condition variable. Not lossless: ``put`` never blocks and
discards the oldest item when full (counted). Lossless: ``put`` waits for space (replay, the recorder).
``SinkRunner``: one named thread per sink (open, handle, close all in that thread), fed by a DropSlot. A sink
that must not lose data says so with ``lossless = True``: its queue then applies back-pressure (``submit`` waits
for room, counted in ``waited`` / ``wait_ms``) instead of dropping; it drops only what is still queued when it
has not finished ``sink_close_timeout_s`` after the end of the run, or what arrives after its queue closed
(both counted in ``dropped`` and logged). A sink with a ``prepare(item)`` method has it called by ``submit`` in the
submitting thread, once the sink is open, and its result queued instead of the item (the recorder writes each
frame's raw bytes there, so that a killed process loses none it has queued); a ``prepare`` that raises counts
as an error of the sink, and the item is not queued.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from typing import Any, Generic, TypeVar

import numpy as np

from livetrack.sinks.base import Sink

log = logging.getLogger(__name__)

T = TypeVar("T")
STATS_WINDOW = 4096  # percentiles are over the last this many items (bounded memory: ~32 bytes per value)


class SlotClosed(Exception):
    """Raised by ``DropSlot.get`` once the slot is closed and empty."""


class DropSlot(Generic[T]):
    """A bounded hand-off between two threads: a deque of at most ``size`` items plus a condition variable.

    ``lossless=False``: ``put`` never blocks; when full, the oldest item is discarded and counted in
    ``dropped``. ``lossless=True``: ``put`` waits while full (until space, ``close()`` or ``abort``).
    """

    def __init__(self, size: int = 1, *, lossless: bool = False):
        if size < 1:
            raise ValueError(f"slot size must be >= 1, got {size}")
        self.size = size
        self.lossless = lossless
        self._items: deque[T] = deque()
        self._cond = threading.Condition()
        self._closed = False
        self.dropped = 0
        self.put_count = 0
        self.waited = 0  # lossless puts that found the slot full and waited

    def put(self, item: T, abort: threading.Event | None = None) -> bool:
        """Hand ``item`` over; False if the slot is closed (or ``abort`` was set while waiting for space)."""
        with self._cond:
            if self.lossless and len(self._items) >= self.size and not self._closed:
                self.waited += 1
                while len(self._items) >= self.size and not self._closed:
                    if abort is not None and abort.is_set():
                        return False
                    self._cond.wait(0.05)
            if self._closed:
                self.dropped += 1  # refused: counted, so that nothing handed over vanishes uncounted
                return False
            if len(self._items) >= self.size:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self.put_count += 1
            self._cond.notify_all()
            return True

    def get(self, timeout_s: float) -> T | None:
        """The oldest item, waiting up to ``timeout_s`` (None on timeout); SlotClosed once closed and empty."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while not self._items:
                if self._closed:
                    raise SlotClosed
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._cond.wait(remaining)
            item = self._items.popleft()
            self._cond.notify_all()
            return item

    def close(self) -> None:
        """No more puts; ``get`` returns what is left, then raises SlotClosed."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def clear(self) -> int:
        """Discard every queued item (counted as dropped); returns how many."""
        with self._cond:
            n = len(self._items)
            self._items.clear()
            self.dropped += n
            self._cond.notify_all()
            return n

    def __len__(self) -> int:
        return len(self._items)


class SinkRunner:
    """Owns one sink in its own thread, fed by a bounded queue of ``queue_size`` items: drop-oldest, or
    back-pressure for a sink with ``lossless = True`` (module docstring)."""

    def __init__(self, sink: Sink, queue_size: int = 2):
        self.sink = sink
        self.name = sink.name
        self.lossless = bool(getattr(sink, "lossless", False))
        self.queue: DropSlot[Any] = DropSlot(queue_size, lossless=self.lossless)
        self.wait_ns = 0  # time submit() waited for room (lossless sinks)
        self._thread = threading.Thread(target=self._run, name=f"livetrack-sink-{sink.name}", daemon=True)
        self._opened = threading.Event()
        self._open_error: BaseException | None = None
        self._discard = threading.Event()
        self.handled = 0
        self.errors = 0
        self.prepare_errors = 0  # prepare() failures (in the submitting thread)
        self.handle_ns: deque[int] = deque(maxlen=STATS_WINDOW)
        self.cpu_ns = 0  # CPU time of this thread in handle(), in total
        self.finished = False

    def start(self, open_timeout_s: float = 10.0) -> None:
        """Start the thread and wait for ``sink.open()``; re-raises its exception. A sink still opening after
        ``open_timeout_s`` (e.g. a viewer that does not answer) keeps opening in its thread; items meanwhile
        queue and drop."""
        self._thread.start()
        if self._opened.wait(open_timeout_s) and self._open_error is not None:
            self._thread.join()
            raise self._open_error

    def submit(self, item: Any) -> bool:
        """Queue ``item``; False if it was not accepted (queue closed; counted as dropped). A lossless sink's
        full queue makes this wait for room (no timeout: ``close()`` releases it)."""
        prepare = getattr(self.sink, "prepare", None)
        if prepare is not None and self._opened.is_set() and self._open_error is None:
            try:
                item = prepare(item)
            except Exception as exc:  # counted as the sink's error; never ends the submitting thread
                self.prepare_errors += 1
                if self.prepare_errors in (1, 10, 100) or self.prepare_errors % 1000 == 0:
                    log.warning("sink %s: error #%d in prepare: %r", self.name, self.prepare_errors, exc)
                return False
        if not self.lossless:
            return self.queue.put(item)
        waited = self.queue.waited
        t0 = time.perf_counter_ns()
        ok = self.queue.put(item)
        if self.queue.waited != waited:
            self.wait_ns += time.perf_counter_ns() - t0
            if self.queue.waited == 1:
                log.warning("sink %s: cannot keep up; the pipeline waits for it rather than lose data "
                            "(back-pressure: a live source drops at its own boundary instead, counted there)",
                            self.name)
        if not ok and self.queue.dropped in (1, 10, 100, 1000):
            log.error("sink %s: %d items lost (its queue was closed: the sink failed or was shut down)",
                      self.name, self.queue.dropped)
        return ok

    def close(self, timeout_s: float) -> bool:
        """Let the sink drain its queue and close, waiting up to ``timeout_s``; then discard what is left and
        wait up to 2 s more. True if the thread ended."""
        self.queue.close()
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            log.warning("sink %s: not finished after %.1f s, discarding %d queued items%s", self.name, timeout_s,
                        len(self.queue), " (data lost)" if self.lossless else "")
            self._discard.set()
            self.queue.clear()
            self._thread.join(2.0)
        return not self._thread.is_alive()

    def _run(self) -> None:
        try:
            self.sink.open()
        except BaseException as exc:  # reported by start() or, if start() stopped waiting, logged here
            self._open_error = exc
            self._opened.set()
            log.error("sink %s: cannot open: %s", self.name, exc)
            self.queue.close()
            self.queue.clear()
            self._close_sink()
            return
        self._opened.set()
        try:
            while not self._discard.is_set():
                try:
                    item = self.queue.get(0.5)
                except SlotClosed:
                    break
                if item is None:
                    continue
                t0 = time.perf_counter_ns()
                cpu0 = time.thread_time_ns()
                try:
                    self.sink.handle(item)
                    self.handled += 1
                except Exception as exc:  # a sink failure must not end the run; count it and go on
                    self.errors += 1
                    if self.errors in (1, 10, 100) or self.errors % 1000 == 0:
                        log.warning("sink %s: error #%d: %r", self.name, self.errors, exc)
                self.cpu_ns += time.thread_time_ns() - cpu0
                self.handle_ns.append(time.perf_counter_ns() - t0)
        finally:
            self._close_sink()

    def _close_sink(self) -> None:
        try:
            self.sink.close()
        except Exception as exc:
            self.errors += 1
            log.error("sink %s: error while closing: %r", self.name, exc)
        self.finished = True

    def summary(self) -> dict[str, Any]:
        times = np.asarray(self.handle_ns, dtype=np.float64) / 1e6
        try:
            sink_stats = dict(self.sink.stats)
        except Exception as exc:  # stats of a half-opened sink
            sink_stats = {"stats_error": repr(exc)}
        out: dict[str, Any] = {"handled": self.handled, "dropped": self.queue.dropped,
                               "errors": self.errors + self.prepare_errors}
        for key in ("dropped", "errors"):  # the sink's own (e.g. failed sends, undelivered items) add to the runner's
            if isinstance(sink_stats.get(key), int):
                out[key] += sink_stats.pop(key)
        if self.lossless:
            out.update(waited=self.queue.waited, wait_ms=round(self.wait_ns / 1e6, 1))
        return {**out, "handle_ms_p50": percentile(times, 50), "handle_ms_p99": percentile(times, 99),
                "cpu_ms_per_item": self.cpu_ns / 1e6 / max(self.handled + self.errors, 1), "closed": self.finished,
                **sink_stats}


def percentile(values: np.ndarray, q: float) -> float | None:
    """q-th percentile of the finite values, None if there are none."""
    values = values[np.isfinite(values)] if values.size else values
    return float(np.percentile(values, q)) if values.size else None
