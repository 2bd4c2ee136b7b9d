"""The one protocol every frame source implements, and the frame record it yields.

Sources sit at the edge of livetrack: they own cameras, files and timing. At the camera boundary they copy the
image out and give the driver's buffer back at once; no processing happens there.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.targets.spec import TargetSpec


@dataclass(frozen=True)
class Frame:
    """One acquired image with the exposure metadata in force when it was taken.

    image: (H, W) uint8 or uint16 (``bit_depth``-bit values, LSB-aligned), owned by the frame (a copy).
    frame_id: the source's counter, monotonically increasing (wrapped device ids are unwrapped by the source).
    timestamp_ns: device time of the exposure (or the recording's / simulation's time), nanoseconds.
    host_timestamp_ns: ``time.time_ns()`` when the frame reached livetrack.
    exposure_us, gain_db: the values in force for this frame (from chunk data or register read-back); None when
        unknown (a camera without the feature, a recording with an empty cell): the one spelling of "unknown",
        never NaN.
    truth: ground-truth poses when the source knows them (simulation, recordings with truth.csv).
    """

    image: npt.NDArray[np.unsignedinteger]
    frame_id: int
    timestamp_ns: int
    host_timestamp_ns: int
    exposure_us: float | None
    gain_db: float | None
    truth: dict[int, Any] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)


class SourceError(RuntimeError):
    """A source cannot be opened or has failed for good (after its own retries)."""


class FrameSource(Protocol):
    """``open()`` once, ``read()`` repeatedly, ``close()`` once (also usable as a context manager).

    read(timeout_s) returns the next Frame, or None on a timeout (a live camera with no frame yet, a camera
    being reconnected); raises EOFError when a finite source (replay, a simulation with max frames) is exhausted.
    ``live`` is True for sources whose frames keep coming whether read or not (cameras, the paced simulator):
    the pipeline drops the oldest frame for them; replay is lossless. ``stats`` counts what the source saw
    (frames, lost packets, reconnects, skipped corrupt frames, ...).
    """

    camera: CameraModel
    targets: list[TargetSpec]
    live: bool

    def open(self) -> None: ...

    def read(self, timeout_s: float = 1.0) -> Frame | None: ...

    def close(self) -> None: ...

    @property
    def stats(self) -> dict[str, int]: ...


class ThreadedCameraSource:
    """``read``, ``close`` and the context manager of a live camera source whose named acquisition thread
    (``self._thread``) fills a ``LatestSlot`` (``self._slot``) until ``self._stop`` is set, and records a fatal
    error in ``self._error``. Subclasses implement ``open`` (which starts the thread) and ``_release`` (free the
    device after the thread has stopped)."""

    name: str
    _thread: Any
    _slot: Any
    _stop: Any
    _error: BaseException | None

    def open(self) -> None:
        raise NotImplementedError

    def _release(self) -> None:
        raise NotImplementedError

    def read(self, timeout_s: float = 1.0) -> Frame | None:
        if self._thread is None:
            raise SourceError(f"{self.name}: not open")
        frame = self._slot.get(timeout_s)
        if frame is None and self._error is not None:
            raise SourceError(f"{self.name}: acquisition failed: {self._error}") from self._error
        return frame

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self._release()
        self._slot.close()

    def __enter__(self):
        if self._thread is None:
            self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
