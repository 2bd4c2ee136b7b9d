"""Recording sink: every acquired frame written as a v1 recording (docs/recording-format.md).

A frame is on disk before the acquisition thread goes on: ``prepare`` (called by ``SinkRunner.submit`` in the
acquisition thread) spools it, i.e. writes its raw values as an uncompressed PGM and appends its frames.csv row
(``RecordingWriter.spool_frame``, a few ms), and hands a small ``SpooledFrame`` to the sink's queue; the sink's
own thread then encodes the PNG (40-200 ms at 1920x1200) and replaces the PGM by it (``handle`` ->
``RecordingWriter.convert``). The page cache outlives a killed process, so a ``kill -9`` loses at most the frame
being spooled, never the frames awaiting the encoder (before: up to ``queue_size`` frames held in memory).

The sink must not lose data (``lossless = True``): when the encoder cannot keep up and ``queue_size`` frames are
spooled, the acquisition thread waits for room (back-pressure) instead of dropping a frame; a live source then
drops at its own boundary (counted in its stats, and visible as gaps in the written ``frame_id``, which is the
source's id). Only at shutdown, if the writer is stuck beyond ``sink_close_timeout_s``, are queued frames left
unconverted (counted as dropped; their PGMs are on disk and read back). ``close()`` (also on SIGINT/SIGTERM)
converts what is still spooled and marks the recording complete.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

from livetrack.camera import CameraModel
from livetrack.geometry import Pose
from livetrack.recording import RecordingWriter
from livetrack.recording.writer import SpooledFrame
from livetrack.sources.base import Frame
from livetrack.targets.spec import TargetSpec

log = logging.getLogger(__name__)

CONFIG_FILE_NAME = "livetrack-config.yaml"


class RecordingSink:
    """Writes Frames to ``path`` with their exposure metadata, host timestamp and any ground truth."""

    consumes: Literal["frames"] = "frames"
    lossless = True  # back-pressure on acquisition instead of dropping (sinks.runner.SinkRunner)

    def __init__(self, path: str | os.PathLike, camera: CameraModel, targets: Sequence[TargetSpec],
                 meta: Mapping[str, Any] | None = None, *, overwrite: bool = False, png_compression: int = 1,
                 fsync_every_n_frames: int = 8, config_text: str | None = None, name: str = "record"):
        self.name = name
        self.path = Path(path)
        self._camera = camera
        self._targets = list(targets)
        self._target_ids = {t.id for t in self._targets}
        self._meta = dict(meta or {})
        self._overwrite = overwrite
        self._png_compression = png_compression
        self._fsync_every = fsync_every_n_frames
        self._config_text = config_text
        self._writer: RecordingWriter | None = None
        self._closed = False
        self._renumbered = 0
        self._spool_ns = 0  # time spent spooling (in the acquisition thread), in total and the longest
        self._spool_max_ns = 0

    def open(self) -> None:
        self._writer = RecordingWriter(self.path, self._camera, self._targets, meta=self._meta,
                                       overwrite=self._overwrite, fsync_every_n_frames=self._fsync_every,
                                       png_compression=self._png_compression)
        if self._config_text is not None:
            self._writer.write_text(CONFIG_FILE_NAME, self._config_text)
        log.info("recording acquired frames to %s", self.path)

    def prepare(self, item: Frame) -> SpooledFrame:
        """Spool the frame (raw PGM and its row, at once); called in the acquisition thread, before queueing."""
        assert self._writer is not None
        t0 = time.perf_counter_ns()
        truth = {tid: pose for tid, pose in (item.truth or {}).items()
                 if isinstance(pose, Pose) and tid in self._target_ids}
        # the source's id, so that frames dropped before the recorder show as gaps; a source whose ids go back
        # (a camera reopened, its counter reset) gets the next free id, its own kept in source_frame_id
        last = self._writer.last_frame_id
        frame_id = item.frame_id if isinstance(item.frame_id, int) and item.frame_id > last else last + 1
        if frame_id != item.frame_id:
            self._renumbered += 1
            if self._renumbered == 1:
                log.warning("%s: source frame id %r after %d: written as %d from here on (source_frame_id keeps "
                            "the source's)", self.path, item.frame_id, last, frame_id)
        spooled = self._writer.spool_frame(item.image, timestamp_ns=item.timestamp_ns,
                                           exposure_us=item.exposure_us, gain_db=item.gain_db,
                                           truth=truth or None, frame_id=frame_id,
                                           extra={"source_frame_id": item.frame_id,
                                                  "host_timestamp_ns": item.host_timestamp_ns})
        elapsed = time.perf_counter_ns() - t0
        self._spool_ns += elapsed
        self._spool_max_ns = max(self._spool_max_ns, elapsed)
        return spooled

    def handle(self, item: SpooledFrame | Frame) -> None:
        """Encode a spooled frame's PNG (a Frame handed over unprepared is spooled first)."""
        assert self._writer is not None
        spooled = item if isinstance(item, SpooledFrame) else self.prepare(item)
        self._writer.convert(spooled)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._closed = True
            log.info("%s: %d frames recorded", self.path, self._writer.frame_count)

    @property
    def stats(self) -> dict[str, Any]:
        written = self._writer.frame_count if self._writer else 0
        out: dict[str, Any] = {"written": written, "path": str(self.path), "closed": self._closed,
                               "spool_ms_mean": round(self._spool_ns / 1e6 / max(written, 1), 2),
                               "spool_ms_max": round(self._spool_max_ns / 1e6, 2)}
        if self._writer is not None and self._writer.spooled_count:
            out["unconverted"] = self._writer.spooled_count
        if self._renumbered:
            out["renumbered"] = self._renumbered
        return out
