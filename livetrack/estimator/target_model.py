"""The whole target in two dimensions: its pose fitted to every pixel of it, a lens halo included.

The edge fits model each edge alone, in one dimension (``edge_model``). Under heavy over-exposure with a wide halo
that is not enough: a halo puts a fraction ``f`` of the PSF's energy in a Gaussian of several pixels, and every pixel
gets ``f`` times the scene's radiance blurred that wide. With the white many times the clip level, the halo of all the
white around the ring (inner disk, code dots, sheet) lifts the black ring to the clip within pixels of every edge:
paper-lab at x32 (a 3 % halo of 6 px, 4 % ink, the black at ~85 % of full scale) reaches the clip ~2.5 px inside the
ring, so what each edge profile shows is the halo's tail, on which position and black level trade off, and the poses
came out 0.6-3.3 % too far whether or not the edge model was told the halo.

Here the image of the target is modelled whole, in image units, for the pixels within 3 px of its outer circle:

    I = clip(B + gx x + gy y + C (G(core) * w) + A (G(halo) * w))

``w`` the share of white of each pixel (the design at the pose inside the outer circle, a ramp one pixel wide at every
circle so that it moves smoothly with the pose; outside, the image's clipped pixels count as white), ``G`` Gaussians
(the core's width given: the blur of the frame's clean edges, or the camera's; the halo's fitted), ``B`` the black's
level with a gradient, ``C = (1 - f)(W - B)`` and ``A = f (W - B)`` the contrasts of the core and of the halo. A clipped
pixel is a censored measurement: it says the model reaches the clip, and costs nothing when it does. The fit runs in two
stages from the edges' pose: (1) the halo alone on the ring's interior, beyond the core's reach of any white
(``measure_halo``: the black with a gradient and the halo's amplitude solved linearly for each pose and width), which
brings a pose 3 % off to within ~1 %; (2) everything, where the pixels beside each edge place it through the core's
steep flank. Paper-lab at x32, 9 poses at 1.5-6 m: 0.58-3.3 % off from the edges, -0.04 to +0.06 % after (median
|error| 0.016 %), the halo found at 2005-2071 for 2060 and 5.9-6.04 px for 6.

On the detection sweep's x32 frames with a halo (seeds 0-1): 17 targets printed on a sheet, median |error| 0.27 % ->
0.004 % (max 1.40 -> 0.051 %); of 5 printed without a sheet 3 got worse (clipped ground is taken for their white), which
the tracker's check on the code dots turns away (``tracker.checks._dots_prefer_edges``).

Pure (arrays in, results out). Each pixel's white and its derivatives by the pose are compiled
(``target_model_kernel``, its numpy reference within 1e-9); both stages are MINPACK's Levenberg-Marquardt with analytic
Jacobians (the blur is linear: the derivative images blurred; stage 1's linear levels projected out, Kaufman's form).
Cost on one core: 0.2-1.2 s per paper-lab x32 target and start (20-130 px, load 3-4.5; 1.3-15 s with the numpy fit
and forward differences of session 17), ~4 s for a 600 px one, growing with its area (the blurs of ~15 window-sized
images per iteration and the kernel, ~70 ns per pixel, dominate); from both starts (``fit_target_model``) 0.8-5.4 s
per paper-lab target at a load of 5-6. A target whose window is 300 px or more has both stages fitted on blocks of 2 x 2
pixels first and finished at full resolution (``BIN_WINDOW_PX``: a 254 px one in 1.2 s instead of 2.7, a 380 px one
in 27 s of CPU instead of 62).

When it is needed (``halo_clips_the_edges``): wherever the halo lifts the black beside the white to within 5 % of the
clip (``Halo.edge_peak``), not only beside a straight edge: between the code dots and the circles the halo of the white
on both sides adds up, and on paper-lab's optics the edges' poses were up to 1.07 % off at x28, where the black plus
half the halo stays below the clip.

A winning fit from the mirror start whose normal is far from the edges' is mirrored back and fitted again: the edges'
own start can lose its way (its distance percents off: stage 2 from there loses the core), while the mirror fit gets
the distance with the wrong normal; its mirror image has both (paper-lab pose 3 at x31: the mirror fit -0.22 %, 85 deg
off, RMS 30.7; mirrored back -0.004 %, 0.06 deg, RMS 26.7).

A tracked frame (``refine_target_model``) runs stage 2 alone from its predicted pose and the last frame's levels (times
the exposure's ratio): a few Gauss-Newton steps, ~35-60 ms for a 75 px target (one core, BLAS on one thread).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from livetrack.camera import CameraModel
from livetrack.estimator import surround_geometry, target_model_kernel
from livetrack.estimator.edge_kernels import kernels
from livetrack.estimator.pose_fit import pixels_to_normalized, project
from livetrack.geometry import Pose, rotation_from_rotvec
from livetrack.targets.spec import TargetSpec

FloatArray = npt.NDArray[np.float64]

HALO_SIGMAS_PX = (1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0)
"""Halo widths tried for the start (px); the fit then takes the width anywhere."""
MIN_HALO_SIGMAS = 8.0
"""A halo counts when its amplitude on the ring's interior is at least this many of its standard deviations."""
MIN_HALO_WIDTH_CORES = 2.5
"""... and it is at least this many times as wide as the core's blur: a narrower one is the core's own shape (a
Gaussian's tail fitted to a pixel-integrated PSF, texture beside the ring: the detection sweep's seed 1 single-003 at
x4, 8 bit, no halo in the scene, measured one of 1.5 px for a core of 0.88 px and 35 times full scale)."""
MAX_HALO_AMPLITUDE_CLIPS = 4.0
"""... and its amplitude ``f (W - B)`` is at most this many clip levels (a 3 % halo reaches it at ~x240 of a white at
55 % of full scale; paper-lab at x32: 0.5)."""
CORE_REACH_SIGMAS = 3.5
"""The interior (stage 1, ``measure_halo``): pixels at least this many core sigmas plus 2 px from any white."""
MIN_INTERIOR_PX = 40
"""Least interior pixels (unclipped black beyond the core's reach) for the halo to be measured."""
MARGIN_PX = 3
"""The pixels fitted: those within this many pixels of the outer circle (at the edges' pose) or inside it."""
WINDOW_PAD_PX = 40
"""The window modelled reaches this far beyond the outer circle (the halo's blur needs the white around)."""
HALO_WIDTH_LIMITS_PX = (0.5, 40.0)
"""The halo widths the fit may try (px): a trial step beyond is held at the limit."""
STAGE1_RMS_KEPT = 1.15
"""Of the two starts (``fit_target_model``), stage 2 runs from each whose stage-1 residual RMS is within this factor of
the better one's (paper-lab x32: a wrong start's RMS 1.17-1.7 times the right one's on 8 of 20 poses, within 1.05 on the
others, where both must run; it saves the larger targets' slowest fits)."""
STAGE1_MAX_EVALUATIONS = 200
"""Stage 1's largest number of model evaluations (Levenberg-Marquardt, MINPACK's, with the analytic Jacobian)."""
STAGE2_MAX_EVALUATIONS = 400
"""Stage 2's largest number of model evaluations (Levenberg-Marquardt, MINPACK's, with the analytic Jacobian)."""
EDGE_BAND_PX = 3.0
"""``Halo.edge_peak`` looks this far (px) from the white: where an edge profile's black side lies."""
EDGE_PEAK_MARGIN = 0.05
"""``halo_clips_the_edges``: the halo-lifted black within this share of the clip counts (shot noise and the core's tail
then reach it; and measured at the edges' pose, percents off, the halo comes out weaker). Paper-lab optics, 2.4-6 m:
the peak at the true pose at x26 is 3742-3827 (the edges' poses within 0.04 %), at x28 4031-4133 (up to 1.07 % off),
the clip 4054; at x28 and 4.7 m, measured at the edges' pose (+1.5 %), 3927. 5 % puts the line at 3851."""
MIRROR_BACK_MIN_DEG = 20.0
"""``fit_target_model``: a winning fit from the mirror start whose normal is this far from the edges' start's is also
mirrored back and fitted again from there."""
REFINE_ITERATIONS = 3
"""``refine_target_model``'s largest number of Gauss-Newton steps (a tracked frame)."""
REFINE_STEP_TOL = 1e-5
"""``refine_target_model`` stops once a step moves the translation by less than this share of the distance."""


@dataclass(frozen=True)
class Halo:
    """A halo measured on a target's interior: amplitude ``A = f (W - B)`` (image units), width (px), the black's
    level at the window's centre (image units), the interior pixels fitted and their residual RMS (image units), and
    ``edge_peak``: the highest level the black so lifted reaches beside the white (within ``EDGE_BAND_PX`` of it: where
    the edge profiles look; image units; NaN: not computed)."""

    amplitude: float
    sigma_px: float
    black_level: float
    n_pixels: int
    residual_rms: float
    edge_peak: float = math.nan


@dataclass(frozen=True)
class TargetModelFit:
    """``fit_target_model``'s result. ``pose`` and ``covariance`` (6 x 6: t in m, then a small rotation in the camera
    frame, R = exp([r]x) R_fit, as ``pose_fit``'s); ``halo`` the fitted halo (amplitude, width), ``black_level`` and
    ``core_contrast`` (image units), ``residual_rms`` (image units, over ``n_pixels``), ``start_pose`` the edges'."""

    pose: Pose
    covariance: FloatArray
    halo: Halo
    black_level: float
    core_contrast: float
    residual_rms: float
    n_pixels: int
    start_pose: Pose
    gradient: tuple[float, float] = (0.0, 0.0)  # the black's gradient over the window (image units per window size)
    ground_share: float = 1.0  # the clipped pixels around the target, a share of its white (``fit_ground_share``)
    ground_share_sd: float = 0.0  # its standard deviation (0: not fitted)


class _Window:
    """The pixels of a target's window: normalized coordinates of their centres (cached: the camera's undistortion
    once), the image's clipped pixels as the white around the target, and the pixels fitted."""

    def __init__(self, camera: CameraModel, pose: Pose, spec: TargetSpec, image: npt.NDArray, saturation: float,
                 bin_px: int = 1):
        height, width = image.shape[:2]
        outline = _outline_px(camera, pose, spec.outer_radius_m)
        self.ok = outline is not None
        if outline is None:
            return
        k = self.bin_px = max(int(bin_px), 1)
        x0 = max(int(math.floor(outline[:, 0].min())) - WINDOW_PAD_PX, 0)
        y0 = max(int(math.floor(outline[:, 1].min())) - WINDOW_PAD_PX, 0)
        x1 = min(int(math.ceil(outline[:, 0].max())) + WINDOW_PAD_PX + 1, width)
        y1 = min(int(math.ceil(outline[:, 1].max())) + WINDOW_PAD_PX + 1, height)
        x1, y1 = x0 + (x1 - x0) // k * k, y0 + (y1 - y0) // k * k  # whole blocks of k x k pixels
        self.ok = x1 - x0 >= 8 * k and y1 - y0 >= 8 * k
        if not self.ok:
            return
        self.x0, self.y0, self.shape = x0, y0, ((y1 - y0) // k, (x1 - x0) // k)
        crop = np.asarray(image[y0:y1, x0:x1], dtype=np.float64)
        self.saturation = float(saturation)
        if k == 1:
            self.crop = crop
            self.clipped = crop >= saturation
            self.around = self.clipped.astype(np.float64)
            mixed = None
        else:  # each block's mean; a block is clipped when all its pixels are, and fitted only then or when none is
            h, w = self.shape
            self.crop = crop.reshape(h, k, w, k).mean(axis=(1, 3))
            self.around = (crop >= saturation).reshape(h, k, w, k).mean(axis=(1, 3))
            self.clipped = self.around >= 1.0
            self.crop[self.clipped] = saturation
            mixed = (self.around > 0.0) & ~self.clipped
        # the pixels' (blocks') centres, in image pixels
        xs, ys = np.meshgrid(x0 + k * np.arange(self.shape[1], dtype=np.float64) + 0.5 * (k - 1),
                             y0 + k * np.arange(self.shape[0], dtype=np.float64) + 0.5 * (k - 1))
        normalized = pixels_to_normalized(camera, np.column_stack([xs.ravel(), ys.ravel()]))
        self.un = np.ascontiguousarray(normalized[:, 0].reshape(self.shape))
        self.vn = np.ascontiguousarray(normalized[:, 1].reshape(self.shape))
        inside = np.zeros(self.shape, np.uint8)
        cv2.fillPoly(inside, [np.round((outline - [x0 + 0.5 * (k - 1), y0 + 0.5 * (k - 1)]) / k).astype(np.int32)], 1)
        margin = max(int(math.ceil(MARGIN_PX / k)), 1)
        near = cv2.dilate(inside, np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)).astype(bool)
        # outside the outer circle only the clipped pixels (the sheet, white ground): unclipped ground is of a
        # radiance the model does not know, not the black it would be taken for. (Ground without a sheet stays a
        # limit: clipped ground counts as the target's white, whatever its radiance: the detection sweep's seed 0's
        # no-sheet-005 at x32 on foliage is -0.66 % from the edges, -1.28 % with that ground fitted as black, -1.43 %
        # without it; a separate contrast for the white around was tried and made paper-lab worse.)
        near &= inside.astype(bool) | self.clipped
        if mixed is not None:
            near &= ~mixed  # a block's mean of clipped and unclipped pixels: no level the model gives
        self.rows, self.cols = np.nonzero(near)
        h, w = self.shape
        self.gradient = np.column_stack([(self.cols - 0.5 * w) / w, (self.rows - 0.5 * h) / h])

    def white(self, pose: Pose, spec: TargetSpec, derivatives: bool = False, ground_share: float = 1.0
              ) -> tuple[FloatArray, FloatArray | None]:
        """(h, w) each pixel's share of white: the design inside the outer circle, the clipped pixels outside (each
        ``ground_share`` of the target's white); with ``derivatives`` also its derivatives (6, h, w) by a small
        rotation in the camera frame and a translation (``target_model_kernel``)."""
        around = self.around if ground_share == 1.0 else self.around * ground_share
        inverse = np.linalg.inv(pose.plane_to_normalized_homography())
        circles = _circles(spec)
        if kernels() == "numba":
            white, d_white = target_model_kernel.white_kernel(self.un, self.vn, around, inverse,
                                                              np.ascontiguousarray(pose.R), circles, derivatives)
            return white, (d_white if derivatives else None)
        return target_model_kernel.white_numpy(self.un, self.vn, around, inverse, pose.R, circles, derivatives)


def _outline_px(camera: CameraModel, pose: Pose, radius_m: float, n: int = 64) -> FloatArray | None:
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    pts = pose.apply(np.column_stack([radius_m * np.cos(a), radius_m * np.sin(a), np.zeros(n)]))
    if np.any(pts[:, 2] <= 0.0):
        return None
    return project(camera, pts)


def _circles(spec: TargetSpec) -> FloatArray:
    """The design's circles as rows ``cx, cy, r, sign`` (m): the outer circle first (its own ramp), then each
    level's outer (+1, black), inner (-1), white code dots (-1) and centre dot (+1)."""
    rows = [(0.0, 0.0, spec.outer_radius_m, 0.0)]
    level: TargetSpec | None = spec
    while level is not None:
        rows += [(0.0, 0.0, level.outer_radius_m, 1.0), (0.0, 0.0, level.inner_radius_m, -1.0)]
        if level.code is not None:
            rows += [(float(cx), float(cy), level.code.dot_radius_m, -1.0)
                     for cx, cy in level.code.white_dot_centres_m()]
        if level.centre_dot_radius_m > 0:
            rows.append((0.0, 0.0, level.centre_dot_radius_m, 1.0))
        level = level.child
    return np.array(rows, dtype=np.float64)


def measure_halo(camera: CameraModel, pose: Pose, spec: TargetSpec, image: npt.NDArray, saturation: float,
                 core_sigma_px: float) -> Halo | None:
    """The halo seen on the target's interior at ``pose`` (stage 1's model, each width of ``HALO_SIGMAS_PX``, the
    best kept), or None when too few interior pixels, no significant halo, or one too narrow or too strong to be a halo
    (``MIN_HALO_WIDTH_CORES``, ``MAX_HALO_AMPLITUDE_CLIPS``)."""
    window = _Window(camera, pose, spec, image, saturation)
    if not window.ok:
        return None
    interior = _interior(window, pose, spec, core_sigma_px)
    if interior is None:
        return None
    rows, cols, y, grad = interior
    white = window.white(pose, spec)[0]
    best = None
    for sigma in HALO_SIGMAS_PX:
        design = np.column_stack([np.ones(len(y)), grad, _blurred(white, sigma)[rows, cols]])
        coef, *_ = np.linalg.lstsq(design, y, rcond=None)
        ss = float(np.sum((y - design @ coef) ** 2))
        if best is None or ss < best[0]:
            best = (ss, sigma, coef, design)
    ss, sigma, coef, design = best
    variance = ss / max(len(y) - 4, 1)
    try:
        sd = math.sqrt(max(float(np.linalg.inv(design.T @ design)[3, 3]) * variance, 0.0))
    except np.linalg.LinAlgError:
        return None
    if not (coef[3] > 0.0 and coef[3] > MIN_HALO_SIGMAS * sd):
        return None
    if sigma < MIN_HALO_WIDTH_CORES * core_sigma_px or coef[3] > MAX_HALO_AMPLITUDE_CLIPS * window.saturation:
        return None
    peak = _edge_peak(window, white, coef[0], coef[1:3], coef[3], sigma)
    return Halo(float(coef[3]), float(sigma), float(coef[0]), len(y), math.sqrt(variance), peak)


def scaled_halo(camera: CameraModel, pose: Pose, spec: TargetSpec, image: npt.NDArray, saturation: float,
                halo: Halo, ratio: float) -> Halo | None:
    """``halo`` (one measured on this target in an earlier frame) with its amplitude and black times ``ratio`` (this
    frame's exposure over that frame's: a linear sensor's levels follow it; the width is the lens's) and its
    ``edge_peak`` at ``pose`` in this frame's window; None if the window is empty. For a target whose interior shows no
    halo of its own: at x32 the ring of a 27 px target (16 bit, a 3 % halo of 6 px, ink lifted to 92 % of the clip)
    keeps ~5 px of black beyond the core's reach, and at the edges' pose, 6 % too far, that strip fitted a halo of 3 px
    at 7 of its sd (measured at x16 on the same target: 6.0 px, its amplitude half the one expected here)."""
    window = _Window(camera, pose, spec, image, saturation)
    if not window.ok or not ratio > 0.0:
        return None
    amplitude, black = halo.amplitude * ratio, halo.black_level * ratio
    peak = _edge_peak(window, window.white(pose, spec)[0], black, np.zeros(2), amplitude, halo.sigma_px)
    return Halo(amplitude, halo.sigma_px, black, 0, math.nan, peak)


def _edge_peak(window: _Window, white: FloatArray, black_level: float, gradient: FloatArray, amplitude: float,
               sigma_px: float) -> float:
    """``Halo.edge_peak``: the black lifted by the halo, ``B + g.(x, y) + A (G(halo) * w)``, at its highest over the
    window's black pixels within ``EDGE_BAND_PX`` of the white (the core's blur left out: it is the halo that matters
    where the core has fallen off), or NaN when there are none."""
    black = white <= 1e-6
    distance = cv2.distanceTransform(black.astype(np.uint8), cv2.DIST_L2, 5)
    band = black[window.rows, window.cols] & (distance[window.rows, window.cols] <= EDGE_BAND_PX)
    if not band.any():
        return math.nan
    rows, cols = window.rows[band], window.cols[band]
    lifted = (black_level + window.gradient[band] @ np.asarray(gradient, dtype=np.float64)
              + amplitude * _blurred(white, sigma_px)[rows, cols])
    return float(lifted.max())


def _interior(window: _Window, pose: Pose, spec: TargetSpec, core_sigma_px: float):
    """The fitted pixels of the ring's interior at ``pose``: black, unclipped, beyond the core's reach of any white."""
    white = window.white(pose, spec)[0]
    distance = cv2.distanceTransform((white <= 1e-6).astype(np.uint8), cv2.DIST_L2, 5)
    keep = (white <= 1e-6) & (distance >= CORE_REACH_SIGMAS * core_sigma_px + 2.0) & ~window.clipped
    keep = keep[window.rows, window.cols]
    if keep.sum() < MIN_INTERIOR_PX:
        return None
    rows, cols = window.rows[keep], window.cols[keep]
    return rows, cols, window.crop[rows, cols], window.gradient[keep]


def _blurred(white: FloatArray, sigma_px: float) -> FloatArray:
    return cv2.GaussianBlur(white, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)


class _HaloOnInterior:
    """Stage 1's model of the ring's interior pixels (``measure_halo``'s: the black with a gradient and the halo's
    amplitude solved linearly for each pose and width), parameters ``p``: the rotation vector (rad, in the camera
    frame, on the left of the start's rotation), the translation (m), the log of the halo's width (px)."""

    def __init__(self, window: _Window, spec: TargetSpec, start: Pose, interior: tuple):
        self.window, self.spec, self.start = window, spec, start
        self.rows, self.cols, self.y, self.gradient = interior

    def _fit(self, white: FloatArray, sigma_px: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        design = np.column_stack([np.ones(len(self.y)), self.gradient,
                                  _blurred(white, sigma_px)[self.rows, self.cols]])
        coef = _normal_solve(design, self.y)
        return design, coef, self.y - design @ coef

    def residuals(self, p: FloatArray) -> FloatArray:
        """Per interior pixel: the data less the best linear model at this pose and width."""
        return self._fit(self.window.white(_pose_at(self.start, p), self.spec)[0], _width_px(p[6]))[2]

    def jacobian(self, p: FloatArray) -> FloatArray:
        """Kaufman's Jacobian of the linearly projected residuals, ``-(I - P) (dD/dp) c`` (``P`` the projection on the
        design ``D``'s columns, ``c`` the levels): the term left out is orthogonal to the residuals, so the fit's
        minimum is the same. Only the halo's column depends on ``p``: the blur is linear, the white's derivatives from
        the kernel, the width by a relative step of 1e-4."""
        white, d_white = self.window.white(_pose_at(self.start, p), self.spec, derivatives=True)
        sigma = _width_px(p[6])
        design, coef, _ = self._fit(white, sigma)
        columns = np.empty((len(self.y), 7))
        for k in range(6):
            columns[:, k] = _blurred_single(d_white[k], sigma)[self.rows, self.cols]
        columns[:, :3] = columns[:, :3] @ _left_jacobian(p[:3])
        step = 1e-4
        columns[:, 6] = (_blurred(white, sigma * math.exp(step))[self.rows, self.cols] - design[:, 3]) / step
        columns *= coef[3]
        return -(columns - design @ _normal_solve(design, columns))


class _WholeTarget:
    """Stage 2's model of a window's pixels (module docstring) and its Jacobian, parameters ``p``: the rotation
    vector (rad, in the camera frame, on the left of the start's rotation), the translation (m), the log of the halo's
    width (px), the black's level and gradient (image units), the logs of the core's and the halo's contrasts."""

    def __init__(self, window: _Window, spec: TargetSpec, start: Pose, core_sigma_px: float,
                 ground_share: float = 1.0):
        self.window, self.spec, self.start, self.core_sigma_px = window, spec, start, core_sigma_px
        self.ground_share = ground_share  # the clipped pixels around the target, a share of its white
        self.y = window.crop[window.rows, window.cols]
        self.sign = np.where(window.clipped[window.rows, window.cols], 1.0, -1.0)  # d residual / d model below clip

    def _model(self, p: FloatArray, white: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        w = self.window
        core = _blurred(white, self.core_sigma_px)[w.rows, w.cols]
        wide = _blurred(white, _width_px(p[6]))[w.rows, w.cols]
        return p[7] + w.gradient @ p[8:10] + _positive(p[10]) * core + _positive(p[11]) * wide, core, wide

    def residuals(self, p: FloatArray) -> FloatArray:
        """Per pixel: data less model (both clipped) for an unclipped pixel; for a clipped one how far the model stays
        below the clip (0 when it reaches it: a censored measurement)."""
        model = self._model(p, self._white(p)[0])[0]
        sat = self.window.saturation
        return np.where(self.sign > 0, np.minimum(model - sat, 0.0), self.y - np.minimum(model, sat))

    def jacobian(self, p: FloatArray, small_rotation: bool = False) -> FloatArray:
        """d residuals / d p (analytic: the blur is linear, the white's derivatives from the kernel; the halo's width
        by a relative step of 1e-4); with ``small_rotation`` the first three columns are by a small rotation at the
        pose (``exp([w]x) R``) instead of by the rotation vector."""
        w = self.window
        white, d_white = self._white(p, derivatives=True)
        model, core, wide = self._model(p, white)
        contrast, amplitude, sigma = _positive(p[10]), _positive(p[11]), _width_px(p[6])
        columns = np.empty((len(self.y), len(p)))
        for k in range(6):
            d_single = d_white[k].astype(np.float32)
            columns[:, k] = (contrast * _blurred_single(d_single, self.core_sigma_px)[w.rows, w.cols]
                             + amplitude * _blurred_single(d_single, sigma)[w.rows, w.cols])
        if not small_rotation:
            columns[:, :3] = columns[:, :3] @ _left_jacobian(p[:3])
        step = 1e-4
        columns[:, 6] = amplitude * (_blurred(white, sigma * math.exp(step))[w.rows, w.cols] - wide) / step
        columns[:, 7] = 1.0
        columns[:, 8:10] = w.gradient
        columns[:, 10] = contrast * core
        columns[:, 11] = amplitude * wide
        if len(p) > 12:  # the ground's share (``_WithGroundShare``)
            around = self.window.white(_pose_at(self.start, p), self.spec)[0] - self._design
            columns[:, 12] = (contrast * _blurred(around, self.core_sigma_px)[w.rows, w.cols]
                              + amplitude * _blurred(around, sigma)[w.rows, w.cols])
        below = model < w.saturation  # a model at the clip moves no residual
        return columns * (self.sign * below)[:, None]

    def _white(self, p: FloatArray, derivatives: bool = False) -> tuple[FloatArray, FloatArray | None]:
        return self.window.white(_pose_at(self.start, p), self.spec, derivatives, self.ground_share)


class _WithGroundShare(_WholeTarget):
    """``_WholeTarget`` with a 13th parameter, the share of the target's white that the clipped pixels around it
    have (``fit_ground_share``): the pixel's white is the design's plus that share of the white around,
    ``w = w_design + g w_around`` (``target_model_kernel``: linear in what is around)."""

    def _white(self, p: FloatArray, derivatives: bool = False) -> tuple[FloatArray, FloatArray | None]:
        pose, window = _pose_at(self.start, p), self.window
        if derivatives:  # the design alone: the Jacobian's column of the share
            self._design = window.white(pose, self.spec, ground_share=0.0)[0]
        return window.white(pose, self.spec, derivatives, float(p[12]))


POSE_AND_WIDTH = np.arange(7)
"""Stage 2's parameters of the pose and the halo's width (the others, ``LEVELS``: black, gradient, log contrasts)."""
LEVELS = np.arange(7, 12)


class _Held:
    """``model`` with the parameters ``held`` (indices) at ``values``: residuals and Jacobian of the others."""

    def __init__(self, model: _WholeTarget, held: npt.NDArray[np.int64], values: FloatArray):
        self.model, self.held, self.values = model, held, values
        self.free = np.setdiff1d(np.arange(12), held)

    def _full(self, q: FloatArray) -> FloatArray:
        p = np.empty(12)
        p[self.held], p[self.free] = self.values, q
        return p

    def residuals(self, q: FloatArray) -> FloatArray:
        return self.model.residuals(self._full(q))

    def jacobian(self, q: FloatArray) -> FloatArray:
        return self.model.jacobian(self._full(q))[:, self.free]


def _width_px(log_width: float) -> float:
    """A halo's width from its log, held within ``HALO_WIDTH_LIMITS_PX`` (a trial step of the fit may ask for any:
    a blur's kernel grows with it)."""
    if not math.isfinite(log_width):  # (MINPACK's trial step can be NaN: min and max would pass it on to the blur)
        raise FloatingPointError(f"halo width's log {log_width}: not finite")
    low, high = HALO_WIDTH_LIMITS_PX
    return min(max(math.exp(min(log_width, 10.0)), low), high)


def _positive(log_value: float) -> float:
    """A contrast from its log, the log held below 60 (a trial step may ask for any; e^60 is beyond every image)."""
    if math.isnan(log_value):
        raise FloatingPointError("a contrast's log is NaN")
    return math.exp(min(log_value, 60.0))


def _normal_solve(design: FloatArray, rhs: FloatArray) -> FloatArray:
    """Least squares of a few well-scaled columns (levels, a gradient over the window, a blurred white in [0, 1]) by
    the normal equations: ~10x faster than an SVD for the thousands of rows here."""
    return np.linalg.solve(design.T @ design, design.T @ rhs)


def _left_jacobian(rotvec: FloatArray) -> FloatArray:
    """SO(3)'s left Jacobian: d exp([v]x) = [J(v) dv]x exp([v]x)."""
    theta = float(np.linalg.norm(rotvec))
    k = np.array([[0.0, -rotvec[2], rotvec[1]], [rotvec[2], 0.0, -rotvec[0]], [-rotvec[1], rotvec[0], 0.0]])
    if theta < 1e-8:
        return np.eye(3) + 0.5 * k
    return (np.eye(3) + (1.0 - math.cos(theta)) / theta**2 * k
            + (theta - math.sin(theta)) / theta**3 * (k @ k))


def _blurred_single(image: npt.NDArray, sigma_px: float) -> npt.NDArray[np.float32]:
    """``_blurred`` in single precision (2.3-2.6x faster): for the Jacobians' columns, whose precision moves only the
    fit's path, not its minimum."""
    return cv2.GaussianBlur(image.astype(np.float32, copy=False), (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)


def _least_squares(model: _HaloOnInterior | _WholeTarget | _Held, start: FloatArray, x_scale: FloatArray,
                   max_evaluations: int):
    """scipy's Levenberg-Marquardt (MINPACK's) on ``model``'s residuals and Jacobian, or None if it failed."""
    try:
        result = least_squares(model.residuals, start, jac=model.jacobian, method="lm", x_scale=x_scale,
                               max_nfev=max_evaluations)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError, cv2.error):
        return None  # (a trial step NaN: ``_width_px``, ``_positive``; held-out seed 6's single-019 at x16)

    return result if result.success and np.all(np.isfinite(result.x)) else None


def _pose_at(start: Pose, params: FloatArray) -> Pose:
    """The pose moved by params[:3] (a rotation in the camera frame, on the left) and set to translation params[3:6]."""
    return Pose(rotation_from_rotvec(params[:3]) @ start.R, params[3:6])


HALO_SCALE_BIAS_MIN_PCT = 0.75
"""``halo_biases_the_edges``: the halo's reach into a clipped edge's crossing, as a share of the target's size (%),
from which the 2-D model is needed even where the halo leaves the black well below the clip. A 19 px target (paper 10x
the clip, ink at 22-57 % of it, a 3 % halo of 6-14 px; the second renderer, ``tests/ray_cast_frames.py``): edges
-0.59 to +0.12 % off at 0.9-1.6 here, the model 0.02-0.06 %; 80 frames of 20-180 px at x2-x32 of the same renderer:
the edges within 0.1 % wherever this was under 1.1 (a sheet: 0.08 % at most; the model no better there)."""


def halo_scale_bias_pct(halo: Halo, saturation: float, core_sigma_px: float, outer_radius_px: float) -> float:
    """How far (% of the target's size, a scale) a halo can pull clipped edges that the edge model reads without it:
    the lift beside a straight edge, half the halo's amplitude, as a share of the room left between the black and the
    clip, times the core's blur, over the outer radius. A clipped edge's crossing lies on the core's tail, where the
    halo's lift moves it by about that share of a blur; how much of the move the exposure bias absorbs (both circles
    alike) and how much the distance takes depends on the target (inner disk, dots, ground), hence a scale, not a
    prediction."""
    room = saturation - halo.black_level
    if room <= 0.0 or outer_radius_px <= 0.0:
        return math.inf
    return 100.0 * 0.5 * halo.amplitude / room * core_sigma_px / outer_radius_px


def halo_needs_the_model(halo: Halo, saturation: float, core_sigma_px: float, outer_radius_px: float) -> bool:
    """Whether a target's edges need ``fit_target_model``: the halo clips them (``halo_clips_the_edges``) or pulls
    them by a share of its size (``halo_scale_bias_pct`` of ``HALO_SCALE_BIAS_MIN_PCT`` or more)."""
    return (halo_clips_the_edges(halo, saturation)
            or halo_scale_bias_pct(halo, saturation, core_sigma_px, outer_radius_px) >= HALO_SCALE_BIAS_MIN_PCT)


def halo_clips_the_edges(halo: Halo, saturation: float) -> bool:
    """Whether the halo lifts the black to within ``EDGE_PEAK_MARGIN`` of the clip anywhere beside the white
    (``Halo.edge_peak``): the edge profiles there show the halo's tail, not the core, and ``fit_target_model`` is
    needed. (Before session 19: the black plus half the halo's amplitude, the level beside a straight edge, reaching the
    clip; but between the dots and the circles the halo of white on both sides adds up: at x28 on paper-lab's optics,
    4 % ink, a 3 % halo of 6 px, that rule said no (2967 + 907 < 4054) while the lifted black reached 4031-4133 beside
    the dots and the edges' poses came out up to 1.07 % off.) Without ``edge_peak``, that older rule."""
    if math.isfinite(halo.edge_peak):
        return halo.edge_peak >= (1.0 - EDGE_PEAK_MARGIN) * saturation
    return halo.black_level + 0.5 * halo.amplitude >= saturation


def fit_target_model(camera: CameraModel, pose: Pose, spec: TargetSpec, image: npt.NDArray, saturation: float,
                     core_sigma_px: float, halo: Halo | None = None) -> TargetModelFit | None:
    """The target's pose fitted to its pixels (module docstring) from ``pose`` (the edges') and from its mirror image
    about the line of sight (``mirrored_about_line_of_sight``), the fit of the lower residual RMS kept; None when no
    halo is measured on its interior (then the edge model holds) or both fail (or end with a core contrast below the
    halo's: a halo of more than half the energy is no halo but a lost fit). ``halo``: ``measure_halo``'s at ``pose``
    when already measured (the mirror image's is measured at it: the interior moves with the pose).

    Why both: one circle's image fits two poses, mirror images about the line of sight; the second, concentric circle
    tells them apart through the ratio of the two ellipses, which the edges' exposure bias distorts. The mirror image
    is turned about its normal to where the image has the code dots (``surround_geometry._dots_turn_rad`` over a full
    turn): from the edges' heading it was 34 deg off on pose 19 in the exposure sweep and the fit lost its core.
    Paper-lab at x32: pose 19 (46 deg tilt) came out of the edges mirrored (normal 92 deg off), pose 10's 11 deg off
    (+0.16 %); fitted from the mirror image they end 0.0-0.2 deg off (-0.06 %, -0.007 %) at a residual RMS 10 % and
    2 % lower, while for poses 3 and 12 the mirror image ends 85-88 deg off at an RMS 4 % and 156 % higher.

    A large target's stages run on blocks of pixels first (``BIN_WINDOW_PX``); where that fails, at full resolution."""
    halo = halo or measure_halo(camera, pose, spec, image, saturation, core_sigma_px)
    if halo is None:
        return None
    k = _bin_px(camera, pose, spec)
    return _fit_from_both_starts(camera, pose, spec, image, saturation, core_sigma_px, halo, k)


def _fit_from_both_starts(camera: CameraModel, pose: Pose, spec: TargetSpec, image: npt.NDArray, saturation: float,
                          core_sigma_px: float, halo: Halo, k: int) -> TargetModelFit | None:
    """``fit_target_model``'s fits from both starts, the stages on blocks of ``k`` x ``k`` pixels (then finished at
    full resolution: ``_at_full_resolution``)."""
    mirrored = _mirror_start(camera, pose, spec, image)
    mirrored_halo = measure_halo(camera, mirrored, spec, image, saturation, core_sigma_px) or halo
    firsts = [_stage1(camera, start, spec, image, saturation, core_sigma_px, start_halo, k)
              for start, start_halo in ((pose, halo), (mirrored, mirrored_halo))]
    kept = [f for f in firsts if f is not None]
    if not kept:
        return None
    best_rms = min(f.rms for f in kept)
    fits = [_stage2(f, spec, core_sigma_px, pose) if f is not None and f.rms <= STAGE1_RMS_KEPT * best_rms else None
            for f in firsts]
    fits = [f if f is not None and f.core_contrast > f.halo.amplitude else None for f in fits]
    best = min((f for f in fits if f is not None), key=lambda f: f.residual_rms, default=None)
    if best is not None and best is fits[1] and not _same_normal(best.pose, pose):
        # The mirror start won, its normal far from the edges': the edges' start may have lost its way (its edges'
        # distance percents off, stage 2 from there losing the core) while the mirror fit, whatever its normal, got
        # the distance. Its own mirror image has the edges' normal at that distance: stage 2 from there too.
        back = _mirror_start(camera, best.pose, spec, image)
        window = _Window(camera, back, spec, image, saturation, k)
        if window.ok:
            start = np.concatenate([np.zeros(3), back.t, [math.log(best.halo.sigma_px)]])
            distance_m = float(np.linalg.norm(back.t))
            x_scale = np.concatenate([np.full(3, 1e-3), np.full(3, 1e-3 * distance_m), [0.05]])
            again = _stage2(_Stage1(back, best.halo, window, start, x_scale, math.nan), spec, core_sigma_px, pose)
            if (again is not None and again.core_contrast > again.halo.amplitude
                    and again.residual_rms < best.residual_rms):
                best = again
    if best is not None and k > 1:
        best = _at_full_resolution(camera, best, k, spec, image, saturation, core_sigma_px, pose)
    return best


BIN_WINDOW_PX = 150
"""``fit_target_model`` runs its two stages on blocks of 2 x 2 pixels for a window at least twice this long
(``_Window(bin_px=2)``: each block's mean, the core's blur and the halo's width in blocks, the blocks of clipped and
unclipped pixels left out), then finishes at full resolution (``_at_full_resolution``: MINPACK's stage 2 from there).
Its cost grows with the window's area times the evaluations (~15 window-sized blurs and the design's kernel each): a
380 px target at x32 (the detection sweep's seed 1 single-001, 8 bit) took 62 s of CPU at full resolution, 6.8 s so.
Smaller windows (targets up to ~320 px; paper-lab's at x32 are 20-130 px) keep full resolution throughout. Paper-lab
at x32 with binning forced on (poses 0-18, windows of 100-350 px): with 2 x 2 blocks the distances within 0.005 % of
the full-resolution fit's but one (-0.078 -> -0.106 %), 2-3x faster; with 3 x 3 and coarser (the core's blur a third
of a block) two of ten fits were lost."""
MAX_BIN_PX = 2
FULL_RESOLUTION_MAX_EVALUATIONS = 50
"""``_at_full_resolution``'s largest number of model evaluations (paper-lab's finishes took 5-10)."""


def _bin_px(camera: CameraModel, pose: Pose, spec: TargetSpec) -> int:
    """The block size for ``fit_target_model``'s stages at ``pose`` (``BIN_WINDOW_PX``): 1 for all but large targets."""
    outline = _outline_px(camera, pose, spec.outer_radius_m)
    if outline is None:
        return 1
    side = float(np.max(outline.max(axis=0) - outline.min(axis=0))) + 2 * WINDOW_PAD_PX
    return min(max(int(side // BIN_WINDOW_PX), 1), MAX_BIN_PX)


def _at_full_resolution(camera: CameraModel, coarse: TargetModelFit, k: int, spec: TargetSpec, image: npt.NDArray,
                        saturation: float, core_sigma_px: float, edges_pose: Pose) -> TargetModelFit | None:
    """Stage 2 at full resolution (MINPACK's, as ``_stage2``'s) from a fit on blocks of ``k`` x ``k`` pixels: its pose,
    halo (its width times ``k``) and levels; None if that fails or loses the core."""
    window = _Window(camera, coarse.pose, spec, image, saturation)
    if not window.ok:
        return None
    model = _WholeTarget(window, spec, coarse.pose, core_sigma_px)
    start = np.concatenate([np.zeros(3), coarse.pose.t,
                            [math.log(coarse.halo.sigma_px * k), coarse.black_level, coarse.gradient[0],
                             coarse.gradient[1], math.log(coarse.core_contrast), math.log(coarse.halo.amplitude)]])
    distance_m = float(np.linalg.norm(coarse.pose.t))
    x_scale = np.concatenate([np.full(3, 1e-3), np.full(3, 1e-3 * distance_m), [0.05, 10.0, 10.0, 10.0, 0.05, 0.05]])
    finished = _least_squares(model, start, x_scale, FULL_RESOLUTION_MAX_EVALUATIONS)
    if finished is None:
        return None
    fitted = _fitted(model, finished.x, edges_pose)
    return fitted if fitted is not None and fitted.core_contrast > fitted.halo.amplitude else None


GROUND_SHARE_MAX_EVALUATIONS = 60
"""``fit_ground_share``'s largest number of model evaluations (the detection sweep's no-sheet targets took 8-28)."""
GROUND_SHARE_MIN_SIGMAS = 3.0
"""``fit_ground_share`` keeps a share at least this many of its standard deviations from 1 (else None: the white
around is the target's, a sheet)."""


def fit_ground_share(camera: CameraModel, fit: TargetModelFit, spec: TargetSpec, image: npt.NDArray,
                     saturation: float, core_sigma_px: float) -> TargetModelFit | None:
    """``fit`` (``fit_target_model``'s, which takes the clipped pixels around the target for its white) fitted again
    with their radiance free, a share ``g`` of the target's white: ``w = w_design + g w_around``. A sheet around the
    target has its white (``g`` 1); ground without a sheet, clipped, is of any radiance the clip hides, and taken for
    the white it put the outer circle's core and halo too high: the detection sweep's x32 targets printed on ground
    (carpet, gradient, text) came out 0.5-0.7 % too near at a distance sd of 0.003-0.05 % (seed 2's no-sheet-000 on
    carpet of reflectance 0.45: -0.667 %, ``g`` fitted 0.52, -0.038 %). Whether ``g`` or the white is right cannot be
    told from the pixels alone on every ground: a chessboard's clipped squares of 0.1 and 0.9 share one ``g`` (its
    fits overshot, -0.62 -> +0.77 %); the caller judges on the code dots (``tracker.checks._dots_prefer_ground``).
    MINPACK's Levenberg-Marquardt at full resolution from ``fit``; None when it fails, loses the core, or ``g`` lies
    within ``GROUND_SHARE_MIN_SIGMAS`` of 1."""
    window = _Window(camera, fit.pose, spec, image, saturation)
    if not window.ok:
        return None
    model = _WithGroundShare(window, spec, fit.pose, core_sigma_px)
    start = np.concatenate([np.zeros(3), fit.pose.t,
                            [math.log(fit.halo.sigma_px), fit.black_level, fit.gradient[0], fit.gradient[1],
                             math.log(fit.core_contrast), math.log(fit.halo.amplitude), fit.ground_share]])
    distance_m = float(np.linalg.norm(fit.pose.t))
    x_scale = np.concatenate([np.full(3, 1e-3), np.full(3, 1e-3 * distance_m),
                              [0.05, 10.0, 10.0, 10.0, 0.05, 0.05, 0.05]])
    result = _least_squares(model, start, x_scale, GROUND_SHARE_MAX_EVALUATIONS)
    if result is None or not 0.0 < result.x[12]:
        return None
    fitted = _fitted(model, result.x, fit.start_pose)
    if fitted is None or not fitted.core_contrast > fitted.halo.amplitude:
        return None
    return fitted if abs(fitted.ground_share - 1.0) > GROUND_SHARE_MIN_SIGMAS * fitted.ground_share_sd else None


def _mirror_start(camera: CameraModel, pose: Pose, spec: TargetSpec, image: npt.NDArray) -> Pose:
    """``mirrored_about_line_of_sight(pose)`` turned about its normal to where the image has the code dots."""
    mirrored = mirrored_about_line_of_sight(pose, spec.outer_radius_m)
    if spec.code is not None and len(spec.code.white_dot_centres_m()):  # its heading: where the image has the dots
        turn = surround_geometry._dots_turn_rad(image, spec.code.white_dot_centres_m(), camera, mirrored, math.pi)
        mirrored = Pose(mirrored.R @ _turn_z(turn), mirrored.t)
    return mirrored


def _same_normal(a: Pose, b: Pose) -> bool:
    """Whether two poses' normals are within ``MIRROR_BACK_MIN_DEG`` of each other."""
    return float(np.clip(a.R[:, 2] @ b.R[:, 2], -1.0, 1.0)) >= math.cos(math.radians(MIRROR_BACK_MIN_DEG))


def mirrored_about_line_of_sight(pose: Pose, radius_m: float) -> Pose:
    """Nearly the other pose the image of ``pose``'s circle of ``radius_m`` fits, as a fit's start: the normal
    mirrored about the line of sight to the centre (``n' = 2 (n.d) d - n``, the centre kept: the exact second pose of
    one circle also moves its centre, the image differs by ~1.5 % of its size at 46 deg), turned about it so that the
    circle's points at 0, 90, 180 and 270 deg project near where they did."""
    normal = pose.R[:, 2]
    sight = pose.t / np.linalg.norm(pose.t)
    mirrored = 2.0 * float(normal @ sight) * sight - normal
    axis = np.cross(normal, mirrored)
    sine, cosine = float(np.linalg.norm(axis)), float(normal @ mirrored)
    if sine < 1e-12:
        return pose
    rotation = rotation_from_rotvec(axis / sine * math.atan2(sine, cosine)) @ pose.R
    marks = radius_m * np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])

    def seen(rotation: FloatArray) -> FloatArray:
        points = marks @ rotation.T + pose.t
        return points[:, :2] / points[:, 2:]

    wanted = seen(pose.R)
    turns = np.linspace(0.0, 2.0 * math.pi, 720, endpoint=False)
    misses = [float(np.sum((seen(rotation @ _turn_z(a)) - wanted) ** 2)) for a in turns]
    return Pose(rotation @ _turn_z(float(turns[int(np.argmin(misses))])), pose.t.copy())


def _turn_z(angle_rad: float) -> FloatArray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class _Stage1:
    """Stage 1's outcome from one start: the window, the parameters (rotation vector, translation, log halo width),
    their scales, and the interior's residual RMS (image units)."""

    start: Pose
    halo: Halo
    window: _Window
    x: FloatArray
    x_scale: FloatArray
    rms: float


def _stage1(camera: CameraModel, pose: Pose, spec: TargetSpec, image: npt.NDArray, saturation: float,
            core_sigma_px: float, halo: Halo, bin_px: int = 1) -> _Stage1 | None:
    """Stage 1 (the halo alone on the ring's interior) from the start ``pose``, or None; on blocks of ``bin_px`` x
    ``bin_px`` pixels (``BIN_WINDOW_PX``: widths in blocks from here on)."""
    window = _Window(camera, pose, spec, image, saturation, bin_px)
    if not window.ok:
        return None
    interior = _interior(window, pose, spec, core_sigma_px / window.bin_px)
    if interior is None:
        return None
    distance_m = float(np.linalg.norm(pose.t))
    start = np.concatenate([np.zeros(3), pose.t, [math.log(halo.sigma_px / window.bin_px)]])
    x_scale = np.concatenate([np.full(3, 1e-3), np.full(3, 1e-3 * distance_m), [0.05]])
    stage1 = _least_squares(_HaloOnInterior(window, spec, pose, interior), start, x_scale, STAGE1_MAX_EVALUATIONS)
    if stage1 is None:
        return None
    return _Stage1(pose, halo, window, stage1.x, x_scale, math.sqrt(2.0 * stage1.cost / len(interior[2])))


def _stage2(first: _Stage1, spec: TargetSpec, core_sigma_px: float, edges_pose: Pose) -> TargetModelFit | None:
    """Stage 2 (every pixel, the core included) from stage 1's outcome, or None (``edges_pose`` reported as the
    start)."""
    window, pose, halo, x_scale = first.window, first.start, first.halo, first.x_scale
    # stage 2: everything, the core included; the linear levels start from stage 1's halo
    model = _WholeTarget(window, spec, pose, core_sigma_px / window.bin_px)
    core_start = max(10.0 * window.saturation, halo.amplitude * (1.0 / 0.03 - 1.0))  # a few-percent halo: C ~ 30 A
    start2 = np.concatenate([first.x, [halo.black_level, 0.0, 0.0, math.log(core_start), math.log(halo.amplitude)]])
    scale2 = np.concatenate([x_scale, [10.0, 10.0, 10.0, 0.05, 0.05]])
    # (2a) the levels (black, gradient, contrasts) settled at stage 1's pose and width, (2b) everything free: from
    # levels far off, the core's contrast could fall to nothing, the halo alone then drawing the target
    held = _Held(model, POSE_AND_WIDTH, start2[POSE_AND_WIDTH])
    settled = _least_squares(held, np.delete(start2, POSE_AND_WIDTH), np.delete(scale2, POSE_AND_WIDTH),
                             STAGE2_MAX_EVALUATIONS)
    if settled is not None:
        start2[LEVELS] = settled.x
    stage2 = _least_squares(model, start2, scale2, STAGE2_MAX_EVALUATIONS)
    return None if stage2 is None else _fitted(model, stage2.x, edges_pose)


def refine_target_model(camera: CameraModel, starts: Sequence[Pose], spec: TargetSpec, image: npt.NDArray,
                        saturation: float, core_sigma_px: float, last: TargetModelFit, level_scale: float = 1.0,
                        edges_pose: Pose | None = None) -> TargetModelFit | None:
    """Stage 2 alone (a tracked frame) from the one of ``starts`` whose residuals are least (e.g. the predicted pose and
    this frame's edges' pose corrected as the last frame's was), with ``last``'s halo width and levels (the last
    frame's fit), the levels times ``level_scale`` (the exposure's ratio to the last frame's: a linear sensor's levels
    follow it); None if the fit failed or lost its core. A tracked frame starts near its optimum, where stage 1 (which
    brings a pose 3 % off to ~1 %) and the mirror image have nothing left to do: a few Gauss-Newton steps
    (``REFINE_ITERATIONS``). ``edges_pose`` is reported as the start (default: the start taken)."""
    if not starts:
        return None
    window = _Window(camera, starts[0], spec, image, saturation)  # its margin covers a frame's motion
    if not window.ok:
        return None
    scale = max(float(level_scale), 1e-6)
    levels = [math.log(last.halo.sigma_px), last.black_level * scale, last.gradient[0] * scale,
              last.gradient[1] * scale, math.log(last.core_contrast * scale), math.log(last.halo.amplitude * scale)]
    best = None
    for pose in starts:
        model = _WholeTarget(window, spec, pose, core_sigma_px, last.ground_share)
        start = np.concatenate([np.zeros(3), pose.t, levels])
        try:
            residuals = model.residuals(start)
        except ArithmeticError:
            continue
        cost = float(residuals @ residuals)
        if best is None or cost < best[0]:
            best = (cost, model, start, pose)
    if best is None:
        return None
    _, model, start, pose = best
    fitted = _gauss_newton(model, start, REFINE_ITERATIONS)
    if fitted is None:
        return None
    p, jacobian = fitted
    refined = _fitted(model, p, pose if edges_pose is None else edges_pose, jacobian)
    return refined if refined is not None and refined.core_contrast > refined.halo.amplitude else None


def _gauss_newton(model: _WholeTarget, p: FloatArray, iterations: int) -> tuple[FloatArray, FloatArray] | None:
    """At most ``iterations`` Gauss-Newton steps of ``model`` from ``p`` (each halved up to twice until the cost falls;
    stopped when none does or the pose's step is below ``REFINE_STEP_TOL``): the parameters and the last Jacobian
    computed (at the last step's start: for the covariance; no step lowering the cost: ``p`` is where the cost is
    least along Gauss-Newton's direction, kept), or None (a singular system). From a
    tracked frame's start, ~0.1 px off, 2 steps are as good as MINPACK's 5-19 evaluations (4-11 Jacobians)."""
    residuals = model.residuals(p)
    cost = float(residuals @ residuals)
    jacobian = None
    for _ in range(iterations):
        jacobian = model.jacobian(p)
        norms = np.sqrt(np.einsum("ij,ij->j", jacobian, jacobian))
        norms[norms == 0.0] = 1.0
        scaled = jacobian / norms
        try:
            step = -np.linalg.solve(scaled.T @ scaled, scaled.T @ residuals) / norms
        except np.linalg.LinAlgError:
            return None
        for _ in range(3):
            trial = p + step
            try:
                trial_residuals = model.residuals(trial)
            except ArithmeticError:
                trial_residuals = None
            if trial_residuals is not None and float(trial_residuals @ trial_residuals) < cost:
                break
            step = 0.5 * step
        else:
            break
        p, residuals, cost = trial, trial_residuals, float(trial_residuals @ trial_residuals)
        if np.max(np.abs(step[3:6])) < REFINE_STEP_TOL * float(np.linalg.norm(p[3:6])):
            break
    return None if jacobian is None else (p, jacobian)


def _fitted(model: _WholeTarget, p: FloatArray, edges_pose: Pose, jacobian: FloatArray | None = None
            ) -> TargetModelFit | None:
    """Stage 2's parameters ``p`` as a ``TargetModelFit`` with the covariance of the pose (None if singular), from
    ``jacobian`` if given (one computed near ``p``), else the Jacobian at ``p``."""
    n = len(model.y)
    residuals = model.residuals(p)
    variance = float(residuals @ residuals) / max(n - len(p), 1)
    if jacobian is None:
        jacobian = model.jacobian(p, small_rotation=True)  # the covariance's rotation: exp([r]x) R_fit
    try:
        covariance = np.linalg.inv(jacobian.T @ jacobian) * variance
    except np.linalg.LinAlgError:
        return None
    # (rotation, t) -> (t, rotation), the tracker's order
    order = [3, 4, 5, 0, 1, 2]
    fitted = _pose_at(model.start, p)
    ground_share = float(p[12]) if len(p) > 12 else model.ground_share
    white = model.window.white(fitted, model.spec, ground_share=ground_share)[0]
    peak = _edge_peak(model.window, white, p[7], p[8:10], _positive(p[11]), _width_px(p[6]))
    wide_halo = Halo(float(_positive(p[11])), float(_width_px(p[6])), float(p[7]), n, math.sqrt(variance), peak)
    return TargetModelFit(pose=fitted, covariance=covariance[np.ix_(order, order)], halo=wide_halo,
                          black_level=float(p[7]), core_contrast=float(_positive(p[10])),
                          residual_rms=math.sqrt(variance), n_pixels=n, start_pose=edges_pose,
                          gradient=(float(p[8]), float(p[9])), ground_share=ground_share,
                          ground_share_sd=math.sqrt(max(float(covariance[12, 12]), 0.0)) if len(p) > 12 else 0.0)
