"""Names, records and checks shared by the recording reader and writer (format v1, see
docs/recording-format.md)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from livetrack.camera import CameraModel

FORMAT_NAME = "livetrack-recording"
FORMAT_VERSION = 1
RECORDING_YAML = "recording.yaml"
FRAMES_CSV = "frames.csv"
TRUTH_CSV = "truth.csv"
FRAMES_DIR = "frames"
SPOOL_SUFFIX = ".pgm"  # a spooled frame's raw image (binary PGM) beside its PNG's name, until the PNG is there
FRAME_COLUMNS = ("frame_id", "timestamp_ns", "exposure_us", "gain_db", "file")
TRUTH_COLUMNS = ("frame_id", "target_id", "tx_m", "ty_m", "tz_m", "qx", "qy", "qz", "qw")


class RecordingError(ValueError):
    """A recording (or one of its files) is unusable. ``str()`` names the file, the line if any, and why."""

    def __init__(self, file: str | os.PathLike, problem: str, line: int | None = None):
        self.file = str(file)
        self.line = line
        self.problem = problem
        where = self.file if line is None else f"{self.file} line {line}"
        super().__init__(f"{where}: {problem}")


@dataclass(frozen=True)
class FrameRecord:
    """One row of ``frames.csv``.

    ``file`` is the image path relative to the recording directory, with ``/`` separators.
    ``exposure_us`` / ``gain_db`` are None when unknown (an empty cell).
    ``extra`` maps every further column of ``frames.csv`` to its text (values are kept as written, unparsed).
    """

    frame_id: int
    timestamp_ns: int
    exposure_us: float | None
    gain_db: float | None
    file: str
    extra: Mapping[str, str] = field(default_factory=dict)


def image_problem(image: object, camera: CameraModel) -> str | None:
    """Why ``image`` is not a valid frame of ``camera`` (shape, dtype, value range), or None if it is.

    Valid: a (height, width) array, uint8 if ``camera.bit_depth == 8`` else uint16 holding LSB-aligned
    ``bit_depth``-bit values (no value above ``2**bit_depth - 1``).
    """
    if not isinstance(image, np.ndarray):
        return f"image must be a numpy array, got {type(image).__name__}"
    if image.ndim != 2:
        return f"image must be single-channel (height, width), got shape {image.shape}"
    if image.shape != (camera.height, camera.width):
        return (f"image size {image.shape[1]}x{image.shape[0]} does not match the camera's "
                f"{camera.width}x{camera.height}")
    expected = np.uint8 if camera.bit_depth == 8 else np.uint16
    if image.dtype != expected:
        return (f"wrong bit depth: image dtype is {image.dtype}, camera bit_depth {camera.bit_depth} "
                f"needs {np.dtype(expected).name}")
    if camera.bit_depth not in (8, 16) and image.size:
        peak = int(image.max())
        if peak > camera.saturation_level:
            return (f"wrong bit depth: value {peak} exceeds the {camera.bit_depth}-bit maximum "
                    f"{camera.saturation_level} (values must be LSB-aligned)")
    return None


def fsync_dir(directory: Path) -> None:
    """Make a rename or file creation in ``directory`` durable (no-op where directories cannot be opened)."""
    if os.name != "posix":
        return
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
