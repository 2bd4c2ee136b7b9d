"""``livetrack calibrate``: camera intrinsics and distortion, written as a camera file that ``run``/``detect``
read (with an ``uncertainty`` section: 1-sigma of every parameter).

- ``calibrate chessboard IMAGES...|RECORDING --inner 9x6 --square-mm S --out camera.yaml``
- ``calibrate targets IMAGES...|RECORDING --targets targets.yaml --out camera.yaml`` (bundle adjustment over the
  edge points of ring targets, with one exposure bias per target per view; docs/calibration.md)

Both print the parameters with their standard deviations, the RMS and per-view errors and the coverage; views
that cannot be used or whose residuals are large are rejected with a message. ``--plots DIR``: residual quiver and
coverage heat map; ``--json OUT``: every figure.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import cv2
import numpy as np

from livetrack.config_checks import ConfigError

NAME = "calibrate"
HELP = "calibrate a camera from chessboard views or from views of ring targets; write a camera file"
log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="mode", metavar="MODE", required=True)
    board = sub.add_parser("chessboard", help="OpenCV chessboard calibration with rejection and uncertainties")
    _common(board)
    board.add_argument("--inner", required=True, help="inner corners COLSxROWS, e.g. 9x6")
    board.add_argument("--square-mm", type=float, required=True, help="side of one square, mm")
    board.add_argument("--subpix-window-px", type=int, default=11,
                       help="largest half-size of the sub-pixel corner window (adapted down to 0.4 x the corner "
                            "spacing of each view; default 11)")
    board.add_argument("--reject-factor", type=float, default=3.0,
                       help="reject a view whose RMS error is above this times the median (and above "
                            "--reject-min-px); default 3")
    board.add_argument("--reject-min-px", type=float, default=1.0, help="default 1.0 px")
    targets = sub.add_parser("targets", help="bundle adjustment over ring-target edges with exposure bias")
    _common(targets)
    targets.add_argument("--targets", type=Path, help="targets YAML (default: the recording's)")
    targets.add_argument("--initial", type=Path, help="initial camera YAML (default: f = image width, centred, "
                         "no distortion; a recording's camera when given one)")
    targets.add_argument("--no-compensation", action="store_true", help="fix every view's delta at 0 (baseline)")
    targets.add_argument("--fit-tangential", action="store_true", help="also fit p1, p2 (default: fixed at 0)")
    targets.add_argument("--fit-k3", action="store_true", help="also fit k3 (default: fixed at 0)")
    targets.add_argument("--delta-per-view", action="store_true",
                         help="one exposure bias per view shared by its targets (default: one per target per view)")


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("inputs", nargs="*", metavar="IMAGES|RECORDING", help="image files or one recording directory")
    p.add_argument("--source", help="collect the views live from a source URI (sim:FILE, aravis:..., v4l2:...) "
                   "instead of files: a frame becomes a view when its features are found and their centre lies "
                   "at least 5 %% of the image diagonal from every earlier view's; stops at --views views or "
                   "--max-frames frames")
    p.add_argument("--source-option", action="append", default=[], metavar="KEY=VALUE",
                   help="a source option (YAML value), e.g. realtime=false; repeatable")
    p.add_argument("--views", type=int, default=20, help="views to collect from --source (default 20)")
    p.add_argument("--out", type=Path, required=True, help="camera YAML to write")
    p.add_argument("--plots", type=Path, help="folder for residuals.png and coverage.png")
    p.add_argument("--json", type=Path, help="every figure as JSON")
    p.add_argument("--max-frames", type=int, default=None, help="use at most N images / frames")


def read_views(inputs: list[Path], max_frames: int | None):
    """(images, names, exposure_us per view or None, recording or None) from image files or one recording."""
    from livetrack.recording import Recording, RecordingError

    if len(inputs) == 1 and inputs[0].is_dir():
        try:
            rec = Recording.open(inputs[0])
        except RecordingError as exc:
            raise ConfigError(str(inputs[0]), str(exc)) from None
        images, names, exposures = [], [], []
        for frame, image in rec.iter_images():
            if max_frames is not None and len(images) >= max_frames:
                break
            images.append(image)
            names.append(f"frame {frame.frame_id}")
            exposures.append(frame.exposure_us)
        return images, names, exposures, rec
    images, names = [], []
    for file in inputs[:max_frames]:
        image = cv2.imread(str(file), cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION)
        if image is None:
            log.warning("%s: cannot read the image; skipped", file)
            continue
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
        images.append(image)
        names.append(file.name)
    return images, names, None, None


def collect_views(args: argparse.Namespace):
    """Views from a live source: frames whose chessboard / targets are found, each new one centred at least 5 %
    of the image diagonal away from the earlier ones; progress and coverage on the console."""
    import yaml

    from livetrack.calibration.report import coverage_map
    from livetrack.sources import open_source
    from livetrack.sources.base import SourceError

    options = {}
    for item in args.source_option:
        key, _, value = item.partition("=")
        options[key] = yaml.safe_load(value)
    try:
        source = open_source(args.source, options)
    except SourceError as exc:
        raise ConfigError("--source", str(exc)) from None
    finder = _view_finder(args, source)
    images, names, exposures, centres, points = [], [], [], [], []
    seen = 0
    try:
        while len(images) < args.views and (args.max_frames is None or seen < args.max_frames):
            try:
                frame = source.read(2.0)
            except EOFError:
                break
            if frame is None:
                continue
            seen += 1
            found = finder(frame.image, frame.exposure_us)
            if found is None:
                continue
            height, width = frame.image.shape[:2]
            centre = found.mean(axis=0)
            if any(np.hypot(*(centre - c)) < 0.05 * np.hypot(width, height) for c in centres):
                continue
            images.append(frame.image)
            names.append(f"frame {frame.frame_id}")
            exposures.append(frame.exposure_us)
            centres.append(centre)
            points.append(found)
            cov = coverage_map(points, width, height)
            print(f"view {len(images)}/{args.views} (frame {frame.frame_id}): coverage "
                  f"{cov.covered_fraction:.0%} of the image cells", flush=True)
    finally:
        source.close()
    return images, names, exposures, _SourceInfo(source)


class _SourceInfo:
    """What ``_targets`` reads of a recording, from a live source: its camera and targets."""

    def __init__(self, source):
        self.camera, self.targets = source.camera, list(source.targets)


def _view_finder(args, source):
    """image, exposure_us -> the found feature points (N, 2), or None."""
    if args.mode == "chessboard":
        from livetrack.calibration.chessboard import find_corners

        cols, rows = _inner(args)
        return lambda image, _exposure: find_corners(image, (cols, rows), args.subpix_window_px)
    from livetrack.estimator.tracker import Tracker
    from livetrack.targets.spec import load_targets

    targets = load_targets(args.targets) if args.targets else list(source.targets)
    tracker = Tracker(source.camera, targets)

    def find(image, exposure_us):
        tracker.reset()
        result = tracker.process(image, exposure_us)
        found = [t.edge_points_px for t in result.targets if t.fit]
        return np.concatenate(found) if found else None
    return find


def _inner(args) -> tuple[int, int]:
    try:
        cols, rows = (int(v) for v in args.inner.lower().split("x"))
    except ValueError:
        raise ConfigError("--inner", f"must be COLSxROWS (inner corners), e.g. 9x6, got {args.inner!r}") from None
    if cols < 2 or rows < 2:
        raise ConfigError("--inner", f"at least 2x2 inner corners, got {args.inner!r}")
    return cols, rows


def run(args: argparse.Namespace) -> int:
    from livetrack.calibration.report import summary_text
    from livetrack.camera_io import write_camera_file

    if args.source:
        images, names, exposures, rec = collect_views(args)
    elif not args.inputs:
        raise ConfigError("inputs", "give image files, a recording directory or --source URI")
    else:
        images, names, exposures, rec = read_views([Path(p) for p in args.inputs], args.max_frames)
    if not images:
        raise ConfigError("inputs", "no readable image")
    try:
        if args.mode == "chessboard":
            result, comment = _chessboard(args, images, names)
        else:
            result, comment = _targets(args, images, names, exposures, rec)
    except ValueError as exc:
        if isinstance(exc, ConfigError):
            raise
        log.error("calibration failed: %s", exc)
        return 1
    print(summary_text(result))
    write_camera_file(args.out, result.camera, None, comment=comment, uncertainty=result.uncertainty)
    print(f"camera -> {args.out}")
    if args.plots:
        from livetrack.calibration.plots import write_plots

        for file in write_plots(result, args.plots):
            print(f"plot -> {file}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(_jsonable(result.to_dict()), indent=1, allow_nan=False))
        print(f"figures -> {args.json}")
    return 0


def _chessboard(args, images, names):
    from livetrack.calibration.chessboard import ChessboardOptions, calibrate_images

    cols, rows = _inner(args)
    if not (np.isfinite(args.square_mm) and args.square_mm > 0):
        raise ConfigError("--square-mm", f"must be a positive length, got {args.square_mm}")
    options = ChessboardOptions(inner=(cols, rows), square_m=args.square_mm * 1e-3,
                                subpix_window_px=args.subpix_window_px, reject_factor=args.reject_factor,
                                reject_min_px=args.reject_min_px)
    depth = 8 if images[0].dtype == np.uint8 else 16
    result = calibrate_images(images, names, options, bit_depth=depth)
    comment = (f"livetrack calibrate chessboard: {len(result.view_names)} views of a {cols}x{rows} board, "
               f"RMS {result.rms_px:.4f} px")
    return result, comment


def _targets(args, images, names, exposures, rec):
    from livetrack.calibration.targets import TargetCalibrationOptions, calibrate_targets
    from livetrack.camera import CameraModel
    from livetrack.camera_io import load_camera
    from livetrack.targets.spec import load_targets

    if args.targets is not None:
        targets = load_targets(args.targets)
    elif rec is not None:
        targets = list(rec.targets)
    else:
        raise ConfigError("--targets", "required for image files (their physical size sets the scale)")
    height, width = images[0].shape[:2]
    if args.initial is not None:
        initial = load_camera(args.initial)
    else:
        depth = rec.camera.bit_depth if rec is not None else (8 if images[0].dtype == np.uint8 else 16)
        initial = CameraModel(width=width, height=height, fx=float(width), fy=float(width), cx=(width - 1) / 2.0,
                              cy=(height - 1) / 2.0, bit_depth=depth)
        log.info("initial camera: f = %d px (the image width), centred, no distortion", width)
    if (initial.width, initial.height) != (width, height):
        raise ConfigError("--initial", f"camera is {initial.width}x{initial.height}, the images {width}x{height}")
    options = TargetCalibrationOptions(compensate=not args.no_compensation, fit_tangential=args.fit_tangential,
                                       fit_k3=args.fit_k3, delta_per_target=not args.delta_per_view)
    result = calibrate_targets(images, targets, initial, exposures, names, options)
    comment = (f"livetrack calibrate targets: {len(result.view_names)} views, "
               f"{'exposure bias compensated' if options.compensate else 'delta fixed at 0'}, "
               f"RMS {result.rms_px:.4f} px")
    return result, comment


def _jsonable(value):
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.floating, float)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value
