"""``livetrack detect``: targets and poses in a recording or in image files, written as JSON.

Images are processed one by one: an image that cannot be used (unreadable, wrong size for ``--camera``, an
unsupported pixel type) is reported on stderr and in the JSON (``"error"``) and skipped; the others are processed.
The exit status is 1 when no input could be used. An image without a camera (no ``--camera``, no ``--focal-px``,
no EXIF focal length: a screenshot, a PNG from another tool) is still searched: its targets are reported with their
ids, levels and ellipses, and ``"pose": null`` with the reason. The JSON is described in docs/detect-json.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from livetrack.batch.executor import add_executor_arguments
from livetrack.camera import CameraModel
from livetrack.camera.encoding import canonical, encoding_problem
from livetrack.camera.io import camera_from_exif, image_encoding, load_camera_with_optics, states_bit_depth
from livetrack.camera.optics import tracker_options_with_optics
from livetrack.config.checks import ConfigError
from livetrack.estimator.clip_level import frame_saturation_dn
from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect import Candidate, detect
from livetrack.estimator.tracker import (
    CLIP_MARGIN_FRACTION,
    FrameResult,
    Tracker,
    TrackerOptions,
    group_levels,
    target_failure_to_dict,
    target_result_to_dict,
)
from livetrack.recording import Recording, RecordingError
from livetrack.targets.spec import TargetSpec, load_targets

NAME = "detect"
HELP = "detect targets and estimate their poses in a recording or in images; write JSON"
log = logging.getLogger(__name__)

NO_CAMERA = "no camera: give --camera or --focal-px"


class ImageError(ValueError):
    """One input image cannot be used; ``str()`` says why. The image is skipped, the others are processed."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="RECORDING|IMAGE", help="a recording directory or image files")
    parser.add_argument("--camera", type=Path, help="camera YAML (default: the recording's, or EXIF for photos); its "
                        "optional optics/response sections (livetrack model --camera-out) go to the estimator")
    parser.add_argument("--pixel-pitch-um", type=float, help="sensor pixel pitch for a camera from EXIF")
    parser.add_argument("--bit-depth", type=int, choices=range(8, 17), metavar="8..16",
                        help="images: the camera's bit depth (its top code is where pixels clip). Default: the "
                             "--camera file's bit_depth when it gives one, else from the data (16-bit words: the "
                             "smallest of 10/12/14/16 bits holding the largest value)")
    parser.add_argument("--focal-px", type=float, help="focal length in pixels for images without a camera file: "
                        "principal point at the image centre, no distortion (overrides EXIF). Without a camera, "
                        "targets are reported without a pose")
    parser.add_argument("--encoding", metavar="linear|srgb|'gamma G'",
                        help="how the pixel values encode light (CameraModel.encoding): linear (machine-vision "
                             "cameras), srgb (phones, webcams, most renderers' PNGs) or 'gamma G'; the estimator "
                             "reads encoded frames linearised. Default: the camera's (linear unless its file says)")
    parser.add_argument("--targets", type=Path, help="targets YAML (default: the recording's)")
    parser.add_argument("--no-compensation", action="store_true", help="fix delta at 0 (baseline)")
    parser.add_argument("--fit-target-model", action=argparse.BooleanOptionalAction,
                        default=TrackerOptions.fit_target_model,
                        help="a target whose edges a lens halo clips (heavy over-exposure) gets its pose from the "
                             "whole target modelled in 2-D, halo included (TrackerOptions.fit_target_model; ~1-5 s "
                             "per such target; default on)")
    parser.add_argument("--propagate-camera-uncertainty", action="store_true",
                        help="add the --camera file's calibration uncertainty (its uncertainty section, written by "
                             "livetrack calibrate) to each pose's covariance, first order (~1-2 ms per target)")
    parser.add_argument("--max-frames", type=int, default=None, help="stop after N frames")
    parser.add_argument("--json", type=Path, help="output file (one recording, or images)")
    parser.add_argument("--json-dir", type=Path, metavar="DIR",
                        help="many recordings (livetrack detect ARCHIVE/* --json-dir OUT/): one JSON per recording in "
                             "DIR, split per frame range over --workers or a --scheduler (livetrack.batch; "
                             "docs/batch.md); the same JSON whatever the number of workers")
    parser.add_argument("--range-frames", type=int, default=None, metavar="N",
                        help="--json-dir: frames per task; each range starts with a fresh tracker (default "
                             "500)")
    parser.add_argument("--no-timings", action="store_true",
                        help="--json-dir: leave out each frame's measured timings_ms (byte-identical reruns)")
    add_executor_arguments(parser)


def _with_camera_uncertainty(options: TrackerOptions, camera_file: Path | None) -> TrackerOptions:
    """``--propagate-camera-uncertainty``: the camera file's uncertainty section as ``TrackerOptions.camera_std``."""

    from livetrack.camera.io import load_camera_uncertainty

    if camera_file is None:
        raise ConfigError("--propagate-camera-uncertainty", "needs --camera FILE with an uncertainty section")
    u = load_camera_uncertainty(camera_file)
    if u is None:
        raise ConfigError("--propagate-camera-uncertainty", f"{camera_file} has no uncertainty section "
                                                            "(livetrack calibrate writes one)")
    return dataclasses.replace(options, camera_std=(u.fx, u.fy, u.cx, u.cy, *u.dist))


def run(args: argparse.Namespace) -> int:
    if (args.json is None) == (args.json_dir is None):
        raise ConfigError("--json", "give --json FILE (one recording or images) or --json-dir DIR (recordings)")
    if args.json_dir is not None:
        if args.propagate_camera_uncertainty:
            raise ConfigError("--propagate-camera-uncertainty", "is for --json (one recording or images)")
        if args.encoding is not None:
            raise ConfigError("--encoding", "is for --json (one recording or images); state the encoding in the "
                                            "--camera file (camera: encoding: srgb) for --json-dir")
        return run_batch(args)
    for name in ("workers", "scheduler", "range_frames"):
        if getattr(args, name) is not None:
            raise ConfigError(f"--{name.replace('_', '-')}", "is for --json-dir (many recordings)")
    inputs = [Path(p) for p in args.inputs]
    if args.focal_px is not None and not (np.isfinite(args.focal_px) and args.focal_px > 0):
        raise ConfigError("--focal-px", f"must be a positive number of pixels, got {args.focal_px}")
    if args.focal_px is not None and args.camera is not None:
        raise ConfigError("--focal-px", "give either --camera or --focal-px, not both")
    _encoding_arg(args.encoding)  # checked before any input is read
    camera_file, optics = load_camera_with_optics(args.camera) if args.camera else (None, None)
    options = tracker_options_with_optics(TrackerOptions(compensate_exposure=not args.no_compensation,
                                                         fit_target_model=args.fit_target_model), optics)
    if args.propagate_camera_uncertainty:
        options = _with_camera_uncertainty(options, args.camera)
    if optics is not None:
        log.info("camera optics: %s", optics)
    if len(inputs) == 1 and inputs[0].is_dir():
        if args.focal_px is not None:
            raise ConfigError("--focal-px", "is for image files (a recording has its camera)")
        frames_out = _run_recording(inputs[0], args, options, camera_file)
        kind = "frames"
    else:
        frames_out = _run_images(inputs, args, options, camera_file)
        kind = "images"
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"frames": frames_out}, indent=1, allow_nan=False))
    used = [f for f in frames_out if "error" not in f]
    n_poses = sum(1 for f in used for t in f["targets"] if t.get("ok"))
    n_unposed = sum(1 for f in used for t in f["targets"] if t.get("pose", True) is None)
    n_failed = sum(len(f["failures"]) for f in used)
    print(f"livetrack detect: {len(used)} {kind}, {n_poses} target poses"
          + (f", {n_unposed} targets without a pose (no camera)" if n_unposed else "")
          + (f", {n_failed} failed fits" if n_failed else "")
          + (f", {len(frames_out) - len(used)} of {len(frames_out)} inputs skipped" if len(used) < len(frames_out)
             else "")
          + f" -> {args.json}")
    if frames_out and not used:
        log.error("no input could be used")
        return 1
    return 0


def run_batch(args: argparse.Namespace) -> int:
    """``--json-dir``: every input is a recording; livetrack.batch runs them split per frame range."""
    from livetrack.batch.detect import (
        DEFAULT_RANGE_FRAMES,
        DetectSettings,
        detect_recordings,
        output_names,
        summary_table,
    )
    from livetrack.batch.executor import make_executor

    if args.focal_px is not None:
        raise ConfigError("--focal-px", "is for image files (a recording has its camera)")
    range_frames = DEFAULT_RANGE_FRAMES if args.range_frames is None else args.range_frames
    if range_frames < 1:
        raise ConfigError("--range-frames", f"must be >= 1, got {range_frames}")
    not_dirs = [p for p in args.inputs if not Path(p).is_dir()]
    if not_dirs:
        raise ConfigError("--json-dir", f"takes recording directories; not a directory: {not_dirs[0]}")
    try:
        names = output_names(args.inputs)
    except ValueError as exc:
        raise ConfigError("inputs", str(exc)) from None
    if args.camera:
        load_camera_with_optics(args.camera)  # checked here, once, before any task
    if args.targets:
        load_targets(args.targets)
    settings = DetectSettings(camera=str(args.camera.resolve()) if args.camera else None,
                              targets=str(args.targets.resolve()) if args.targets else None,
                              compensate_exposure=not args.no_compensation,
                              fit_target_model=args.fit_target_model, timings=not args.no_timings,
                              max_frames=args.max_frames)
    t0 = time.perf_counter()
    with make_executor(args.workers, args.scheduler, args.retries) as executor:
        print(f"livetrack detect: {len(args.inputs)} recordings on {executor.description}, ranges of "
              f"{range_frames} frames", file=sys.stderr)
        outputs = detect_recordings(args.inputs, settings, executor, range_frames, progress=not args.no_progress)
    seconds = time.perf_counter() - t0
    args.json_dir.mkdir(parents=True, exist_ok=True)
    for out, name in zip(outputs, names, strict=True):
        (args.json_dir / name).write_text(json.dumps(out.to_dict(), indent=1, allow_nan=False))
    print(summary_table(outputs, names))
    frames = sum(len(o.frames) for o in outputs)
    print(f"{frames} frames in {seconds:.1f} s ({frames / max(seconds, 1e-9):.1f} frames/s) -> {args.json_dir}")
    for out in outputs:
        for error in out.errors:
            where = "" if error["frames"] is None else f" frames {error['frames'][0]}-{error['frames'][1]}"
            print(f"FAILED {out.path}{where}: {error['error'].splitlines()[0]}", file=sys.stderr)
    return 0 if all(o.complete for o in outputs) else 1


def _run_recording(folder: Path, args, options, camera_file) -> list[dict]:
    try:
        rec = Recording.open(folder)
    except RecordingError as exc:
        raise ConfigError(str(folder), str(exc)) from None
    camera = _with_encoding(camera_file or rec.camera, args.encoding)
    targets = load_targets(args.targets) if args.targets else rec.targets
    tracker = Tracker(camera, targets, options)
    out = []
    for n, (frame, image) in enumerate(rec.iter_images()):
        if args.max_frames is not None and n >= args.max_frames:
            break
        result = tracker.process(image, frame.exposure_us)
        out.append({"frame_id": frame.frame_id, "timestamp_ns": frame.timestamp_ns, "exposure_us": frame.exposure_us,
                    **_result_dict(result)})
        for failure in result.failures:
            log.info("frame %s: %s", frame.frame_id, _failure_text(target_failure_to_dict(failure)))
    for frame_id, reason in rec.skipped:
        log.warning("frame %s skipped: %s", frame_id, reason)
    return out


def _run_images(files: list[Path], args, options, camera_file: CameraModel | None) -> list[dict]:
    if not args.targets:
        raise ConfigError("--targets", "required for image files (their physical size sets the scale)")
    targets = load_targets(args.targets)
    out = []
    for n, file in enumerate(files):
        if args.max_frames is not None and n >= args.max_frames:
            break
        try:
            entry = _run_image(file, targets, args, options, camera_file)
        except (ImageError, ConfigError) as exc:
            log.error("%s: %s; skipped", file, exc)
            out.append({"file": str(file), "error": str(exc), "targets": [], "failures": []})
            continue
        for warning in entry["warnings"]:
            log.warning("%s: %s", file, warning)
        print(_image_text(entry))
        out.append(entry)
    return out


def _run_image(file: Path, targets: list[TargetSpec], args, options, camera_file: CameraModel | None) -> dict:
    stated = args.bit_depth is not None or (camera_file is not None and states_bit_depth(args.camera))
    if args.bit_depth is not None and camera_file is not None:
        camera_file = dataclasses.replace(camera_file, bit_depth=args.bit_depth)
    image, warnings = load_image(file, camera_file if stated else None)
    height, width = image.shape
    if stated:
        depth = args.bit_depth if args.bit_depth is not None else camera_file.bit_depth
    else:
        depth = data_bit_depth(image)
        log.info("%s: bit depth %d taken from the data (largest value %d; --bit-depth or the camera file's "
                 "bit_depth say otherwise)", file, depth, int(image.max()))
        if camera_file is not None:
            camera_file = dataclasses.replace(camera_file, bit_depth=depth)
    camera, camera_kind, no_camera_reason = camera_file, "file", NO_CAMERA
    if camera is not None and (camera.width, camera.height) != (width, height):
        raise ImageError(f"image is {width}x{height} but the camera is {camera.width}x{camera.height}")
    if camera is None and args.focal_px is not None:
        camera, camera_kind = CameraModel(width=width, height=height, fx=args.focal_px, fy=args.focal_px,
                                          cx=(width - 1) / 2.0, cy=(height - 1) / 2.0, bit_depth=depth), "focal_px"
    elif camera is None:
        try:
            camera, camera_kind = camera_from_exif(file, width, height, args.pixel_pitch_um, depth), "exif"
        except ConfigError as exc:
            camera_kind, no_camera_reason = None, f"{NO_CAMERA} ({exc.problem})"
    entry: dict[str, Any] = {"file": str(file), "width_px": width, "height_px": height,
                             "dtype": str(image.dtype), "bit_depth": depth,
                             "bit_depth_from": "stated" if stated else "data", "camera": camera_kind}
    if camera is None:
        entry.update(_detections_without_camera(image, targets, depth, no_camera_reason))
    else:
        if args.encoding is None and camera_kind == "focal_px":
            # no camera file: the image's own word (a PNG's sRGB or gAMA chunk, EXIF ColorSpace), if any
            camera = dataclasses.replace(camera, encoding=image_encoding(file) or camera.encoding)
        camera = _with_encoding(camera, args.encoding)
        entry["encoding"] = camera.encoding
        entry.update(_result_dict(Tracker(camera, targets, options).process(image)))
    entry["warnings"] = warnings
    return entry


def _encoding_arg(value: str | None) -> str | None:
    """``--encoding`` in its canonical spelling (None: not given); ConfigError naming the option otherwise."""
    if value is None:
        return None
    known = canonical(value)
    if known is None:
        raise ConfigError("--encoding", str(encoding_problem(value)))
    return known


def _with_encoding(camera: CameraModel, value: str | None) -> CameraModel:
    """``camera`` with the ``--encoding`` given (checked by ``_encoding_arg``), or as it is."""
    encoding = _encoding_arg(value)
    return camera if encoding is None else dataclasses.replace(camera, encoding=encoding)


DATA_BIT_DEPTHS = (10, 12, 14, 16)


def data_bit_depth(image: np.ndarray) -> int:
    """The bit depth an image's values suggest when nobody states it: 8 for 8-bit data; for 16-bit words the
    smallest of 10, 12, 14 and 16 bits whose top code holds the largest value (a 12-bit camera's frames saved
    LSB-aligned in a 16-bit PNG clip at 4095: taken as 16-bit, their clipped pixels would not count as clipped,
    and over-exposed edges would be read biased)."""
    if image.dtype == np.uint8:
        return 8
    top = int(image.max()) if image.size else 0
    return next((b for b in DATA_BIT_DEPTHS if top <= (1 << b) - 1), 16)


def load_image(file: Path, camera: CameraModel | None) -> tuple[np.ndarray, list[str]]:
    """A single-channel uint8 or uint16 image from ``file``, and warnings about its values.

    Colour is converted to grey (OpenCV's weights). A float image (e.g. a 32-bit TIFF) holding values in [0, 1]
    is scaled to the camera's full scale (``camera.saturation_level``; 65535 without a camera file) and rounded;
    one holding larger values is taken as digital numbers (rounded; at most 65535). Non-finite or negative float
    values, signed integers and other pixel types are refused (``ImageError``). Values above the camera's
    saturation level (e.g. 16-bit data with a 12-bit camera file: MSB-aligned, or another camera) are kept and
    warned about: the estimator takes them as saturated.
    """
    if not file.is_file():
        raise ImageError("no such file" if not file.exists() else "not a regular file")
    image = cv2.imread(str(file), cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION)
    if image is None:
        raise ImageError("cannot read the image (not an image format OpenCV reads, or corrupt)")
    if image.ndim == 3:
        channels = image.shape[2]
        if image.dtype == np.float64:
            image = image.astype(np.float32)
        if channels == 1:
            image = image[:, :, 0]
        elif channels in (3, 4) and image.dtype in (np.uint8, np.uint16, np.float32):
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if channels == 3 else cv2.COLOR_BGRA2GRAY)
        else:
            raise ImageError(f"unsupported image: {channels} channels of {image.dtype}")
    if image.ndim != 2 or image.size == 0:
        raise ImageError(f"unsupported image shape {image.shape}")
    full_scale = float(camera.saturation_level) if camera is not None else 65535.0
    if image.dtype.kind == "f":
        image = _from_float(image, full_scale, camera)
    elif image.dtype not in (np.uint8, np.uint16):
        raise ImageError(f"unsupported pixel type {image.dtype} (unsigned 8 or 16 bit, or float, are read)")
    warnings = []
    if camera is not None:
        peak = int(image.max())
        if peak > camera.saturation_level:
            above = int(np.count_nonzero(image > camera.saturation_level))
            warnings.append(f"{above} pixel values above the camera's {camera.bit_depth}-bit maximum "
                            f"{camera.saturation_level} (largest {peak}): the data are not {camera.bit_depth}-bit "
                            "LSB-aligned (MSB-aligned, or another camera?); they count as saturated")
    return image, warnings


def _from_float(image: np.ndarray, full_scale: float, camera: CameraModel | None) -> np.ndarray:
    if not np.all(np.isfinite(image)):
        raise ImageError("float image with non-finite values (NaN or infinity)")
    low, high = float(image.min()), float(image.max())
    if low < 0:
        raise ImageError(f"float image with negative values (min {low:g}); expected [0, 1] or digital numbers")
    if high > 65535:
        raise ImageError(f"float image with values up to {high:g}, beyond 16 bits")
    scale = full_scale if high <= 1.0 else 1.0
    log.info("float image (%s, %g to %g): %s", image.dtype, low, high,
             f"scaled from [0, 1] to 0-{full_scale:g}" if high <= 1.0 else "values taken as digital numbers")
    dtype = np.uint8 if camera is not None and camera.bit_depth == 8 and high <= 1.0 else np.uint16
    return np.rint(image.astype(np.float64) * scale).astype(dtype)


def _result_dict(result: FrameResult) -> dict:
    return {"timings_ms": result.timings_ms,
            "targets": [target_result_to_dict(t) for t in result.targets],
            "failures": [target_failure_to_dict(f) for f in result.failures]}


def _detections_without_camera(image: np.ndarray, targets: list[TargetSpec], depth: int, reason: str) -> dict:
    """What the detector finds, per target: id, levels and their ellipses; the pose omitted with ``reason``."""
    t0 = time.perf_counter_ns()
    top = float((1 << depth) - 1)  # the data's, or lower where its pixels clip lower (as the tracker reads it)
    candidates = detect(image, targets, saturation=frame_saturation_dn(image, top, CLIP_MARGIN_FRACTION * top))
    detect_ms = (time.perf_counter_ns() - t0) / 1e6
    found = []
    for group in group_levels(candidates):
        top = group[0]
        found.append({"target_id": top.target_id, "levels": [c.level for c in group],
                      "heading_known": top.heading_rad is not None,
                      "heading_rad": None if top.heading_rad is None else float(top.heading_rad),
                      "ellipses": [_ellipses_dict(c) for c in group], "pose": None, "pose_reason": reason})
    return {"timings_ms": {"detect_ms": detect_ms, "total_ms": detect_ms}, "targets": found, "failures": []}


def _ellipses_dict(cand: Candidate) -> dict:
    return {"level": cand.level, "outer": _ellipse_dict(cand.outer), "inner": _ellipse_dict(cand.inner),
            "darker_outside": bool(cand.darker_outside)}


def _ellipse_dict(ellipse: Ellipse) -> dict:
    return {"centre_px": [float(v) for v in ellipse.centre_px],
            "semi_axes_px": [float(v) for v in ellipse.semi_axes_px], "angle_rad": float(ellipse.angle_rad)}


def _failure_text(failure: dict) -> str:
    x, y = failure["centre_px"]
    return (f"target {failure['target_id']} level {failure['level']} at ({x:.1f}, {y:.1f}): "
            f"{failure['stage']} failed: {failure['reason']}")


def _image_text(entry: dict) -> str:
    lines = [f"{entry['file']}: {entry['width_px']}x{entry['height_px']}, camera "
             f"{entry['camera'] or 'none'}, {len(entry['targets'])} target(s)"]
    for t in entry["targets"]:
        if t.get("pose", True) is None:
            centre = t["ellipses"][0]["outer"]["centre_px"]
            lines.append(f"  target {t['target_id']} levels {t['levels']} at ({centre[0]:.1f}, {centre[1]:.1f}): "
                         f"no pose ({t['pose_reason']})")
        elif t["ok"]:
            lines.append(f"  target {t['target_id']} levels {t['levels']}: {t['distance_m']:.4f} m, "
                         f"delta {t['delta_px']:+.2f} px, residual {t['residual_rms_px']:.2f} px")
    for f in entry["failures"]:
        lines.append("  " + _failure_text(f))
    return "\n".join(lines)
