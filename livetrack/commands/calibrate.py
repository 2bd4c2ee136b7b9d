"""``livetrack calibrate``: camera intrinsics and distortion, written as a camera file that ``run``/``detect``
read (with an ``uncertainty`` section: 1-sigma of every parameter).

- ``calibrate chessboard IMAGES...|RECORDING --inner 9x6 --square-mm S --out camera.yaml``
- ``calibrate charuco IMAGES...|RECORDING --squares 7x5 --square-mm S --marker-mm M --dictionary DICT_5X5_100
  --out camera.yaml`` (OpenCV's aruco module; views may show the board in part)
- ``calibrate targets IMAGES...|RECORDING --targets targets.yaml --out camera.yaml`` (bundle adjustment over the
  edge points of ring targets, with one exposure bias per target per view; docs/calibration.md)

Live (``--source URI``): views are collected from a source, the coverage shown on the console and, with
``--rerun MODE``, in Rerun (``livetrack.calibration.live_view``); the collection stops by itself once the coverage
(cells and corner cells) and the 1-sigma of fx, cx, cy, k1 of a calibration of the views so far reach the
``--stop-*`` thresholds (``livetrack.calibration.live``), else at ``--views`` / ``--max-frames`` /
``--max-seconds``, saying which thresholds were not reached.

Every mode prints the parameters with their standard deviations, the RMS and per-view errors and the coverage; views
that cannot be used or whose residuals are large are rejected with a message. ``--plots DIR``: residual quiver and
coverage heat map; ``--json OUT``: every figure.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
from pathlib import Path

import cv2
import numpy as np

from livetrack.config.checks import ConfigError

NAME = "calibrate"
HELP = "calibrate a camera from chessboard / ChArUco views or from views of ring targets; write a camera file"
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
    charuco = sub.add_parser("charuco", help="ChArUco board calibration (OpenCV's aruco module): partial views "
                             "of the board count")
    _common(charuco)
    charuco.add_argument("--squares", required=True, help="squares of the board COLSxROWS, e.g. 7x5")
    charuco.add_argument("--square-mm", type=float, required=True, help="side of one square, mm")
    charuco.add_argument("--marker-mm", type=float, required=True, help="side of one ArUco marker, mm")
    charuco.add_argument("--dictionary", default="DICT_5X5_100",
                         help="ArUco dictionary, OpenCV's name (default DICT_5X5_100; e.g. DICT_4X4_50, "
                              "DICT_6X6_250, DICT_APRILTAG_36h11)")
    charuco.add_argument("--min-corners", type=int, default=8,
                         help="a view needs at least this many identified corners (default 8)")
    charuco.add_argument("--reject-factor", type=float, default=3.0,
                         help="reject a view whose RMS error is above this times the median (and above "
                              "--reject-min-px); default 3")
    charuco.add_argument("--reject-min-px", type=float, default=1.0, help="default 1.0 px")
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
                   "at least 5 %% of the image diagonal from every earlier view's; stops when the --stop-* "
                   "thresholds are reached, else at --views views, --max-frames frames or --max-seconds")
    p.add_argument("--source-option", action="append", default=[], metavar="KEY=VALUE",
                   help="a source option (YAML value), e.g. realtime=false; repeatable")
    p.add_argument("--views", type=int, default=40, help="most views to collect from --source (default 40)")
    p.add_argument("--max-seconds", type=float, default=600.0,
                   help="stop collecting from --source after this long, s (default 600)")
    p.add_argument("--rerun", metavar="MODE", help="show a --source collection in Rerun: spawn | connect[:URL] | "
                   "serve | save:PATH.rrd | off (default: the console only)")
    from livetrack.calibration.report import COVERAGE_CELLS

    p.add_argument("--stop-coverage", type=float, default=0.6,
                   help="--source stops once this fraction of the {}x{} image cells hold a feature point (default "
                        "0.6) and the other thresholds are reached".format(*COVERAGE_CELLS))
    p.add_argument("--stop-corners", type=int, default=4,
                   help="... and this many of the 4 corner cells (default 4)")
    p.add_argument("--stop-std-fx", type=float, default=0.002,
                   help="... and the 1-sigma of fx is at most this fraction of fx (default 0.002)")
    p.add_argument("--stop-std-c", type=float, default=0.004,
                   help="... and the 1-sigma of cx, cy at most this fraction of cx, cy (default 0.004)")
    p.add_argument("--stop-std-k1", type=float, default=0.05,
                   help="... and the 1-sigma of k1 at most this fraction of max(|k1|, 0.05) (default 0.05)")
    p.add_argument("--stop-min-views", type=int, default=6,
                   help="no uncertainty check before this many views (default 6)")
    p.add_argument("--check-every", type=int, default=1,
                   help="once the coverage is reached, calibrate the views so far every N new views for the "
                        "uncertainty check (default 1; a targets adjustment of 10 views takes ~4 s of CPU)")
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
    of the image diagonal away from the earlier ones. Progress on the console (and in Rerun with ``--rerun``);
    stops when the coverage and the parameter uncertainties of a calibration of the views so far reach the
    ``--stop-*`` thresholds (``livetrack.calibration.live``), else at ``--views`` views, ``--max-frames`` frames
    or ``--max-seconds``. Returns (images, names, exposures, source info, the collection's state)."""
    import time

    import yaml

    from livetrack.calibration.live import check
    from livetrack.calibration.live_view import make_view
    from livetrack.sources import open_source
    from livetrack.sources.base import SourceError

    rule = _stop_rule(args)
    options = {}
    for item in args.source_option:
        key, _, value = item.partition("=")
        options[key] = yaml.safe_load(value)
    try:
        source = open_source(args.source, options)
    except SourceError as exc:
        raise ConfigError("--source", str(exc)) from None
    try:
        view = make_view(args.rerun)
    except (ValueError, ConnectionError, OSError, RuntimeError) as exc:
        source.close()
        raise ConfigError("--rerun", str(exc)) from None
    finder = _view_finder(args, source)
    images, names, exposures, centres, points, found_extra = [], [], [], [], [], []
    seen, last_check, progress, reason = 0, 0, None, ""
    start_s = time.monotonic()
    try:
        while True:
            if len(images) >= args.views:
                reason = f"{args.views} views (--views)"
                break
            if args.max_frames is not None and seen >= args.max_frames:
                reason = f"{seen} frames (--max-frames)"
                break
            if args.max_seconds is not None and time.monotonic() - start_s > args.max_seconds:
                reason = f"{args.max_seconds:g} s (--max-seconds)"
                break
            try:
                frame = source.read(2.0)
            except EOFError:
                reason = "end of the source"
                break
            if frame is None:
                continue
            seen += 1
            found = finder(frame.image, frame.exposure_us, len(images))
            if found is None:
                continue
            found_points, extra = found
            height, width = frame.image.shape[:2]
            centre = found_points.mean(axis=0)
            if any(np.hypot(*(centre - c)) < 0.05 * np.hypot(width, height) for c in centres):
                continue
            images.append(frame.image)
            names.append(f"frame {frame.frame_id}")
            exposures.append(frame.exposure_us)
            centres.append(centre)
            points.append(found_points)
            found_extra.append(extra)
            view.view_added(frame.image, frame.frame_id, points, args.views, source.camera.bit_depth)
            progress = check(rule, points, width, height)
            due = len(images) - last_check >= args.check_every or last_check == 0
            if progress.coverage_reached and len(images) >= rule.min_views and due:
                last_check = len(images)
                fit = _quick_calibration(args, source, points, found_extra, width, height)
                progress = check(rule, points, width, height, *(fit or (None, None)))
                view.checked(progress, rule)
                if progress.done:
                    reason = "every threshold reached"
                    break
    except BaseException:
        view.close()
        raise
    finally:
        source.close()
    if progress is None or not progress.done:
        view.message(f"collection stopped at {reason}, thresholds not reached: "
                     + ("; ".join(progress.unmet) if progress is not None else "no view found"))
    else:
        view.message(f"collection done after {len(images)} views ({seen} frames): {reason}")
    return images, names, exposures, _SourceInfo(source), _Collection(view, rule, reason, progress)


class _SourceInfo:
    """What ``_targets`` reads of a recording, from a live source: its camera and targets."""

    def __init__(self, source):
        self.camera, self.targets = source.camera, list(source.targets)


class _Collection:
    """A live collection's viewer, stop rule, why it stopped and its last check."""

    def __init__(self, view, rule, reason, progress):
        self.view, self.rule, self.reason, self.progress = view, rule, reason, progress


def _stop_rule(args):
    from livetrack.calibration.live import StopRule

    try:
        return StopRule(coverage=args.stop_coverage, corners=args.stop_corners, fx_rel=args.stop_std_fx,
                        cx_rel=args.stop_std_c, cy_rel=args.stop_std_c, k1_rel=args.stop_std_k1,
                        min_views=args.stop_min_views)
    except ValueError as exc:
        raise ConfigError("--stop-*", str(exc)) from None


def _quick_calibration(args, source, points, extras, width, height):
    """(camera, uncertainty) of the views so far, for the stop check; None if the calibration fails."""
    try:
        if args.mode == "chessboard":
            from livetrack.calibration.chessboard import ChessboardOptions, board_points_m, calibrate_points

            cols, rows = _inner(args)
            board = board_points_m((cols, rows), args.square_mm * 1e-3)
            result = calibrate_points([board] * len(points), points, width, height,
                                      options=ChessboardOptions(inner=(cols, rows), square_m=args.square_mm * 1e-3,
                                                                reject_factor=args.reject_factor,
                                                                reject_min_px=args.reject_min_px))
        elif args.mode == "targets":
            from livetrack.calibration.targets import bundle_adjust

            obs = [o for extra in extras for o in extra]
            result = bundle_adjust(obs, source.camera, len(points), _target_options(args))
        else:
            from livetrack.calibration.chessboard import ChessboardOptions, calibrate_points

            result = calibrate_points(extras, points, width, height,
                                      options=ChessboardOptions(reject_factor=args.reject_factor,
                                                                reject_min_px=args.reject_min_px))
    except (ValueError, np.linalg.LinAlgError) as exc:
        log.info("stop check: the calibration of %d views failed (%s)", len(points), exc)
        return None
    return result.camera, result.uncertainty


def _view_finder(args, source):
    """image, exposure_us, view index -> (the found feature points (N, 2), mode data), or None. Mode data: for
    targets the edge points assigned to their circles (``TargetView``), for the stop checks' adjustments."""
    if args.mode == "chessboard":
        from livetrack.calibration.chessboard import find_corners

        cols, rows = _inner(args)

        def corners(image, _exposure, _index):
            found = find_corners(image, (cols, rows), args.subpix_window_px)
            return None if found is None else (found, None)
        return corners
    if args.mode == "charuco":
        from livetrack.calibration.charuco import CharucoFinder

        finder = CharucoFinder(_charuco_options(args))

        def charuco(image, _exposure, _index):
            found = finder.find(image)
            return None if found is None else (found[1], found[0])  # image points; board points for the checks
        return charuco
    from livetrack.calibration.targets import TargetView, assign_circles
    from livetrack.estimator.tracker import Tracker
    from livetrack.targets.spec import load_targets

    targets = load_targets(args.targets) if args.targets else list(source.targets)
    by_id = {t.id: t for t in targets}
    tracker = Tracker(source.camera, targets)

    def find(image, exposure_us, index):
        tracker.reset()
        result = tracker.process(image, exposure_us)
        fitted = [t for t in result.targets if t.fit and t.target_id in by_id]
        if not fitted:
            return None
        obs = [TargetView(index, t.target_id, assign_circles(source.camera, t.edge_points_px, t.pose,
                                                             by_id[t.target_id]), t.pose, float(t.delta_px))
               for t in fitted]
        return np.concatenate([t.edge_points_px for t in fitted]), [o for o in obs if len(o.edges) >= 30]
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
    from livetrack.camera.io import write_camera_file

    collection = None
    if args.source:
        images, names, exposures, rec, collection = collect_views(args)
    elif not args.inputs:
        raise ConfigError("inputs", "give image files, a recording directory or --source URI")
    else:
        images, names, exposures, rec = read_views([Path(p) for p in args.inputs], args.max_frames)
    if not images:
        if collection is not None:
            collection.view.close()
        raise ConfigError("inputs", "no readable image" if collection is None else "no view found")
    try:
        if args.mode == "chessboard":
            result, comment = _chessboard(args, images, names)
        elif args.mode == "charuco":
            result, comment = _charuco(args, images, names)
        else:
            result, comment = _targets(args, images, names, exposures, rec)
    except ValueError as exc:
        if collection is not None:
            collection.view.close()
        if isinstance(exc, ConfigError):
            raise
        log.error("calibration failed: %s", exc)
        return 1
    print(summary_text(result))
    if collection is not None:
        _final_check(collection, result)
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


def _final_check(collection, result) -> None:
    """The stop thresholds against the final calibration of the collected views (printed, and in Rerun)."""
    from livetrack.calibration.live import check

    cam = result.camera
    final = check(collection.rule, result.points_px, cam.width, cam.height, cam, result.uncertainty)
    collection.view.checked(final, collection.rule)
    if final.done:
        collection.view.message("final calibration: every threshold reached")
    else:
        collection.view.message("final calibration: thresholds not reached: " + "; ".join(final.unmet))
    collection.view.close()


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


def _charuco_options(args):
    from livetrack.calibration.charuco import CharucoOptions

    try:
        cols, rows = (int(v) for v in args.squares.lower().split("x"))
    except ValueError:
        raise ConfigError("--squares", f"must be COLSxROWS (squares), e.g. 7x5, got {args.squares!r}") from None
    for flag, value in (("--square-mm", args.square_mm), ("--marker-mm", args.marker_mm)):
        if not (np.isfinite(value) and value > 0):
            raise ConfigError(flag, f"must be a positive length, got {value}")
    if args.marker_mm >= args.square_mm:
        raise ConfigError("--marker-mm", f"the marker ({args.marker_mm} mm) must be smaller than the square "
                                         f"({args.square_mm} mm)")
    try:
        return CharucoOptions(squares=(cols, rows), square_m=args.square_mm * 1e-3, marker_m=args.marker_mm * 1e-3,
                              dictionary=args.dictionary, min_corners=args.min_corners,
                              reject_factor=args.reject_factor, reject_min_px=args.reject_min_px)
    except ValueError as exc:
        flag = "--dictionary" if "dictionary" in str(exc) else "--squares"
        raise ConfigError(flag, str(exc)) from None


def _charuco(args, images, names):
    from livetrack.calibration.charuco import calibrate_charuco_images, make_board

    options = _charuco_options(args)
    try:
        make_board(options)
    except ValueError as exc:
        raise ConfigError("--dictionary", str(exc)) from None
    depth = 8 if images[0].dtype == np.uint8 else 16
    result = calibrate_charuco_images(images, names, options, bit_depth=depth)
    cols, rows = options.squares
    comment = (f"livetrack calibrate charuco: {len(result.view_names)} views of a {cols}x{rows} {options.dictionary} "
               f"board, RMS {result.rms_px:.4f} px")
    return result, comment


def _targets(args, images, names, exposures, rec):
    from livetrack.calibration.targets import calibrate_targets
    from livetrack.camera import CameraModel
    from livetrack.camera.encoding import as_linear
    from livetrack.camera.io import load_camera
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
                              cy=(height - 1) / 2.0, bit_depth=depth,
                              encoding=rec.camera.encoding if rec is not None else "linear")
        log.info("initial camera: f = %d px (the image width), centred, no distortion", width)
    if (initial.width, initial.height) != (width, height):
        raise ConfigError("--initial", f"camera is {initial.width}x{initial.height}, the images {width}x{height}")
    options = _target_options(args)
    # the edges are modelled in linear light: an encoded camera's views are read linearised (as the tracker does),
    # and the calibrated camera is written back in the views' own terms (bit depth, encoding)
    linear_initial, linear_images = as_linear(initial, images)
    result = calibrate_targets(linear_images, targets, linear_initial, exposures, names, options)
    if linear_initial is not initial:
        result = dataclasses.replace(result, camera=dataclasses.replace(
            result.camera, bit_depth=initial.bit_depth, encoding=initial.encoding))
    comment = (f"livetrack calibrate targets: {len(result.view_names)} views, "
               f"{'exposure bias compensated' if options.compensate else 'delta fixed at 0'}, "
               f"RMS {result.rms_px:.4f} px")
    return result, comment


def _target_options(args):
    from livetrack.calibration.targets import TargetCalibrationOptions

    return TargetCalibrationOptions(compensate=not args.no_compensation, fit_tangential=args.fit_tangential,
                                    fit_k3=args.fit_k3, delta_per_target=not args.delta_per_view)


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
