"""``livetrack record-sweep``: record an exposure sweep from a camera (or the simulator) as a v1 recording, the
input ``livetrack model`` takes to check the image-formation model of that camera on its own targets.

For each exposure in turn the source is asked for it (``set_exposure``), frames are read until the exposure in
force (per-frame metadata: chunk data or register read-back) is the one applied, and ``--frames-per-exposure``
settled frames are written. A frame counts as settled when its ``exposure_us`` is the value the camera read back
(within 0.1 % or 1 us) and, when the source only knows the exposure from the register read-back, at least
``--settle-frames`` frames (default 2) came before it since the change (``meta["frames_since_change"]``: the first
frames after a change may still have been exposed with the previous value -- those already in flight, more when
the host is loaded).
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from livetrack.config.checks import ConfigError

NAME = "record-sweep"
HELP = ("record an exposure sweep (N frames at each exposure) from a source into a recording, the input of "
        "livetrack model")

log = logging.getLogger(__name__)

EXPOSURE_TOLERANCE_REL = 1e-3
"""A frame's exposure matches the applied one within this fraction (or EXPOSURE_TOLERANCE_US)."""
EXPOSURE_TOLERANCE_US = 1.0
"""Cameras hold whole microseconds (e.g. ExposureTimeAbs of the fake GigE camera)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--source", required=True, metavar="URI",
                        help="sim: | sim:SCENARIO.yaml | aravis:[DEVICE] | v4l2:/dev/videoN (a source with exposure "
                             "control)")
    parser.add_argument("--exposures", required=True, metavar="US,US,...",
                        help="exposures to record, microseconds, comma separated, e.g. 500,1000,2000,4000")
    parser.add_argument("--frames-per-exposure", type=int, default=3, metavar="N",
                        help="settled frames recorded at each exposure (default 3)")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="recording directory to write")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing recording at --out")
    parser.add_argument("--config", type=Path, metavar="FILE",
                        help="run config whose source options (ROI, pixel format, camera, targets ...) and camera / "
                             "targets sections are used (see livetrack dump-config)")
    parser.add_argument("--gain-db", type=float, default=None, metavar="DB",
                        help="gain to hold during the sweep (default: the source's)")
    parser.add_argument("--settle-frames", type=int, default=2, metavar="N",
                        help="with register read-back (no chunk data), skip the first N frames after each change "
                             "(default 2)")
    parser.add_argument("--settle-timeout-s", type=float, default=10.0, metavar="S",
                        help="give up on an exposure when its frames have not arrived after this long (default 10)")


def parse_exposures(text: str) -> list[float]:
    """``"500,1000,2000"`` -> [500.0, 1000.0, 2000.0]; ConfigError naming --exposures otherwise."""
    values = []
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        try:
            value = float(item)
        except ValueError:
            raise ConfigError("--exposures", f"not a number: {item!r}") from None
        if not (math.isfinite(value) and value > 0):
            raise ConfigError("--exposures", f"exposures must be > 0 microseconds, got {item}")
        values.append(value)
    if not values:
        raise ConfigError("--exposures", "no exposure given")
    return values


@dataclass
class SweepSummary:
    """What a sweep recorded: per exposure asked for, the exposure applied (read back), the frames written and
    the frames read but discarded while the exposure settled."""

    requested_us: list[float] = field(default_factory=list)
    applied_us: list[float] = field(default_factory=list)
    written: list[int] = field(default_factory=list)
    discarded: list[int] = field(default_factory=list)
    seconds: float = 0.0


def settled(frame: Any, applied_us: float, settle_frames: int = 2) -> bool:
    """True when ``frame`` was exposed with ``applied_us`` (module docstring)."""
    if frame.exposure_us is not None and (abs(frame.exposure_us - applied_us)
                                          > max(EXPOSURE_TOLERANCE_US, EXPOSURE_TOLERANCE_REL * applied_us)):
        return False  # (an unknown exposure, None, is taken as applied once the camera has had a frame)
    meta = frame.meta or {}
    if meta.get("exposure_source", "readback") == "chunk":
        return True
    return int(meta.get("frames_since_change", settle_frames)) >= settle_frames


def record_sweep(source: Any, writer: Any, exposures_us: Sequence[float], frames_per_exposure: int,
                 gain_db: float | None = None, settle_timeout_s: float = 10.0, settle_frames: int = 2) -> SweepSummary:
    """Set each exposure on the open ``source``, wait until frames carry it, write ``frames_per_exposure`` of them
    with ``writer`` (a ``RecordingWriter``; truth poses too when the source knows them). Raises ``RuntimeError``
    when an exposure's frames do not arrive within ``settle_timeout_s`` (plus the exposures themselves)."""
    from livetrack.sources.base import SourceError

    if not hasattr(source, "set_exposure"):
        raise SourceError("this source cannot set the exposure (sim:, aravis: and v4l2: can)")
    known_ids = {t.id for t in source.targets}
    summary = SweepSummary()
    started = time.perf_counter()
    for exposure_us in exposures_us:
        applied = source.set_exposure(exposure_us=exposure_us, gain_db=gain_db)
        if applied is None:
            raise SourceError(f"the camera is not connected: exposure {exposure_us:g} us not applied")
        applied_us = float(exposure_us) if applied[0] is None else float(applied[0])  # None: not read back
        if abs(applied_us - exposure_us) > max(EXPOSURE_TOLERANCE_US, EXPOSURE_TOLERANCE_REL * exposure_us):
            log.warning("exposure %.1f us asked, %.1f us applied (the camera's limits or step)", exposure_us,
                        applied_us)
        deadline = time.monotonic() + settle_timeout_s + 1e-6 * applied_us * (frames_per_exposure + settle_frames + 1)
        written = discarded = 0
        while written < frames_per_exposure:
            if time.monotonic() > deadline:
                raise RuntimeError(f"exposure {applied_us:g} us: {written} of {frames_per_exposure} frames after "
                                   f"{settle_timeout_s:g} s ({discarded} read with another exposure)")
            frame = source.read(timeout_s=1.0)
            if frame is None:
                continue
            if not settled(frame, applied_us, settle_frames):
                discarded += 1
                continue
            truth = {tid: pose for tid, pose in (frame.truth or {}).items() if tid in known_ids}
            writer.write_frame(frame.image, timestamp_ns=frame.timestamp_ns, exposure_us=frame.exposure_us,
                               gain_db=frame.gain_db, truth=truth or None)
            written += 1
        log.info("exposure %.1f us: %d frames (%d discarded while settling)", applied_us, written, discarded)
        summary.requested_us.append(float(exposure_us))
        summary.applied_us.append(applied_us)
        summary.written.append(written)
        summary.discarded.append(discarded)
    summary.seconds = time.perf_counter() - started
    return summary


def run(args: argparse.Namespace) -> int:
    from livetrack.config.app import load_config
    from livetrack.recording import RecordingWriter
    from livetrack.sources import open_source
    from livetrack.sources.base import SourceError

    exposures = parse_exposures(args.exposures)
    if args.settle_frames < 0:
        raise ConfigError("--settle-frames", f"must be >= 0, got {args.settle_frames}")
    if args.frames_per_exposure < 1:
        raise ConfigError("--frames-per-exposure", f"must be >= 1, got {args.frames_per_exposure}")
    out = Path(args.out)
    if out.exists() and any(out.iterdir()) and not args.overwrite:
        raise ConfigError("--out", f"{out} exists and is not empty (pass --overwrite to replace a recording)")
    config = load_config(args.config, {"source": {"uri": args.source}})
    try:
        source = open_source(config.source.uri, config.source.options)
    except SourceError as exc:
        print(f"livetrack record-sweep: cannot open the source {args.source}: {exc}", file=sys.stderr)
        return 1
    try:
        camera = config.camera or source.camera
        targets = config.targets if config.targets is not None else list(source.targets)
        if not targets:
            log.warning("no targets known (give them in --config): livetrack model needs the targets' specs")
        meta = {"recorded_by": "livetrack record-sweep", "source": args.source,
                "exposures_us": [float(e) for e in exposures], "frames_per_exposure": args.frames_per_exposure,
                "timestamp_epoch": "the source's clock"}
        try:
            with RecordingWriter(out, camera, targets, meta=meta, overwrite=args.overwrite) as writer:
                summary = record_sweep(source, writer, exposures, args.frames_per_exposure, args.gain_db,
                                       args.settle_timeout_s, args.settle_frames)
        except FileExistsError as exc:
            raise ConfigError("--out", str(exc)) from None
        except (RuntimeError, SourceError) as exc:
            print(f"livetrack record-sweep: {exc} (the frames written so far stay in {out}, marked complete)",
                  file=sys.stderr)
            return 1
    finally:
        source.close()
    total = sum(summary.written)
    print(f"livetrack record-sweep: {total} frames at {len(exposures)} exposures "
          f"({', '.join(f'{e:g}' for e in summary.applied_us)} us) -> {out} in {summary.seconds:.1f} s; "
          f"{sum(summary.discarded)} frames discarded while the exposure settled")
    return 0
