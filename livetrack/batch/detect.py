"""Detection over many recordings, split per recording and per frame range (``livetrack detect DIR... --json-dir``).

Each recording's frames (positions in ``Recording.frames``) are cut into ranges of ``range_frames``; one task runs a
fresh ``Tracker`` over one range, so a range starts with a full search and the tracker's state is carried from
frame to frame within it. The ranges, not the workers, define the result: the serial run (``workers=0``) runs the
same ranges in this process, one after the other, and gives the same JSON as any number of workers (only the
``timings_ms`` of each frame are measured times; ``timings=False`` leaves them out).

The task functions take and return plain data: the recording path as text, a frame range, a settings dict; the
frames as the JSON of ``livetrack detect`` (docs/detect-json.md). A recording that cannot be opened, a frame whose
image cannot be read and a range whose task failed are reported in that recording's output, the rest goes on.
"""

from __future__ import annotations

import functools
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from livetrack.batch.executor import Executor, Outcome, Task
from livetrack.estimator.tracker import TrackerOptions
from livetrack.recording import Recording, RecordingError

log = logging.getLogger(__name__)

DEFAULT_RANGE_FRAMES = 500
"""Frames per task. Each range costs one full search at its start (the tracker restarts); larger ranges mean
fewer tasks (less scheduling overhead, ~ms each) but coarser load balancing and more work lost per failed task."""


@dataclass(frozen=True)
class DetectSettings:
    """What every task needs besides its range; plain data (``to_dict``) on the way to the workers."""

    camera: str | None = None  # camera YAML; default: the recording's
    targets: str | None = None  # targets YAML; default: the recording's
    compensate_exposure: bool = True
    fit_target_model: bool | None = TrackerOptions.fit_target_model
    timings: bool = True  # keep each frame's timings_ms (measured, so not reproducible)
    max_frames: int | None = None  # per recording

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class RecordingOutput:
    """One recording's result: the frames in order, the frames skipped and the ranges that failed."""

    path: str
    frame_count: int = 0
    frames: list[dict] = field(default_factory=list)
    skipped: list[dict] = field(default_factory=list)
    errors: list[dict] = field(default_factory=list)  # {"frames": [start, stop] or None, "error": text}

    @property
    def complete(self) -> bool:
        return not self.errors

    def to_dict(self) -> dict[str, Any]:
        return {"recording": self.path, "frame_count": self.frame_count, "complete": self.complete,
                "errors": self.errors, "skipped": self.skipped, "frames": self.frames}

    def counts(self) -> dict[str, int]:
        return {"frames": len(self.frames),
                "poses": sum(1 for f in self.frames for t in f["targets"] if t.get("ok")),
                "failed_fits": sum(len(f["failures"]) for f in self.frames),
                "skipped": len(self.skipped),
                "failed_ranges": len(self.errors)}


# ------------------------------------------------------------------------------------------- task functions
def recording_info(path: str) -> dict[str, Any]:
    """Task: the number of frames of the recording at ``path`` and the rows skipped when opening it; or
    ``{"error": ...}`` when it cannot be opened."""
    try:
        rec = _open(path)
    except RecordingError as exc:
        return {"error": str(exc)}
    return {"frames": len(rec), "skipped": [{"frame_id": i, "reason": r} for i, r in rec.skipped]}


def detect_range(path: str, start: int, stop: int, settings: dict[str, Any]) -> dict[str, Any]:
    """Task: frames ``start`` to ``stop - 1`` (positions in the recording's frame list) through a fresh tracker.
    Returns ``{"frames": [...], "skipped": [...]}``: each frame as in ``livetrack detect``'s JSON."""
    from livetrack.estimator.tracker import Tracker, target_failure_to_dict, target_result_to_dict

    rec = _open(path)
    camera, targets, options = _tracker_inputs(rec, settings["camera"], settings["targets"],
                                               settings["compensate_exposure"],
                                               settings.get("fit_target_model", TrackerOptions.fit_target_model))
    tracker = Tracker(camera, targets, options)
    frames, skipped = [], []
    for index in range(start, min(stop, len(rec))):
        frame = rec.frames[index]
        try:
            image = rec.read_image(index)
        except RecordingError as exc:
            skipped.append({"frame_id": frame.frame_id, "reason": str(exc)})
            continue
        result = tracker.process(image, frame.exposure_us)
        entry = {"frame_id": frame.frame_id, "timestamp_ns": frame.timestamp_ns, "exposure_us": frame.exposure_us}
        if settings["timings"]:
            entry["timings_ms"] = result.timings_ms
        entry["targets"] = [target_result_to_dict(t) for t in result.targets]
        entry["failures"] = [target_failure_to_dict(f) for f in result.failures]
        frames.append(entry)
    return {"frames": frames, "skipped": skipped}


@functools.lru_cache(maxsize=4)
def _open_cached(path: str, stamp: tuple[int, ...]) -> Recording:
    return Recording.open(path)


def _open(path: str) -> Recording:
    """The recording, opened once per process while its index files are unchanged (frames.csv is read once,
    not once per range)."""
    stamp: list[int] = []
    for name in ("recording.yaml", "frames.csv"):
        try:
            st = os.stat(Path(path) / name)
            stamp += [st.st_mtime_ns, st.st_size]
        except OSError:
            stamp += [-1, -1]
    return _open_cached(path, tuple(stamp))


@functools.lru_cache(maxsize=8)
def _load_camera(file: str) -> tuple[Any, Any]:
    from livetrack.camera.io import load_camera_with_optics

    return load_camera_with_optics(Path(file))


@functools.lru_cache(maxsize=8)
def _load_targets(file: str) -> list[Any]:
    from livetrack.targets.spec import load_targets

    return load_targets(Path(file))


def _tracker_inputs(rec: Recording, camera_file: str | None, targets_file: str | None, compensate: bool,
                    fit_target_model: bool | None = TrackerOptions.fit_target_model):
    from livetrack.camera.optics import tracker_options_with_optics

    camera, optics = _load_camera(camera_file) if camera_file else (rec.camera, None)
    targets = _load_targets(targets_file) if targets_file else rec.targets
    options = tracker_options_with_optics(TrackerOptions(compensate_exposure=compensate,
                                                         fit_target_model=fit_target_model), optics)
    return camera, targets, options


# ------------------------------------------------------------------------------------------------- the run
def frame_ranges(count: int, range_frames: int) -> list[tuple[int, int]]:
    """``[(start, stop), ...]`` covering ``0..count-1`` in ranges of ``range_frames`` (the last one shorter)."""
    if range_frames < 1:
        raise ValueError(f"range_frames must be >= 1, got {range_frames}")
    return [(a, min(a + range_frames, count)) for a in range(0, count, range_frames)]


def detect_recordings(paths: Sequence[str | os.PathLike], settings: DetectSettings, executor: Executor,
                      range_frames: int = DEFAULT_RANGE_FRAMES, progress: bool = False) -> list[RecordingOutput]:
    """Detection over every recording in ``paths`` with ``executor``; one ``RecordingOutput`` per path, in order.

    Two rounds of tasks: one per recording for its frame count, then one per frame range."""
    paths = [str(p) for p in paths]
    infos = executor.run([Task(recording_info, (p,), f"{p} (index)") for p in paths],
                         progress="index" if progress else None)
    outputs = [RecordingOutput(p) for p in paths]
    tasks, owners = [], []
    plain = settings.to_dict()
    for n, (out, info) in enumerate(zip(outputs, infos, strict=True)):
        value = info.value if info.ok else {"error": info.error}
        if "error" in value:
            out.errors.append({"frames": None, "error": value["error"]})
            continue
        count = value["frames"] if settings.max_frames is None else min(value["frames"], settings.max_frames)
        out.frame_count = count
        out.skipped.extend(value["skipped"])
        for start, stop in frame_ranges(count, range_frames):
            tasks.append(Task(detect_range, (out.path, start, stop, plain), f"{out.path} frames {start}-{stop - 1}",
                              weight=stop - start))
            owners.append(n)
    results = executor.run(tasks, progress="frames" if progress else None)
    for n, outcome in zip(owners, results, strict=True):
        _merge(outputs[n], outcome)
    return outputs


def _merge(out: RecordingOutput, outcome: Outcome) -> None:
    if outcome.ok:
        out.frames.extend(outcome.value["frames"])
        out.skipped.extend(outcome.value["skipped"])
    else:
        start, stop = outcome.task.args[1], outcome.task.args[2]
        log.error("%s: %s", outcome.task.label, outcome.error)
        out.errors.append({"frames": [start, stop - 1], "error": outcome.error})


def output_names(paths: Sequence[str | os.PathLike]) -> list[str]:
    """The JSON file name of each recording in ``--json-dir``: its folder name, with the parent folders' names
    prefixed where two recordings share one (``a/run1``, ``b/run1`` -> ``a_run1.json``, ``b_run1.json``)."""
    parts = [Path(os.path.abspath(p)).parts for p in paths]
    depth = 1
    while True:
        names = ["_".join(p[-depth:]) for p in parts]
        if len(set(names)) == len(names) or depth >= max((len(p) for p in parts), default=1):
            break
        depth += 1
    if len(set(names)) != len(names):
        raise ValueError("the same recording is given twice")
    return [f"{name}.json" for name in names]


def summary_table(outputs: Sequence[RecordingOutput], names: Sequence[str]) -> str:
    """One line per recording (frames, poses, failed fits, frames skipped, failed ranges) and the totals."""
    head = f"{'recording':32s} {'frames':>8s} {'poses':>8s} {'failed fits':>11s} {'skipped':>8s} {'status':s}"
    lines = [head, "-" * (len(head) + 12)]
    total = dict.fromkeys(("frames", "poses", "failed_fits", "skipped", "failed_ranges"), 0)
    for out, name in zip(outputs, names, strict=True):
        c = out.counts()
        for k in total:
            total[k] += c[k]
        if out.complete:
            status = "ok"
        elif out.errors[0]["frames"] is None:
            status = f"FAILED: {out.errors[0]['error'].splitlines()[0]}"
        else:
            status = f"{len(out.errors)} range(s) failed"
        lines.append(f"{name[:-5][:32]:32s} {c['frames']:8d} {c['poses']:8d} {c['failed_fits']:11d} "
                     f"{c['skipped']:8d} {status}")
    lines.append("-" * (len(head) + 12))
    failed = sum(1 for o in outputs if not o.complete)
    lines.append(f"{f'{len(outputs)} recordings':32s} {total['frames']:8d} {total['poses']:8d} "
                 f"{total['failed_fits']:11d} {total['skipped']:8d} "
                 + ("ok" if not failed else f"{failed} incomplete, {total['failed_ranges']} range(s) failed"))
    return "\n".join(lines)
