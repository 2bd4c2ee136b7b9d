"""Model versus measurement on recordings of livetrack ring targets (``livetrack model RECORDING``).

The input is any exposure series of known targets (three or more exposures, the target static or moving, the
poses unknown): ``RingSeries``, built from a v1 recording by ``livetrack.modelcheck.rings_input``. No file I/O
here; plots in ``rings_plots``.

1. **Poses**: the tracker (``livetrack.estimator.tracker``, exposure-compensated) estimates every frame's poses,
   frames in increasing exposure (the all-clipped frames take the blur of the last clean one). Frames whose poses
   agree within ``STATIC_TOLERANCE`` form a static segment, rendered at the pose of its best-exposed unclipped
   frame; a frame where the tracker found nothing joins the segment its pixels correlate with (``pose_groups``).
2. **Rendering at the poses** (the simulator's coverage renderer, ``livetrack.sim``): for a subsample of frames
   (``FIT_FRAMES_PER_EXPOSURE`` per exposure, spread over the recording), around each target the paper and ink
   indicators are rendered ``OVERSAMPLING`` times finer than the pixels (exact area coverage, lens model
   included), blurred by a Gaussian core of each width on ``SIGMA_GRID_PX`` and binned to pixels: the core is
   then interpolated between grid widths during the fits (the image formation of the simulator, PSF before pixel
   integration, at a cost of a few array operations per evaluation).
3. **Forward model** per pixel: reflectance ``W + k B + g (1 - W - B)`` (paper, ink ratio k, background ratio g
   measured beside the sheet), the catalogue's optics (``OpticsModel.apply`` of the simulator: halo, defocus,
   motion blur ... on the core-blurred pixel image), the white rate x exposure, vignetting ``1 - s r^2``, veiling
   glare ``(1 - f) E + f mean(E)`` (the frame mean measured on unclipped frames: glare keeps energy), the
   simulator's sensor well (``SensorModel.well``: clip, knee, blooming along columns) in DN units, then the mean
   of the clipped noisy reading at the top code (noise ``var = a + b DN`` measured on flat paper and ink).
4. **Fit** on the pixels within ``BAND_PX`` of the target's edges (plus a share of its flat areas) by
   ``scipy.optimize.least_squares`` (baseline: core sigma, white rate, ink ratio when the print is unknown),
   **choose by held-out error** (fit on half of the exposures, predict the others), greedy, as the disk check.
5. **Compare**: the per-edge exposure bias ``delta`` of the 50 %-threshold ring (dark area against the printed
   one, per edge length: positive when the white grows, as the tracker's delta), measured and predicted, the ring
   thickness after compensation, residuals binned by edge direction, predicted intensity and image position.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares
from scipy.special import ndtr

from livetrack.camera import CameraModel
from livetrack.geometry import Pose
from livetrack.modelcheck.analysis import plain
from livetrack.modelcheck.fitting import parameter_space
from livetrack.modelcheck.measure import binned as binned_stats
from livetrack.sim.coverage import Placement, render_reflectance, sheet_roi
from livetrack.sim.optics import OpticsModel, gaussian_kernel, tail_kernel
from livetrack.sim.sensor import SensorModel
from livetrack.sim.texture import TargetTexture
from livetrack.targets.spec import TargetSpec

log = logging.getLogger(__name__)
FloatArray = npt.NDArray[np.float64]

OVERSAMPLING = 3
"""Fine-grid factor of the rendering (the simulator's default): the core acts before pixel integration."""
FINE_SUPERSAMPLING = 4
"""Sub-cells per mixed fine pixel (the fine grid is already 3x: curved edges stay exact to ~1e-4)."""
SIGMA_GRID_PX = np.concatenate([np.arange(0.3, 1.55, 0.1), np.arange(1.7, 3.15, 0.2)])
"""Core widths (px) rendered per frame; the fits interpolate linearly between them (error < 0.1 % of a step)."""
BAND_PX = 6
"""Pixels within this distance of an ink/paper edge are fitted (all of them)."""
FLAT_SHARE = 0.05
"""Share of the target's other pixels (flat paper and ink) fitted as well: the levels, glare, vignetting."""
ROI_MARGIN_PX = 16
"""Pixels around the sheet's image rendered with it (a halo of this width reaches into the band)."""
MODEL_TOLERANCE = 0.003
"""Relative accuracy granted to the model (of the frame's unclipped white level), in quadrature with the noise:
the poses come from the tracker (0.01-0.03 % in distance) and the renderer is good to ~0.2 % of a step."""
MIN_RELATIVE_GAIN = 0.02
"""An effect is named only if it lowers the held-out error by more than this fraction."""
MAX_EFFECTS = 2
NOISE_FLOOR = 1.05
"""Once the held-out error is down to this (the noise, with the model tolerance: ~1), no further effect is tried."""
FIT_FRAMES_PER_EXPOSURE = 2
"""Frames (per distinct exposure) in the fits: cost."""
STATIC_TOLERANCE = 2e-3
"""Translations within this fraction of the distance (and rotations within this many radians): a static target."""
CLIPPED_JOIN_PX = 3.0
"""A clipped frame whose tracked pose images the target's centre within this of a static segment's joins it."""
HELDOUT_MAX_NFEV = 14
FINAL_MAX_NFEV = 80

RING_EFFECTS: dict[str, dict[str, tuple[float, float, float]]] = {
    "halo": {"halo_fraction": (0.03, 1e-4, 0.6), "halo_sigma_px": (5.0, 1.0, 15.0)},
    "exponential_tail": {"exponential_tail_fraction": (0.15, 1e-3, 0.8), "exponential_tail_scale_px": (1.0, 0.2, 5.0)},
    "lorentzian_tail": {"lorentzian_tail_fraction": (0.1, 1e-3, 0.8), "lorentzian_tail_scale_px": (0.5, 0.05, 3.0)},
    "defocus": {"defocus_radius_px": (1.5, 0.05, 6.0)},
    "anisotropic_core": {"aniso_c": (0.0, -0.7, 0.7), "aniso_s": (0.0, -0.7, 0.7)},
    "blooming": {"spill_log10": (-2.5, -6.0, 0.0)},
    "nonlinear": {"knee_fraction": (0.7, 0.2, 0.999)},
    "ink_floor": {"ink_to_white": (0.08, 0.0, 0.9)},
    "veiling_glare": {"glare_fraction": (0.02, 1e-5, 0.5)},
    "vignetting": {"vignetting_strength": (0.1, 1e-4, 1.0)},
}
"""Catalogue of the ring check: effect -> fitted parameter -> (start, lower, upper)."""

NOT_IN_RING_CATALOGUE = {
    "lens_distortion": "a geometric calibration error: the poses are estimated through the same lens model, so a "
                       "target covering a small part of the frame cannot tell it (use a calibration pattern)",
    "motion_blur": "not tried (two parameters with an angle: local minima; a static target has none)",
}

NEGLIGIBLE: dict[str, tuple[str, float, float]] = {
    "halo": ("halo_fraction", -1.0, 0.005),
    "defocus": ("defocus_radius_px", -1.0, 0.3),
    "blooming": ("spill_log10", -9.0, -4.0),
    "nonlinear": ("knee_fraction", 0.97, 2.0),
    "veiling_glare": ("glare_fraction", -1.0, 0.003),
    "exponential_tail": ("exponential_tail_fraction", -1.0, 0.01),
    "lorentzian_tail": ("lorentzian_tail_fraction", -1.0, 0.005),
    "anisotropic_core": ("aniso_e", -1.0, 0.03),
    "vignetting": ("vignetting_strength", -1.0, 0.03),
}
"""effect -> (parameter, lo, hi): fitted inside [lo, hi] the effect is too small to name."""


def effect_parameters(effect: str, p: dict[str, float]) -> dict[str, float]:
    """Fitted parameters of ``effect`` under the simulator's names (``livetrack.sim.effects``)."""
    if effect == "halo":
        return {"fraction": p["halo_fraction"], "sigma_px": p["halo_sigma_px"]}
    if effect == "defocus":
        return {"radius_px": p["defocus_radius_px"]}
    if effect in ("exponential_tail", "lorentzian_tail"):
        return {"fraction": p[f"{effect}_fraction"], "scale_px": p[f"{effect}_scale_px"]}
    if effect == "ink_floor":
        return {"black_to_white": p["ink_to_white"]}
    if effect == "anisotropic_core":
        e = math.hypot(p["aniso_c"], p["aniso_s"])
        sigma = p["sigma_px"]
        return {"sigma_x_px": sigma * math.sqrt(1.0 + e), "sigma_y_px": sigma * math.sqrt(max(1.0 - e, 0.0)),
                "angle_deg": 0.5 * math.degrees(math.atan2(p["aniso_s"], p["aniso_c"]))}
    if effect == "blooming":
        return {"spill_fraction": 10.0 ** p["spill_log10"]}
    if effect == "nonlinear":
        return {"knee_fraction_of_full_well": p["knee_fraction"]}
    if effect == "veiling_glare":
        return {"fraction": p["glare_fraction"]}
    if effect == "vignetting":
        return {"strength": p["vignetting_strength"]}
    raise KeyError(effect)


# ---------------------------------------------------------------------------------------------- input
@dataclass(frozen=True)
class RingSeries:
    """An exposure series of known ring targets: ``images[i]`` (H, W) uint8/uint16 taken at ``exposure_us[i]``.
    ``white_reflectance``/``black_reflectance``: the print's paper and ink when known (else None)."""

    name: str
    camera: CameraModel
    targets: tuple[TargetSpec, ...]
    exposure_us: FloatArray
    images: list[npt.NDArray[np.unsignedinteger]]
    white_reflectance: float | None = None
    black_reflectance: float | None = None

    @property
    def n_frames(self) -> int:
        return len(self.images)

    @property
    def saturation_dn(self) -> float:
        return float((1 << self.camera.bit_depth) - 1)

    @property
    def black_to_white(self) -> float | None:
        if self.white_reflectance is None or self.black_reflectance is None:
            return None
        return self.black_reflectance / self.white_reflectance

    @property
    def half_diagonal_px(self) -> float:
        return 0.5 * math.hypot(self.camera.width, self.camera.height)


@dataclass(frozen=True)
class TrackedTarget:
    """The tracker's estimate of one target in one frame."""

    pose: Pose
    delta_px: float


def estimate_poses(series: RingSeries) -> list[dict[int, TrackedTarget]]:
    """Per frame: target id -> tracked pose and delta (frames in increasing exposure through one tracker)."""
    from livetrack.estimator.tracker import Tracker, TrackerOptions

    tracker = Tracker(series.camera, list(series.targets), TrackerOptions())
    out: list[dict[int, TrackedTarget]] = [{} for _ in range(series.n_frames)]
    for i in np.argsort(series.exposure_us, kind="stable"):
        result = tracker.process(series.images[i], float(series.exposure_us[i]))
        out[i] = {t.target_id: TrackedTarget(t.pose, float(t.delta_px)) for t in result.targets if t.fit}
    return out


def pose_groups(series: RingSeries, tracked: list[dict[int, TrackedTarget]]) -> tuple[list[dict[int, Pose]], int]:
    """Per frame: target id -> the pose to render it at, and the number of static segments found.

    Tracked poses that agree (translation within ``STATIC_TOLERANCE`` of the distance, rotation within 10x that
    in radians) form a static segment, rendered at the pose of its best-exposed unclipped frame (the least
    exposed otherwise). A frame in which the tracker found nothing (e.g. blooming over the ring) takes the segment
    whose frames its pixels correlate with best (normalised correlation > 0.5 in the segment's sheet box)."""
    top = series.saturation_dn
    out: list[dict[int, Pose]] = [{} for _ in range(series.n_frames)]
    n_static = 0
    for spec in series.targets:
        groups: list[list[int]] = []
        for i in np.argsort(series.exposure_us, kind="stable"):
            if spec.id not in tracked[i]:
                continue
            pose = tracked[i][spec.id].pose
            for g in groups:
                ref = tracked[g[0]][spec.id].pose
                if (np.linalg.norm(pose.t - ref.t) <= STATIC_TOLERANCE * np.linalg.norm(ref.t)
                        and np.linalg.norm(pose.rotvec - ref.rotvec) <= 10 * STATIC_TOLERANCE):
                    g.append(int(i))
                    break
            else:
                # A clipped frame's pose is the tracker's least reliable (an unmodelled effect such as blooming
                # moves its edges): it joins a segment that images the target's centre within CLIPPED_JOIN_PX of
                # its own, at a distance within 5 %, when its pixels correlate with the segment's (> 0.5).
                g = _clipped_join(series, spec, i, pose, groups, tracked) if np.mean(
                    series.images[i] >= top) >= 1e-4 else None
                if g is not None:
                    g.append(int(i))
                else:
                    groups.append([int(i)])
        reps = []
        for g in groups:
            clean = [i for i in g if np.mean(series.images[i] >= top) < 1e-4]
            pick = max(clean, key=lambda i: series.exposure_us[i]) if clean else g[0]
            reps.append(tracked[pick][spec.id].pose)
            for i in g:
                out[i][spec.id] = reps[-1]
            n_static += len(g) > 1
        untracked = [i for i in range(series.n_frames) if spec.id not in tracked[i]]
        for i in untracked:
            best, score = None, 0.5
            for g, pose in zip(groups, reps, strict=True):
                roi = sheet_roi(series.camera, pose, TargetTexture(spec).bounds_m, margin_px=0)
                if roi is None:
                    continue
                i0, i1, j0, j1 = roi
                a = series.images[i][i0:i1, j0:j1].astype(np.float64)
                b = series.images[g[-1]][i0:i1, j0:j1].astype(np.float64)
                a, b = a - a.mean(), b - b.mean()
                den = math.sqrt(float(np.sum(a * a) * np.sum(b * b)))
                c = float(np.sum(a * b)) / den if den > 0 else 0.0
                if c > score:
                    best, score = pose, c
            if best is not None:
                out[i][spec.id] = best
    return out, n_static


def _correlation(series: RingSeries, spec: TargetSpec, pose: Pose, i: int, j: int) -> float:
    """Normalised correlation of frames i and j in the box of the target's sheet at ``pose``."""
    roi = sheet_roi(series.camera, pose, TargetTexture(spec).bounds_m, margin_px=0)
    if roi is None:
        return 0.0
    i0, i1, j0, j1 = roi
    a = series.images[i][i0:i1, j0:j1].astype(np.float64)
    b = series.images[j][i0:i1, j0:j1].astype(np.float64)
    a, b = a - a.mean(), b - b.mean()
    den = math.sqrt(float(np.sum(a * a) * np.sum(b * b)))
    return float(np.sum(a * b)) / den if den > 0 else 0.0


def _clipped_join(series: RingSeries, spec: TargetSpec, i: int, pose: Pose, groups: list[list[int]],
                  tracked: list[dict[int, TrackedTarget]]) -> list[int] | None:
    centre = series.camera.project(pose.t[None, :])[0]
    for g in groups:
        ref = tracked[g[0]][spec.id].pose
        if (np.linalg.norm(series.camera.project(ref.t[None, :])[0] - centre) <= CLIPPED_JOIN_PX
                and abs(np.linalg.norm(pose.t) / np.linalg.norm(ref.t) - 1.0) <= 0.05
                and _correlation(series, spec, ref, i, g[-1]) > 0.5):
            return g
    return None


# ---------------------------------------------------------------------------------------------- items
@dataclass
class RingItem:
    """One target in one fitted frame: its pixels around the target and what the fits need, all (h, w) on the
    ROI rows i0:i1, columns j0:j1 of the frame."""

    frame: int
    target_id: int
    exposure_us: float
    pose: Pose
    delta_px: float
    roi: tuple[int, int, int, int]
    measured: FloatArray
    core_white: npt.NDArray[np.float32]  # (K, h, w) paper indicator blurred by SIGMA_GRID_PX[k], binned
    core_black: npt.NDArray[np.float32]  # (K, h, w) ink indicator
    white_px: FloatArray  # exact pixel coverage of paper
    black_px: FloatArray  # exact pixel coverage of ink
    band: npt.NDArray[np.bool_]
    fit_mask: npt.NDArray[np.bool_]
    flat_white: npt.NDArray[np.bool_]
    flat_black: npt.NDArray[np.bool_]
    outside: npt.NDArray[np.bool_]
    r2: FloatArray  # (distance from the principal point / half-diagonal)^2
    position: FloatArray  # distance from the image centre / half-diagonal
    angle_rad: FloatArray  # direction of the edge normal (toward the ink), image axes
    cos2: FloatArray  # cos 2 angle_rad
    sin2: FloatArray
    edge_length_px: float
    sd: FloatArray = field(default_factory=lambda: np.zeros(0))
    masked_white: npt.NDArray[np.float32] = field(default_factory=lambda: np.zeros((0, 0), np.float32))
    masked_black: npt.NDArray[np.float32] = field(default_factory=lambda: np.zeros((0, 0), np.float32))
    masked_measured: FloatArray = field(default_factory=lambda: np.zeros(0))
    masked_sd: FloatArray = field(default_factory=lambda: np.zeros(0))


def _render_item(series: RingSeries, spec: TargetSpec, frame: int, tracked: TrackedTarget | None,
                 pose: Pose) -> RingItem | None:
    cam = series.camera
    n = OVERSAMPLING
    white_tex = TargetTexture(spec, white=1.0, black=0.0)
    roi = sheet_roi(cam, pose, white_tex.bounds_m, margin_px=ROI_MARGIN_PX)
    if roi is None:
        return None
    i0, i1, j0, j1 = roi
    h, w = i1 - i0, j1 - j0
    fine_cam = CameraModel(width=w * n, height=h * n, fx=cam.fx * n, fy=cam.fy * n, cx=(cam.cx - j0 + 0.5) * n - 0.5,
                           cy=(cam.cy - i0 + 0.5) * n - 0.5, dist=cam.dist, bit_depth=cam.bit_depth)
    fine_w = render_reflectance(fine_cam, [Placement(pose, white_tex)], background=0.0,
                                supersampling=FINE_SUPERSAMPLING).astype(np.float32)
    fine_b = render_reflectance(fine_cam, [Placement(pose, TargetTexture(spec, white=0.0, black=1.0))],
                                background=0.0, supersampling=FINE_SUPERSAMPLING).astype(np.float32)

    def binned(img: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)  # exact n x n means

    core_w = np.empty((len(SIGMA_GRID_PX), h, w), np.float32)
    core_b = np.empty_like(core_w)
    for k, sigma in enumerate(SIGMA_GRID_PX):
        optics = OpticsModel(psf_sigma_px=float(sigma) * n, oversampling=1)
        core_w[k] = binned(optics.apply(fine_w))
        core_b[k] = binned(optics.apply(fine_b))
    white_px = fine_w.reshape(h, n, w, n).mean(axis=(1, 3), dtype=np.float64)
    black_px = fine_b.reshape(h, n, w, n).mean(axis=(1, 3), dtype=np.float64)
    sheet = white_px + black_px
    edge = ((white_px > 1e-6) & (white_px < 1 - 1e-6)) | ((black_px > 1e-6) & (black_px < 1 - 1e-6))
    border = (sheet > 1e-6) & (sheet < 1 - 1e-6)
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * BAND_PX + 1, 2 * BAND_PX + 1))
    near_edge = cv2.dilate((edge & ~border).astype(np.uint8), disk) > 0
    near_border = cv2.dilate(((sheet < 1 - 1e-6)).astype(np.uint8), disk) > 0
    band = near_edge & ~near_border
    far = cv2.dilate(edge.astype(np.uint8), disk) == 0
    flat_white = far & (white_px > 1 - 1e-9) & ~near_border
    flat_black = far & (black_px > 1 - 1e-9) & ~near_border
    outside = cv2.dilate((sheet > 1e-6).astype(np.uint8), disk) == 0
    rng = np.random.default_rng(frame * 1009 + spec.id)
    fit_mask = band | ((flat_white | flat_black) & (rng.random((h, w)) < FLAT_SHARE))
    if np.count_nonzero(band) < 50:
        return None
    ys, xs = np.mgrid[i0:i1, j0:j1].astype(np.float64)
    hd = series.half_diagonal_px
    r2 = ((xs - cam.cx) ** 2 + (ys - cam.cy) ** 2) / hd**2
    position = np.hypot(xs - (cam.width - 1) / 2, ys - (cam.height - 1) / 2) / hd
    k1 = int(np.argmin(np.abs(SIGMA_GRID_PX - 1.0)))
    gy, gx = np.gradient(core_b[k1].astype(np.float64))
    angle = np.arctan2(gy, gx)
    gy0, gx0 = np.gradient(black_px)
    length = float(np.sum(np.hypot(gx0, gy0)[band]))
    measured = series.images[frame][i0:i1, j0:j1].astype(np.float64)
    delta = tracked.delta_px if tracked is not None else float("nan")
    return RingItem(frame, spec.id, float(series.exposure_us[frame]), pose, delta, roi, measured,
                    core_w, core_b, white_px, black_px, band, fit_mask, flat_white, flat_black, outside, r2, position,
                    angle, np.cos(2 * angle), np.sin(2 * angle), length)


def choose_frames(series: RingSeries, poses: list[dict[int, Pose]],
                  per_exposure: int = FIT_FRAMES_PER_EXPOSURE) -> list[int]:
    """Up to ``per_exposure`` frames with a posed target per distinct exposure, spread over the recording."""
    out = []
    for e in np.unique(series.exposure_us):
        frames = [i for i in np.flatnonzero(series.exposure_us == e) if poses[i]]
        if not frames:
            continue
        pick = np.unique(np.linspace(0, len(frames) - 1, min(per_exposure, len(frames))).round().astype(int))
        out.extend(int(frames[k]) for k in pick)
    return sorted(out)


# ---------------------------------------------------------------------------------------------- the check
@dataclass
class RingCandidate:
    effects: tuple[str, ...]
    heldout_rms: float
    fold_params: list[dict[str, float]] = field(default_factory=list)


@dataclass(frozen=True)
class RingFit:
    effects: tuple[str, ...]
    params: dict[str, float]
    chi_rms: float
    n_pixels: int
    success: bool
    seconds: float


def _core_weights(sigma_px: float) -> list[tuple[int, float]]:
    """Weights of the rendered cores (index into ``SIGMA_GRID_PX``) giving the core of ``sigma_px``: cubic Hermite
    interpolation with central-difference slopes (continuous first derivative, so the fits do not stick at the
    grid's nodes); clamped to the grid's range."""
    g = SIGMA_GRID_PX
    n = len(g)
    sigma = min(max(sigma_px, g[0]), g[-1])
    k = min(max(int(np.searchsorted(g, sigma)) - 1, 0), n - 2)
    h = g[k + 1] - g[k]
    u = (sigma - g[k]) / h
    h00, h10, h01, h11 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u, -2 * u**3 + 3 * u**2, u**3 - u**2
    w: dict[int, float] = {k: h00, k + 1: h01}

    def slope(j: int, c: float) -> None:  # add c x (central difference slope at node j) x h
        lo, hi = max(j - 1, 0), min(j + 1, n - 1)
        d = c * h / (g[hi] - g[lo])
        w[hi] = w.get(hi, 0.0) + d
        w[lo] = w.get(lo, 0.0) - d

    slope(k, h10)
    slope(k + 1, h11)
    return [(j, c) for j, c in w.items() if c != 0.0]


def _core_at(stack: npt.NDArray[np.float32], sigma_px: FloatArray) -> npt.NDArray[np.float32]:
    """The stack (K, ...) interpolated at a core width per pixel (``sigma_px`` shaped as ``stack[0]``), with the
    interpolation of :func:`_core_weights`."""
    g = SIGMA_GRID_PX
    n = len(g)
    shape = stack.shape[1:]
    flat = stack.reshape(n, -1)
    sig = np.clip(np.asarray(sigma_px, dtype=np.float64).ravel(), g[0], g[-1])
    k = np.clip(np.searchsorted(g, sig) - 1, 0, n - 2)
    lo1, hi2 = np.maximum(k - 1, 0), np.minimum(k + 2, n - 1)
    h = g[k + 1] - g[k]
    u = (sig - g[k]) / h
    h00, h10, h01, h11 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u, -2 * u**3 + 3 * u**2, u**3 - u**2
    a = h10 * h / (g[k + 1] - g[lo1])
    b = h11 * h / (g[hi2] - g[k])
    cols = np.arange(flat.shape[1])

    def at(idx: npt.NDArray[np.int64]) -> FloatArray:
        return flat[idx, cols]

    yk, yk1 = at(k), at(k + 1)
    out = h00 * yk + h01 * yk1 + a * (yk1 - at(lo1)) + b * (at(hi2) - yk)
    return out.reshape(shape).astype(np.float32)


def _clipped_mean(mean: FloatArray, var: FloatArray, top: float) -> FloatArray:
    """E[min(X, top)] for X ~ N(mean, var): the mean reading of a pixel near the clip level."""
    near = mean > top - 6.0 * np.sqrt(max(float(np.max(var)), 1e-12))
    if not np.any(near):
        return mean
    out = mean.copy()
    mn = mean[near]
    sd = np.sqrt(np.maximum(var[near], 1e-12))
    z = (mn - top) / sd
    out[near] = mn - (mn - top) * ndtr(z) - sd * np.exp(-0.5 * z**2) / math.sqrt(2 * math.pi)
    return out


@dataclass(frozen=True)
class _Model:
    params: dict[str, float]
    effects: tuple[str, ...]
    sensor: SensorModel
    tails: list[tuple[float, npt.NDArray[np.float32]]]
    halo: tuple[float, npt.NDArray[np.float32]] | None
    defocus: OpticsModel | None


class RingCheck:
    """Fits of the forward model to the rendered items of one series (module docstring)."""

    def __init__(self, series: RingSeries, items: list[RingItem]):
        self.series = series
        self.items = items
        top = series.saturation_dn
        self.top = top
        whites, blacks, outs = [], [], []
        for it in items:
            wv, bv = it.measured[it.flat_white], it.measured[it.flat_black]
            if wv.size and np.percentile(wv, 99) < 0.95 * top:
                whites.append(float(np.median(wv)) / it.exposure_us)
                if bv.size:
                    blacks.append(float(np.median(bv)) / float(np.median(wv)))
                ov = it.measured[it.outside]
                if ov.size:
                    outs.append(float(np.median(ov)) / float(np.median(wv)))
        if whites:
            rate = float(np.median(whites))
        else:  # every paper pixel clipped: the shortest exposure gives a lower bound
            it = min(items, key=lambda i: i.exposure_us)
            rate = 1.5 * top / it.exposure_us
        self.init: dict[str, float] = {"sigma_px": 1.0, "white_dn_per_us": rate,
                                       "black_to_white": series.black_to_white if series.black_to_white is not None
                                       else (float(np.median(blacks)) if blacks else 0.05),
                                       "background_to_white": float(np.median(outs)) if outs else 0.25,
                                       "ink_to_white": float(np.median(blacks)) if blacks else 0.08}
        self.noise_a, self.noise_b = self._noise()
        frame_means = [float(np.mean(series.images[i])) / series.exposure_us[i] for i in range(series.n_frames)
                       if np.mean(series.images[i] >= top) < 1e-3]
        self.frame_mean_dn_per_us = float(np.median(frame_means)) if frame_means else rate * 0.3
        for it in items:
            tol2 = (MODEL_TOLERANCE * min(rate * it.exposure_us, top)) ** 2
            it.sd = np.sqrt(self.noise_a + self.noise_b * np.maximum(it.measured, 0.0) + tol2)
            it.masked_white = it.core_white[:, it.fit_mask]
            it.masked_black = it.core_black[:, it.fit_mask]
            it.masked_measured = it.measured[it.fit_mask]
            it.masked_sd = it.sd[it.fit_mask]

    def _noise(self) -> tuple[float, float]:
        """(a, b) of ``var = a + b DN`` from flat paper and ink: pixel minus the mean of its 4 neighbours."""
        levels, variances = [], []
        for it in self.items:
            img = it.measured
            nb = 0.25 * (img[:-2, 1:-1] + img[2:, 1:-1] + img[1:-1, :-2] + img[1:-1, 2:])
            c = img[1:-1, 1:-1]
            flat = (it.flat_white | it.flat_black)
            ok = (flat[1:-1, 1:-1] & flat[:-2, 1:-1] & flat[2:, 1:-1] & flat[1:-1, :-2] & flat[1:-1, 2:]
                  & (c < 0.8 * self.top) & (nb < 0.8 * self.top) & (c > 0))
            levels.append(nb[ok])
            variances.append(0.8 * (c[ok] - nb[ok]) ** 2)
        level, var = np.concatenate(levels), np.concatenate(variances)
        if level.size < 100:
            return 1.0, 0.0
        edges = np.unique(np.quantile(level, np.linspace(0, 1, 11)))
        mids, vs = [], []
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            sel = (level >= lo) & (level <= hi)
            if np.count_nonzero(sel) > 30:
                mids.append(float(np.mean(level[sel])))
                vs.append(float(np.mean(var[sel])))
        if len(mids) < 2:
            return max(float(np.mean(var)), 0.25), 0.0
        (a, b), *_ = np.linalg.lstsq(np.column_stack([np.ones(len(mids)), mids]), np.asarray(vs), rcond=None)
        return max(float(a), 0.25), max(float(b), 0.0)

    # ------------------------------------------------------------------ forward model
    def model(self, p: dict[str, float], effects: Sequence[str]) -> _Model:
        """What one parameter set needs for every item: the sensor and the kernels (built once)."""
        sensor = SensorModel(full_well_e=self.top, read_noise_e=0.0, bit_depth=self.series.camera.bit_depth,
                             dn_per_e=1.0, shot_noise=False,
                             bloom_spill_fraction=10.0 ** p["spill_log10"] if "blooming" in effects else 0.0,
                             knee_fraction_of_full_well=min(p["knee_fraction"], 0.999) if "nonlinear" in effects
                             else 1.0)
        tails = [(p[f"{kind}_tail_fraction"], tail_kernel(kind, p[f"{kind}_tail_scale_px"]))
                 for kind in ("exponential", "lorentzian") if f"{kind}_tail" in effects]
        halo = (p["halo_fraction"], gaussian_kernel(p["halo_sigma_px"])) if "halo" in effects else None
        defocus = (OpticsModel(psf_sigma_px=0.0, defocus_radius_px=p["defocus_radius_px"], oversampling=1)
                   if "defocus" in effects else None)
        return _Model(p, tuple(effects), sensor, tails, halo, defocus)

    def predict_item(self, it: RingItem, p: dict[str, float], effects: Sequence[str],
                     model: _Model | None = None, masked: bool = False) -> FloatArray:
        """Expected reading (DN) of the item's pixels under parameters ``p`` with ``effects`` on: (h, w), or the
        ``fit_mask`` pixels (N,) when ``masked``.

        The simulator's optics (``OpticsModel`` kernels), composed as ``ImageFormation.optical_image`` does: the
        core ``(1 - t) G + t T`` (G from the rendered stack, the tail T of ``exponential_tail``/``lorentzian_tail``
        on the pixel image), the ``halo`` ``(1 - a) core + a H`` on the pixel image, ``defocus`` on both; then the
        simulator's sensor well in DN (clip, knee, blooming along columns) and the clipped-noise mean."""
        m = model or self.model(p, effects)
        full = not masked or m.defocus is not None or m.sensor.bloom_spill_fraction > 0
        sel = it.fit_mask
        stack_w, stack_b = (it.core_white, it.core_black) if full else (it.masked_white, it.masked_black)
        if "anisotropic_core" in m.effects:
            # the core's variance across an edge of normal direction theta: sigma^2 (1 + c cos 2 theta + s sin 2 theta)
            cos2, sin2 = (it.cos2, it.sin2) if full else (it.cos2[sel], it.sin2[sel])
            var = 1.0 + p["aniso_c"] * cos2 + p["aniso_s"] * sin2
            sigma = p["sigma_px"] * np.sqrt(np.maximum(var, 0.01))
            white = _core_at(stack_w, sigma)
            black = _core_at(stack_b, sigma)
        else:
            weights = _core_weights(p["sigma_px"])
            white = sum(np.float32(c) * stack_w[j] for j, c in weights)
            black = sum(np.float32(c) * stack_b[j] for j, c in weights)
        g = np.float32(p["background_to_white"])
        ink = np.float32(p["black_to_white"] if "ink_floor" not in m.effects else p["ink_to_white"])
        optical = white + ink * black + g * (1.0 - white - black)
        if m.tails or m.halo is not None:
            pixel = (it.white_px + ink * it.black_px + g * (1.0 - it.white_px - it.black_px)).astype(np.float32)
            for t, kern in m.tails:
                tail = cv2.filter2D(pixel, cv2.CV_32F, kern, borderType=cv2.BORDER_REPLICATE)
                optical = (1.0 - t) * optical + t * (tail if full else tail[sel])
            if m.halo is not None:
                a, kern = m.halo
                halo = cv2.sepFilter2D(pixel, cv2.CV_32F, kern, kern, borderType=cv2.BORDER_REPLICATE)
                optical = (1.0 - a) * optical + a * (halo if full else halo[sel])
        if m.defocus is not None:
            optical = m.defocus.apply(optical)
        e = optical.astype(np.float64) * (p["white_dn_per_us"] * it.exposure_us)
        if "vignetting" in m.effects:
            e *= np.maximum(1.0 - p["vignetting_strength"] * (it.r2 if full else it.r2[sel]), 0.0)
        if "veiling_glare" in m.effects:
            f = p["glare_fraction"]
            e = (1.0 - f) * e + f * self.frame_mean_dn_per_us * it.exposure_us
        dn = m.sensor.expected_dn(e)
        dn = _clipped_mean(dn, self.noise_a + self.noise_b * dn, self.top)
        if masked and full:
            return dn[sel]
        return dn

    def residuals(self, p: dict[str, float], effects: Sequence[str], items: Sequence[RingItem],
                  informative_only: bool = False) -> FloatArray:
        model = self.model(p, effects)
        out = []
        for it in items:
            pred = self.predict_item(it, p, effects, model, masked=True)
            meas = it.masked_measured
            r = (pred - meas) / it.masked_sd
            if informative_only:
                r = r[~((meas >= self.top) & (pred >= self.top - 1e-6))]
            out.append(r)
        return np.concatenate(out)

    # ------------------------------------------------------------------ fits
    def _spec(self, effects: Sequence[str], start: dict[str, float]) -> tuple[list[str], FloatArray, FloatArray,
                                                                           FloatArray]:
        rate = self.init["white_dn_per_us"]
        return parameter_space(["sigma_px", "white_dn_per_us"], [float(SIGMA_GRID_PX[0]), rate / 100.0],
                               [float(SIGMA_GRID_PX[-1]), rate * 100.0], self.series.black_to_white is None,
                               effects, RING_EFFECTS, start)

    def fit(self, effects: tuple[str, ...], items: Sequence[RingItem] | None = None,
            start: dict[str, float] | None = None, max_nfev: int = FINAL_MAX_NFEV) -> RingFit:
        t0 = time.perf_counter()
        items = self.items if items is None else list(items)
        st = dict(self.init)
        if start:
            st.update(start)
        names, x0, lo, hi = self._spec(effects, st)

        def params(x: FloatArray) -> dict[str, float]:
            p = dict(self.init)
            p.update({k: v for k, v in st.items() if k not in names and k in p})
            p.update({k: float(v) for k, v in zip(names, x, strict=True)})
            return p

        def fun(x: FloatArray) -> FloatArray:
            return self.residuals(params(x), effects, items)

        x_scale = np.maximum(np.abs(x0) * 0.1, 1e-2)
        res = least_squares(fun, x0, bounds=(lo, hi), x_scale=x_scale, diff_step=1e-3, max_nfev=max_nfev,
                            method="trf")
        p = params(res.x)
        log.debug("fit %s: %d evaluations, %d Jacobians, %.1f s", "+".join(effects) or "baseline", res.nfev,
                  res.njev or 0, time.perf_counter() - t0)
        r = self.residuals(p, effects, items, informative_only=True)
        return RingFit(tuple(effects), p, float(np.sqrt(np.mean(r**2))), int(r.size), bool(res.success),
                       time.perf_counter() - t0)

    def folds(self) -> list[tuple[list[RingItem], list[RingItem]]]:
        """Held-out folds over the distinct exposures: even/odd positions (leave-one-out for three)."""
        exposures = np.unique([it.exposure_us for it in self.items])
        if len(exposures) <= 3:
            tests = [[e] for e in exposures]
        else:
            tests = [list(exposures[k::2]) for k in range(2)]
        out = []
        for test in tests:
            held = [it for it in self.items if it.exposure_us in test]
            train = [it for it in self.items if it.exposure_us not in test]
            out.append((train, held))
        return out

    def heldout(self, effects: tuple[str, ...], start: dict[str, float] | None = None) -> RingCandidate:
        sq, count, params = 0.0, 0, []
        for train, test in self.folds():
            f = self.fit(effects, train, start, max_nfev=HELDOUT_MAX_NFEV)
            r = self.residuals(f.params, effects, test, informative_only=True)
            sq += float(np.sum(r**2))
            count += r.size
            params.append(f.params)
        return RingCandidate(tuple(effects), math.sqrt(sq / max(count, 1)), params)

    def candidates(self) -> tuple[list[str], dict[str, str]]:
        skipped = dict(NOT_IN_RING_CATALOGUE)
        names = []
        for e in RING_EFFECTS:
            if e == "veiling_glare":
                skipped[e] = ("not identifiable on a target: like a lighter ink (ink_floor) it lifts the ink relative "
                              "to the paper in proportion to the exposure, and the background level is measured "
                              "beside the sheet; a uniform veil needs a scene region of known reflectance")
                continue
            if e == "ink_floor" and self.series.black_to_white is None:
                skipped[e] = ("the print's ink/paper reflectance is not given (meta white_reflectance, "
                              "black_reflectance): the baseline fits the ink level, a floor is part of it")
                continue
            if e == "vignetting":
                r2 = np.concatenate([it.r2[it.fit_mask] for it in self.items])
                if float(np.ptp(r2)) < 0.15:
                    skipped[e] = (f"not identifiable: the target's images span too little of the frame (r^2 range "
                                  f"{float(np.ptp(r2)):.2f} of the half-diagonal^2 < 0.15) for a falloff to differ "
                                  f"from a white level")
                    continue
            names.append(e)
        return names, skipped


def negligible(effect: str, params: dict[str, float], series: RingSeries | None = None) -> bool:
    if effect == "ink_floor":
        nominal = series.black_to_white if series is not None and series.black_to_white is not None else 0.0
        return abs(params["ink_to_white"] - nominal) <= 0.005
    name, lo, hi = NEGLIGIBLE[effect]
    if name == "aniso_e":
        return math.hypot(params["aniso_c"], params["aniso_s"]) <= hi
    return lo <= params[name] <= hi


def _single_start(effect: str, baseline: RingFit) -> dict[str, float] | None:
    """Where a single effect's fit starts (None: the catalogue's start, the baseline for the rest). Defocus:
    the pillbox that, on a 0.6 px core, has the baseline core's variance (r^2 / 4 = sigma^2 - 0.6^2), so that
    a wide defocus is not left in the local minimum of a large Gaussian core with a small pillbox."""
    if effect == "defocus":
        sigma = baseline.params["sigma_px"]
        return {"defocus_radius_px": 2.0 * math.sqrt(max(sigma**2 - 0.36, 0.09)), "sigma_px": 0.6}
    return None


def _start(c: RingCandidate) -> dict[str, float]:
    keys = c.fold_params[0].keys()
    return {k: float(np.mean([p[k] for p in c.fold_params])) for k in keys}


# ---------------------------------------------------------------------------------------------- report
@dataclass
class RingReport:
    """Everything ``livetrack model`` writes for a ring recording; arrays kept for the plots."""

    series: RingSeries
    check: RingCheck
    tracked: list[dict[int, TrackedTarget]]
    poses: list[dict[int, Pose]]
    static_segments: int
    baseline: RingFit
    final: RingFit
    baseline_heldout: RingCandidate
    singles: list[RingCandidate]
    path: list[RingCandidate]
    skipped: dict[str, str]
    chosen: tuple[str, ...]
    bias: dict[str, FloatArray]  # per item: delta (px per edge) of the 50 % threshold: measured, baseline, extended
    compensated: dict[str, Any]
    binned: dict[str, dict[str, Any]]
    read_noise_dn: float | None
    seconds: float
    verdict: list[str] = field(default_factory=list)

    @property
    def final_heldout(self) -> float:
        return self.path[-1].heldout_rms if self.path else self.baseline_heldout.heldout_rms

    @property
    def relative_gain(self) -> float:
        return 1.0 - self.final_heldout / self.baseline_heldout.heldout_rms

    def named(self) -> list[tuple[str, dict[str, float]]]:
        """The causes, in the order chosen, with their fitted parameters (simulator names)."""
        return [(e, effect_parameters(e, self.final.params)) for e in self.chosen]

    def to_json(self) -> dict[str, Any]:
        s = self.series

        def fit_dict(f: RingFit) -> dict[str, Any]:
            return {"effects": list(f.effects), "chi_rms_in_sample": f.chi_rms, "pixels": f.n_pixels,
                    "converged": f.success,
                    "baseline_parameters": {k: f.params[k] for k in ("sigma_px", "white_dn_per_us", "black_to_white",
                                                                     "background_to_white")},
                    "effect_parameters": {e: effect_parameters(e, f.params) for e in f.effects}}

        items = self.check.items
        return plain({
            "input": {"name": s.name, "kind": "ring targets", "frames": s.n_frames,
                      "exposure_us": sorted(set(s.exposure_us.tolist())), "saturation_dn": s.saturation_dn,
                      "targets": [t.id for t in s.targets], "print_known": s.black_to_white is not None,
                      "static_segments": self.static_segments,
                      "frames_tracked": sum(1 for t in self.tracked if t),
                      "frames_posed": sum(1 for t in self.poses if t),
                      "frames_fitted": sorted({it.frame for it in items}),
                      "fitted_pixels": int(sum(np.count_nonzero(it.fit_mask) for it in items))},
            "noise": {"variance_dn2": f"{self.check.noise_a:.4g} + {self.check.noise_b:.4g} * DN",
                      "a_dn2": self.check.noise_a, "b_dn": self.check.noise_b},
            "baseline": fit_dict(self.baseline),
            "heldout": {"metric": "RMS of (predicted - measured) / noise sd over the held-out exposures' pixels",
                        "baseline": self.baseline_heldout.heldout_rms,
                        "single_effects": {"+".join(c.effects): c.heldout_rms for c in self.singles},
                        "greedy_path": [{"effects": list(c.effects), "heldout_rms": c.heldout_rms} for c in self.path],
                        "skipped": self.skipped, "min_relative_gain": MIN_RELATIVE_GAIN, "chosen": list(self.chosen),
                        "chosen_heldout_rms": self.final_heldout, "relative_gain": self.relative_gain},
            "chosen_model": fit_dict(self.final),
            "bias_curve": {"exposure_us": [it.exposure_us for it in items], "frame": [it.frame for it in items],
                           "target": [it.target_id for it in items],
                           "tracker_delta_px": [it.delta_px for it in items],
                           **{f"delta_px_{k}": v for k, v in self.bias.items()}},
            "compensation": self.compensated,
            "binned_residuals": self.binned,
            "read_noise_dn": self.read_noise_dn,
            "verdict": self.verdict,
            "seconds": self.seconds,
        })

    def summary(self) -> str:
        s = self.series
        lines = [f"model check of {s.name}: ring targets {[t.id for t in s.targets]}, {s.n_frames} frames at "
                 f"{len(set(s.exposure_us.tolist()))} exposures "
                 f"({', '.join(f'{e:g}' for e in sorted(set(s.exposure_us.tolist())))} us); "
                 f"{len({it.frame for it in self.check.items})} frames fitted"
                 f"; {sum(1 for t in self.tracked if t)} frames tracked, {self.static_segments} static segment(s)"]
        b = self.baseline.params
        lines.append(f"baseline: PSF sigma {b['sigma_px']:.3f} px, white {b['white_dn_per_us']:.4g} DN/us, "
                     f"ink/paper {b['black_to_white']:.4f}; in-sample chi {self.baseline.chi_rms:.3f}")
        lines.append(f"held-out RMS normalised error: baseline {self.baseline_heldout.heldout_rms:.4f}")
        for c in self.singles:
            lines.append(f"  + {'+'.join(c.effects):16s} {c.heldout_rms:.4f}  "
                         f"({100 * (1 - c.heldout_rms / self.baseline_heldout.heldout_rms):+.1f} %)")
        for name, why in self.skipped.items():
            lines.append(f"  ({name} not tried: {why})")
        lines.append(f"chosen: {' + '.join(self.chosen) or 'baseline (no extension helps)'}; held-out "
                     f"{self.final_heldout:.4f}, gain {100 * self.relative_gain:.1f} %")
        for e, par in self.named():
            lines.append(f"  {e}: " + ", ".join(f"{k} = {v:.4g}" for k, v in par.items()))
        c = self.compensated
        lines.append(f"exposure bias per edge (px, 50 % threshold) over exposures: spread raw "
                     f"{c['spread_raw_px']:.4f}, compensated with baseline {c['spread_baseline_px']:.4f}, with the "
                     f"chosen model {c['spread_extended_px']:.4f}")
        lines.extend(f"verdict: {v}" for v in self.verdict)
        return "\n".join(lines)


# ---------------------------------------------------------------------------------------------- pipeline
def build_items(series: RingSeries, tracked: list[dict[int, TrackedTarget]], poses: list[dict[int, Pose]],
                frames: Sequence[int]) -> list[RingItem]:
    by_id = {t.id: t for t in series.targets}
    items = []
    for i in frames:
        for tid, pose in poses[i].items():
            item = _render_item(series, by_id[tid], i, tracked[i].get(tid), pose)
            if item is not None:
                items.append(item)
    return items


def analyse_rings(series: RingSeries, per_exposure: int = FIT_FRAMES_PER_EXPOSURE) -> RingReport:
    """The whole check of one ring series (module docstring). Raises ValueError when fewer than three exposures
    have a tracked target."""
    t0 = time.perf_counter()
    tracked = estimate_poses(series)
    poses, n_static = pose_groups(series, tracked)
    frames = choose_frames(series, poses, per_exposure)
    if len({float(series.exposure_us[i]) for i in frames}) < 3:
        raise ValueError(f"{series.name}: the targets were found at fewer than three exposures "
                         f"({sum(1 for t in tracked if t)} of {series.n_frames} frames tracked): need three or more")
    items = build_items(series, tracked, poses, frames)
    log.info("poses and renders: %d items in %.1f s", len(items), time.perf_counter() - t0)
    check = RingCheck(series, items)
    baseline = check.fit(())
    check.init.update({k: baseline.params[k] for k in ("sigma_px", "white_dn_per_us", "black_to_white")})
    base_ho = check.heldout(())
    log.info("baseline: sigma %.3f px, held-out %.4f (%.1f s)", baseline.params["sigma_px"], base_ho.heldout_rms,
             time.perf_counter() - t0)
    names, skipped = check.candidates()
    singles = []
    for e in names:
        c = check.heldout((e,), start=_single_start(e, baseline))
        log.info("  + %s: held-out %.4f", e, c.heldout_rms)
        singles.append(c)
    singles.sort(key=lambda c: c.heldout_rms)
    for c in singles:
        if negligible(c.effects[0], _start(c), series):
            skipped[c.effects[0]] = "fitted size negligible (absorbs model-accuracy residue, not named)"
    eligible = [c for c in singles if c.effects[0] not in skipped]
    path: list[RingCandidate] = []
    current = base_ho
    if eligible and eligible[0].heldout_rms < (1 - MIN_RELATIVE_GAIN) * current.heldout_rms:
        current = eligible[0]
        path.append(current)
        while len(current.effects) < MAX_EFFECTS and current.heldout_rms > NOISE_FLOOR:
            best = None
            for c0 in eligible:
                e = c0.effects[0]
                if e in current.effects or c0.heldout_rms >= (1 - MIN_RELATIVE_GAIN) * base_ho.heldout_rms:
                    continue
                c = check.heldout(current.effects + (e,), start=_start(current))
                log.info("  + %s: held-out %.4f", "+".join(c.effects), c.heldout_rms)
                if negligible(e, _start(c), series):
                    continue
                if best is None or c.heldout_rms < best.heldout_rms:
                    best = c
            if best is None or best.heldout_rms >= (1 - MIN_RELATIVE_GAIN) * current.heldout_rms:
                break
            current = best
            path.append(current)
    chosen = current.effects if path else ()
    final = check.fit(chosen, start=_start(current)) if chosen else baseline
    bias, compensated, binned = _compare(check, baseline, final)
    report = RingReport(series, check, tracked, poses, n_static, baseline, final, base_ho, singles, path, skipped,
                        chosen, bias, compensated, binned, saturated_read_noise_dn(check, final), 0.0)
    report.verdict = _verdict(report)
    report.seconds = time.perf_counter() - t0
    return report


# ---------------------------------------------------------------------------------------------- comparison
def threshold_delta_px(image: FloatArray, it: RingItem, top: float) -> float:
    """Per-edge displacement (px, positive when the white grows) of the 50 % threshold of ``image`` in the band:
    (printed dark area - dark area) / edge length; the threshold is the mid-level between the item's flat ink and
    paper (the clip level where the paper clips). NaN when the ink clips too."""
    black = float(np.median(image[it.flat_black])) if np.any(it.flat_black) else 0.0
    white = min(float(np.median(image[it.flat_white])), top) if np.any(it.flat_white) else top
    if black >= 0.9 * top or white - black < 1.0:
        return float("nan")
    mid = 0.5 * (black + white)
    dark = float(np.count_nonzero(image[it.band] < mid))
    printed = float(np.sum(it.black_px[it.band]))
    return (printed - dark) / max(it.edge_length_px, 1e-9)


def _compare(check: RingCheck, baseline: RingFit, final: RingFit) -> tuple[dict[str, FloatArray], dict[str, Any],
                                                                          dict[str, dict[str, Any]]]:
    top = check.top
    fits = {"baseline": baseline, "extended": final}
    pred = {k: [check.predict_item(it, f.params, f.effects) for it in check.items] for k, f in fits.items()}
    bias = {"measured": np.array([threshold_delta_px(it.measured, it, top) for it in check.items])}
    for k in fits:
        bias[k] = np.array([threshold_delta_px(p, it, top) for p, it in zip(pred[k], check.items, strict=True)])
    comp: dict[str, Any] = {"note": "per-edge exposure bias of the 50 % threshold (px), measured minus predicted: its "
                                    "spread over the fitted frames (std) is what a threshold detector compensated "
                                    "with the model would keep"}
    raw = bias["measured"]
    comp["spread_raw_px"] = float(np.nanstd(raw))
    for k in fits:
        corrected = raw - bias[k]
        comp[f"delta_compensated_{k}_px"] = corrected
        comp[f"spread_{k}_px"] = float(np.nanstd(corrected))
    binned = {k: _binned(check, fits[k], pred[k]) for k in fits}
    return bias, comp, binned


def _binned(check: RingCheck, fit: RingFit, pred: list[FloatArray]) -> dict[str, Any]:
    """Normalised residuals of the band pixels binned by edge direction (over-exposed frames), by predicted
    intensity and by distance from the image centre."""
    top = check.top
    res_o, ang, res_i, lev, res_p, pos = [], [], [], [], [], []
    for it, pr in zip(check.items, pred, strict=True):
        r = (pr - it.measured) / it.sd
        info = it.band & ~((it.measured >= top) & (pr >= top - 1e-6))
        res_i.append(r[info])
        lev.append(pr[info] / top)
        res_p.append(r[info])
        pos.append(it.position[info])
        if fit.params["white_dn_per_us"] * it.exposure_us > top:
            res_o.append(r[info])
            ang.append(np.degrees(it.angle_rad[info]) % 360.0)
    out: dict[str, Any] = {}
    if res_o:
        c, m, q = binned_stats(np.concatenate(res_o), np.concatenate(ang), np.linspace(0, 360, 17), min_count=10)
        out["orientation"] = {"angle_deg": c, "mean": m, "rms": q,
                              "note": "band pixels of over-exposed frames; angle of the edge normal toward the ink, "
                                      "image axes (90 deg = down)"}
    c, m, q = binned_stats(np.concatenate(res_i), np.concatenate(lev), np.linspace(0, 1.0001, 11), min_count=10)
    out["intensity"] = {"predicted_fraction_of_saturation": c, "mean": m, "rms": q}
    c, m, q = binned_stats(np.concatenate(res_p), np.concatenate(pos), np.linspace(0, 1, 9), min_count=10)
    out["position"] = {"distance_from_centre_over_half_diagonal": c, "mean": m, "rms": q}
    return out


def saturated_read_noise_dn(check: RingCheck, fit: RingFit, deep: float = 2.0, min_pixels: int = 200) -> float | None:
    """sd (DN) of saturated paper pixels below the top code (``sqrt(2 mean((top - reading)^2))``, see
    ``modelcheck.export``), on frames whose paper is at least ``deep`` x the clip level; None without enough."""
    top = check.top
    deficits = [top - it.measured[it.flat_white] for it in check.items
                if fit.params["white_dn_per_us"] * it.exposure_us >= deep * top]
    if not deficits:
        return None
    d = np.concatenate(deficits)
    if d.size < min_pixels:
        return None
    return float(math.sqrt(2.0 * np.mean(np.maximum(d, 0.0) ** 2)))


def _verdict(rep: RingReport) -> list[str]:
    out = []
    base = rep.baseline_heldout.heldout_rms
    if not rep.chosen:
        out.append(f"no catalogue extension lowers the held-out error by more than {100 * MIN_RELATIVE_GAIN:.0f} %: "
                   f"the baseline (Gaussian PSF, linear response, clipping) explains the recording (held-out RMS "
                   f"{base:.3f}).")
    for c in rep.path:
        e = c.effects[-1]
        par = effect_parameters(e, rep.final.params)
        out.append(f"cause: {e} ({', '.join(f'{k} = {v:.4g}' for k, v in par.items())}); with it the held-out error "
                   f"falls to {c.heldout_rms:.4f} from {base:.4f} for the baseline "
                   f"({100 * (1 - c.heldout_rms / base):.1f} %).")
    if rep.final_heldout > 1.25:
        b = rep.binned["extended"]
        worst = []
        for view, key in (("intensity", "predicted_fraction_of_saturation"),
                          ("position", "distance_from_centre_over_half_diagonal"), ("orientation", "angle_deg")):
            if view in b:
                m = np.asarray(b[view]["mean"], dtype=float)
                if np.any(np.isfinite(m)):
                    j = int(np.nanargmax(np.abs(m)))
                    worst.append(f"{view}: mean residual {m[j]:+.2f} sd at {key} = {float(b[view][key][j]):.3g}")
        out.append(f"structure remains (held-out RMS {rep.final_heldout:.3f} sd, noise alone would give about 1): "
                   + "; ".join(worst) + ".")
    c = rep.compensated
    out.append(f"downstream: the 50 %-threshold edges move by {c['spread_raw_px']:.3f} px (std over the fitted "
               f"frames); what the baseline leaves unexplained {c['spread_baseline_px']:.3f} px, the chosen model "
               f"{c['spread_extended_px']:.3f} px.")
    return out


def with_exposures(series: RingSeries, keep: Sequence[int]) -> RingSeries:
    """The series restricted to frames ``keep`` (e.g. held-out frames)."""
    return replace(series, exposure_us=series.exposure_us[list(keep)], images=[series.images[i] for i in keep])
