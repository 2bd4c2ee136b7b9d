"""Refinement of a pair on a crop with the target's own mid-level threshold."""

from __future__ import annotations

import math

import cv2
import numpy as np

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect.options import DetectOptions
from livetrack.estimator.detect.pairs import _pairs
from livetrack.estimator.detect.threshold import _quantile
from livetrack.estimator.target_map import (
    affine_homography,
    sample_target,
)

# ---------------------------------------------------------------------- refinement
_ANGLES_64X3 = np.tile(np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False), 3)
_ANGLES_64X3.flags.writeable = False


def _refine(pyramid: list[np.ndarray], outer: Ellipse, inner: Ellipse, ratios: list[float],
            opts: DetectOptions) -> tuple[Ellipse, Ellipse] | None:
    """Re-fit the pair on a crop with a global threshold halfway between its black and white levels (in input
    units)."""
    s = max(0, math.ceil(math.log2(max(outer.a / opts.refine_max_radius_px, 1e-9))))
    s = min(s, len(pyramid) - 1)
    scale = 2.0**s
    level_img = pyramid[s]
    o, i = outer, inner
    if s > 0:
        o = Ellipse(outer.centre_px / scale, outer.semi_axes_px / scale, outer.angle_rad)
        i = Ellipse(inner.centre_px / scale, inner.semi_axes_px / scale, inner.angle_rad)
    H0 = affine_homography(o)
    rho = i.a / o.a
    vals = sample_target(level_img, H0, np.repeat([rho + 0.2 * (1 - rho), 0.93, 0.8 * rho], 64), _ANGLES_64X3)
    dark, bright = vals[:128], vals[128:]
    dark, bright = dark[np.isfinite(dark)], bright[np.isfinite(bright)]
    if dark.size < 16 or bright.size < 8:
        return None
    black, white = _quantile(dark, 25), _quantile(bright, 75)
    if white - black < 6:  # 8-bit levels: too little contrast for a clean global threshold on the crop
        return None
    half = o.half_extent_px()
    margin = 0.25 * o.a + 4
    cx0 = max(int(o.centre_px[0] - half[0] - margin), 0)
    cy0 = max(int(o.centre_px[1] - half[1] - margin), 0)
    cx1 = min(int(o.centre_px[0] + half[0] + margin) + 2, level_img.shape[1])
    cy1 = min(int(o.centre_px[1] + half[1] + margin) + 2, level_img.shape[0])
    crop = level_img[cy0:cy1, cx0:cx1]
    # Halfway between black and white. Full resolution: in input units (the level holds their square roots, and
    # the lens blurred the input). Coarser levels: in level units (pyrDown's blur, wider there than the lens's,
    # acted on the square roots).
    middle = math.sqrt(0.5 * (black * black + white * white)) if s == 0 else 0.5 * (black + white)
    _, binary = cv2.threshold(crop, middle, 255, cv2.THRESH_BINARY_INV)
    binary = np.ascontiguousarray(binary)
    found = _pairs(binary, 0.7 * o.a, 1.3 * o.a + 2, ratios, opts.exposure_bias_px / scale + 0.5, opts)
    offset = np.array([cx0, cy0], dtype=np.float64)
    best, best_d = None, np.inf
    for fo, fi in found:
        d = np.hypot(fo.centre_px[0] + cx0 - o.centre_px[0], fo.centre_px[1] + cy0 - o.centre_px[1])
        if d < best_d and d <= 0.2 * o.b + 1.5:
            best, best_d = (fo, fi), d
    if best is None:
        return None
    fo, fi = best
    return (Ellipse((fo.centre_px + offset) * scale, fo.semi_axes_px * scale, fo.angle_rad),
            Ellipse((fi.centre_px + offset) * scale, fi.semi_axes_px * scale, fi.angle_rad))
