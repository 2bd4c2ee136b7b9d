"""The naive ring-target reader: Canny edges, ``cv2.fitEllipse``, concentric-circle pose, no exposure model.

This is how most people read a black/white ring target, and the baseline livetrack's exposure compensation is
measured against. Per frame:

1. ``detect`` (livetrack's coarse detector) finds each target, its id and rough outer/inner ellipses; only the
   outermost visible level of each target is used.
2. Canny on an 8-bit copy of a crop around the target (thresholds from the crop's own contrast, see
   ``NaiveOptions``); Canny marks whole pixels where the gradient magnitude peaks across the edge.
3. The Canny pixels within ``band_px`` of each detected ellipse (outer, inner) are that circle's contour;
   ``cv2.fitEllipse`` on each, and points farther than ``outlier_px`` from that fit are dropped.
4. The remaining points are undistorted to normalized coordinates, a conic is fitted to each circle
   (``fit_conic``) and the closed-form concentric pose (``concentric_pose``) gives the normal and the centre;
   the distance comes from the OUTER circle only (its radius ``outer_radius_m``), as a naive user does.

No exposure model: with the white clipped, the gradient peak moves into the black side of every edge, the
outer circle looks smaller and the distance comes out too large (by about the edge shift over the outer
radius in pixels). ``PoseEstimate.delta_px`` is None; ``quality`` is the RMS distance (px) of the kept points to
their ``cv2.fitEllipse`` ellipses; ``extra`` holds ``outer_ellipse`` / ``inner_ellipse`` (``Ellipse``, pixels),
``n_points`` (outer, inner) and ``level``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.baselines.common import PoseEstimate, full_scale, is_usable_image, to_uint8
from livetrack.camera import CameraModel
from livetrack.estimator.circle_pose import concentric_pose, fit_conic, rotation_from_normal
from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect import Candidate, Detector
from livetrack.geometry import Pose
from livetrack.targets.spec import TargetSpec

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class NaiveOptions:
    """Tunables of the naive reader.

    band_px: half-width of the band around each detected ellipse in which Canny pixels are taken as that
        circle's contour (pixels, default 3). Must cover the detector's own exposure bias; wider risks taking
        code-dot edges.
    outlier_px: after ``cv2.fitEllipse``, points farther than this from the fitted ellipse are dropped before
        the pose (pixels, default 1.5).
    canny_low, canny_high: Canny's hysteresis thresholds as fractions of the gradient (OpenCV's 3x3 Sobel, L2)
        of a sharp step of the crop's black-to-white contrast (8-bit levels between its 2nd and 98th
        percentiles), 4 x contrast. A step blurred by a 0.8 px PSF peaks near 0.75, by a 1.5 px PSF near 0.5
        (defaults 0.15 and 0.3: every ring edge, not the noise).
    min_points: fewest contour points per circle for a fit (default 12).
    """

    band_px: float = 3.0
    outlier_px: float = 1.5
    canny_low: float = 0.15
    canny_high: float = 0.3
    min_points: int = 12


class NaiveEllipseMethod:
    """Canny + ``cv2.fitEllipse`` + concentric-circle pose, distance from the outer circle; see the module doc.

    ``targets``: the ring target specs to look for. ``saturation``: image value of full scale (default: 255 for
    uint8, else the camera's top code; 1.0 for float images in [0, 1]).
    """

    def __init__(self, camera: CameraModel, targets: Sequence[TargetSpec], options: NaiveOptions | None = None,
                 saturation: float | None = None, name: str = "naive-ellipse") -> None:
        self.name = name
        self.camera = camera
        self.saturation = saturation
        self.targets = list(targets)
        self.options = options or NaiveOptions()
        self._detector = Detector(self.targets)

    def estimate(self, image: npt.NDArray[np.generic]) -> list[PoseEstimate]:
        if not is_usable_image(image):
            return []
        image = np.asarray(image)
        saturation = full_scale(image, self.camera, self.saturation)
        try:
            candidates = self._detector.detect(image, saturation=saturation)
        except ValueError:
            return []
        img8 = to_uint8(image, saturation)
        out = []
        for cand in _outermost(candidates):
            est = self._estimate_one(img8, cand)
            if est is not None:
                out.append(est)
        return out

    # ------------------------------------------------------------------ one target
    def _estimate_one(self, img8: npt.NDArray[np.uint8], cand: Candidate) -> PoseEstimate | None:
        opts = self.options
        points = _canny_points(img8, cand.outer, opts)
        if points is None:
            return None
        fits = []
        for ellipse in (cand.outer, cand.inner):
            near = points[np.abs(ellipse.sampson_distance(points)) <= opts.band_px]
            fit = _fit_ellipse(near, opts)
            if fit is None:
                return None
            fits.append(fit)
        (outer, pts_outer, rms_outer), (inner, pts_inner, rms_inner) = fits
        norm_outer = self.camera.pixels_to_normalized(pts_outer)
        norm_inner = self.camera.pixels_to_normalized(pts_inner)
        try:
            with np.errstate(all="ignore"):  # degenerate conics give NaNs, rejected below
                sol = concentric_pose(fit_conic(norm_outer), fit_conic(norm_inner), cand.spec.outer_radius_m)
        except (np.linalg.LinAlgError, ValueError):
            return None
        t = sol.t_m
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(sol.normal_cam)) and t[2] > 0):
            return None
        R = rotation_from_normal(sol.normal_cam, _x_axis_hint(self.camera, t, sol.normal_cam, cand.heading_rad))
        n_out, n_in = len(pts_outer), len(pts_inner)
        rms = math.sqrt((n_out * rms_outer**2 + n_in * rms_inner**2) / (n_out + n_in))
        extra = {"outer_ellipse": outer, "inner_ellipse": inner, "n_points": (n_out, n_in), "level": cand.level,
                 "radius_ratio": sol.radius_ratio}
        return PoseEstimate(target_id=cand.target_id, pose=Pose(R, t.copy()), delta_px=None, quality=rms,
                            extra=extra)


def _outermost(candidates: Sequence[Candidate]) -> list[Candidate]:
    """Each target's outermost detected level: a candidate whose centre lies inside the inner disk of a larger
    candidate of the same id (a nested level) is dropped, whatever level the detector gave it."""
    kept: list[Candidate] = []
    for cand in sorted(candidates, key=lambda c: -c.outer.a):
        nested = any(
            k.target_id == cand.target_id and cand.outer.a < k.inner.b
            and float(np.linalg.norm(cand.outer.centre_px - k.outer.centre_px)) < k.inner.b
            for k in kept)
        if not nested:
            kept.append(cand)
    return kept


def _canny_points(img8: npt.NDArray[np.uint8], outer: Ellipse, opts: NaiveOptions) -> FloatArray | None:
    """(N, 2) pixel centres (x, y) of Canny edge pixels in a crop around the ``outer`` ellipse, or None."""
    height, width = img8.shape
    half = outer.half_extent_px() + opts.band_px + 4.0
    x0 = max(int(math.floor(outer.centre_px[0] - half[0])), 0)
    y0 = max(int(math.floor(outer.centre_px[1] - half[1])), 0)
    x1 = min(int(math.ceil(outer.centre_px[0] + half[0])) + 1, width)
    y1 = min(int(math.ceil(outer.centre_px[1] + half[1])) + 1, height)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    crop = np.ascontiguousarray(img8[y0:y1, x0:x1])
    lo, hi = np.percentile(crop, [2.0, 98.0])
    contrast = float(hi - lo)
    if contrast < 4.0:
        return None
    edges = cv2.Canny(crop, opts.canny_low * 4.0 * contrast, opts.canny_high * 4.0 * contrast, L2gradient=True)
    rows, cols = np.nonzero(edges)
    if rows.size == 0:
        return None
    return np.column_stack([cols + x0, rows + y0]).astype(np.float64)


def _fit_ellipse(points: FloatArray, opts: NaiveOptions) -> tuple[Ellipse, FloatArray, float] | None:
    """``cv2.fitEllipse``, then again without the points farther than ``outlier_px`` from the first fit:
    (ellipse, kept points (N, 2), RMS distance of the kept points in px), or None."""
    first = _cv_fit(points, opts.min_points)
    if first is None:
        return None
    points = points[np.abs(first.sampson_distance(points)) <= opts.outlier_px]
    ellipse = _cv_fit(points, opts.min_points)
    if ellipse is None:
        return None
    return ellipse, points, float(np.sqrt(np.mean(ellipse.sampson_distance(points) ** 2)))


def _cv_fit(points: FloatArray, min_points: int) -> Ellipse | None:
    if len(points) < max(min_points, 5):
        return None
    try:
        return Ellipse.from_cv(cv2.fitEllipse(points.astype(np.float32).reshape(-1, 1, 2)))
    except (cv2.error, ValueError):
        return None


def _x_axis_hint(camera: CameraModel, t_m: FloatArray, normal: FloatArray, heading_rad: float | None) -> FloatArray:
    """Target +x in the camera frame from the code's image-plane heading (camera +x when unknown): the plane
    point seen a few pixels from the centre along the heading, minus the centre."""
    if heading_rad is None:
        return np.array([1.0, 0.0, 0.0])
    centre_px = camera.project(t_m[None, :])[0]
    ray = camera.unproject((centre_px + 5.0 * np.array([math.cos(heading_rad), math.sin(heading_rad)]))[None, :])[0]
    return ray * float(normal @ t_m) / float(normal @ ray) - t_m
