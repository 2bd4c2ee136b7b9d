"""``livetrack detect``: targets and poses in a recording or in image files, written as JSON."""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import cv2
import numpy as np

from livetrack.camera_io import camera_from_exif, load_camera_with_optics
from livetrack.camera_optics import tracker_options_with_optics
from livetrack.config_checks import ConfigError
from livetrack.estimator.tracker import Tracker, TrackerOptions, target_result_to_dict
from livetrack.recording import Recording, RecordingError
from livetrack.targets.spec import load_targets

NAME = "detect"
HELP = "detect targets and estimate their poses in a recording or in images; write JSON"
log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="RECORDING|IMAGE", help="a recording directory or image files")
    parser.add_argument("--camera", type=Path, help="camera YAML (default: the recording's, or EXIF for photos); its "
                        "optional optics/response sections (livetrack model --camera-out) go to the estimator")
    parser.add_argument("--pixel-pitch-um", type=float, help="sensor pixel pitch for a camera from EXIF")
    parser.add_argument("--targets", type=Path, help="targets YAML (default: the recording's)")
    parser.add_argument("--no-compensation", action="store_true", help="fix delta at 0 (baseline)")
    parser.add_argument("--max-frames", type=int, default=None, help="stop after N frames")
    parser.add_argument("--json", type=Path, required=True, help="output file")


def run(args: argparse.Namespace) -> int:
    inputs = [Path(p) for p in args.inputs]
    camera_file, optics = load_camera_with_optics(args.camera) if args.camera else (None, None)
    options = tracker_options_with_optics(TrackerOptions(compensate_exposure=not args.no_compensation), optics)
    if optics is not None:
        log.info("camera optics: %s", optics)
    frames_out = []
    if len(inputs) == 1 and inputs[0].is_dir():
        frames_out = _run_recording(inputs[0], args, options, camera_file)
    else:
        frames_out = _run_images(inputs, args, options, camera_file)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"frames": frames_out}, indent=1))
    n_targets = sum(len(f["targets"]) for f in frames_out)
    print(f"livetrack detect: {len(frames_out)} frames, {n_targets} target poses -> {args.json}")
    return 0


def _run_recording(folder: Path, args, options, camera_file) -> list[dict]:
    try:
        rec = Recording.open(folder)
    except RecordingError as exc:
        raise ConfigError(str(folder), str(exc)) from None
    camera = camera_file or rec.camera
    targets = load_targets(args.targets) if args.targets else rec.targets
    tracker = Tracker(camera, targets, options)
    out = []
    for n, (frame, image) in enumerate(rec.iter_images()):
        if args.max_frames is not None and n >= args.max_frames:
            break
        result = tracker.process(image, frame.exposure_us)
        out.append({"frame_id": frame.frame_id, "timestamp_ns": frame.timestamp_ns, "exposure_us": frame.exposure_us,
                    "timings_ms": result.timings_ms,
                    "targets": [target_result_to_dict(t) for t in result.targets]})
    for frame_id, reason in rec.skipped:
        log.warning("frame %s skipped: %s", frame_id, reason)
    return out


def _run_images(files: list[Path], args, options, camera_file) -> list[dict]:
    if not args.targets:
        raise ConfigError("--targets", "required for image files (their physical size sets the scale)")
    targets = load_targets(args.targets)
    out = []
    for n, file in enumerate(files):
        if args.max_frames is not None and n >= args.max_frames:
            break
        image = cv2.imread(str(file), cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION)
        if image is None:
            log.warning("%s: cannot read the image, skipped", file)
            out.append({"file": str(file), "error": "unreadable image", "targets": []})
            continue
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        depth = 8 if image.dtype == np.uint8 else 16
        camera = camera_file or camera_from_exif(file, image.shape[1], image.shape[0], args.pixel_pitch_um, depth)
        if (camera.width, camera.height) != (image.shape[1], image.shape[0]):
            raise ConfigError(str(file), f"image is {image.shape[1]}x{image.shape[0]} but the camera is "
                              f"{camera.width}x{camera.height}")
        result = Tracker(camera, targets, options).process(image)
        out.append({"file": str(file), "timings_ms": result.timings_ms,
                    "targets": [target_result_to_dict(t) for t in result.targets]})
    return out
