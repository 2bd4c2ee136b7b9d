"""A second renderer for tests, written apart from :mod:`livetrack.sim` (its own geometry, sampling, optics and
sensor): frames as another simulator would draw them, so that the estimator is not checked only against the
conventions of the simulator it was developed with.

Each pixel is integrated over ``SUBSAMPLES`` x ``SUBSAMPLES`` rays cast through it (pixel (row i, column j) covers
x in [j - 0.5, j + 0.5], y in [i - 0.5, i + 0.5], livetrack's convention); a ray that meets the target plane within
the target's outer disk takes the printed reflectance there (ink or paper: the inner disk, the code dots and the
nested level), within the optional square white sheet the paper's, elsewhere the ground's reflectance at that
pixel (a picture behind, not on the target's plane). Linear light is blurred by a Gaussian lens PSF (and an
optional wide Gaussian halo holding a share of the light), turned into electrons (shot noise, read noise), clipped
at the full well and quantised to the bit depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from livetrack.targets import TargetSpec

SUBSAMPLES = 5
PAPER = 0.9
"""Reflectance of the paper (the target's white and its sheet)."""


@dataclass(frozen=True)
class Shot:
    """One frame's camera and exposure. ``paper_of_full_well``: the paper's light at this exposure as a share of the
    full well (over 1: the paper clips)."""

    focal_px: float
    width: int = 1920
    height: int = 1200
    bits: int = 12
    psf_px: float = 0.9
    halo: tuple[float, float] | None = None  # (share of light, sigma px)
    paper_of_full_well: float = 0.6
    full_well_e: float = 20000.0
    read_noise_e: float = 5.0

    @property
    def camera_matrix(self) -> np.ndarray:
        return np.array([[self.focal_px, 0.0, (self.width - 1) / 2.0],
                         [0.0, self.focal_px, (self.height - 1) / 2.0], [0.0, 0.0, 1.0]])


def printed_reflectance(spec: TargetSpec, u_m: np.ndarray, v_m: np.ndarray, ink: float) -> np.ndarray:
    """Reflectance of the printed target at target-plane points (m); NaN outside its outer disk."""
    r = np.hypot(u_m, v_m)
    out = np.full(u_m.shape, np.nan)
    out[r <= spec.outer_radius_m] = ink
    out[r <= spec.inner_radius_m] = PAPER
    if spec.code is not None:
        for x, y in spec.code.white_dot_centres_m():
            out[np.hypot(u_m - x, v_m - y) <= spec.code.dot_radius_m] = PAPER
    if spec.centre_dot_radius_m > 0:
        out[r <= spec.centre_dot_radius_m] = ink
    if spec.child is not None:
        child = printed_reflectance(spec.child, u_m, v_m, ink)
        out = np.where(np.isnan(child), out, child)
    return out


def gradient_ground(shot: Shot, low: float, high: float, angle_rad: float) -> np.ndarray:
    """Ground reflectance rising linearly from ``low`` to ``high`` across the frame along ``angle_rad``."""
    yy, xx = np.mgrid[0:shot.height, 0:shot.width].astype(np.float64)
    g = math.cos(angle_rad) * xx / shot.width + math.sin(angle_rad) * yy / shot.height
    return low + (high - low) * (g - g.min()) / max(float(np.ptp(g)), 1e-12)


def render(spec: TargetSpec, rotation: np.ndarray, t_m: np.ndarray, ground: np.ndarray, shot: Shot,
           rng: np.random.Generator, ink: float = 0.05, sheet_side_of_radius: float | None = None) -> np.ndarray:
    """The frame (uint8 or uint16) of ``spec`` at pose (``rotation``: target to camera, ``t_m``: its centre in the
    camera frame) over ``ground`` (H, W reflectance), with a white square sheet of side
    ``sheet_side_of_radius`` x R around it, or none."""
    K = shot.camera_matrix
    light = np.array(ground, dtype=np.float64, copy=True)
    normal = rotation[:, 2]
    plane_d = float(normal @ t_m)
    half = spec.outer_radius_m * max(1.0, (sheet_side_of_radius or 0.0) / 2.0) * math.sqrt(2.0)
    corners = np.array([[x, y, 0.0] for x in (-half, half) for y in (-half, half)])
    seen = (K @ (rotation @ corners.T + t_m[:, None])).T
    seen = seen[:, :2] / seen[:, 2:]
    margin = int(6 * shot.psf_px + 4)
    x0 = max(0, int(math.floor(seen[:, 0].min())) - margin)
    x1 = min(shot.width, int(math.ceil(seen[:, 0].max())) + margin)
    y0 = max(0, int(math.floor(seen[:, 1].min())) - margin)
    y1 = min(shot.height, int(math.ceil(seen[:, 1].max())) + margin)
    offsets = (np.arange(SUBSAMPLES) + 0.5) / SUBSAMPLES - 0.5
    xs = (np.arange(x0, x1)[:, None] + offsets[None, :]).ravel()
    ys = (np.arange(y0, y1)[:, None] + offsets[None, :]).ravel()
    gx, gy = np.meshgrid(xs, ys)
    rays = np.linalg.solve(K, np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)]))
    on_plane = rays * (plane_d / (normal @ rays))
    local = rotation.T @ (on_plane - t_m[:, None])
    u, v = local[0].reshape(gx.shape), local[1].reshape(gx.shape)
    printed = printed_reflectance(spec, u, v, ink)
    behind = np.repeat(np.repeat(ground[y0:y1, x0:x1], SUBSAMPLES, 0), SUBSAMPLES, 1)
    if sheet_side_of_radius:
        h = 0.5 * sheet_side_of_radius * spec.outer_radius_m
        behind = np.where((np.abs(u) <= h) & (np.abs(v) <= h), PAPER, behind)
    sub = np.where(np.isnan(printed), behind, printed)
    light[y0:y1, x0:x1] = sub.reshape(y1 - y0, SUBSAMPLES, x1 - x0, SUBSAMPLES).mean(axis=(1, 3))
    blurred = cv2.GaussianBlur(light, (0, 0), shot.psf_px)
    if shot.halo is not None:
        share, sigma_px = shot.halo
        blurred = (1.0 - share) * blurred + share * cv2.GaussianBlur(light, (0, 0), sigma_px)
    electrons_per_unit = shot.paper_of_full_well * shot.full_well_e / PAPER
    electrons = rng.poisson(np.clip(blurred * electrons_per_unit, 0.0, None)).astype(np.float64)
    electrons += rng.normal(0.0, shot.read_noise_e, electrons.shape)
    top = 2**shot.bits - 1
    counts = np.round(np.clip(electrons / shot.full_well_e * top, 0.0, top))
    return counts.astype(np.uint8 if shot.bits == 8 else np.uint16)


def tilted(tilt_rad: float, tilt_axis_rad: float, roll_rad: float) -> np.ndarray:
    """Target-to-camera rotation: rolled by ``roll_rad`` about its normal, then tilted by ``tilt_rad`` about an
    in-plane axis at ``tilt_axis_rad`` from the camera's x axis."""
    axis = np.array([math.cos(tilt_axis_rad), math.sin(tilt_axis_rad), 0.0])
    return cv2.Rodrigues(axis * tilt_rad)[0] @ cv2.Rodrigues(np.array([0.0, 0.0, roll_rad]))[0]


def on_ray(shot: Shot, x_px: float, y_px: float, distance_m: float) -> np.ndarray:
    """The point at ``distance_m`` along the ray through pixel (x, y)."""
    ray = np.linalg.solve(shot.camera_matrix, np.array([x_px, y_px, 1.0]))
    return ray / np.linalg.norm(ray) * distance_m
