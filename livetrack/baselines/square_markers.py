"""Square fiducial markers as baselines: OpenCV ArUco and AprilTag 36h11 (``pupil_apriltags``).

Outer size. A square marker is compared with a ring target of outer radius R at the same physical outer size:
the side of the marker's BLACK square (the outer edge its corners are detected on) equals 2R. The white quiet
zone around it is extra paper, as the white sheet around a ring target is. ``marker_size_m`` / ``tag_size_m``
below are that black side.

* ArUco ``DICT_4X4_50``: 4x4 data cells in a black border of 1 cell: the black square is 6 x 6 cells.
* AprilTag 36h11: 6x6 data cells in a black border of 1 cell (8 x 8 cells of black square), in a white border of
  1 cell: 10 x 10 cells with the white border. (AprilTag's own "tag size" convention is this black side too.)

Marker images have exactly one texel per cell (``(h, w)`` float64, 0 = black, 1 = white) with a white quiet zone
of ``quiet_zone_cells`` (default 1) around the black square; ``texture_side_m`` gives the physical side of such
an image for a given black side, for ``ImageTexture(image, size_m=...)``.

Pose. Both methods solve ``cv2.solvePnPGeneric(..., SOLVEPNP_IPPE_SQUARE)`` from the four corners with the
camera's K and distortion (pixel (x, y), (0, 0) = centre of the top-left pixel, as OpenCV's corners). OpenCV's
marker frame has y up and z toward the viewer; it is turned into livetrack's target frame (origin at the centre,
x right and y down seen from the front, z away from the viewer) by a half turn about x:
``R_livetrack = R_cv @ diag(1, -1, -1)``, same ``t``. IPPE returns two solutions (the planar "flip"
ambiguity); the lower-error one is reported, and ``extra`` carries both errors:

* ``reprojection_errors_px``: (2,) RMS corner reprojection error of the chosen and the other solution, px;
* ``flip_ratio``: other / chosen error (close to 1 = ambiguous pose);
* ``flip_angle_deg``: angle between the two solutions' plane normals;
* ``other_pose``: the rejected solution (``Pose``, livetrack's frame);
* ``corners_px``: (4, 2) detected corners (TL, TR, BR, BL of the upright marker).

Measured on the simulator (0.8 px Gaussian PSF, white at half of full well): ArUco's ``CORNER_REFINE_SUBPIX``
corners sit about 0.15 px inside the true corners (a blurred L-corner pulls ``cornerSubPix`` inward), so ArUco
reads distances about 0.13 % long at 2 m; AprilTag's ``refine_edges`` corners are within ~0.05 px on average
(after the half-pixel shift below). Neither has an exposure model: at 2x / 4x over-saturation both read about
0.6-0.9 % / 1.0-1.5 % long, like the naive ellipse reader.
"""

from __future__ import annotations

import atexit
import math
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.baselines.common import PoseEstimate, full_scale, is_usable_image, to_uint8
from livetrack.camera import CameraModel
from livetrack.geometry import Pose, rotation_from_rotvec

FloatArray = npt.NDArray[np.float64]

_CV_TO_LIVETRACK = np.diag([1.0, -1.0, -1.0])
"""OpenCV marker frame (y up, z toward the viewer) -> livetrack target frame (y down, z away from the viewer)."""

APRILTAG_FAMILY = "tag36h11"


# ---------------------------------------------------------------------------------------------- marker images
def _with_quiet_zone(black_square: npt.NDArray[np.uint8], quiet_zone_cells: int) -> FloatArray:
    if quiet_zone_cells < 0:
        raise ValueError(f"quiet_zone_cells must be >= 0, got {quiet_zone_cells}")
    image = black_square.astype(np.float64) / 255.0
    return np.pad(image, quiet_zone_cells, constant_values=1.0)


def aruco_marker_image(marker_id: int, dictionary: int = cv2.aruco.DICT_4X4_50, quiet_zone_cells: int = 1
                       ) -> FloatArray:
    """(n, n) float64 image of an ArUco marker, one texel per cell, 0 = black, 1 = white.

    n = markerSize + 2 (black border) + 2 ``quiet_zone_cells`` (white): 8 for DICT_4X4_* with the default
    quiet zone. The black square is the central (markerSize + 2) cells.
    """
    d = cv2.aruco.getPredefinedDictionary(dictionary)
    cells = d.markerSize + 2
    return _with_quiet_zone(cv2.aruco.generateImageMarker(d, int(marker_id), cells, borderBits=1), quiet_zone_cells)


def apriltag_marker_image(tag_id: int, quiet_zone_cells: int = 1) -> FloatArray:
    """(n, n) float64 image of AprilTag 36h11 ``tag_id`` as the AprilTag library draws it (the printed tag),
    one texel per cell; n = 8 + 2 ``quiet_zone_cells`` (10 with the default, the standard tag36h11 layout).

    Made from OpenCV's ``DICT_APRILTAG_36h11``, which holds the same codes but draws each tag turned by a half
    turn from the AprilTag library's layout (its ``bit_x``/``bit_y`` tables); the half turn is undone here, so
    the tag's upright orientation (and the in-plane rotation of the pose) is the AprilTag library's.
    """
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    opencv_layout = cv2.aruco.generateImageMarker(d, int(tag_id), d.markerSize + 2, borderBits=1)
    return _with_quiet_zone(np.ascontiguousarray(np.rot90(opencv_layout, 2)), quiet_zone_cells)


def texture_side_m(image: FloatArray, black_side_m: float, quiet_zone_cells: int = 1) -> float:
    """Physical side of a marker image (black square + quiet zone) whose black square is ``black_side_m``."""
    cells = image.shape[0]
    return float(black_side_m) * cells / (cells - 2 * quiet_zone_cells)


# ---------------------------------------------------------------------------------------------- pose from corners
def square_object_points_cv(side_m: float) -> FloatArray:
    """(4, 3) corners in the order ``SOLVEPNP_IPPE_SQUARE`` requires, in OpenCV's marker frame (y up):
    (-s/2, s/2), (s/2, s/2), (s/2, -s/2), (-s/2, -s/2) = top-left, top-right, bottom-right, bottom-left of the
    upright marker seen from the front."""
    h = 0.5 * float(side_m)
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def square_pose(camera: CameraModel, corners_px: FloatArray, side_m: float, marker_id: int,
                quality: float | None = None, extra: dict[str, Any] | None = None) -> PoseEstimate | None:
    """Pose of a square of side ``side_m`` from its (4, 2) pixel corners (TL, TR, BR, BL of the upright marker,
    distorted pixels), in livetrack's target frame; None if the PnP fails. ``quality`` default: the RMS
    reprojection error (px) of the chosen solution. ``extra`` entries are added to the documented ones."""
    corners = np.ascontiguousarray(np.asarray(corners_px, dtype=np.float64).reshape(4, 1, 2))
    if not np.all(np.isfinite(corners)):
        return None
    try:
        n, rvecs, tvecs, errors = cv2.solvePnPGeneric(
            square_object_points_cv(side_m), corners, camera.K, camera.dist_array, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    except cv2.error:
        return None
    if n < 1:
        return None
    errs = np.asarray(errors, dtype=np.float64).reshape(-1)
    order = np.argsort(errs)
    poses = []
    for i in order:
        R = rotation_from_rotvec(np.asarray(rvecs[i], dtype=np.float64).reshape(3)) @ _CV_TO_LIVETRACK
        poses.append(Pose(R, np.asarray(tvecs[i], dtype=np.float64).reshape(3).copy()))
    best = poses[0]
    if best.t[2] <= 0 or not np.all(np.isfinite(best.t)):
        return None
    extra = {"reprojection_errors_px": errs[order].copy(), "corners_px": corners.reshape(4, 2), **(extra or {})}
    if len(poses) > 1:
        cos = float(np.clip(best.normal_cam @ poses[1].normal_cam, -1.0, 1.0))
        extra["flip_angle_deg"] = math.degrees(math.acos(cos))
        extra["flip_ratio"] = float(errs[order[1]] / max(errs[order[0]], 1e-12))
        extra["other_pose"] = poses[1]
    quality = float(errs[order[0]]) if quality is None else float(quality)
    return PoseEstimate(target_id=int(marker_id), pose=best, delta_px=None, quality=quality, extra=extra)


# ---------------------------------------------------------------------------------------------- ArUco
class ArucoMethod:
    """OpenCV ArUco: ``ArucoDetector`` with ``CORNER_REFINE_SUBPIX`` + IPPE_SQUARE with the full camera model.

    ``marker_size_m``: side of the black square (= 2R of the ring target it is compared with).
    ``dictionary``: an OpenCV predefined dictionary id (default ``DICT_4X4_50``).
    ``saturation``: image value of full scale (default: 255 for uint8, else the camera's top code; 1.0 for
    float images in [0, 1]); the detector sees an 8-bit copy scaled to it.
    ``corner_refinement``: ``cv2.aruco.CORNER_REFINE_*`` (default ``CORNER_REFINE_SUBPIX``, the accurate choice
    the evaluations use; OpenCV's own default is ``CORNER_REFINE_NONE``: integer-pixel contour corners, a little
    faster, what ``livetrack bench`` also times as "ArUco at defaults").
    ``quality``: the RMS corner reprojection error of the chosen IPPE solution in px (lower is better).
    """

    def __init__(self, camera: CameraModel, marker_size_m: float, dictionary: int = cv2.aruco.DICT_4X4_50,
                 saturation: float | None = None, name: str = "aruco",
                 corner_refinement: int = cv2.aruco.CORNER_REFINE_SUBPIX) -> None:
        self.name = name
        self.camera = camera
        self.marker_size_m = float(marker_size_m)
        self.saturation = saturation
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = int(corner_refinement)
        self._detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(dictionary), params)

    def estimate(self, image: npt.NDArray[np.generic]) -> list[PoseEstimate]:
        if not is_usable_image(image):
            return []
        gray = to_uint8(image, full_scale(image, self.camera, self.saturation))
        try:
            corners, ids, _ = self._detector.detectMarkers(gray)
        except cv2.error:
            return []
        if ids is None:
            return []
        out = []
        for c, marker_id in zip(corners, np.asarray(ids).reshape(-1), strict=True):
            est = square_pose(self.camera, np.asarray(c, dtype=np.float64).reshape(4, 2), self.marker_size_m,
                              int(marker_id))
            if est is not None:
                out.append(est)
        return out


# ---------------------------------------------------------------------------------------------- AprilTag
class AprilTagMethod:
    """AprilTag 36h11 via ``pupil_apriltags.Detector(refine_edges=1, nthreads=1)``; its pose estimate assumes no
    distortion and is not used: the corners go through the same IPPE_SQUARE + camera model as ArUco.

    ``tag_size_m``: side of the black square. ``quad_decimate``: detection on an image decimated by this factor
    (faster, corners are still refined on the full image with ``refine_edges``; default 1.0 = full resolution,
    the accurate choice the evaluations use; the library's own default, and what most users run, is 2.0: ~4x
    faster on 1920x1200, small or distant tags are missed more often). The other settings are the library's
    defaults (``nthreads=1``, ``quad_sigma=0``, ``refine_edges=1``, ``decode_sharpening=0.25``).
    ``saturation``: as for ``ArucoMethod``.
    ``quality``: the detector's ``decision_margin`` (higher is better); ``extra`` also has ``hamming``.

    Not thread-safe: methods with the same ``quad_decimate`` share one detector (see ``_apriltag_detector``).
    ``decode_sharpening=0.25`` is requested, but pupil-apriltags 1.0.4 stores it through ``int()``, i.e. 0.

    Pixel convention: the AprilTag library puts (0, 0) at the top-left corner of the top-left pixel; its corners
    are shifted by -0.5 px here to livetrack's (and OpenCV's) pixel-centre convention.
    """

    def __init__(self, camera: CameraModel, tag_size_m: float, quad_decimate: float = 1.0,
                 saturation: float | None = None, name: str = "apriltag") -> None:
        self.name = name
        self.camera = camera
        self.tag_size_m = float(tag_size_m)
        self.saturation = saturation
        self._detector = _apriltag_detector(float(quad_decimate))

    def estimate(self, image: npt.NDArray[np.generic]) -> list[PoseEstimate]:
        if not is_usable_image(image):
            return []
        gray = to_uint8(image, full_scale(image, self.camera, self.saturation))
        try:
            detections = self._detector.detect(gray)
        except (RuntimeError, ValueError):
            return []
        out = []
        for det in detections:
            # pupil_apriltags wraps counter-clockwise in the image starting bottom-left: BL, BR, TR, TL.
            corners = np.asarray(det.corners, dtype=np.float64)[[3, 2, 1, 0]] + APRILTAG_PIXEL_OFFSET_PX
            est = square_pose(self.camera, corners, self.tag_size_m, int(det.tag_id),
                              quality=float(det.decision_margin), extra={"hamming": int(det.hamming)})
            if est is not None:
                out.append(est)
        return out


APRILTAG_PIXEL_OFFSET_PX = -0.5
"""Added to AprilTag corners to move them to the pixel-centre convention (measured in the tests)."""

_APRILTAG_DETECTORS: dict[float, Any] = {}


def _apriltag_detector(quad_decimate: float) -> Any:
    """The process-wide ``pupil_apriltags.Detector`` for these settings, created once and never destroyed.

    Destroying a detector (``Detector.__del__``) corrupts the heap in pupil-apriltags 1.0.4.post11 (a later,
    unrelated allocation aborts with "malloc(): mismatching next->prev_size"; pupil-labs/apriltags issue #39
    reports the same symptom), while detections on a long-lived detector are clean. So detectors are cached
    here and disarmed at exit (their memory goes back with the process).
    """
    detector = _APRILTAG_DETECTORS.get(quad_decimate)
    if detector is None:
        import pupil_apriltags  # optional dependency, imported where it is needed

        if not _APRILTAG_DETECTORS:
            atexit.register(_disarm_apriltag_detectors)
        detector = pupil_apriltags.Detector(families=APRILTAG_FAMILY, nthreads=1, quad_decimate=quad_decimate,
                                            quad_sigma=0.0, refine_edges=1, decode_sharpening=0.25)
        _APRILTAG_DETECTORS[quad_decimate] = detector
    return detector


def _disarm_apriltag_detectors() -> None:
    for detector in _APRILTAG_DETECTORS.values():
        detector.tag_detector_ptr = None  # Detector.__del__ then skips the faulty destroy
