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
- ``livetrack-sink-<name>``: one thread per sink owns it (``sinks.runner.SinkRunner``: open, handle, close) and
  reads its bounded queue (``sinks.runner.DropSlot``); a full queue drops its oldest item (counted): a slow result
  sink (viewer, network stream) never blocks tracking.

``Pipeline.run()`` returns a ``RunSummary`` (frames, fps, drops per stage, latency percentiles, stage times).
``stop()`` may be called from any thread or a signal handler: acquisition stops, the frames already acquired are
finished, sinks drain their queues (bounded by ``sink_close_timeout_s``) and are closed (the recording is marked
complete).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from livetrack.config_checks import ConfigError
from livetrack.estimator.tracker import Tracker
from livetrack.sinks.base import Sink, TrackedFrame
from livetrack.sinks.runner import STATS_WINDOW, DropSlot, SinkRunner, SlotClosed, percentile
from livetrack.sources.base import Frame, FrameSource

if TYPE_CHECKING:
    from livetrack.app_config import AppConfig

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
    """

    max_frames: int | None = None
    lossless: bool | None = None
    slot_size: int = 1
    read_timeout_s: float = 0.5
    sink_queue_size: int = 4
    sink_close_timeout_s: float = 10.0


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
    device_latency_ms: dict[str, float | None] = field(default_factory=dict)
    stage_ms: dict[str, dict[str, float | None]] = field(default_factory=dict)
    source_stats: dict[str, Any] = field(default_factory=dict)
    sinks: dict[str, dict[str, Any]] = field(default_factory=dict)

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
        self._process = threading.Thread(target=self._process_loop, name="livetrack-process", daemon=True)
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
        self._device_latency: deque[float] = deque(maxlen=STATS_WINDOW)
        self._stage: dict[str, deque[float]] = {}
        self.on_processed: Callable[[TrackedFrame], None] | None = None  # test hook, called in the process thread
        self.config_text: str | None = None  # the resolved config, when built by build_pipeline

    @property
    def lossless(self) -> bool:
        return self._slot.lossless

    @property
    def runners(self) -> list[SinkRunner]:
        return self._frame_sinks + self._result_sinks

    # ------------------------------------------------------------------ control
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
        handoff_ns = time.time_ns()
        device_gap = handoff_ns - frame.timestamp_ns
        tracked = TrackedFrame(
            sequence=self._processed, frame=frame, result=result, stage_ms=stage, handoff_ns=handoff_ns,
            latency_ms=(handoff_ns - frame.host_timestamp_ns) / 1e6,
            device_latency_ms=device_gap / 1e6 if 0 <= device_gap < SAME_CLOCK_WINDOW_NS else None)
        for runner in self._result_sinks:
            runner.submit(tracked)
        t2 = time.perf_counter_ns()
        self._processed += 1
        self._targets += len(result.targets)
        self._fits_ok += sum(1 for t in result.targets if t.fit.ok)
        self._latency.append(tracked.latency_ms)
        if tracked.device_latency_ms is not None:
            self._device_latency.append(tracked.device_latency_ms)
        stage["handoff_ms"] = (t2 - t1) / 1e6
        for key, value in stage.items():
            self._stage.setdefault(key, deque(maxlen=STATS_WINDOW)).append(value)
        if self._first_done_ns is None:
            self._first_done_ns = t2
        self._last_done_ns = t2
        # time of this thread spent on the frame outside Tracker.process (bookkeeping included)
        outside_ms = ((t0 - got_ns) + (time.perf_counter_ns() - t1)) / 1e6
        self._stage.setdefault("outside_track_ms", deque(maxlen=STATS_WINDOW)).append(outside_ms)
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
        try:
            source_stats = dict(self.source.stats)
        except Exception as exc:
            source_stats = {"stats_error": repr(exc)}
        return RunSummary(
            frames_acquired=self._acquired, frames_processed=self._processed, targets_found=self._targets,
            fits_ok=self._fits_ok, duration_s=duration_s,
            processing_fps=rate(self._processed, self._first_done_ns, self._last_done_ns),
            acquisition_fps=rate(self._acquired, self._first_acquired_ns, self._last_acquired_ns),
            dropped_before_processing=self._slot.dropped,
            read_cpu_ms_per_frame=self._read_cpu_ns / 1e6 / max(self._acquired, 1), process_errors=self._process_errors,
            stopped_by=self._stopped_by or "end", source_error=self._source_error,
            latency_ms={"p50": percentile(lat, 50), "p99": percentile(lat, 99),
                        "max": float(lat.max()) if lat.size else None},
            device_latency_ms={"p50": percentile(dev, 50), "p99": percentile(dev, 99)},
            stage_ms={k: {"p50": percentile(np.asarray(v), 50), "p99": percentile(np.asarray(v), 99),
                          "mean": float(np.mean(v)) if v else None} for k, v in self._stage.items()},
            source_stats=source_stats,
            sinks={r.name: r.summary() for r in self.runners},
        )


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


# ---------------------------------------------------------------------------------------------- assembly
def build_pipeline(config: AppConfig, *, console: bool = True) -> Pipeline:
    """Open the configured source, build the Tracker and the enabled sinks, and connect them (not started).

    The camera and targets are the config's, else the source's. The resolved config (with the camera and
    targets actually used) is saved beside the recording (``livetrack-config.yaml`` inside it) and beside an
    .rrd output (``NAME.config.yaml``), and logged into Rerun. Raises ConfigError for a bad option or
    inconsistent camera / targets, SourceError when the source cannot be opened.
    """
    from livetrack import __version__
    from livetrack.app_config import resolved_config_path
    from livetrack.sinks.factory import build_sinks
    from livetrack.sources import open_source

    check_outputs_spare_the_input(config)
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
        tracker = Tracker(camera, targets, config.tracker)
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
                sinks.append(ExposureControlSink(source, 2**camera.bit_depth - 1, config.exposure_control))
            except ValueError as exc:
                raise ConfigError("exposure_control.enabled", str(exc)) from None
            sizes["exposure_control"] = 1
        p = config.pipeline
        options = PipelineOptions(max_frames=p.max_frames, lossless=p.lossless, slot_size=p.slot_size,
                                  read_timeout_s=p.read_timeout_s, sink_queue_size=p.sink_queue_size,
                                  sink_close_timeout_s=p.sink_close_timeout_s)
        pipeline = Pipeline(source, tracker, sinks, options, sink_queue_sizes=sizes)
    except BaseException:
        source.close()
        raise
    pipeline.config_text = config_text
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
