"""The live pipeline: source -> acquisition thread -> processing thread (``Tracker.process``) -> sinks.

Threads and hand-offs (every hand-off is bounded; nothing queues without limit):

- ``livetrack-acquire`` reads the source and puts each Frame into the processing slot, then into the queue of
  every frame sink (the recorder, which must not lose data: when its queue is full, acquisition waits for it --
  back-pressure -- and a live source drops at its own boundary instead, counted in its stats; tracking then
  runs at the recorder's pace). For a live source the slot holds one frame and a new frame replaces an
  unprocessed one (dropped, counted: the tracker always works on the newest frame); for a finite source (replay)
  the slot blocks instead, so every frame is processed (lossless).
- ``livetrack-process`` runs ``Tracker.process``, times each stage with ``perf_counter_ns``, stamps the
  latency at the moment the result is handed to the sinks, and puts the TrackedFrame into each result sink's
  queue.
- With a search worker (``PipelineOptions.search_worker``; by default on for a live source and a tracker in
  tracking mode) a search frame does not hold up the tracked frames behind it: ``livetrack-process`` only
  tracks (``Tracker.track``: the kept targets from their last edges and pose) and hands the frames that need a
  search (every target lost or none kept: the frame has no pose without it; or the verify interval reached, or
  some targets lost while others stay tracked: the frame goes out at once with the tracked targets' poses, and
  the search, when the worker is idle, looks for the lost ones only: ``Tracker.lost_search_due``,
  ``search(lost_only=True)``) to ``livetrack-search`` (``Tracker.search``) through a one-item hand-off
  (a newer request replaces one not yet started, counted; lossless sources wait instead). Finished searches are
  adopted by the tracker on the processing thread before its next frame (``Tracker.adopt``: targets tracked
  since keep their newer tracks, the search adds the others), so the Tracker is only ever changed by one thread
  and the algorithm layer has no threads. Results are merged by frame: a reorder buffer holds each processed
  frame until every earlier one has gone out, so every target's pose (every frame) goes out in frame order, each
  frame at most once. A frame that needs its search (not tracked) goes out when the search is done. From a live
  source, once a tracked frame behind it is ready or after ``search_wait_ms``, it is dropped instead (counted,
  like a frame dropped before processing; the tracker still adopts the late search), and a search request not
  yet started is replaced by a newer frame's. Every frame handed out was tracked or searched; from a lossless
  source (replay) every frame is handed out, the tracked frames behind a search waiting for it.
- ``livetrack-sink-<name>``: one thread per sink owns it (``sinks.runner.SinkRunner``: open, handle, close) and
  reads its bounded queue (``sinks.runner.DropSlot``); a full queue drops its oldest item (counted): a slow result
  sink (viewer, network stream) never blocks tracking.

Before acquisition begins every compiled kernel is loaded from numba's cache (or compiled: ``Pipeline.warm_up``,
``estimator.warm``; ``build_pipeline`` does it before it opens the source), so the first frames pay no compilation;
the summary gives how long that took and the first frame's latency, its first search and first tracked frame (which
the percentiles include too).

``Pipeline.run()`` returns a ``RunSummary`` (frames, fps, drops per stage, latency percentiles, stage times).
``stop()`` may be called from any thread or a signal handler: acquisition stops, the frames already acquired are
finished, sinks drain their queues (bounded by ``sink_close_timeout_s``) and are closed (the recording is marked
complete).
"""

from __future__ import annotations

import inspect
import logging
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from livetrack.config.checks import ConfigError
from livetrack.estimator.tracker import FrameResult, SearchOutcome, Tracker, TrackerOptions
from livetrack.sinks.base import Sink, TrackedFrame
from livetrack.sinks.runner import STATS_WINDOW, DropSlot, SinkRunner, SlotClosed, percentile
from livetrack.sources.base import Frame, FrameSource

if TYPE_CHECKING:
    from livetrack.config.app import AppConfig

log = logging.getLogger(__name__)

SAME_CLOCK_WINDOW_NS = 10_000_000_000  # device timestamps within 10 s of the host clock are taken as Unix time


@dataclass(frozen=True)
class PipelineOptions:
    """Tunables of the threads around the tracker.

    max_frames: stop after this many processed frames (None: until the source ends or ``stop()``).
    lossless: None = from the source (``not source.live``): live sources drop the oldest unprocessed frame,
        finite sources (replay) block so that every frame is processed. True/False forces it.
    slot_size: frames the acquisition -> processing slot holds (1: always the newest; more adds latency).
    read_timeout_s: ``source.read`` timeout; also how often the acquisition thread checks for ``stop()``.
    sink_queue_size: default queue length per result sink (drop oldest beyond it); per-sink values override.
    sink_close_timeout_s: how long a sink may take to drain and close at the end before the rest is dropped.
    search_worker: run searches on a second thread (module docstring) so that a search frame does not hold up the
        tracked frames behind it. None (default): when the source is live (not lossless) and the tracker is in
        tracking mode; True forces it (the tracker needs ``track``/``search``/``adopt``); False: every frame
        through ``Tracker.process`` on one thread. Cost: a search's frame goes out with the search's result only
        when it was not tracked and no tracked frame came behind it before the search ended. Config:
        ``pipeline.search_worker: auto | on | off``.
    search_wait_ms: from a live source, the longest a frame without a tracked pose waits for its search (the
        frames behind it wait with it: frame order); then it is dropped (counted). A lossless source's frames wait
        until their search ends. Default 1000 ms.
    """

    max_frames: int | None = None
    lossless: bool | None = None
    slot_size: int = 1
    read_timeout_s: float = 0.5
    sink_queue_size: int = 4
    sink_close_timeout_s: float = 10.0
    search_worker: bool | None = None
    search_wait_ms: float = 1000.0


@dataclass
class RunSummary:
    """What a run did. Times in ms; ``*_p50``/``*_p99`` are percentiles over the last STATS_WINDOW frames."""

    frames_acquired: int = 0
    frames_processed: int = 0
    targets_found: int = 0
    fits_ok: int = 0
    duration_s: float = 0.0
    processing_fps: float = 0.0
    acquisition_fps: float = 0.0
    dropped_before_processing: int = 0
    read_cpu_ms_per_frame: float = 0.0  # CPU of the acquisition thread in source.read (e.g. PNG decoding)
    process_errors: int = 0
    stopped_by: str = ""
    source_error: str | None = None
    latency_ms: dict[str, float | None] = field(default_factory=dict)
    pose_latency_ms: dict[str, float | None] = field(default_factory=dict)  # frames with at least one target
    searches: dict[str, int] = field(default_factory=dict)  # search worker: requested, replaced, merged, late, ...
    device_latency_ms: dict[str, float | None] = field(default_factory=dict)
    stage_ms: dict[str, dict[str, float | None]] = field(default_factory=dict)
    source_stats: dict[str, Any] = field(default_factory=dict)
    sinks: dict[str, dict[str, Any]] = field(default_factory=dict)
    warm_up_s: float | None = None  # compiled kernels loaded (or compiled) before acquisition (Pipeline.warm_up)
    # the first frame handed out: its latency ("latency"); the first search's and first tracked frame's time on
    # their thread ("search", "tracked"); None where none ran
    first_frames_ms: dict[str, float | None] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items()}

    def format(self) -> str:
        lines = [f"{self.frames_processed} frames processed of {self.frames_acquired} acquired in "
                 f"{self.duration_s:.2f} s: {self.processing_fps:.1f} fps processed, {self.acquisition_fps:.1f} "
                 f"fps acquired; {self.targets_found} target poses ({self.fits_ok} ok); stopped by "
                 f"{self.stopped_by}"]
        drops = {"source": self.source_stats.get("dropped", 0), "before processing": self.dropped_before_processing}
        drops.update({f"sink {k}": v.get("dropped", 0) for k, v in self.sinks.items()})
        lines.append("drops: " + ", ".join(f"{k} {v}" for k, v in drops.items()))
        lines.append(f"latency (host arrival -> sinks): p50 {_fmt(self.latency_ms.get('p50'))} ms, "
                     f"p99 {_fmt(self.latency_ms.get('p99'))} ms, max {_fmt(self.latency_ms.get('max'))} ms")
        if self.pose_latency_ms.get("p50") is not None:
            lines.append(f"latency of frames with a target pose: p50 {_fmt(self.pose_latency_ms['p50'])} ms, "
                         f"p99 {_fmt(self.pose_latency_ms['p99'])} ms")
        if self.warm_up_s is not None or self.first_frames_ms:
            first = self.first_frames_ms
            lines.append(f"start-up: compiled kernels ready in {_fmt(self.warm_up_s)} s before acquisition; first "
                         f"frame latency {_fmt(first.get('latency'))} ms, first search {_fmt(first.get('search'))} ms, "
                         f"first tracked frame {_fmt(first.get('tracked'))} ms (in the figures above too)")
        if self.searches:
            lines.append("search worker: " + ", ".join(f"{k} {v}" for k, v in self.searches.items()))
        if self.device_latency_ms.get("p50") is not None:
            lines.append(f"latency (device timestamp -> sinks): p50 {_fmt(self.device_latency_ms['p50'])} ms, "
                         f"p99 {_fmt(self.device_latency_ms['p99'])} ms")
        lines.append("stages (p50 / p99 ms): " + ", ".join(
            f"{name} {_fmt(v['p50'])} / {_fmt(v['p99'])}" for name, v in self.stage_ms.items()))
        for name, stats in self.sinks.items():
            detail = ", ".join(f"{k} {v}" for k, v in stats.items()
                               if k not in ("handle_ms_p50", "handle_ms_p99", "cpu_ms_per_item"))
            lines.append(f"sink {name}: {detail}; handle p50 {_fmt(stats.get('handle_ms_p50'))} ms, CPU "
                         f"{_fmt(stats.get('cpu_ms_per_item'))} ms per item")
        if self.source_stats:
            lines.append("source: " + ", ".join(f"{k} {v}" for k, v in self.source_stats.items()))
        if self.process_errors:
            lines.append(f"processing errors: {self.process_errors}")
        if self.source_error:
            lines.append(f"source error: {self.source_error}")
        return "\n".join(lines)


class Pipeline:
    """Connects an opened source, a Tracker and sinks with threads (module docstring). Closes the source."""

    def __init__(self, source: FrameSource, tracker: Tracker, sinks: Sequence[Sink] = (),
                 options: PipelineOptions | None = None, sink_queue_sizes: dict[str, int] | None = None):
        self.source = source
        self.tracker = tracker
        self.options = options or PipelineOptions()
        lossless = self.options.lossless if self.options.lossless is not None else not bool(source.live)
        self._slot: DropSlot[Frame] = DropSlot(self.options.slot_size, lossless=lossless)
        sizes = sink_queue_sizes or {}
        names = [s.name for s in sinks]
        if len(set(names)) != len(names):
            raise ValueError(f"sink names must be unique, got {names}")
        runners = [SinkRunner(s, sizes.get(s.name, self.options.sink_queue_size)) for s in sinks]
        self._frame_sinks = [r for r in runners if r.sink.consumes == "frames"]
        self._result_sinks = [r for r in runners if r.sink.consumes == "results"]
        self._stop = threading.Event()
        self._stopped_by = ""
        self._source_error: str | None = None
        self._acquire = threading.Thread(target=self._acquire_loop, name="livetrack-acquire", daemon=True)
        worker = self.options.search_worker
        if worker is None:
            worker = _search_worker_auto(lossless, getattr(tracker, "options", None)) and hasattr(tracker, "search")
        self.search_worker = bool(worker)
        loop = self._process_loop_with_search if self.search_worker else self._process_loop
        self._process = threading.Thread(target=loop, name="livetrack-process", daemon=True)
        self._search = threading.Thread(target=self._search_loop, name="livetrack-search", daemon=True)
        self._requests = _SearchRequests(lossless=lossless)
        self._lock = threading.Lock()  # the reorder buffer, the finished searches and the statistics
        self._pending: OrderedDict[int, _Pending] = OrderedDict()  # by arrival index (frame ids increase with it)
        self._found: deque[tuple[int, SearchOutcome | None]] = deque()
        self._searched_ids: dict[int, int] = {}  # arrival index -> frame id of the frames handed to the search
        self._tracks_index: int | None = None  # arrival index of the frame the tracker's kept targets come from
        self._tracks_frame_id: int | None = None  # and its frame id
        self._last_frame_id: int | None = None  # one thread: the frame last given to Tracker.process
        self._frames_ahead = _takes(tracker.process, "frames_ahead")  # (a test's fake tracker may not)
        self._tracks_failed = True  # the last track() lost a target (or none kept): search every frame until adopted
        self._failed_index = -1  # arrival index of the frame where tracking last failed
        self._dropped_unprocessed = 0  # not tracked and not searched in time (search worker)
        # requested: searches asked for; replaced: withdrawn before they started (a newer frame's, or a tracked
        # frame came); run; merged: results that went out with their frame; late: frames that went out before
        # their search ended; adopted: searches the tracker took its targets from; errors
        self._search_counts = dict.fromkeys(("requested", "replaced", "run", "merged", "late", "adopted",
                                             "errors"), 0)
        self._started = False
        self._closed = False
        self._summary: RunSummary | None = None
        # statistics (written by one thread each, read after join)
        self._acquired = 0
        self._processed = 0
        self._targets = 0
        self._fits_ok = 0
        self._process_errors = 0
        self._read_cpu_ns = 0
        self._first_acquired_ns: int | None = None
        self._last_acquired_ns: int | None = None
        self._first_done_ns: int | None = None
        self._last_done_ns: int | None = None
        self._start_ns = 0
        self._latency: deque[float] = deque(maxlen=STATS_WINDOW)
        self._pose_latency: deque[float] = deque(maxlen=STATS_WINDOW)
        self._device_latency: deque[float] = deque(maxlen=STATS_WINDOW)
        self._stage: dict[str, deque[float]] = {}
        self.on_processed: Callable[[TrackedFrame], None] | None = None  # test hook, called in the process thread
        self.config_text: str | None = None  # the resolved config, when built by build_pipeline
        self.warm_up_s: float | None = None  # seconds of warm_up() (None: not run yet)
        self._first: dict[str, float | None] = {"latency": None, "search": None, "tracked": None}

    @property
    def lossless(self) -> bool:
        return self._slot.lossless

    @property
    def runners(self) -> list[SinkRunner]:
        return self._frame_sinks + self._result_sinks

    # ------------------------------------------------------------------ control
    def warm_up(self) -> float:
        """Load every compiled kernel from numba's cache (or compile it: ``livetrack.estimator.warm``) unless done
        already; the seconds it took (``start`` calls it before acquisition begins)."""
        if self.warm_up_s is None:
            from livetrack.estimator import warm

            self.warm_up_s = warm.warm_up()
        return self.warm_up_s

    def start(self) -> None:
        """Open every sink (in its thread; raises if one fails, closing the others), then start acquisition."""
        if self._started:
            raise RuntimeError("pipeline already started")
        self._started = True
        self._start_ns = time.perf_counter_ns()
        started: list[SinkRunner] = []
        try:
            for runner in self.runners:
                runner.start(getattr(runner.sink, "open_timeout_s", 10.0))
                started.append(runner)
        except BaseException:
            for runner in started:
                runner.close(self.options.sink_close_timeout_s)
            self._closed = True
            self.source.close()
            raise
        self.warm_up()
        if self.search_worker:
            self._search.start()
        self._process.start()
        self._acquire.start()

    def stop(self, reason: str = "stop()") -> None:
        """Ask the pipeline to finish (thread- and signal-safe: only sets flags)."""
        if not self._stop.is_set():
            self._stopped_by = reason
            self._stop.set()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until processing has ended (source exhausted, max_frames, stop()); True if it has (or never
        started)."""
        if self._process.ident is None:
            return True
        self._process.join(timeout_s)
        return not self._process.is_alive()

    def run(self) -> RunSummary:
        """start(), wait (in short joins, so that signal handlers run in the main thread), close()."""
        self.start()
        try:
            while not self.wait(0.2):
                pass
        finally:
            summary = self.close()
        return summary

    def close(self) -> RunSummary:
        """Stop, join the threads, close the source and the sinks; returns the summary. Idempotent."""
        if self._summary is not None:
            return self._summary
        self.stop(self._stopped_by or "close()")
        if self._started and not self._closed:
            # acquisition may be waiting for the recorder (back-pressure): give it the time a sink has to drain
            self._acquire.join(self.options.read_timeout_s + 1.0 + self.options.sink_close_timeout_s)
            self._slot.close()
            self._process.join()
            self._requests.close()
            if self._search.ident is not None:  # a hung search is left behind (daemon thread), not waited for
                self._search.join(self.options.sink_close_timeout_s)
                if self._search.is_alive():
                    log.warning("the search thread did not finish within %.1f s; left running",
                                self.options.sink_close_timeout_s)
            for runner in self.runners:  # frame sinks first: closing their queues releases a waiting acquisition
                runner.close(self.options.sink_close_timeout_s)
            self._acquire.join(2.0)
            self._closed = True
            self._close_source()
        elif not self._started:
            self._closed = True
            self._close_source()
        self._summary = self._make_summary()
        return self._summary

    def _close_source(self) -> None:
        try:
            self.source.close()
        except Exception as exc:
            log.warning("closing the source: %r", exc)

    # ------------------------------------------------------------------ threads
    def _acquire_loop(self) -> None:
        max_frames = self.options.max_frames
        try:
            while not self._stop.is_set():
                if self.lossless and max_frames is not None and self._acquired >= max_frames:
                    break  # lossless: every acquired frame gets processed; no need to read more
                cpu0 = time.thread_time_ns()
                frame = self.source.read(self.options.read_timeout_s)
                self._read_cpu_ns += time.thread_time_ns() - cpu0
                if frame is None:
                    continue
                now = time.perf_counter_ns()
                if self._first_acquired_ns is None:
                    self._first_acquired_ns = now
                self._last_acquired_ns = now
                self._acquired += 1
                # tracking first: a recorder that makes acquisition wait (back-pressure) does not delay this frame
                handed = self._slot.put(frame, abort=self._stop)
                for runner in self._frame_sinks:
                    runner.submit(frame)
                if not handed:
                    break
        except EOFError:
            log.info("source exhausted after %d frames", self._acquired)
            if not self._stop.is_set():
                self._stopped_by = "end of source"
        except Exception as exc:  # SourceError or an unexpected failure: end the run, report it
            self._source_error = f"{type(exc).__name__}: {exc}"
            log.error("source failed: %s", exc)
            self.stop("source error")
        finally:
            self._slot.close()

    def _process_loop(self) -> None:
        max_frames = self.options.max_frames
        while True:
            try:
                frame = self._slot.get(0.5)
            except SlotClosed:
                break
            if frame is None:
                if self._stop.is_set():  # stopped and nothing came for 0.5 s: acquisition is done or stuck
                    break
                continue
            if max_frames is not None and self._processed >= max_frames:
                continue  # drain (live: frames acquired after the limit are not processed)
            self._process_frame(frame, time.perf_counter_ns())
            if max_frames is not None and self._processed >= max_frames:
                self.stop("max_frames")

    def _process_frame(self, frame: Frame, got_ns: int) -> None:
        """Track one frame and hand it to the sinks. ``got_ns``: perf_counter_ns when it left the slot."""
        start_ns = time.time_ns()
        cpu0 = time.thread_time_ns()
        t0 = time.perf_counter_ns()
        try:
            if self._frames_ahead:  # frames dropped since the last one: the tracker's motion prediction spans them
                ahead = _frame_gap(self._last_frame_id, frame.frame_id)
                self._last_frame_id = frame.frame_id
                result = self.tracker.process(frame.image, frame.exposure_us, frames_ahead=ahead)
            else:
                result = self.tracker.process(frame.image, frame.exposure_us)
        except Exception as exc:  # an unexpected estimator failure on one frame: count, log, go on
            self._process_errors += 1
            if self._process_errors in (1, 10, 100) or self._process_errors % 1000 == 0:
                log.error("frame %d: tracker failed (#%d): %r", frame.frame_id, self._process_errors, exc)
            return
        t1 = time.perf_counter_ns()
        stage = {"queue_ms": (start_ns - frame.host_timestamp_ns) / 1e6,
                 "detect_ms": result.timings_ms.get("detect_ms", float("nan")),
                 "pose_ms": result.timings_ms.get("pose_ms", float("nan")),
                 "track_ms": (t1 - t0) / 1e6,
                 "track_cpu_ms": (time.thread_time_ns() - cpu0) / 1e6}
        kind = "search" if "detect_ms" in result.timings_ms else "tracked"  # Tracker.process searched or tracked
        if self._first[kind] is None:
            self._first[kind] = stage["track_ms"]
        tracked, t2 = self._hand_out(frame, result, stage, t1)
        # time of this thread spent on the frame outside Tracker.process (bookkeeping included)
        outside_ms = ((t0 - got_ns) + (time.perf_counter_ns() - t1)) / 1e6
        self._stage.setdefault("outside_track_ms", deque(maxlen=STATS_WINDOW)).append(outside_ms)
        if self.on_processed is not None:
            self.on_processed(tracked)

    def _hand_out(self, frame: Frame, result: FrameResult, stage: dict[str, float],
                  t1: int) -> tuple[TrackedFrame, int]:
        """Hand ``frame`` with its ``result`` to every result sink and count it (latency, poses, stage times, with
        ``handoff_ms`` from ``t1``, a ``perf_counter_ns``). Returns the TrackedFrame and the ``perf_counter_ns``
        after the hand-off. Both processing paths (with and without the search worker) end here."""
        handoff_ns = time.time_ns()
        device_gap = handoff_ns - frame.timestamp_ns
        tracked = TrackedFrame(
            sequence=self._processed, frame=frame, result=result, stage_ms=stage, handoff_ns=handoff_ns,
            latency_ms=(handoff_ns - frame.host_timestamp_ns) / 1e6,
            device_latency_ms=device_gap / 1e6 if 0 <= device_gap < SAME_CLOCK_WINDOW_NS else None)
        for runner in self._result_sinks:
            runner.submit(tracked)
        t2 = time.perf_counter_ns()
        if self._processed == 0:
            self._first["latency"] = tracked.latency_ms
        self._processed += 1
        self._targets += len(result.targets)
        self._fits_ok += sum(1 for t in result.targets if t.fit.ok)
        self._latency.append(tracked.latency_ms)
        if result.targets:
            self._pose_latency.append(tracked.latency_ms)
        if tracked.device_latency_ms is not None:
            self._device_latency.append(tracked.device_latency_ms)
        stage["handoff_ms"] = (t2 - t1) / 1e6
        for key, value in stage.items():
            self._stage.setdefault(key, deque(maxlen=STATS_WINDOW)).append(value)
        if self._first_done_ns is None:
            self._first_done_ns = t2
        self._last_done_ns = t2
        return tracked, t2

    # ------------------------------------------------------------------ with a search worker
    def _process_loop_with_search(self) -> None:
        """Track each frame, hand searches to ``livetrack-search``, release frames in order (module docstring)."""
        max_frames = self.options.max_frames
        index = 0
        try:
            while True:
                with self._lock:
                    self._flush_locked()
                try:
                    frame = self._slot.get(self._wait_s())
                except SlotClosed:
                    break
                if frame is None:
                    if self._stop.is_set():
                        break
                    continue
                if max_frames is not None and self._processed >= max_frames:
                    continue  # drain (the frame that reached it stopped the run)
                self._track_frame(index, frame, time.perf_counter_ns())
                index += 1
        finally:
            # the searches asked for: let them finish (bounded), then everything goes out, in order
            deadline = time.monotonic() + self.options.sink_close_timeout_s
            while time.monotonic() < deadline:
                with self._lock:
                    self._flush_locked()
                    if not self._pending:
                        break
                time.sleep(0.002)
            dropped = self._requests.close()
            if dropped is not None:
                self._withdrawn(dropped[0])
            with self._lock:
                self._flush_locked(force=True)

    def _wait_s(self) -> float:
        """How long the processing thread may wait for a frame: until the oldest waiting frame's bound."""
        with self._lock:
            if not self._pending:
                return 0.5
            first = next(iter(self._pending.values()))
        left_s = (first.ready_ns + self.options.search_wait_ms * 1e6 - time.perf_counter_ns()) / 1e9
        return min(0.5, max(left_s, 0.001))

    def _adopt_found(self) -> None:
        """Let the tracker track from the searches that have finished (on this thread: it alone changes it)."""
        while True:
            with self._lock:
                if not self._found:
                    return
                index, outcome = self._found.popleft()
            if outcome is None:
                continue
            keep_current = (not self._tracks_failed and self._tracks_index is not None
                            and self._tracks_index > index)
            frame_id = self._searched_ids.pop(index, None)
            # the kept targets' motion to the searched frame, when they are from an earlier frame
            with_motion = (self._tracks_index is not None and self._tracks_index < index
                           and frame_id is not None and self._tracks_frame_id is not None)
            if self._frames_ahead:
                self.tracker.adopt(outcome, keep_current=keep_current, with_motion=with_motion,
                                   motion_frames=_frame_gap(self._tracks_frame_id, frame_id) if with_motion else 1)
            else:
                self.tracker.adopt(outcome, keep_current=keep_current, with_motion=with_motion)
            with self._lock:
                self._search_counts["adopted"] += 1
            if not keep_current:
                self._tracks_index, self._tracks_frame_id = index, frame_id
                # a search of a frame before the one where tracking failed does not end the searching
                self._tracks_failed = self._tracks_failed and index < self._failed_index

    def _track_frame(self, index: int, frame: Frame, got_ns: int) -> None:
        """Track one frame (or, with no target kept, only hand it to the search), queue it for release."""
        self._adopt_found()
        start_ns = time.time_ns()
        cpu0 = time.thread_time_ns()
        t0 = time.perf_counter_ns()
        tracked: FrameResult | None = None
        if not self._tracks_failed:
            try:
                if self._frames_ahead:
                    tracked = self.tracker.track(frame.image, frame.exposure_us,
                                                 frames_ahead=_frame_gap(self._tracks_frame_id, frame.frame_id))
                else:
                    tracked = self.tracker.track(frame.image, frame.exposure_us)
            except Exception as exc:  # an unexpected estimator failure: count, log, search the frame
                with self._lock:
                    self._process_errors += 1
                if self._process_errors in (1, 10, 100) or self._process_errors % 1000 == 0:
                    log.error("frame %d: tracker failed (#%d): %r", frame.frame_id, self._process_errors, exc)
            if tracked is None:
                self._tracks_failed, self._failed_index = True, index
            else:
                self._tracks_index, self._tracks_frame_id = index, frame.frame_id
        t1 = time.perf_counter_ns()
        if tracked is not None and self._first["tracked"] is None:
            self._first["tracked"] = (t1 - t0) / 1e6
        stage = {"queue_ms": (start_ns - frame.host_timestamp_ns) / 1e6, "track_ms": (t1 - t0) / 1e6,
                 "track_cpu_ms": (time.thread_time_ns() - cpu0) / 1e6}
        entry = _Pending(frame, tracked, stage, ready_ns=t1, awaiting=tracked is None)
        with self._lock:
            self._pending[index] = entry
        if tracked is not None:
            # a tracked frame: a search not yet started for an earlier frame would only be late (live sources);
            # a verify search runs only when the worker is idle
            cancelled = None if self.lossless else self._requests.cancel_before(index)
            if cancelled is not None:
                self._withdrawn(cancelled[0])
            if self.tracker.search_due and self._requests.idle:
                # a target lost while others stay tracked: a search for it alone (``Tracker.lost_search_due``)
                self._request_search(index, frame, lost_only=bool(getattr(self.tracker, "lost_search_due", False)))
        else:
            self._request_search(index, frame)
        outside_ms = ((t0 - got_ns) + (time.perf_counter_ns() - t1)) / 1e6
        with self._lock:
            self._stage.setdefault("outside_track_ms", deque(maxlen=STATS_WINDOW)).append(outside_ms)
            self._flush_locked()

    def _request_search(self, index: int, frame: Frame, lost_only: bool = False) -> None:
        self._searched_ids[index] = frame.frame_id
        if len(self._searched_ids) > 64:  # withdrawn requests' ids (bounded)
            self._searched_ids.pop(next(iter(self._searched_ids)))
        replaced = self._requests.put((index, frame, lost_only), abort=self._stop)
        with self._lock:
            self._search_counts["requested"] += 1
        if replaced is not None:
            self._withdrawn(replaced[0])

    def _withdrawn(self, index: int) -> None:
        """A search request withdrawn before it started: its frame waits no longer."""
        with self._lock:
            self._search_counts["replaced"] += 1
            old = self._pending.get(index)
            if old is not None:
                old.awaiting = False

    def _search_loop(self) -> None:
        while True:
            try:
                request = self._requests.take(0.5)
            except SlotClosed:
                return
            if request is None:
                continue
            index, frame, lost_only = request
            t0 = time.perf_counter_ns()
            outcome: SearchOutcome | None
            try:
                if lost_only:
                    outcome = self.tracker.search(frame.image, frame.exposure_us, lost_only=True)
                else:
                    outcome = self.tracker.search(frame.image, frame.exposure_us)
            except Exception as exc:  # count, log; the frame goes out without a search result
                outcome = None
                with self._lock:
                    self._search_counts["errors"] += 1
                    self._process_errors += 1
                log.error("frame %d: search failed: %r", frame.frame_id, exc)
            search_ms = (time.perf_counter_ns() - t0) / 1e6
            with self._lock:
                if self._first["search"] is None:
                    self._first["search"] = search_ms
                self._search_counts["run"] += 1
                self._found.append((index, outcome))
                entry = self._pending.get(index)
                if entry is not None and entry.awaiting:  # still in the buffer: merged into its frame
                    entry.awaiting = False
                    entry.stage["search_ms"] = search_ms
                    if outcome is not None:
                        entry.result = outcome.result
                        self._search_counts["merged"] += 1
                self._stage.setdefault("search_ms", deque(maxlen=STATS_WINDOW)).append(search_ms)
                self._flush_locked()
            self._requests.done()

    def _flush_locked(self, force: bool = False) -> None:
        """Hand out the frames at the head of the reorder buffer that may go out (call with ``_lock`` held): a
        frame waiting for its search holds the ones behind it; from a live source only until a tracked frame is
        behind it or it has waited ``search_wait_ms``: it then goes without the search's result (counted as late).
        A frame with no result (not tracked; its search withdrawn, late or failed) is dropped, counted with the
        frames dropped before processing: every frame handed out was tracked or searched."""
        if not self._pending:
            return
        now = time.perf_counter_ns()
        wait_ns = self.options.search_wait_ms * 1e6
        lossy = not self.lossless
        max_frames = self.options.max_frames
        last_tracked = max((i for i, e in self._pending.items() if e.tracked is not None), default=-1)
        while self._pending:
            index, entry = next(iter(self._pending.items()))
            if entry.awaiting:
                overtaken = lossy and (index < last_tracked or now - entry.ready_ns >= wait_ns)
                if not (force or overtaken):
                    break
                entry.awaiting = False
                self._search_counts["late"] += 1
            del self._pending[index]
            if entry.result is None or (max_frames is not None and self._processed >= max_frames):
                self._dropped_unprocessed += 1
                continue
            self._release_locked(entry)

    def _release_locked(self, entry: _Pending) -> None:
        """Hand a frame with its result to the result sinks (call with ``_lock`` held)."""
        frame, result = entry.frame, entry.result
        assert result is not None
        stage = dict(entry.stage)
        stage["detect_ms"] = result.timings_ms.get("detect_ms", float("nan"))
        stage["pose_ms"] = result.timings_ms.get("pose_ms", float("nan"))
        t1 = time.perf_counter_ns()
        stage["reorder_wait_ms"] = (t1 - entry.ready_ns) / 1e6
        tracked, _ = self._hand_out(frame, result, stage, t1)
        if self.options.max_frames is not None and self._processed >= self.options.max_frames:
            self.stop("max_frames")
        if self.on_processed is not None:
            self.on_processed(tracked)

    # ------------------------------------------------------------------ summary
    def _make_summary(self) -> RunSummary:
        duration_s = (time.perf_counter_ns() - self._start_ns) / 1e9 if self._start_ns else 0.0

        def rate(count: int, first: int | None, last: int | None) -> float:
            if count < 2 or first is None or last is None or last <= first:
                return 0.0
            return (count - 1) / ((last - first) / 1e9)

        lat = np.asarray(self._latency, dtype=np.float64)
        dev = np.asarray(self._device_latency, dtype=np.float64)
        pose = np.asarray(self._pose_latency, dtype=np.float64)
        try:
            source_stats = dict(self.source.stats)
        except Exception as exc:
            source_stats = {"stats_error": repr(exc)}
        return RunSummary(
            frames_acquired=self._acquired, frames_processed=self._processed, targets_found=self._targets,
            fits_ok=self._fits_ok, duration_s=duration_s,
            processing_fps=rate(self._processed, self._first_done_ns, self._last_done_ns),
            acquisition_fps=rate(self._acquired, self._first_acquired_ns, self._last_acquired_ns),
            dropped_before_processing=self._slot.dropped + self._dropped_unprocessed,
            read_cpu_ms_per_frame=self._read_cpu_ns / 1e6 / max(self._acquired, 1), process_errors=self._process_errors,
            stopped_by=self._stopped_by or "end", source_error=self._source_error,
            latency_ms={"p50": percentile(lat, 50), "p99": percentile(lat, 99),
                        "max": float(lat.max()) if lat.size else None},
            pose_latency_ms={"p50": percentile(pose, 50), "p99": percentile(pose, 99)},
            searches=dict(self._search_counts) if self.search_worker else {},
            device_latency_ms={"p50": percentile(dev, 50), "p99": percentile(dev, 99)},
            stage_ms={k: {"p50": percentile(np.asarray(v), 50), "p99": percentile(np.asarray(v), 99),
                          "mean": float(np.mean(v)) if v else None} for k, v in self._stage.items()},
            source_stats=source_stats,
            sinks={r.name: r.summary() for r in self.runners},
            warm_up_s=self.warm_up_s, first_frames_ms=dict(self._first),
        )


MAX_FRAME_GAP = 1000
"""Frame-id differences above this (or below 1: a source restarted, a camera's block id wrapped) count as 1."""


def _frame_gap(before: int | None, now: int | None) -> int:
    """Camera frames from frame id ``before`` to ``now`` (1 when unknown or implausible)."""
    if before is None or now is None or not 1 <= now - before <= MAX_FRAME_GAP:
        return 1
    return int(now - before)


def _takes(fn: Callable[..., Any], name: str) -> bool:
    """Whether ``fn`` takes a keyword argument ``name``."""
    try:
        return name in inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False


@dataclass
class _Pending:
    """A processed frame in the reorder buffer: its tracked result (None: not tracked), its stage times, when it
    was ready (perf_counter_ns), whether it waits for its search, and whether it went out without it."""

    frame: Frame
    tracked: FrameResult | None
    stage: dict[str, float]
    ready_ns: int
    awaiting: bool
    result: FrameResult | None = None

    def __post_init__(self) -> None:
        self.result = self.tracked


_Request = tuple[int, Frame, bool]
"""A search request: the frame's arrival index, the frame, and whether only the lost targets are searched for."""


class _SearchRequests:
    """The one-item hand-off to the search thread. Lossy: a newer request replaces one not yet taken (``put``
    returns it). Lossless: ``put`` waits until the last one was taken. ``idle``: nothing queued or running."""

    def __init__(self, lossless: bool):
        self.lossless = lossless
        self._cond = threading.Condition()
        self._item: _Request | None = None
        self._busy = False
        self._closed = False

    def put(self, item: _Request, abort: threading.Event) -> _Request | None:
        with self._cond:
            while self.lossless and self._item is not None and not self._closed and not abort.is_set():
                self._cond.wait(0.05)
            replaced, self._item = self._item, item
            self._cond.notify_all()
            return replaced

    def take(self, timeout_s: float) -> _Request | None:
        """The request (None after ``timeout_s``); SlotClosed once closed and empty. Marks the worker busy."""
        with self._cond:
            if self._item is None and not self._closed:
                self._cond.wait(timeout_s)
            if self._item is None:
                if self._closed:
                    raise SlotClosed
                return None
            item, self._item, self._busy = self._item, None, True
            self._cond.notify_all()
            return item

    def done(self) -> None:
        with self._cond:
            self._busy = False

    def cancel_before(self, index: int) -> _Request | None:
        """Withdraw a request not yet taken for a frame before ``index`` (returned)."""
        with self._cond:
            if self._item is None or self._item[0] >= index:
                return None
            item, self._item = self._item, None
            self._cond.notify_all()
            return item

    @property
    def idle(self) -> bool:
        with self._cond:
            return self._item is None and not self._busy

    def close(self) -> _Request | None:
        """No more requests; one not yet taken is dropped (returned)."""
        with self._cond:
            self._closed = True
            dropped, self._item = self._item, None
            self._cond.notify_all()
            return dropped


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


# ---------------------------------------------------------------------------------------------- assembly
def _search_worker_auto(lossless: bool, tracker_options: Any) -> bool:
    """``PipelineOptions.search_worker``'s auto: on for a live (not lossless) source and a tracker in tracking mode."""
    return not lossless and bool(getattr(tracker_options, "tracking", False))


def _tracker_options_for(options: TrackerOptions, source: FrameSource, lossless: bool | None, worker: bool | None
                         ) -> TrackerOptions:
    """``options`` with ``fit_target_model``'s auto (None) decided: off where a search holds up the frames behind it
    (a live source without a search worker: the 2-D model takes ~1-5 s per target, every frame would wait for it),
    else on. ``lossless``, ``worker``: the pipeline's settings (None: auto, as ``Pipeline`` decides them)."""
    if options.fit_target_model is not None:
        return options
    lossless = lossless if lossless is not None else not bool(source.live)
    worker = worker if worker is not None else _search_worker_auto(lossless, options)
    on = lossless or worker
    if not on:
        log.info("tracker.fit_target_model auto: off (a live source without a search worker: a search holds up the "
                 "frames behind it)")
    return replace(options, fit_target_model=on)


def build_pipeline(config: AppConfig, *, console: bool = True, search_worker: bool | None = None) -> Pipeline:
    """Open the configured source, build the Tracker and the enabled sinks, and connect them (not started).

    The camera and targets are the config's, else the source's. The resolved config (with the camera and
    targets actually used) is saved beside the recording (``livetrack-config.yaml`` inside it) and beside an
    .rrd output (``NAME.config.yaml``), and logged into Rerun. Raises ConfigError for a bad option or
    inconsistent camera / targets, SourceError when the source cannot be opened. ``search_worker``:
    ``PipelineOptions.search_worker``, True or False; None (default): the config's ``pipeline.search_worker``
    (auto: on for a live source in tracking mode).
    """
    from livetrack import __version__
    from livetrack.config.app import resolved_config_path
    from livetrack.sinks.factory import build_sinks
    from livetrack.sources import open_source

    check_outputs_spare_the_input(config)
    from livetrack.estimator import warm

    warm_up_s = warm.warm_up()  # before the source opens: a live source's frames do not wait for it
    try:
        source = open_source(config.source.uri, config.source.options)
    except ConfigError as exc:
        raise ConfigError(_source_key_path(exc.path), exc.problem) from None
    try:
        camera = config.camera or source.camera
        if camera is None:
            raise ConfigError("camera", f"the source {config.source.uri} has no camera model: give one")
        if config.camera is not None and source.camera is not None and (
                (config.camera.width, config.camera.height) != (source.camera.width, source.camera.height)):
            raise ConfigError("camera", f"is {config.camera.width}x{config.camera.height} but the source "
                                        f"delivers {source.camera.width}x{source.camera.height} images")
        targets = list(config.targets if config.targets is not None else source.targets)
        if not targets:
            raise ConfigError("targets", f"none configured and the source {config.source.uri} names none")
        p = config.pipeline
        worker = p.search_worker if search_worker is None else search_worker
        tracker = Tracker(camera, targets, _tracker_options_for(config.tracker, source, p.lossless, worker))
        config_text = config.to_yaml(camera, targets)
        if config.outputs.rerun.mode == "save" and config.outputs.rerun.argument:
            rrd = Path(config.outputs.rerun.argument)
            rrd.parent.mkdir(parents=True, exist_ok=True)
            resolved_config_path(rrd).write_text(config_text, encoding="utf-8")
        meta = {"written_by": f"livetrack {__version__} run", "source_uri": config.source.uri,
                "timestamp_ns_clock": "the source's device clock (host arrival in host_timestamp_ns, Unix ns)"}
        sinks, sizes = build_sinks(config, camera, targets, config_text, meta=meta, console=console)
        if config.exposure_control is not None:  # writes to the source: built here, where the source is
            from livetrack.sinks.exposure_control_sink import ExposureControlSink

            try:
                sinks.append(ExposureControlSink(source, 2**camera.bit_depth - 1, config.exposure_control,
                                                 encoding=camera.encoding))
            except ValueError as exc:
                raise ConfigError("exposure_control.enabled", str(exc)) from None
            sizes["exposure_control"] = 1
        options = PipelineOptions(max_frames=p.max_frames, lossless=p.lossless, slot_size=p.slot_size,
                                  read_timeout_s=p.read_timeout_s, sink_queue_size=p.sink_queue_size,
                                  sink_close_timeout_s=p.sink_close_timeout_s,
                                  search_worker=p.search_worker if search_worker is None else search_worker)
        pipeline = Pipeline(source, tracker, sinks, options, sink_queue_sizes=sizes)
    except BaseException:
        source.close()
        raise
    pipeline.config_text = config_text
    pipeline.warm_up_s = warm_up_s
    return pipeline


def check_outputs_spare_the_input(config: AppConfig) -> None:
    """A command never writes over what it reads: ConfigError if the recording directory (or an .rrd output) is
    the replayed recording, inside it, or holds it (paths resolved, symlinks followed), overwrite or not."""
    uri = config.source.uri
    if not uri.startswith("replay:"):
        return
    source_dir = Path(uri[len("replay:"):]).expanduser().resolve()
    outputs = []
    if config.outputs.record.dir is not None:
        outputs.append(("outputs.record.dir", Path(config.outputs.record.dir)))
    if config.outputs.rerun.mode == "save" and config.outputs.rerun.argument:
        outputs.append(("outputs.rerun.mode", Path(config.outputs.rerun.argument)))
    for key, out in outputs:
        out = out.expanduser().resolve()
        if out == source_dir or source_dir in out.parents or out in source_dir.parents:
            relation = ("is" if out == source_dir else "is inside" if source_dir in out.parents else "contains")
            raise ConfigError(key, f"{out} {relation} the recording being replayed ({source_dir}); livetrack "
                                   "never writes over what it reads: choose another directory")


def _source_key_path(path: str) -> str:
    """Sources name their options ``source.KEY``; in the app config they live under ``source.options``."""
    if path == "source":
        return "source.uri"
    if path.startswith("source."):
        return "source.options." + path[len("source."):]
    return path
