"""Recording sink: every acquired frame written as a v1 recording (docs/recording-format.md), in its own thread.

PNG encoding takes 40-200 ms per frame, so this sink is fed straight from the acquisition thread through its
own bounded queue. The sink must not lose data (``lossless = True``): when the disk or the encoder cannot keep up
and the queue is full, the acquisition thread waits for room (back-pressure) instead of dropping a frame, so every
acquired frame is written; a live source then drops at its own boundary (counted in its stats, and visible as
gaps in the written ``frame_id``, which is the source's id). Only at shutdown, if the writer is stuck beyond
``sink_close_timeout_s``, are queued frames discarded, with a warning and counted. ``RecordingWriter`` is
crash-safe: a kill at any moment leaves a recording readable up to the last complete frame; ``close()`` (also on
SIGINT/SIGTERM) marks it complete.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

from livetrack.camera import CameraModel
from livetrack.geometry import Pose
from livetrack.recording import RecordingWriter
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
                 fsync_every_n_frames: int = 1, config_text: str | None = None, name: str = "record"):
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

    def open(self) -> None:
        self._writer = RecordingWriter(self.path, self._camera, self._targets, meta=self._meta,
                                       overwrite=self._overwrite, fsync_every_n_frames=self._fsync_every,
                                       png_compression=self._png_compression)
        if self._config_text is not None:
            self._writer.write_text(CONFIG_FILE_NAME, self._config_text)
        log.info("recording acquired frames to %s", self.path)

    def handle(self, item: Frame) -> None:
        assert self._writer is not None
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
        self._writer.write_frame(item.image, timestamp_ns=item.timestamp_ns, exposure_us=item.exposure_us,
                                 gain_db=item.gain_db, truth=truth or None, frame_id=frame_id,
                                 extra={"source_frame_id": item.frame_id,
                                        "host_timestamp_ns": item.host_timestamp_ns})

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._closed = True
            log.info("%s: %d frames recorded", self.path, self._writer.frame_count)

    @property
    def stats(self) -> dict[str, Any]:
        out: dict[str, Any] = {"written": self._writer.frame_count if self._writer else 0, "path": str(self.path),
                               "closed": self._closed}
        if self._renumbered:
            out["renumbered"] = self._renumbered
        return out
