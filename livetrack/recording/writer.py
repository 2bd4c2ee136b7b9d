"""Write a recording directory (format v1) frame by frame, crash-safely.

Order of operations, so that a crash or kill at any moment leaves a readable recording:

1. at open, ``recording.yaml`` is written atomically (temp file + ``os.replace``) with ``complete: false``;
2. per frame, the PNG is written to a temp name in ``frames/`` and renamed into place, then its rows are
   appended to ``truth.csv`` (if any) and ``frames.csv`` and flushed: a row never names an image that is not
   on disk, and at most the last row can be torn (the reader drops it);
3. at close (also on ``__exit__`` after an exception) everything is fsynced and ``recording.yaml`` is
   rewritten atomically with ``complete: true`` and ``frame_count`` -- unless writing a CSV row failed: the
   recording then stays incomplete, so the reader drops a torn line.

Spooling (``spool_frame`` then ``convert``, what ``livetrack run --record`` does): PNG encoding is far slower than
a camera (1920x1200: 50-130 ms a frame against 17 ms at 60 fps), so a recorder that encodes before anything is
on disk holds the frames it has not encoded yet in memory, and a killed process loses them. ``spool_frame``
writes the frame's raw values at once as an uncompressed binary PGM (``frames/NNNNNN.pgm``, temp + rename, a few
ms) and appends its rows, which name the final ``frames/NNNNNN.png``; ``convert`` (later, in another thread)
reads the PGM back, encodes the PNG, renames it into place and deletes the PGM. No image is held in memory
meanwhile: how many frames may wait is a matter of disk space. The reader reads a row's PGM while its PNG is not
there (docs/recording-format.md, "Spooled frames"). A file written and renamed is in the kernel's page cache:
it survives a killed process (not a power loss: that needs fsync). ``close()`` converts what is still spooled,
so a complete recording holds PNGs only.

Flushing makes rows survive a killed process. Surviving power loss needs fsync, see ``fsync_every_n_frames``.

Replacing a recording (``overwrite=True``) never loses the old one before the new one is complete: the new
recording is written into a hidden sibling directory (``.NAME.new-XXXX``) and moved into place by ``close()``
(rename the old one aside, rename the new one in, delete the old one). A run that fails or is killed leaves the
old recording where it was and the new, readable but incomplete, one in the sibling directory.
"""

from __future__ import annotations

import contextlib
import csv
import logging
import math
import os
import shutil
import stat
import tempfile
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import cv2
import numpy as np
import numpy.typing as npt
import yaml

from livetrack.camera import CameraModel
from livetrack.geometry import Pose
from livetrack.recording._format import (
    FORMAT_NAME,
    FORMAT_VERSION,
    FRAME_COLUMNS,
    FRAMES_CSV,
    FRAMES_DIR,
    RECORDING_YAML,
    SPOOL_SUFFIX,
    TRUTH_COLUMNS,
    TRUTH_CSV,
    fsync_dir,
    image_problem,
)
from livetrack.targets.spec import TargetSpec

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SpooledFrame:
    """A frame written raw by ``RecordingWriter.spool_frame`` and listed in frames.csv, awaiting ``convert``."""

    frame_id: int
    file: str  # the final image path in the recording, frames/NNNNNN.png (the PGM: .pgm instead of .png)


class RecordingWriter:
    """Writes images, their metadata and optional truth poses to a new recording directory.

    Parameters
    ----------
    path : directory to create (parents too). An existing non-empty directory is refused unless
        ``overwrite=True``, and even then only if it holds a ``recording.yaml``: the new recording is then
        written beside it and replaces it at ``close()`` (module docstring), so a failed run keeps the old one.
    camera, targets : stored in ``recording.yaml``; images must match ``camera`` (size, bit depth), truth
        poses must name ids of ``targets``.
    meta : free mapping of plain YAML data (str, numbers, lists, dicts) stored as ``meta``.
    fsync_every_n_frames : fsync image, directory and CSV files every N frames (default 1: every frame; for
        spooled frames, every N converted frames). Frames up to the last fsync survive a power loss; without
        fsync they survive a killed process only (the page cache outlives the process). Cost: a few ms per fsync
        on an SSD (lost in the PNG encoding time here), far more on SD cards or network disks. 0 = fsync only at
        close. Spooled frames (PGM) are never fsynced: a power loss can lose those not yet converted.
    png_compression : zlib level 0..9 (default 1); lossless at every level. Encoding dominates the cost of a
        frame: measured 34 ms for 1280x1024 8-bit and 190 ms for 2448x2048 12-bit at level 1 (one core).
        Level 0 is ~2.3x faster with files ~1.6-2.2x larger; levels 3-6 save under 4 % for 1.3-5x the time.

    Use as a context manager; ``close()`` marks the recording complete.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        camera: CameraModel,
        targets: Sequence[TargetSpec],
        meta: Mapping[str, Any] | None = None,
        *,
        overwrite: bool = False,
        fsync_every_n_frames: int = 1,
        png_compression: int = 1,
    ):
        if not isinstance(camera, CameraModel):
            raise TypeError(f"camera must be a CameraModel, got {type(camera).__name__}")
        targets = list(targets)
        if not all(isinstance(t, TargetSpec) for t in targets):
            raise TypeError("targets must be TargetSpec objects")
        ids = [t.id for t in targets]
        if len(set(ids)) != len(ids):
            raise ValueError(f"duplicate target ids in {ids}")
        if meta is not None and not isinstance(meta, Mapping):
            raise TypeError(f"meta must be a mapping, got {type(meta).__name__}")
        if fsync_every_n_frames < 0:
            raise ValueError(f"fsync_every_n_frames must be >= 0, got {fsync_every_n_frames}")
        if not 0 <= png_compression <= 9:
            raise ValueError(f"png_compression must be in 0..9, got {png_compression}")
        self.path = Path(path)
        self.camera = camera
        self._target_ids = set(ids)
        self._fsync_every = fsync_every_n_frames
        self._png_params = [cv2.IMWRITE_PNG_COMPRESSION, png_compression]
        self._header: dict[str, Any] = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "complete": False,
            "camera": camera.to_dict(),
            "targets": [t.to_dict() for t in targets],
        }
        if meta is not None:
            self._header["meta"] = dict(meta)
        try:
            yaml.safe_dump(self._header)
        except yaml.YAMLError as exc:
            raise ValueError(f"meta must hold plain YAML data (str, int, float, bool, list, dict): "
                             f"{exc}") from None

        self._replaces = _prepare_directory(self.path, overwrite)
        # where the files go: the final directory, or a sibling that replaces it at close()
        self.directory = (Path(tempfile.mkdtemp(prefix=f".{self.path.name}.new-", dir=self.path.parent))
                          if self._replaces else self.path)
        if self._replaces:
            os.chmod(self.directory, stat.S_IMODE(self.path.stat().st_mode))  # mkdtemp makes it 0700
            log.info("%s: writing the new recording to %s; it replaces the existing one when complete",
                     self.path, self.directory)
        self._frames_dir = self.directory / FRAMES_DIR
        self._frames_dir.mkdir()
        self._write_header()
        self._frames_file: IO[str] | None = None
        self._truth_file: IO[str] | None = None
        self._frames_csv: Any = None
        self._truth_csv: Any = None
        self._extra_columns: list[str] | None = None
        self._count = 0
        self._last_id = -1
        self._closed = False
        self._failed = False
        self._converted = 0  # spooled frames converted to PNG (counts towards fsync_every_n_frames)
        self._pending: dict[int, SpooledFrame] = {}  # spooled, not yet converted, by frame_id
        # spool_frame (the acquisition thread) and convert / close (the recorder's thread) share the CSV files
        self._lock = threading.RLock()

    # ------------------------------------------------------------------ public
    @property
    def frame_count(self) -> int:
        """Frames written so far (listed in frames.csv, spooled ones included)."""
        return self._count

    @property
    def spooled_count(self) -> int:
        """Spooled frames not yet converted to PNG."""
        return len(self._pending)

    @property
    def last_frame_id(self) -> int:
        """The id of the last frame written (-1 before the first)."""
        return self._last_id

    def write_frame(
        self,
        image: npt.NDArray[np.uint8] | npt.NDArray[np.uint16],
        *,
        timestamp_ns: int,
        exposure_us: float | None,
        gain_db: float | None,
        truth: Mapping[int, Pose] | None = None,
        extra: Mapping[str, Any] | None = None,
        frame_id: int | None = None,
    ) -> int:
        """Append one frame; returns its frame_id.

        ``frame_id``: the id to write (e.g. the source's, so that frames the source dropped show as gaps);
        must be greater than the previous frame's. None: the previous id + 1 (0, 1, 2, ... by default).

        ``image`` is (height, width) uint8 (bit_depth 8) or uint16 (LSB-aligned values). ``truth`` maps
        target id -> target-to-camera Pose. ``extra`` adds frames.csv columns: the first frame's keys fix the
        columns; later frames may leave some out (written empty) but not add new ones. ``exposure_us`` and
        ``gain_db`` None (unknown) are written as empty cells (NaN is refused: None is the one spelling).
        Raises ValueError, writing nothing, if any argument is invalid.
        """
        with self._lock:
            frame_id, row, truth_rows, extra_columns = self._rows(image, timestamp_ns, exposure_us, gain_db, truth,
                                                                  extra, frame_id)
            durable = self._fsync_every > 0 and (self._count + 1) % self._fsync_every == 0
            self._write_png(image, frame_id, row[4], durable)
            self._append_rows(frame_id, row, truth_rows, extra_columns, durable)
            return frame_id

    def spool_frame(
        self,
        image: npt.NDArray[np.uint8] | npt.NDArray[np.uint16],
        *,
        timestamp_ns: int,
        exposure_us: float | None,
        gain_db: float | None,
        truth: Mapping[int, Pose] | None = None,
        extra: Mapping[str, Any] | None = None,
        frame_id: int | None = None,
    ) -> SpooledFrame:
        """Append one frame as ``write_frame`` does, but write its image raw (uncompressed PGM, a few ms) instead
        of encoding the PNG: pass the result to ``convert`` later (any thread). The frame is listed at once and
        reads back (the reader falls back to the PGM); it survives a killed process from the moment this
        returns. Same arguments and checks as ``write_frame``."""
        with self._lock:
            frame_id, row, truth_rows, extra_columns = self._rows(image, timestamp_ns, exposure_us, gain_db, truth,
                                                                  extra, frame_id)
            final = self.directory / row[4]
            spool = final.with_suffix(SPOOL_SUFFIX)
            temp = self._frames_dir / f".{spool.name}.tmp"
            header = f"P5\n{image.shape[1]} {image.shape[0]}\n{self.camera.saturation_level}\n".encode("ascii")
            # PGM holds 16-bit samples big-endian
            data = np.ascontiguousarray(image if image.dtype == np.uint8 else image.astype(">u2"))
            try:
                with open(temp, "wb") as f:
                    f.write(header)
                    f.write(data.data)
                os.replace(temp, spool)
            except BaseException:
                with contextlib.suppress(OSError):
                    temp.unlink()
                raise
            self._append_rows(frame_id, row, truth_rows, extra_columns, durable=False)
            spooled = SpooledFrame(frame_id, row[4])
            self._pending[frame_id] = spooled
            return spooled

    def convert(self, spooled: SpooledFrame) -> None:
        """Encode a spooled frame's PNG, rename it into place, delete its PGM; fsync every
        ``fsync_every_n_frames`` conversions. No-op if it was converted already. On failure (disk full) the PGM
        stays and the frame still reads back; ``close()`` tries again."""
        with self._lock:
            if self._pending.get(spooled.frame_id) is not spooled:
                return
            durable = self._fsync_every > 0 and (self._converted + 1) % self._fsync_every == 0
        spool = (self.directory / spooled.file).with_suffix(SPOOL_SUFFIX)
        # read back (from the page cache, ~1 ms at 1920x1200): the spool holds no image in memory, so a long one
        # (queue_size) costs disk, not RAM
        image = cv2.imread(str(spool), cv2.IMREAD_UNCHANGED)
        problem = "cannot be read" if image is None else image_problem(image, self.camera)
        if problem:
            raise ValueError(f"frame {spooled.frame_id}: its spooled image {spool.name} {problem}")
        self._write_png(image, spooled.frame_id, spooled.file, durable)  # outside the lock: slow
        spool.unlink()
        with self._lock:
            self._pending.pop(spooled.frame_id, None)
            self._converted += 1
        if durable and not self._failed:
            self._fsync_files()

    def write_text(self, name: str, text: str) -> None:
        """Write a side file (e.g. the config of the run) into the recording, atomically."""
        if "/" in name or name in ("", ".", "..", RECORDING_YAML, FRAMES_CSV, TRUTH_CSV, FRAMES_DIR):
            raise ValueError(f"side file name {name!r} must be a plain file name other than the format's")
        temp = self.directory / f".{name}.tmp"
        temp.write_text(text, encoding="utf-8")
        os.replace(temp, self.directory / name)

    def close(self, *, replace: bool = True) -> None:
        """Fsync everything and mark the recording complete. Idempotent.

        If writing a CSV row failed (disk full, interrupted), the files are closed but the recording stays
        ``complete: false``: its last line may be torn. When replacing a recording (``overwrite``), the new one
        takes the old one's place only if ``replace`` (``__exit__`` after an exception passes False: the old
        recording stays, the new one is left complete in ``directory``).

        Spooled frames not yet converted are converted first; if one cannot be (disk full), the recording stays
        incomplete too, its PGM kept (it reads back).
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True  # no frame is added from here on
            pending = sorted(self._pending.values(), key=lambda spooled: spooled.frame_id)
        if pending and not self._failed:
            log.info("%s: converting the %d frames still spooled", self.directory, len(pending))
            for spooled in pending:
                try:
                    self.convert(spooled)
                except (OSError, ValueError) as exc:
                    log.error("%s: frame %d: cannot write its PNG: %s", self.directory, spooled.frame_id, exc)
                    self._failed = True
                    break
        if self._failed:
            for f in (self._frames_file, self._truth_file):
                if f is not None:
                    with contextlib.suppress(OSError):
                        f.close()
            log.error("%s: writing a frame failed; recording left incomplete with %d frames%s", self.directory,
                      self._count, f" ({self.path} keeps the old recording)" if self._replaces else "")
            return
        if self._frames_file is None:
            self._frames_file, self._frames_csv = self._open_csv(FRAMES_CSV, FRAME_COLUMNS)
        self._fsync_files()
        for f in (self._frames_file, self._truth_file):
            if f is not None:
                f.close()
        fsync_dir(self._frames_dir)
        self._header["complete"] = True
        self._header["frame_count"] = self._count
        self._write_header()
        if self._replaces and not replace:
            log.error("%s: the run failed; the existing recording is kept, the new one (%d frames) is in %s",
                      self.path, self._count, self.directory)
            return
        if self._replaces:
            self._move_into_place()
        log.info("%s: recording complete, %d frames", self.path, self._count)

    def _move_into_place(self) -> None:
        """Replace the old recording at ``path`` by the complete new one (each step a rename: at any moment
        one complete recording exists, at ``path`` or beside it)."""
        old = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.old-", dir=self.path.parent))
        if self.path.exists():
            os.replace(self.path, old / "recording")
        try:
            os.replace(self.directory, self.path)
        except OSError:
            if (old / "recording").exists():  # put the old one back: never neither
                os.replace(old / "recording", self.path)
                old.rmdir()
            raise
        fsync_dir(self.path.parent)
        self.directory = self.path
        self._frames_dir = self.path / FRAMES_DIR
        shutil.rmtree(old)

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, exc_type: object, *exc_info: object) -> None:
        self.close(replace=exc_type is None)

    # ------------------------------------------------------------------ internals
    def _rows(self, image: Any, timestamp_ns: Any, exposure_us: Any, gain_db: Any, truth: Any, extra: Any,
              frame_id: Any) -> tuple[int, list[str], list[list[str]], list[str]]:
        """Check a frame's arguments; (frame_id, frames.csv row, truth.csv rows, extra columns). ValueError if any
        is invalid."""
        if self._closed or self._failed:
            raise ValueError(f"{self.path}: recording already {'closed' if self._closed else 'failed'}")
        if frame_id is None:
            frame_id = self._last_id + 1
        else:
            frame_id = _check_int(frame_id, "frame_id")
            if frame_id <= self._last_id:
                raise ValueError(f"frame_id {frame_id} must be greater than the previous frame's, "
                                 f"{self._last_id}")
        problem = image_problem(image, self.camera)
        if problem:
            raise ValueError(f"frame {frame_id}: {problem}")
        row = [str(frame_id), str(_check_int(timestamp_ns, "timestamp_ns")),
               "" if exposure_us is None else repr(_check_float(exposure_us, "exposure_us", positive=True)),
               "" if gain_db is None else repr(_check_float(gain_db, "gain_db")), f"{FRAMES_DIR}/{frame_id:06d}.png"]
        extra_columns = self._extra_columns if self._extra_columns is not None else list(extra or {})
        row += _extra_values(extra or {}, extra_columns)
        truth_rows = [[str(frame_id)] + _truth_values(tid, pose, self._target_ids)
                      for tid, pose in (truth or {}).items()]
        return frame_id, row, truth_rows, extra_columns

    def _write_png(self, image: Any, frame_id: int, file: str, durable: bool) -> None:
        """Encode ``image`` and put it at ``file`` (temp + rename; fsynced with its directory if ``durable``)."""
        ok, png = cv2.imencode(".png", image, self._png_params)
        if not ok:
            raise ValueError(f"frame {frame_id}: OpenCV could not encode the image as PNG")
        final = self.directory / file
        temp = self._frames_dir / f".{final.name}.tmp"
        with open(temp, "wb") as f:
            f.write(png.data)
            if durable:
                f.flush()
                os.fsync(f.fileno())
        os.replace(temp, final)
        if durable:
            fsync_dir(self._frames_dir)

    def _append_rows(self, frame_id: int, row: list[str], truth_rows: list[list[str]], extra_columns: list[str],
                     durable: bool) -> None:
        """Append a frame's truth.csv and frames.csv rows (its image is in place) and flush them."""
        try:
            if truth_rows:
                if self._truth_file is None:
                    self._truth_file, self._truth_csv = self._open_csv(TRUTH_CSV, TRUTH_COLUMNS)
                self._truth_csv.writerows(truth_rows)
                self._truth_file.flush()
            if self._frames_file is None:
                self._extra_columns = extra_columns
                self._frames_file, self._frames_csv = self._open_csv(FRAMES_CSV,
                                                                     [*FRAME_COLUMNS, *extra_columns])
            self._frames_csv.writerow(row)
            self._frames_file.flush()
            if durable:
                self._fsync_files()
        except BaseException:
            # A CSV line may now be torn: stop here and leave the recording marked incomplete, so that the
            # reader drops the torn line instead of parsing it.
            self._failed = True
            raise
        self._count += 1
        self._last_id = frame_id

    def _write_header(self) -> None:
        """Write recording.yaml atomically: temp file, fsync, rename, fsync the directory."""
        temp = self.directory / f".{RECORDING_YAML}.tmp"
        order = ["format", "version", "complete", "frame_count", "camera", "targets", "meta"]
        data = {key: self._header[key] for key in order if key in self._header}
        with open(temp, "w", encoding="utf-8") as f:
            yaml.safe_dump(data, f, sort_keys=False)
            f.flush()
            os.fsync(f.fileno())
        os.replace(temp, self.directory / RECORDING_YAML)
        fsync_dir(self.directory)

    def _open_csv(self, name: str, header: Sequence[str]) -> tuple[IO[str], Any]:
        f = open(self.directory / name, "w", encoding="utf-8", newline="")  # closed in close()
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(header)
        f.flush()
        return f, writer

    def _fsync_files(self) -> None:
        with self._lock:  # flushed under the lock (spool_frame writes rows meanwhile), fsynced outside it
            files = [f for f in (self._truth_file, self._frames_file) if f is not None]
            for f in files:
                f.flush()
        for f in files:
            os.fsync(f.fileno())


def _prepare_directory(path: Path, overwrite: bool) -> bool:
    """Create ``path`` if needed; True if it holds a recording that the new one is to replace at close."""
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"{path}: exists and is not a directory")
    if path.is_dir() and any(path.iterdir()):
        if not overwrite:
            raise FileExistsError(f"{path}: directory exists and is not empty; not replaced unless asked to "
                                  "overwrite")
        if path.is_symlink() or not (path / RECORDING_YAML).is_file():
            raise FileExistsError(f"{path}: not empty and not a recording (no {RECORDING_YAML}); refusing to "
                                  "replace it even when asked to overwrite")
        return True
    path.mkdir(parents=True, exist_ok=True)
    return False


def _check_int(value: Any, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    return int(value)


def _check_float(value: Any, name: str, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value) or (positive and value <= 0):
        raise ValueError(f"{name} must be finite{' and > 0' if positive else ''}, got {value}")
    return value


def _check_text(text: str, what: str) -> str:
    if "\n" in text or "\r" in text:
        raise ValueError(f"{what} must not contain line breaks: {text!r}")
    return text


def _extra_values(extra: Mapping[str, Any], columns: Sequence[str]) -> list[str]:
    for key in extra:
        if not isinstance(key, str) or not key.strip() or key in FRAME_COLUMNS:
            raise ValueError(f"extra column name {key!r} must be a non-empty string other than "
                             f"{FRAME_COLUMNS}")
        _check_text(key, "extra column name")
        if key not in columns:
            raise ValueError(f"extra column {key!r} was not among the first frame's extra columns "
                             f"{list(columns)}")
    return [_check_text(str(extra.get(key, "")), f"extra[{key!r}]") for key in columns]


def _truth_values(target_id: Any, pose: Any, known_ids: set[int]) -> list[str]:
    target_id = _check_int(target_id, "truth target id")
    if target_id not in known_ids:
        raise ValueError(f"truth for target {target_id}, which is not among the recording's targets "
                         f"{sorted(known_ids)}")
    if not isinstance(pose, Pose):
        raise ValueError(f"truth[{target_id}] must be a Pose, got {type(pose).__name__}")
    t = np.asarray(pose.t, dtype=np.float64)
    R = np.asarray(pose.R, dtype=np.float64)
    if t.shape != (3,) or R.shape != (3, 3) or not (np.all(np.isfinite(t)) and np.all(np.isfinite(R))):
        raise ValueError(f"truth[{target_id}] must have a finite (3, 3) R and (3,) t")
    return [str(target_id)] + [repr(float(v)) for v in (*t, *pose.quaternion)]
