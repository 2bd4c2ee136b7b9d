"""``replay:DIR`` -- a recording (format v1, docs/recording-format.md) read back frame by frame.

Lossless (``live = False``): every readable frame is delivered once, in file order. ``pace: recorded`` (default)
delivers frame k at ``t0 + (timestamp_ns[k] - timestamp_ns[0])`` of the host's monotonic clock, t0 being the
first read; ``pace: fast`` as fast as the reader reads. A frame whose image is missing, truncated or of the wrong
size is logged, skipped and counted in ``stats["skipped"]`` (with the rows the reader rejected at open);
``read`` raises EOFError after the last frame. Truth poses (truth.csv) are attached when the recording has them.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.config import checks as cc
from livetrack.recording import FrameRecord, Recording, RecordingError
from livetrack.sources.base import Frame, SourceError
from livetrack.targets.spec import TargetSpec

log = logging.getLogger(__name__)

OPTIONS = ["pace", "max_frames"]
PACES = ("recorded", "fast")


class ReplaySource:
    """A recording as a frame source (module docstring).

    Parameters
    ----------
    path : the recording directory.
    pace : "recorded" (the recorded frame intervals) or "fast" (no waiting).
    max_frames : stop (EOFError) after this many delivered frames; None = the whole recording.
    """

    live = False

    def __init__(self, path: str | Path, *, pace: str = "recorded", max_frames: int | None = None):
        if pace not in PACES:
            raise cc.ConfigError("source.pace", f"must be one of {list(PACES)}, got {pace!r}")
        self.path = Path(path)
        self.pace = pace
        self.max_frames = max_frames
        self.recording: Recording | None = None
        self.camera: CameraModel | None = None  # type: ignore[assignment]
        self.targets: list[TargetSpec] = []
        self._frames: Iterator[tuple[FrameRecord, npt.NDArray[np.unsignedinteger]]] | None = None
        self._pending: tuple[FrameRecord, npt.NDArray[np.unsignedinteger]] | None = None
        self._t0: tuple[float, int] | None = None  # (host monotonic s, recording timestamp_ns) at the first frame
        self._delivered = 0

    @classmethod
    def from_options(cls, argument: str, options: Mapping[str, Any]) -> ReplaySource:
        cc.mapping(options, "source", optional=OPTIONS)
        if not argument:
            raise cc.ConfigError("source", "replay needs a directory: replay:DIR")
        max_frames = (cc.integer(options, "max_frames", "source", ge=0)
                      if options.get("max_frames") is not None else None)
        return cls(argument, pace=cc.string(options, "pace", "source", default="recorded", choices=PACES),
                   max_frames=max_frames)

    # ------------------------------------------------------------------ protocol
    def open(self) -> None:
        if self.recording is not None:
            raise SourceError(f"replay:{self.path}: already open")
        try:
            self.recording = Recording.open(self.path)
        except RecordingError as exc:
            raise SourceError(f"replay:{self.path}: {exc}") from exc
        self.camera = self.recording.camera
        self.targets = list(self.recording.targets)
        self._frames = self.recording.iter_images()
        log.info("replay: %s, %d frames, pace %s", self.path, len(self.recording), self.pace)

    def read(self, timeout_s: float = 1.0) -> Frame | None:
        if self._frames is None:
            raise SourceError(f"replay:{self.path}: not open")
        if self.max_frames is not None and self._delivered >= self.max_frames:
            raise EOFError(f"replay:{self.path}: max_frames reached")
        if self._pending is None:
            self._pending = next(self._frames, None)
            if self._pending is None:
                raise EOFError(f"replay:{self.path}: end of recording")
        record, image = self._pending
        if self.pace == "recorded":
            now = time.monotonic()
            if self._t0 is None:
                self._t0 = (now, record.timestamp_ns)
            wait_s = self._t0[0] + (record.timestamp_ns - self._t0[1]) * 1e-9 - now
            if wait_s > timeout_s:
                time.sleep(max(0.0, timeout_s))
                return None
            if wait_s > 0:
                time.sleep(wait_s)
        self._pending = None
        self._delivered += 1
        assert self.recording is not None
        return Frame(image=image, frame_id=record.frame_id, timestamp_ns=record.timestamp_ns,
                     host_timestamp_ns=time.time_ns(), exposure_us=record.exposure_us, gain_db=record.gain_db,
                     truth=self.recording.truth(record.frame_id), meta=dict(record.extra))

    def close(self) -> None:
        self._frames = None
        self._pending = None

    def __enter__(self) -> ReplaySource:
        if self.recording is None:
            self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def stats(self) -> dict[str, int]:
        skipped = len(self.recording.skipped) if self.recording is not None else 0
        return {"frames": self._delivered, "skipped": skipped}
