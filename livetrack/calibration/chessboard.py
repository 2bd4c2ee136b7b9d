"""Calibration from chessboard views: sub-pixel inner corners, OpenCV's 5-coefficient calibration, rejection of
views with large residuals. Pure functions on images and arrays (no file I/O).

OpenCV's corner coordinates already put (0, 0) at the centre of the top-left pixel, livetrack's convention, so
corners are used as found.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.calibration.report import CalibrationResult, CameraUncertainty, RejectedView
from livetrack.camera import CameraModel

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)


@dataclass(frozen=True)
class ChessboardOptions:
    """inner : inner corners (columns, rows), e.g. (9, 6).
    square_m : side of one square, metres (sets the scale of the poses only; intrinsics do not depend on it).
    subpix_window_px : largest half-size of cornerSubPix's search window, pixels (OpenCV's tutorial uses 11).
        With ``adaptive_window`` (default) each view uses at most 0.4 x its smallest corner spacing: a window
        wider than a square pulls corners toward the neighbouring ones (OpenCV's left02.jpg, squares of ~20 px:
        1.22 px RMS with an 11 px window, 0.17 px with an adaptive one).
    reject_factor, reject_min_px : a view whose RMS error exceeds both reject_factor x the median view RMS and
        reject_min_px is rejected (the worst first, then recalibrated), while at least ``min_views`` remain.
    """

    inner: tuple[int, int] = (9, 6)
    square_m: float = 0.025
    subpix_window_px: int = 11
    adaptive_window: bool = True
    reject_factor: float = 3.0
    reject_min_px: float = 1.0
    min_views: int = 3


def board_points_m(inner: tuple[int, int], square_m: float) -> FloatArray:
    """Inner-corner positions on the board (N, 3), metres, row by row as findChessboardCorners orders them."""
    cols, rows = inner
    grid = np.zeros((rows * cols, 3))
    grid[:, 0] = np.tile(np.arange(cols), rows) * square_m
    grid[:, 1] = np.repeat(np.arange(rows), cols) * square_m
    return grid


def to_gray8(image: npt.NDArray) -> npt.NDArray[np.uint8]:
    """A grey uint8 image from grey/colour uint8 or uint16 (scaled by its maximum bit depth in use)."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.dtype == np.uint8:
        return image
    top = float(image.max()) or 1.0
    return np.clip(np.asarray(image, dtype=np.float64) * (255.0 / top), 0, 255).round().astype(np.uint8)


def find_corners(image: npt.NDArray, inner: tuple[int, int], subpix_window_px: int = 11,
                 adaptive_window: bool = True) -> FloatArray | None:
    """Inner corners of a chessboard, sub-pixel, (N, 2) float64 (x, y), or None when the board is not found
    whole. The refinement window's half-size is ``subpix_window_px``, or with ``adaptive_window`` at most 0.4 x
    the smallest distance between neighbouring corners (at least 2 px)."""
    gray = to_gray8(image)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(gray, inner, flags=flags)
    if not found or corners is None:
        return None
    w = int(subpix_window_px)
    if adaptive_window:
        w = min(w, max(2, int(0.4 * _min_spacing_px(corners.reshape(-1, 2), inner))))
    corners = cv2.cornerSubPix(gray, corners.astype(np.float32), (w, w), (-1, -1), SUBPIX_CRITERIA)
    return corners.reshape(-1, 2).astype(np.float64)


def _min_spacing_px(corners: npt.NDArray, inner: tuple[int, int]) -> float:
    grid = np.asarray(corners, dtype=np.float64).reshape(inner[1], inner[0], 2)
    along_rows = np.linalg.norm(np.diff(grid, axis=1), axis=2)
    along_cols = np.linalg.norm(np.diff(grid, axis=0), axis=2)
    return float(min(along_rows.min(), along_cols.min()))


def calibrate_points(object_points: list[FloatArray], image_points: list[FloatArray], width: int, height: int,
                     names: list[str] | None = None, options: ChessboardOptions | None = None,
                     bit_depth: int = 8) -> CalibrationResult:
    """Calibrate from per-view board points (N, 3) metres and their image points (N, 2) px; reject views with
    large residuals (``options``) and recalibrate. Raises ValueError with fewer than ``min_views`` views."""
    options = options or ChessboardOptions()
    names = list(names) if names is not None else [f"view{i}" for i in range(len(image_points))]
    keep = list(range(len(image_points)))
    rejected: list[RejectedView] = []
    while True:
        if len(keep) < options.min_views:
            raise ValueError(f"{len(keep)} usable views, at least {options.min_views} needed")
        fit = _calibrate([object_points[i] for i in keep], [image_points[i] for i in keep], width, height)
        per_view = fit[4]
        median = float(np.median(per_view))
        worst = int(np.argmax(per_view))
        limit = max(options.reject_factor * median, options.reject_min_px)
        if per_view[worst] <= limit or len(keep) <= options.min_views:
            break
        name = names[keep[worst]]
        reason = (f"RMS {per_view[worst]:.3f} px > {limit:.3f} px ({options.reject_factor:g} x the median "
                  f"{median:.3f} px)")
        log.warning("view %s rejected: %s; recalibrating", name, reason)
        rejected.append(RejectedView(name, float(per_view[worst]), reason))
        del keep[worst]
    rms, K, dist, std, per_view, residuals = fit
    camera = CameraModel(width=width, height=height, fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]),
                         cy=float(K[1, 2]), dist=tuple(float(d) for d in dist), bit_depth=bit_depth)
    return CalibrationResult(camera=camera, uncertainty=CameraUncertainty.from_vector(std), rms_px=rms,
                             view_names=[names[i] for i in keep], per_view_rms_px=per_view,
                             points_px=[np.asarray(image_points[i], dtype=np.float64) for i in keep],
                             residuals_px=residuals, rejected=rejected)


def _calibrate(object_points, image_points, width, height):
    obj = [np.asarray(p, dtype=np.float32).reshape(-1, 1, 3) for p in object_points]
    img = [np.asarray(p, dtype=np.float32).reshape(-1, 1, 2) for p in image_points]
    rms, K, dist, rvecs, tvecs, std_intr, _std_extr, per_view = cv2.calibrateCameraExtended(
        obj, img, (width, height), None, None)
    dist = np.asarray(dist, dtype=np.float64).ravel()[:5]
    residuals = []
    for o, p, r, t in zip(obj, image_points, rvecs, tvecs, strict=True):
        projected, _ = cv2.projectPoints(o.astype(np.float64), r, t, K, dist)
        residuals.append(np.asarray(p, dtype=np.float64) - projected.reshape(-1, 2))
    per_view_rms = np.array([np.sqrt(np.mean(np.sum(r * r, axis=1))) for r in residuals])
    return float(rms), K, dist, np.asarray(std_intr, dtype=np.float64).ravel()[:9], per_view_rms, residuals


@dataclass
class Views:
    """The views a board was found in (its object points in metres, image points in pixels, names), the image
    size and the views rejected (with why, already logged)."""

    obj: list[npt.NDArray]
    img: list[npt.NDArray]
    used: list[str]
    rejected: list[RejectedView]
    width: int
    height: int


def collect_views(images: list[npt.NDArray], names: list[str],
                  find: Callable[[npt.NDArray], tuple[npt.NDArray, npt.NDArray] | None], not_found: str) -> Views:
    """Run ``find`` (image -> (object points, image points), or None) on every image of the first image's size;
    the others and those ``find`` gives nothing for (``not_found``: why) are rejected with a warning. Shared by
    the chessboard and ChArUco modes."""
    if not images:
        raise ValueError("no images")
    height, width = images[0].shape[:2]
    views = Views([], [], [], [], width, height)
    for image, name in zip(images, names, strict=True):
        if image.shape[:2] != (height, width):
            views.rejected.append(RejectedView(name, float("nan"), f"image is {image.shape[1]}x{image.shape[0]}, "
                                                                   f"the first was {width}x{height}"))
            continue
        found = find(image)
        if found is None:
            views.rejected.append(RejectedView(name, float("nan"), not_found))
            continue
        views.obj.append(found[0])
        views.img.append(found[1])
        views.used.append(name)
    for r in views.rejected:
        log.warning("view %s rejected: %s", r.name, r.reason)
    return views


def calibrate_images(images: list[npt.NDArray], names: list[str], options: ChessboardOptions | None = None,
                     bit_depth: int = 8) -> CalibrationResult:
    """Find the board in every image (views without it are rejected with a message) and calibrate."""
    options = options or ChessboardOptions()
    board = board_points_m(options.inner, options.square_m)

    def find(image: npt.NDArray) -> tuple[npt.NDArray, npt.NDArray] | None:
        corners = find_corners(image, options.inner, options.subpix_window_px, options.adaptive_window)
        return None if corners is None else (board, corners)

    v = collect_views(images, names, find, f"no whole {options.inner[0]}x{options.inner[1]} board found")
    result = calibrate_points(v.obj, v.img, v.width, v.height, v.used, options, bit_depth)
    return CalibrationResult(**{**result.__dict__, "rejected": v.rejected + result.rejected})
