"""Calibration from ChArUco boards (a chessboard whose white squares hold ArUco markers), through OpenCV's aruco
module (``cv2.aruco.CharucoBoard``, ``cv2.aruco.CharucoDetector``, OpenCV >= 4.7): every corner is identified by
the markers next to it, so a view may show the board only in part (near the image corners, where the distortion is
largest, a whole chessboard rarely fits). Found corners then go through the chessboard mode's calibration
(``calibrate_points``: OpenCV's 5-coefficient model, rejection of views with large residuals, uncertainties).

OpenCV's corner coordinates put (0, 0) at the centre of the top-left pixel, livetrack's convention. Pure functions
on images and arrays (no file I/O).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.calibration.chessboard import ChessboardOptions, calibrate_points, collect_views, to_gray8
from livetrack.calibration.report import CalibrationResult

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class CharucoOptions:
    """squares : squares of the board (columns, rows), e.g. (7, 5) (inner corners: (6, 4)).
    square_m, marker_m : side of a square and of a marker, metres (the marker smaller than the square).
    dictionary : the ArUco dictionary's OpenCV name, e.g. ``"DICT_5X5_100"`` (it must hold at least one marker per
        white square: 17 for 7x5).
    min_corners : a view needs at least this many identified corners (default 8; OpenCV's pose needs 4 and a
        calibration view says little with fewer).
    refine_window : refine the corners again with a window clear of the markers (``refine_corners``; default
        True). False: OpenCV's CharucoDetector corners as they are (their windows reach the markers' borders).
    refine_upsample : the image is enlarged this many times (bicubic) for that refinement (default 2; 1: none).
        ``cornerSubPix`` samples its window by bilinear interpolation, which with the small window pulls each
        corner toward the nearest pixel boundary by up to 0.035 px (a sine of its sub-pixel position; noise-free
        test board, 30 draws of 10 views); enlarged twice first: 0.005-0.009 px, the corners' error 0.033 ->
        0.024 px RMS. Costs ~1 ms per view.
    reject_factor, reject_min_px, min_views : as ``ChessboardOptions``.
    """

    squares: tuple[int, int] = (7, 5)
    square_m: float = 0.04
    marker_m: float = 0.03
    dictionary: str = "DICT_5X5_100"
    min_corners: int = 8
    refine_window: bool = True
    refine_upsample: int = 2
    reject_factor: float = 3.0
    reject_min_px: float = 1.0
    min_views: int = 3

    def __post_init__(self) -> None:
        cols, rows = self.squares
        if cols < 3 or rows < 3:
            raise ValueError(f"squares: at least 3x3, got {cols}x{rows}")
        if not (0 < self.marker_m < self.square_m):
            raise ValueError(f"the marker ({self.marker_m} m) must be smaller than the square ({self.square_m} m) "
                             "and positive")
        if dictionary_id(self.dictionary) is None:
            raise ValueError(f"unknown ArUco dictionary {self.dictionary!r} (e.g. DICT_4X4_50, DICT_5X5_100, "
                             "DICT_6X6_250, DICT_APRILTAG_36h11)")
        if self.refine_upsample < 1:
            raise ValueError(f"refine_upsample must be at least 1, got {self.refine_upsample}")
        if self.min_corners < 4:
            raise ValueError(f"min_corners must be at least 4, got {self.min_corners}")


def dictionary_id(name: str) -> int | None:
    """OpenCV's id of an ArUco dictionary name (``DICT_...``), None if there is none."""
    value = getattr(cv2.aruco, name, None) if name.startswith("DICT_") else None
    return value if isinstance(value, int) else None


def make_board(options: CharucoOptions) -> cv2.aruco.CharucoBoard:
    """The board; ValueError if its dictionary has fewer markers than it needs."""
    dictionary = cv2.aruco.getPredefinedDictionary(dictionary_id(options.dictionary))
    cols, rows = options.squares
    needed = (cols * rows) // 2
    if dictionary.bytesList.shape[0] < needed:
        raise ValueError(f"{options.dictionary} has {dictionary.bytesList.shape[0]} markers, a {cols}x{rows} board "
                         f"needs {needed}")
    return cv2.aruco.CharucoBoard((cols, rows), options.square_m, options.marker_m, dictionary)


class CharucoFinder:
    """Finds a board's corners in images: ``find(image) -> (board points (N, 3) m, image points (N, 2) px)`` or
    None when fewer than ``min_corners`` are identified."""

    def __init__(self, options: CharucoOptions):
        self.options = options
        self.board = make_board(options)
        self.detector = cv2.aruco.CharucoDetector(self.board)

    def find(self, image: npt.NDArray) -> tuple[FloatArray, FloatArray] | None:
        gray = to_gray8(image)
        corners, ids, _, _ = self.detector.detectBoard(gray)
        if corners is None or ids is None or len(ids) < self.options.min_corners:
            return None
        obj, img = self.board.matchImagePoints(corners, ids)
        obj = np.asarray(obj, dtype=np.float64).reshape(-1, 3)
        img = np.asarray(img, dtype=np.float64).reshape(-1, 2)
        if len(obj) < self.options.min_corners or self.board.checkCharucoCornersCollinear(ids):
            return None
        if self.options.refine_window:
            img = refine_corners(gray, obj, img, self.options)
        return obj, img


def refine_corners(gray: npt.NDArray[np.uint8], obj: FloatArray, img: FloatArray, options: CharucoOptions
                   ) -> FloatArray:
    """The corners (N, 2) refined again by ``cv2.cornerSubPix`` with a window that stays clear of the markers: its
    half-size is the marker's margin in the square ((square - marker) / 2) at the view's smallest corner spacing,
    less 2 px for the blur, at least 2 px; on the image enlarged ``options.refine_upsample`` times (bicubic: see
    ``CharucoOptions``). OpenCV's CharucoDetector refines with larger windows, which reach the markers' black
    borders: on the noise-free test board its corners are 0.041 px RMS off their true projections, pushed outward
    by ~0.005 px 100-300 px from the principal point; refined here 0.024 px, no radial trend (docs/calibration.md).
    """
    if len(obj) < 2:
        return img
    board_d = np.linalg.norm(obj[:, None, :2] - obj[None, :, :2], axis=-1)
    image_d = np.linalg.norm(img[:, None, :] - img[None, :, :], axis=-1)
    adjacent = np.abs(board_d - options.square_m) < 1e-6 * options.square_m
    if not adjacent.any():
        return img
    spacing_px = float(np.min(image_d[adjacent]))
    margin = 0.5 * (options.square_m - options.marker_m) / options.square_m
    half = max(2, int(np.floor(margin * spacing_px - 2.0)))
    up = options.refine_upsample
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4 * up)
    image = gray.astype(np.float32)
    if up > 1:  # pixel centres on integers at both scales: x_up = up * x + (up - 1) / 2
        image = cv2.resize(image, None, fx=up, fy=up, interpolation=cv2.INTER_CUBIC)
    start = (img * up + (up - 1) / 2).astype(np.float32).reshape(-1, 1, 2).copy()
    refined = cv2.cornerSubPix(image, start, (half * up, half * up), (-1, -1), criteria)
    return (refined.reshape(-1, 2).astype(np.float64) - (up - 1) / 2) / up


def board_image(options: CharucoOptions, px_per_square: int) -> npt.NDArray[np.uint8]:
    """The board as printed, no margin: (rows x px_per_square, cols x px_per_square) uint8; pixel (u, v) covers
    the board's [u, u + 1) x [v, v + 1) x square_m / px_per_square (board x right, y down from its top-left)."""
    cols, rows = options.squares
    return make_board(options).generateImage((cols * px_per_square, rows * px_per_square), marginSize=0,
                                              borderBits=1)


def calibrate_charuco_images(images: list[npt.NDArray], names: list[str], options: CharucoOptions | None = None,
                             bit_depth: int = 8) -> CalibrationResult:
    """Find the board in every image (views with too few identified corners are rejected with a message) and
    calibrate (``calibrate_points``). Raises ValueError with fewer than ``min_views`` usable views."""
    options = options or CharucoOptions()
    finder = CharucoFinder(options)
    v = collect_views(images, names, finder.find, f"fewer than {options.min_corners} board corners identified")
    board = ChessboardOptions(reject_factor=options.reject_factor, reject_min_px=options.reject_min_px,
                              min_views=options.min_views)
    result = calibrate_points(v.obj, v.img, v.width, v.height, v.used, board, bit_depth)
    extra = {"corners_per_view": {n: int(len(p)) for n, p in zip(result.view_names, result.points_px,
                                                                  strict=True)}}
    return CalibrationResult(**{**result.__dict__, "rejected": v.rejected + result.rejected,
                                "extra": {**result.extra, **extra}})
