"""Read a recording directory (format v1, docs/recording-format.md).

``Recording.open`` reads recording.yaml, frames.csv and truth.csv but no image. Whole-recording problems
(unreadable or invalid recording.yaml, malformed frames.csv header) raise ``RecordingError``; a bad row (wrong
fields, a stray quote, bytes that are not UTF-8) or a bad image only skips that frame, with a warning naming its
line, and is listed in ``Recording.skipped``. A row whose PNG is not there is read from its spooled raw PGM
(``frames/NNNNNN.pgm``) if that is, as a writer killed before converting it leaves it. Only regular files
inside the recording directory are read: a FIFO, a device or a symbolic link leading outside is refused
(``RecordingError``), never opened for reading.
"""

from __future__ import annotations

import csv
import logging
import math
import os
import stat
from collections.abc import Iterator
from pathlib import Path, PurePosixPath
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.config import checks as cc
from livetrack.geometry import Pose
from livetrack.recording._format import (
    FORMAT_NAME,
    FORMAT_VERSION,
    FRAME_COLUMNS,
    FRAMES_CSV,
    RECORDING_YAML,
    SPOOL_SUFFIX,
    TRUTH_COLUMNS,
    TRUTH_CSV,
    FrameRecord,
    RecordingError,
    image_problem,
)
from livetrack.targets.spec import TargetSpec

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
TruthEntry = tuple[FloatArray, FloatArray]  # quaternion (4,) xyzw, translation (3,) metres


class Recording:
    """An opened recording.

    Attributes
    ----------
    path : the recording directory.
    camera, targets, meta : from recording.yaml (``meta`` is ``{}`` if absent).
    complete : False if the writer did not finish (crash, kill, still running); the frames listed are still
        usable, a torn last CSV line has been dropped.
    frames : the valid rows of frames.csv in file order; ``len(rec) == len(rec.frames)``.
    skipped : (frame_id, reason) of every frame left out: malformed or duplicate rows at open (frame_id -1 if
        the id itself is unreadable), unreadable images met by ``iter_images``.
    """

    def __init__(self, path: Path, camera: CameraModel, targets: list[TargetSpec], meta: dict[str, Any],
                 complete: bool, frames: list[FrameRecord], truth: dict[int, dict[int, TruthEntry]],
                 skipped: list[tuple[int, str]]):
        self.path = path
        self.camera = camera
        self.targets = targets
        self.meta = meta
        self.complete = complete
        self.frames = frames
        self.skipped = skipped
        self._truth = truth

    @classmethod
    def open(cls, path: str | os.PathLike) -> Recording:
        """Open a recording directory; raises RecordingError naming the file (and line) if it is unusable."""
        path = Path(path)
        yaml_file = path / RECORDING_YAML
        if not yaml_file.exists():
            raise RecordingError(path, f"not a recording: no {RECORDING_YAML}")
        try:
            data = cc.parse_yaml(read_regular_file(path, RECORDING_YAML), yaml_file)
            camera, targets, meta, complete, frame_count = _parse_recording_yaml(data)
        except cc.ConfigError as exc:
            raise RecordingError(yaml_file, exc.problem if exc.path == str(yaml_file) else str(exc)) from None
        skipped: list[tuple[int, str]] = []
        frames, n_rows = _read_frames(path / FRAMES_CSV, complete, skipped)
        if complete and frame_count is not None and frame_count != n_rows:
            log.warning("%s: frame_count is %d but %s has %d rows", yaml_file, frame_count, FRAMES_CSV,
                        n_rows)
        truth = _read_truth(path / TRUTH_CSV, complete)
        if not complete:
            log.warning("%s: recording is incomplete (writer did not finish); %d frames usable", path,
                        len(frames))
        return cls(path, camera, targets, meta, complete, frames, truth, skipped)

    def __len__(self) -> int:
        return len(self.frames)

    def __repr__(self) -> str:
        state = "complete" if self.complete else "incomplete"
        return f"Recording({str(self.path)!r}, {len(self)} frames, {state})"

    def read_image(self, index: int) -> npt.NDArray[np.uint8] | npt.NDArray[np.uint16]:
        """Image of ``frames[index]`` (position in ``frames``, not frame_id): (height, width) uint8 or uint16.

        Raises RecordingError naming the file if it is missing, corrupt, or of the wrong size or bit depth.
        """
        frame = self.frames[index]
        file = self.path / frame.file
        try:
            data = read_regular_file(self.path, frame.file)
        except FileNotFoundError:
            # a spooled frame: its raw PGM, while the PNG is not there yet (docs/recording-format.md)
            spool = str(PurePosixPath(frame.file).with_suffix(SPOOL_SUFFIX))
            try:
                if not frame.file.endswith(".png"):
                    raise RecordingError(file, f"image file of frame {frame.frame_id} is missing") from None
                data = read_regular_file(self.path, spool)
                file = self.path / spool
            except FileNotFoundError:  # converted meanwhile (a recording being written): the PNG is there now
                try:
                    data = read_regular_file(self.path, frame.file)
                except FileNotFoundError:
                    data = None
            if data is None:
                raise RecordingError(file, f"image file of frame {frame.frame_id} is missing") from None
        image = None
        if data:
            try:
                image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
            except cv2.error:
                image = None
        if image is None:
            raise RecordingError(file, f"image of frame {frame.frame_id} cannot be decoded (truncated or "
                                       "corrupt)")
        problem = image_problem(image, self.camera)
        if problem:
            raise RecordingError(file, problem)
        return image

    def iter_images(self) -> Iterator[tuple[FrameRecord, npt.NDArray[np.uint8] | npt.NDArray[np.uint16]]]:
        """Yield (frame, image) in file order, reading lazily; unreadable frames are logged, skipped and
        appended to ``skipped``."""
        for index, frame in enumerate(self.frames):
            try:
                image = self.read_image(index)
            except RecordingError as exc:
                log.warning("skipping frame %d: %s", frame.frame_id, exc)
                entry = (frame.frame_id, str(exc))
                if entry not in self.skipped:
                    self.skipped.append(entry)
                continue
            yield frame, image

    def truth(self, frame_id: int) -> dict[int, Pose]:
        """Ground-truth target-to-camera poses of frame ``frame_id``: target id -> Pose ({} if none)."""
        return {tid: Pose.from_quaternion(q, t) for tid, (q, t) in self._truth.get(frame_id, {}).items()}


# ---------------------------------------------------------------------- recording.yaml
def _parse_recording_yaml(
    data: Any,
) -> tuple[CameraModel, list[TargetSpec], dict[str, Any], bool, int | None]:
    if not isinstance(data, dict):
        raise cc.ConfigError("", f"must be a mapping, got {type(data).__name__}")
    cc.string(data, "format", "", choices=[FORMAT_NAME])
    version = cc.integer(data, "version", "")
    if version != FORMAT_VERSION:
        raise cc.ConfigError("version", f"unsupported version {version}; this reader reads {FORMAT_VERSION}")
    cc.mapping(data, "", required=["format", "version", "complete", "camera", "targets"],
               optional=["frame_count", "meta"])
    complete = data["complete"]
    if not isinstance(complete, bool):
        raise cc.ConfigError("complete", f"must be true or false, got {complete!r}")
    frame_count = cc.integer(data, "frame_count", "", ge=0) if data.get("frame_count") is not None else None
    camera = CameraModel.from_dict(data["camera"], "camera")
    if not isinstance(data["targets"], list):
        raise cc.ConfigError("targets", "must be a list of target specs")
    targets = [TargetSpec.from_dict(item, f"targets[{i}]") for i, item in enumerate(data["targets"])]
    ids = [t.id for t in targets]
    if len(set(ids)) != len(ids):
        raise cc.ConfigError("targets", f"duplicate ids in {ids}")
    meta = data.get("meta") or {}
    if not isinstance(meta, dict):
        raise cc.ConfigError("meta", f"must be a mapping, got {type(meta).__name__}")
    return camera, targets, meta, complete, frame_count


# ---------------------------------------------------------------------- CSV files
def _read_csv(
    file: Path, complete: bool, required: tuple[str, ...], skipped: list[tuple[int, str]] | None = None,
) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """Header (stripped names) and (line number, fields) rows of a CSV file; ([], []) if it does not exist.

    Each line is parsed on its own (values never contain line breaks, docs/recording-format.md), so a stray
    quote or a byte that is not UTF-8 costs that line only: it is warned about with its line number and, for
    frames.csv, listed in ``skipped`` with frame_id -1. In an incomplete recording a last line without its
    newline is torn: it is dropped with a warning.
    """
    try:
        data = read_regular_file(file.parent, file.name)
    except FileNotFoundError:
        return [], []
    if not complete and data and not data.endswith(b"\n"):
        log.warning("%s line %d: torn last line of an incomplete recording, ignored", file, data.count(b"\n") + 1)
        data = data[: data.rfind(b"\n") + 1]
    header: list[str] = []
    rows: list[tuple[int, list[str]]] = []
    for number, raw in enumerate(data.split(b"\n"), start=1):
        raw = raw.removesuffix(b"\r")
        if number == 1:
            raw = raw.removeprefix(b"\xef\xbb\xbf")  # a UTF-8 byte order mark
        if not raw.strip():
            continue  # blank line (and the end of the file)
        try:
            fields = _csv_fields(raw)
        except ValueError as exc:
            if not header:
                raise RecordingError(file, f"header: {exc}", number) from None
            reason = f"{file} line {number}: {exc}"
            log.warning("skipping row: %s", reason)
            if skipped is not None:
                skipped.append((-1, reason))
            continue
        if not header:
            header = [name.strip() for name in fields]
            _check_header(file, header, required)
        else:
            rows.append((number, fields))
    return header, rows


def _csv_fields(raw: bytes) -> list[str]:
    """The fields of one CSV line (RFC 4180 quoting); ValueError if it is not UTF-8 or not CSV."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"not UTF-8 text (byte 0x{raw[exc.start]:02x} at column {exc.start + 1})") from None
    try:
        return next(csv.reader([text], strict=True))
    except csv.Error as exc:
        raise ValueError(f"not valid CSV: {exc}") from None


def read_regular_file(folder: Path, relative: str) -> bytes:
    """The bytes of ``folder / relative`` if it is a regular file inside ``folder`` (symbolic links allowed
    only if they resolve inside it). Never blocks on a FIFO or a device.

    Raises FileNotFoundError if it does not exist, RecordingError naming it if it is something else (outside
    the recording, a FIFO, a directory, unreadable).
    """
    file = folder / relative
    try:
        real = file.resolve(strict=True)
        root = folder.resolve(strict=True)
    except FileNotFoundError:
        raise
    except (OSError, RuntimeError, ValueError) as exc:  # RuntimeError: a link loop, ValueError: a NUL byte
        raise RecordingError(file, f"cannot read: {getattr(exc, 'strerror', None) or exc}") from None
    if not real.is_relative_to(root):
        raise RecordingError(file, f"is a link to {real}, outside the recording; only files inside it are read")
    try:
        flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
        fd = os.open(real, flags | getattr(os, "O_NOFOLLOW", 0))  # a link swapped in after resolve() is refused
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise RecordingError(file, f"cannot read: {exc.strerror or exc}") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise RecordingError(file, "not a regular file (a FIFO, device or directory); only regular files are "
                                       "read")
        with os.fdopen(fd, "rb", closefd=False) as stream:
            return stream.read()
    except OSError as exc:
        raise RecordingError(file, f"cannot read: {exc.strerror or exc}") from None
    finally:
        os.close(fd)


def _check_header(file: Path, header: list[str], required: tuple[str, ...]) -> None:
    missing = [name for name in required if name not in header]
    if missing:
        raise RecordingError(file, f"header lacks column(s) {missing}; it must contain {list(required)}", 1)
    dupes = sorted({name for name in header if header.count(name) > 1})
    if dupes or "" in header:
        raise RecordingError(file, f"header has duplicate or empty column names: {header}", 1)


def _read_frames(file: Path, complete: bool, skipped: list[tuple[int, str]]) -> tuple[list[FrameRecord], int]:
    """Valid frame records and the number of data rows (valid or not)."""
    if not file.exists() and complete:
        raise RecordingError(file, "missing (required in a complete recording)")
    header, rows = _read_csv(file, complete, FRAME_COLUMNS, skipped)
    extra_columns = [name for name in header if name not in FRAME_COLUMNS]
    frames: list[FrameRecord] = []
    seen: set[int] = set()
    for line, fields in rows:
        frame_id = -1
        try:
            if len(fields) != len(header):
                raise ValueError(f"expected {len(header)} fields, got {len(fields)}")
            values = dict(zip(header, fields, strict=True))
            frame_id = _int(values, "frame_id", ge=0)
            frame = FrameRecord(
                frame_id=frame_id,
                timestamp_ns=_int(values, "timestamp_ns"),
                exposure_us=_float(values, "exposure_us", positive=True, optional=True),
                gain_db=_float(values, "gain_db", optional=True),
                file=_relative_file(values["file"]),
                extra={name: values[name] for name in extra_columns},
            )
            if frame_id in seen:
                raise ValueError(f"duplicate frame_id {frame_id}, keeping the first")
        except ValueError as exc:
            reason = f"{file} line {line}: {exc}"
            log.warning("skipping row: %s", reason)
            skipped.append((frame_id, reason))
            continue
        seen.add(frame_id)
        frames.append(frame)
    return frames, len(rows)


def _read_truth(file: Path, complete: bool) -> dict[int, dict[int, TruthEntry]]:
    """frame_id -> target_id -> (quaternion (4,) xyzw, translation (3,) metres). Bad rows are warned about."""
    header, rows = _read_csv(file, complete, TRUTH_COLUMNS)
    truth: dict[int, dict[int, TruthEntry]] = {}
    for line, fields in rows:
        try:
            if len(fields) != len(header):
                raise ValueError(f"expected {len(header)} fields, got {len(fields)}")
            values = dict(zip(header, fields, strict=True))
            frame_id, target_id = _int(values, "frame_id", ge=0), _int(values, "target_id", ge=0)
            t = np.array([_float(values, k) for k in ("tx_m", "ty_m", "tz_m")])
            q = np.array([_float(values, k) for k in ("qx", "qy", "qz", "qw")])
            if not np.linalg.norm(q) > 1e-9:
                raise ValueError("quaternion is zero")
            if target_id in truth.get(frame_id, {}):
                raise ValueError(f"duplicate truth for frame {frame_id} target {target_id}, keeping the "
                                 "first")
        except ValueError as exc:
            log.warning("skipping truth row: %s line %d: %s", file, line, exc)
            continue
        truth.setdefault(frame_id, {})[target_id] = (q, t)
    return truth


def _int(values: dict[str, str], name: str, ge: int | None = None) -> int:
    text = values[name].strip()
    try:
        value = int(text)
    except ValueError:
        raise ValueError(f"{name} is not an integer: {text!r}") from None
    if ge is not None and value < ge:
        raise ValueError(f"{name} must be >= {ge}, got {value}")
    return value


def _float(values: dict[str, str], name: str, positive: bool = False, optional: bool = False) -> float | None:
    """The column's number; an empty cell is None (unknown) when ``optional``."""
    text = values[name].strip()
    if optional and not text:
        return None
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{name} is not a number: {text!r}") from None
    if not math.isfinite(value) or (positive and value <= 0):
        raise ValueError(f"{name} must be finite{' and > 0' if positive else ''}, got {text!r}")
    return value


def _relative_file(text: str) -> str:
    text = text.strip()
    parts = PurePosixPath(text).parts
    if not text or PurePosixPath(text).is_absolute() or ".." in parts or "\\" in text:
        raise ValueError(f"file must be a relative path inside the recording, with '/' separators: {text!r}")
    if any(ord(c) < 0x20 or c == "\x7f" for c in text):
        raise ValueError(f"file contains a control character (NUL, tab, ...): {text!r}")
    return text
