"""Refinement of a pair on a crop with the target's own mid-level threshold."""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect.fit_kernel import fit_distances_reference, near_count
from livetrack.estimator.detect.hole_pairs import DISK_PAIR_MAX_RADIUS_PX
from livetrack.estimator.detect.options import DetectOptions
from livetrack.estimator.detect.pairs import _pairs
from livetrack.estimator.detect.threshold import _quantile
from livetrack.estimator.target_map import (
    affine_homography,
    sample_target,
    sample_target_points,
)

# ---------------------------------------------------------------------- refinement
_ANGLES_64X4 = np.tile(np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False), 4)
_ANGLES_64X4.flags.writeable = False
_COS_64X4, _SIN_64X4 = np.cos(_ANGLES_64X4), np.sin(_ANGLES_64X4)
"""cos and sin of ``_ANGLES_64X4`` (what ``sample_target`` computes of them at every call)."""
_COS_64X4.flags.writeable = False
_SIN_64X4.flags.writeable = False
REFINE_OUTSIDE = 1.3
"""Where ``_refine`` samples the ground around a pair (in outer radii)."""


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
    radius = np.repeat([rho + 0.2 * (1 - rho), 0.93, 0.8 * rho, REFINE_OUTSIDE], 64)
    vals = sample_target_points(level_img, H0, radius * _COS_64X4, radius * _SIN_64X4)
    dark, bright, outside = vals[:128], vals[128:192], vals[192:]
    dark, bright, outside = dark[np.isfinite(dark)], bright[np.isfinite(bright)], outside[np.isfinite(outside)]
    if dark.size < 16 or bright.size < 8:
        return None
    black, white = _quantile(dark, 25), _quantile(bright, 75)
    if white - black < 6:  # 8-bit levels: too little contrast for a clean global threshold on the crop
        return None
    bias = opts.exposure_bias_px / scale + 0.5
    best = _pair_at_threshold(level_img, o, black, white, s == 0, ratios, bias, opts)
    if best is None and outside.size >= 32:
        # A target printed without a sheet on darker ground: halfway to its inner white, the ground reads dark and
        # the ring has no outer edge. Halfway to the ground instead (the outer edge's own step; the inner edge,
        # black to white, then comes out a little wide, which the edge fits take up): a 13 px target on grey
        # (0.2) kept the local threshold's pair, 2-3 px wide, and its pose fit failed.
        ground = _quantile(outside, 50)
        if 6 <= ground - black and ground < 0.5 * (black + white):
            best = _pair_at_threshold(level_img, o, black, ground, s == 0, ratios, bias, opts)
    if best is None:
        return None
    fo, fi = best
    return (Ellipse(fo.centre_px * scale, fo.semi_axes_px * scale, fo.angle_rad),
            Ellipse(fi.centre_px * scale, fi.semi_axes_px * scale, fi.angle_rad))


def _pair_at_threshold(level_img: np.ndarray, o: Ellipse, black: float, white: float, input_units: bool,
                       ratios: list[float], bias_px: float, opts: DetectOptions) -> tuple[Ellipse, Ellipse] | None:
    """The pair (level pixels) nearest to ``o``'s centre that ``_pairs`` finds on a crop around ``o`` thresholded
    halfway between ``black`` and ``white`` (8-bit levels of ``level_img``), of 0.7-1.3 times ``o``'s size; None
    if there is none within 0.2 of its semi-minor axis (+1.5 px)."""
    half = o.half_extent_px()
    margin = 0.25 * o.a + 4
    cx0 = max(int(o.centre_px[0] - half[0] - margin), 0)
    cy0 = max(int(o.centre_px[1] - half[1] - margin), 0)
    cx1 = min(int(o.centre_px[0] + half[0] + margin) + 2, level_img.shape[1])
    cy1 = min(int(o.centre_px[1] + half[1] + margin) + 2, level_img.shape[0])
    crop = level_img[cy0:cy1, cx0:cx1]
    # Halfway between black and white. Full resolution (``input_units``): in input units (the level holds their
    # square roots, and the lens blurred the input). Coarser levels: in level units (pyrDown's blur, wider there
    # than the lens's, acted on the square roots).
    middle = math.sqrt(0.5 * (black * black + white * white)) if input_units else 0.5 * (black + white)
    _, binary = cv2.threshold(crop, middle, 255, cv2.THRESH_BINARY_INV)
    binary = np.ascontiguousarray(binary)
    found = _pairs(binary, 0.7 * o.a, 1.3 * o.a + 2, ratios, bias_px, opts)
    offset = np.array([cx0, cy0], dtype=np.float64)
    best, best_d = None, np.inf
    for fo, fi in found:
        d = np.hypot(fo.centre_px[0] + cx0 - o.centre_px[0], fo.centre_px[1] + cy0 - o.centre_px[1])
        if d < best_d and d <= 0.2 * o.b + 1.5:
            best, best_d = (fo, fi), d
    if best is None:
        return None
    fo, fi = best
    return (Ellipse(fo.centre_px + offset, fo.semi_axes_px, fo.angle_rad),
            Ellipse(fi.centre_px + offset, fi.semi_axes_px, fi.angle_rad))


SMALL_BLOB_MAX_RADIUS_PX = 16.0
"""Largest outer semi-minor axis (full-resolution pixels) of a dark blob without a pair that is tried again with
its own threshold (``_small_blob_pair``)."""


def _small_blob_pair(img8: np.ndarray, outer: Ellipse, ratios: list[float],
                     opts: DetectOptions) -> tuple[Ellipse, Ellipse] | None:
    """The pair of a small dark blob of outline ``outer`` (full-resolution level) that the local threshold gave
    without a usable hole, found again on its crop with a threshold halfway between its ring's black (at 0.7 and
    0.9 of ``outer``) and the brighter of its surroundings (at 1.35) and its inner disk (at 0.3). A target of
    10-12 px keeps a blurred grey inner disk (its nested level, 2.5 px across, darkens it by a third): against
    the window's mean (the white sheet and ground around it) the whole target reads dark."""
    radius = np.repeat([0.7, 0.9, 1.35, 0.3], 64)
    vals = sample_target_points(img8, affine_homography(outer), radius * _COS_64X4, radius * _SIN_64X4)
    dark = vals[:128][np.isfinite(vals[:128])]
    around, middle = vals[128:192], vals[192:]
    around, middle = around[np.isfinite(around)], middle[np.isfinite(middle)]
    if dark.size < 64 or around.size < 32 or middle.size < 32:
        return None
    black = _quantile(dark, 25)
    white = max(_quantile(around, 75), _quantile(middle, 75))
    if white - black < 6:
        return None
    return _pair_at_threshold(img8, outer, black, white, True, ratios, opts.exposure_bias_px + 0.5, opts)


EDGE_SEEN_RADII = np.linspace(0.8, 1.25, 19)
EDGE_SEEN_RADII.flags.writeable = False
EDGE_SEEN_ANGLES = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
EDGE_SEEN_ANGLES.flags.writeable = False
EDGE_SEEN_MIN_STEP = 0.25
"""``outer_edge_seen``: the least rise across a direction's outer edge, as a share of the target's white minus
its black."""


def outer_edge_seen(img8: np.ndarray, outer: Ellipse, inner: Ellipse) -> tuple[float, float]:
    """Where the image itself (not a threshold of it) shows a ring's outer edge about ``outer``: (the share of
    32 directions that show it, its radius in units of ``outer``'s). Along each direction, the steepest rise
    over 0.1 of the radius within 0.8-1.25 of it must be at least ``EDGE_SEEN_MIN_STEP`` of the target's white
    (its inner disk) minus its black (the ring), and lie with the other directions' at one radius (within a
    pixel of the radius most directions agree on). A ring merged by the threshold with dark texture around it
    keeps its step to the ground in most directions; a round bright hole in dark texture scaled by a design's
    radius ratio has no edge there."""
    H = affine_homography(outer)
    rho = inner.a / outer.a
    n_r = len(EDGE_SEEN_RADII)
    radii = np.concatenate([np.repeat(EDGE_SEEN_RADII, 32), np.full(32, 0.6 * rho),
                            np.full(32, rho + 0.2 * (1 - rho))])
    angles = np.tile(EDGE_SEEN_ANGLES, n_r + 2)
    vals = sample_target(img8, H, radii, angles)
    prof = vals[: 32 * n_r].reshape(n_r, 32)
    white, ring = vals[32 * n_r : 32 * n_r + 32], vals[32 * n_r + 32 :]
    white, ring = white[np.isfinite(white)], ring[np.isfinite(ring)]
    if white.size < 16 or ring.size < 16:
        return 0.0, 1.0
    contrast = _quantile(white, 75) - _quantile(ring, 25)
    if not contrast > 0.0:
        return 0.0, 1.0
    rise = prof[4:] - prof[:-4]  # across 0.1 R, centred on EDGE_SEEN_RADII[2:-2]
    rise = np.where(np.isfinite(rise), rise, -np.inf)
    at = np.argmax(rise, axis=0)
    ok = rise[at, np.arange(32)] >= EDGE_SEEN_MIN_STEP * contrast
    if np.count_nonzero(ok) < 4:
        return 0.0, 1.0
    where = EDGE_SEEN_RADII[2:-2][at[ok]]
    close = np.abs(where[:, None] - where[None, :]) <= max(0.05, 1.0 / outer.b)
    near = close[int(np.argmax(close.sum(axis=1)))]  # the directions about the radius most of them agree on
    return float(np.count_nonzero(near)) / 32, float(np.mean(where[near]))


RING_ABOVE_GROUND_SHARE = 0.7
RING_ABOVE_GROUND_STEP = 0.1
"""``ring_above_ground``: the least share of the directions whose ground lies below the ring's median by this
share of the white's step above the ring at least (ink at 4 % on velvet at 2 %, x4, 12 bit: 0.17 in the 8-bit
map)."""
RING_ABOVE_GROUND_MAX_STEP = 0.5
"""``ring_above_ground``: the ring's step above the ground is at most this share of the white's (medians): ink is
nearer black velvet than paper (0.18-0.35 in the 8-bit map at x4-x16, the white clipped); the holes of dark
foliage, their rims blurred, read 0.55-1.0 of it (seed 0's no-sheet-005 at x16)."""
_GROUND_ANGLES = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
_GROUND_ANGLES.flags.writeable = False


def ring_above_ground(img8: np.ndarray, outer: Ellipse, inner: Ellipse) -> bool:
    """Whether the grey image shows a pair from a hole on dark ground (``hole_pairs.DARK_GROUND``) as a ring
    brighter than the ground beyond it: the ground at 1.25 of ``outer`` (the hole scaled, beyond the ring's outer
    edge: over-exposure grows the hole) below the median of the ring just outside the hole (1.1 of ``inner``: the
    band between the inner disk and the code dots) in ``RING_ABOVE_GROUND_SHARE`` of 32 directions, by
    ``RING_ABOVE_GROUND_STEP`` of the white's step above the ring, and the ring nearer the ground than the white
    (``RING_ABOVE_GROUND_MAX_STEP``; the white: the hole's middle). A cheap test
    before ``pair_from_edges``: every round hole in dark texture gives such a pair, and so does each code dot of
    a ring on dark ground."""
    H = affine_homography(outer)
    rho = inner.a / outer.a
    t = _GROUND_ANGLES
    vals = sample_target(img8, H, np.concatenate([np.full(t.size, 0.6 * rho), np.full(t.size, 1.1 * rho),
                                                  np.full(t.size, 1.25)]), np.concatenate([t, t, t]))
    white, ring, ground = (v[np.isfinite(v)] for v in (vals[: t.size], vals[t.size : 2 * t.size], vals[2 * t.size :]))
    if min(white.size, ring.size, ground.size) < t.size // 2:
        return False
    white_level, ring_level, ground_level = _quantile(white, 50), _quantile(ring, 50), _quantile(ground, 50)
    if not ring_level - ground_level <= RING_ABOVE_GROUND_MAX_STEP * (white_level - ground_level):
        return False  # no ring of ink: the lighter side of a fleck of dark texture, blurred into its hole
    below = ring_level - RING_ABOVE_GROUND_STEP * (white_level - ring_level)
    return bool(np.count_nonzero(ground < below) >= RING_ABOVE_GROUND_SHARE * ground.size)


EDGE_PAIR_DIRECTIONS = np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)
EDGE_PAIR_DIRECTIONS.flags.writeable = False
EDGE_PAIR_STEP_PX = 0.35
"""``pair_from_edges``: the radial sampling step along the pair's semi-minor axis (pixels of ``img8``)."""
EDGE_PAIR_MIN_STEP = 0.25
"""``pair_from_edges``: the least fall (inner edge) or rise (outer edge) over 0.1 of the outer radius, as a share
of the target's white minus its black, for a direction to give an edge point."""
DARKER_GROUND_MIN_STEP = 0.08
"""``pair_from_edges(darker_ground=True)``: the least fall out of the ring over 0.1 of the outer radius, as a share
of the target's white minus its black: ink (4 %) against black velvet (2 %) at x4 fell by 0.17 of it in the 8-bit
map, its white clipped."""
EDGE_PAIR_INNER_SHARE = 0.6
EDGE_PAIR_OUTER_SHARE = 0.4
"""``pair_from_edges``: the least share of the directions whose edge points an ellipse must keep (within
``0.75 px + 3 %`` of its size) for the inner and the outer edge. The outer edge of a ring merged with dark ground
shows only where the ground is brighter than the ring."""


def pair_from_edges(img8: np.ndarray, outer: Ellipse, inner: Ellipse, outer_from: float = 0.85,
                    sampled_start: bool = False, darker_ground: bool = False) -> tuple[Ellipse, Ellipse, float] | None:
    """The pair (outer, inner) re-placed on the intensity edges of ``img8`` (the full-resolution level) about a
    pair found in the threshold image, with the share of the directions that showed the outer edge, or None.

    The threshold image can be wrong where the grey image is not: a ring joined to dark texture (foliage, carpet)
    loses its outer outline, and a tilted ring's hole, joined to a code dot or cut by the local window's mean,
    comes out wide (a 32 x 19 px target in foliage: its hole fitted 13.3 x 9.6 px for the truth's 12.8 x 7.5, the
    outer ellipse scaled from it 28 x 21 px, and its code did not read). Along 64 directions from the centre
    (in ``outer``'s frame), the steepest fall from the white disk into the ring (within 0.6 rho .. rho + 0.45
    (1 - rho), rho = the pair's radius ratio) is an inner edge point and the steepest rise out of the ring
    (within 0.85-1.35 of ``outer``) an outer edge point, each with a step of at least ``EDGE_PAIR_MIN_STEP`` of
    the contrast; an ellipse is fitted to each set, dropping the points far from it (code dots, texture), and
    must keep ``EDGE_PAIR_INNER_SHARE`` / ``EDGE_PAIR_OUTER_SHARE`` of the directions. Edge points are where
    the slope is steepest: blur's middle, the exposure's shift kept (the edge fits take it up later).
    ``outer_from``: where the outer edge's window starts (share of ``outer``): lower for an outer ellipse scaled
    from a hole, which over-exposure grows (``detector.LARGE_HOLE_PAIR_EDGE_SEEN``). ``sampled_start``: an edge
    whose fits keep too few points is fitted once more from ``_sampled_start``'s points (the caller asks it for
    the large pairs from a hole alone). ``darker_ground``: the outer edge is the steepest fall out of the ring
    instead, of at least ``DARKER_GROUND_MIN_STEP`` of the contrast (a ring on darker ground: ``hole_pairs``'
    "dark ground" pairs)."""
    H = affine_homography(outer)
    rho = inner.a / outer.a
    dr = max(EDGE_PAIR_STEP_PX / outer.b, 1.0 / 200)
    radii = np.arange(0.6 * rho - dr, 1.35 + 2.0 * dr, dr)
    n_dir, n_r = len(EDGE_PAIR_DIRECTIONS), len(radii)
    vals = sample_target(img8, H, np.concatenate([np.repeat(radii, n_dir), np.full(n_dir, 0.8 * rho),
                                                  np.full(n_dir, rho + 0.2 * (1.0 - rho))]),
                         np.tile(EDGE_PAIR_DIRECTIONS, n_r + 2))
    white, ring = vals[n_r * n_dir : (n_r + 1) * n_dir], vals[(n_r + 1) * n_dir :]
    white, ring = white[np.isfinite(white)], ring[np.isfinite(ring)]
    if white.size < n_dir // 2 or ring.size < n_dir // 2:
        return None
    contrast = _quantile(white, 50) - _quantile(ring, 25)
    if not contrast >= 6.0:  # 8-bit levels
        return None
    slope = np.gradient(vals[: n_r * n_dir].reshape(n_r, n_dir), axis=0)  # per step dr
    least = EDGE_PAIR_MIN_STEP * contrast * dr / 0.1
    r_in, ok_in = _steepest(slope, radii, 0.6 * rho, rho + 0.45 * (1.0 - rho), -1.0, least)
    points_in = _edge_points(H, r_in[ok_in], EDGE_PAIR_DIRECTIONS[ok_in])
    fitted_in = _robust_ellipse(points_in, EDGE_PAIR_INNER_SHARE * n_dir)
    if fitted_in is None and sampled_start:
        start = _sampled_start(points_in, EDGE_PAIR_INNER_SHARE * n_dir)
        fitted_in = None if start is None else _robust_ellipse(points_in, EDGE_PAIR_INNER_SHARE * n_dir, start)
    if fitted_in is None:
        return None
    out_sign, out_least = (-1.0, least * DARKER_GROUND_MIN_STEP / EDGE_PAIR_MIN_STEP) if darker_ground else (1.0, least)
    r_out, ok_out = _steepest(slope, radii, outer_from, 1.35, out_sign, out_least)
    points_out = _edge_points(H, r_out[ok_out], EDGE_PAIR_DIRECTIONS[ok_out])
    fitted_out = _robust_ellipse(points_out, EDGE_PAIR_OUTER_SHARE * n_dir)
    if fitted_out is None:
        # started from the densest radii instead of all: a ring merged with dark squares all around (a 192 px
        # one on a chessboard, 16 joined) has a third of its rises beyond them, and a first fit through all of
        # them lies between the two sets
        fitted_out = _robust_ellipse(points_out, EDGE_PAIR_OUTER_SHARE * n_dir,
                                     start=_densest(r_out[ok_out], EDGE_PAIR_DENSEST_PX / outer.b))
    if fitted_out is None and sampled_start:
        start = _sampled_start(points_out, EDGE_PAIR_OUTER_SHARE * n_dir)
        fitted_out = None if start is None else _robust_ellipse(points_out, EDGE_PAIR_OUTER_SHARE * n_dir, start)
        if fitted_out is not None:
            # the steepest rise near the ellipse found, per direction: where a code dot's near edge was steeper,
            # the outer edge shows all the same (the share seen decides whether the pair is kept)
            e = fitted_out[0]
            half = (0.75 + 0.03 * math.sqrt(e.a * e.b)) / outer.b
            r_near, ok_near = _steepest_near(slope, radii, _ray_radii(H, e), half, out_sign, out_least)
            again = _robust_ellipse(_edge_points(H, r_near[ok_near], EDGE_PAIR_DIRECTIONS[ok_near]),
                                    EDGE_PAIR_OUTER_SHARE * n_dir)
            if again is not None and again[1] > fitted_out[1]:
                fitted_out = again
    if fitted_out is None:
        return None
    (e_in, _), (e_out, kept) = fitted_in, fitted_out
    if not (e_in.a < e_out.a and e_in.b < e_out.b):
        return None
    return e_out, e_in, kept / n_dir


def _steepest(slope: np.ndarray, radii: np.ndarray, lo: float, hi: float, sign: float,
              least: float) -> tuple[np.ndarray, np.ndarray]:
    """Per direction (columns of ``slope``, (n_r, n_dir)), the radius of the steepest ``sign`` slope within
    [lo, hi] (to a fraction of a step: the parabola through it and its neighbours), and whether it is at
    least ``least``."""
    idx = np.flatnonzero((radii >= lo) & (radii <= hi))
    idx = idx[(idx > 0) & (idx < len(radii) - 1)]
    n_dir = slope.shape[1]
    if idx.size == 0:
        return np.zeros(n_dir), np.zeros(n_dir, dtype=bool)
    s = sign * slope
    window = np.where(np.isfinite(s[idx]), s[idx], -np.inf)
    return _peak(s, radii, idx[np.argmax(window, axis=0)], least)


def _steepest_near(slope: np.ndarray, radii: np.ndarray, centre: np.ndarray, half: float, sign: float,
                   least: float) -> tuple[np.ndarray, np.ndarray]:
    """``_steepest`` within ``half`` of a radius per direction (``centre``, (n_dir,); NaN: none there)."""
    rows = np.arange(len(radii))[:, None]
    inside = (np.abs(radii[:, None] - centre[None, :]) <= half) & (rows > 0) & (rows < len(radii) - 1)
    s = sign * slope
    window = np.where(inside & np.isfinite(s), s, -np.inf)
    at = np.argmax(window, axis=0)
    r, ok = _peak(s, radii, np.maximum(at, 1), least)
    return r, ok & np.isfinite(window.max(axis=0))


def _peak(s: np.ndarray, radii: np.ndarray, at: np.ndarray, least: float) -> tuple[np.ndarray, np.ndarray]:
    """For ``_steepest``: the radius of each column's peak of ``s`` at row ``at`` (the parabola through it and its
    neighbours), and whether it is finite and at least ``least``."""
    cols = np.arange(s.shape[1])
    y0, y1, y2 = s[at - 1, cols], s[at, cols], s[at + 1, cols]
    ok = np.isfinite(y0) & np.isfinite(y2) & (y1 >= least)
    den = y0 - 2.0 * y1 + y2
    frac = np.where(ok & (den < 0), 0.5 * (y0 - y2) / np.where(den < 0, den, -1.0), 0.0)
    step = radii[1] - radii[0]
    return radii[at] + np.clip(frac, -0.5, 0.5) * step, ok


def _ray_radii(H: np.ndarray, e: Ellipse) -> np.ndarray:
    """Per direction of ``EDGE_PAIR_DIRECTIONS`` from the origin of the affine map ``H`` (target units -> pixels),
    the radius (target units) at which the ray meets the ellipse ``e`` (pixels); NaN where it does not."""
    u = H[:2, :2] @ np.stack([np.cos(EDGE_PAIR_DIRECTIONS), np.sin(EDGE_PAIR_DIRECTIONS)])  # (2, n_dir) pixels
    R = e.rotation()
    M = R @ np.diag([1.0 / e.a**2, 1.0 / e.b**2]) @ R.T
    d = H[:2, 2] - e.centre_px
    alpha = np.einsum("in,ij,jn->n", u, M, u)
    beta = u.T @ (M @ d)
    gamma = float(d @ M @ d) - 1.0
    disc = beta * beta - alpha * gamma
    with np.errstate(invalid="ignore"):
        return np.where(disc >= 0.0, (-beta + np.sqrt(np.maximum(disc, 0.0))) / alpha, np.nan)


def _edge_points(H: np.ndarray, r: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Target points (radius in units of R, angle) mapped by ``H`` to pixels, (N, 2)."""
    tx, ty = r * np.cos(angle), r * np.sin(angle)
    w = H[2, 0] * tx + H[2, 1] * ty + H[2, 2]
    return np.stack([(H[0, 0] * tx + H[0, 1] * ty + H[0, 2]) / w, (H[1, 0] * tx + H[1, 1] * ty + H[1, 2]) / w], 1)


EDGE_PAIR_DENSEST_PX = 2.0
"""``pair_from_edges``'s second start for the outer edge: the edge points whose radii lie within this many pixels
(along the minor axis) of the most common radius."""


def _densest(r: np.ndarray, half: float) -> np.ndarray:
    """A mask of the values of ``r`` within ``half`` of the window of width 2 ``half`` that holds most of them."""
    rs = np.sort(r)
    counts = np.searchsorted(rs, rs + 2.0 * half, side="right") - np.arange(len(rs))
    middle = rs[int(np.argmax(counts))] + half if len(rs) else 0.0
    return np.abs(r - middle) <= half


EDGE_PAIR_SAMPLES = 200
"""``_sampled_start``: how many 5-point samples it fits."""


def _sampled_start(points: np.ndarray, least: float) -> np.ndarray | None:
    """A mask of the points within ``_robust_ellipse``'s distance of the ellipse through 5 of them that has the
    most such points, of ``EDGE_PAIR_SAMPLES`` samples drawn with a fixed seed (the same points give the same
    mask), or None when none has ``least``. ``pair_from_edges``' start for a large ring under strong perspective:
    its outer edge points lie at radii spread over a third of the window (a 416 x 151 px ring at x32: the outer
    ellipse's centre 45 px from the hole's), where the code dots' near edges are as steep, and a first fit
    through all of them, or through the densest radii, keeps too few."""
    n = len(points)
    if n < max(8.0, least):
        return None
    best, best_count = None, 0
    for sample in points.astype(np.float32)[_samples(n)]:
        try:
            (cx, cy), (w, h), angle_deg = cv2.fitEllipse(sample)
        except cv2.error:
            continue
        if not (math.isfinite(w) and math.isfinite(h) and min(w, h) >= 2.0):
            continue
        theta = math.radians(angle_deg)
        args = (cx, cy, math.cos(theta), math.sin(theta), 0.5 * w, 0.5 * h)
        reach = 0.75 + 0.015 * math.sqrt(w * h)
        count = near_count(points, *args, reach)  # compiled; the mask only for the best
        if count > best_count:
            best, best_count = (args, reach), count
    if best is None or best_count < least or best_count < 5:
        return None
    return np.abs(fit_distances_reference(points, *best[0])) <= best[1]


@functools.lru_cache(maxsize=16)
def _samples(n: int) -> np.ndarray:
    """``_sampled_start``'s draws for ``n`` points, (``EDGE_PAIR_SAMPLES``, 5) indices: ``rng.choice(n, 5,
    replace=False)`` again and again from a generator seeded with 0, drawn once per ``n`` (read-only; the same
    sequence every call, so drawn once: ~8 us a draw)."""
    rng = np.random.default_rng(0)
    out = np.array([rng.choice(n, 5, replace=False) for _ in range(EDGE_PAIR_SAMPLES)])
    out.flags.writeable = False
    return out


def _robust_ellipse(points: np.ndarray, least: float, start: np.ndarray | None = None
                    ) -> tuple[Ellipse, int] | None:
    """An ellipse through ``points`` (N, 2) with those farther than 0.75 px + 3 % of its size dropped (until
    none changes side, at most four fits), and how many it keeps, or None when it keeps fewer than ``least``
    (and 8). ``start``: a mask of the points the first fit uses (default all)."""
    least = max(8.0, least)
    if len(points) < least:
        return None
    pts = points.astype(np.float32)
    keep = np.ones(len(pts), dtype=bool) if start is None else start.copy()
    if np.count_nonzero(keep) < 5:
        return None
    for _ in range(4):
        try:
            box = cv2.fitEllipse(pts[keep])
        except cv2.error:
            return None
        (cx, cy), (w, h), angle_deg = box
        if not (math.isfinite(w) and math.isfinite(h) and min(w, h) >= 2.0):
            return None
        theta = math.radians(angle_deg)  # the direction of the axis of length w
        dist = fit_distances_reference(points, cx, cy, math.cos(theta), math.sin(theta), 0.5 * w, 0.5 * h)
        now = np.abs(dist) <= 0.75 + 0.015 * math.sqrt(w * h)
        if np.count_nonzero(now) < least:
            return None
        if np.array_equal(now, keep):
            break
        keep = now
    return Ellipse.from_cv(box), int(np.count_nonzero(keep))


DISK_PAIR_ITERATIONS = 4
DISK_PAIR_SETTLED_PX = 0.3
"""``pair_from_disk``: at most this many ``pair_from_edges`` placements, until neither ellipse's centre nor
semi-axes move by more than ``DISK_PAIR_SETTLED_PX``. One placement samples in the frame of its start and keeps
its error in part: a hole closed round (6.2 x 4.8 px for the truth's 5.6 x 3.6, seed 4's multi-001 id 1) gave an
outer ellipse 14.1 x 9.9 px, the next one 14.3 x 8.5 (the truth: 14.4 x 9.0); from an inner disk 1 px too large
and 1 px off-centre (seed 9's no-sheet-005, id 3) one placement read no code, three did."""
DISK_PAIR_EDGE_SEEN = 0.5
"""``pair_from_disk``: the least share of the directions whose outer edge points the settled outer ellipse keeps
(``pair_from_edges``; 0.4 of them suffice there): the four tiny targets it was made for showed 0.67-0.97."""


def pair_from_disk(img8: np.ndarray, inner: Ellipse, ratios: list[float]) -> tuple[Ellipse, Ellipse, float] | None:
    """A small ring's pair (outer, inner, the share of the directions that showed its outer edge) placed on the
    grey image's edges (``pair_from_edges``, again from each placement until it settles) from an ellipse about
    its inner disk (a hole of the threshold image, or a closing's), its outer ellipse first the disk scaled by
    each design ratio's inverse in turn; None when no start settles within ``DISK_PAIR_ITERATIONS`` placements
    with an outer semi-minor axis up to ``DISK_PAIR_MAX_RADIUS_PX`` and its outer edge seen in
    ``DISK_PAIR_EDGE_SEEN`` of the directions. A start is placed only when the grey image about it looks like a
    ring around a white disk (``_disk_start``)."""
    for rho in ratios:
        outer = inner.scaled(1.0 / rho)
        if outer.b > 1.25 * DISK_PAIR_MAX_RADIUS_PX or not _disk_start(img8, inner, rho):
            continue
        o, i = outer, inner
        for _ in range(DISK_PAIR_ITERATIONS):
            edged = pair_from_edges(img8, o, i)
            if edged is None:
                break
            moved = max(float(np.max(np.abs(edged[0].centre_px - o.centre_px))),
                        float(np.max(np.abs(edged[1].centre_px - i.centre_px))),
                        float(np.max(np.abs(edged[0].semi_axes_px - o.semi_axes_px))),
                        float(np.max(np.abs(edged[1].semi_axes_px - i.semi_axes_px))))
            o, i = edged[0], edged[1]
            if moved <= DISK_PAIR_SETTLED_PX:
                if o.b <= DISK_PAIR_MAX_RADIUS_PX and edged[2] >= DISK_PAIR_EDGE_SEEN:
                    return o, i, edged[2]
                break
    return None


DISK_START_ANGLES = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
DISK_START_ANGLES.flags.writeable = False
DISK_START_RING = 1.35
DISK_START_RING_DARK = 0.7
DISK_START_OUTSIDE = 1.15
DISK_START_OUTSIDE_BRIGHT = 0.5
"""``_disk_start``: a start of ``pair_from_disk`` is placed only when the grey image is below the middle between
its white (the median at half the disk) and its black (the lower quartile just outside the disk, at
``DISK_START_RING`` of it) on ``DISK_START_RING_DARK`` of 32 directions there, and above it on
``DISK_START_OUTSIDE_BRIGHT`` of them beyond the outer edge (``DISK_START_OUTSIDE`` of the disk scaled by 1 / rho).
Over 40 frames of textured ground without targets and the frames of the four tiny targets it was made for, 1423
starts (the threshold image's holes included) were placed 67 times; 313 passed this, 35 of them placed, and every
tiny target's start passed (dark 0.75-1.0, bright 0.72-1.0): ``pair_from_edges`` costs ~1 ms a call, this ~30 us."""


def _disk_start(img8: np.ndarray, inner: Ellipse, rho: float) -> bool:
    """Whether the grey image about the inner disk ``inner`` looks like a ring of radius ratio ``rho`` around it
    (``DISK_START_RING_DARK``)."""
    n = len(DISK_START_ANGLES)
    vals = sample_target(img8, affine_homography(inner),
                         np.repeat([0.5, DISK_START_RING, DISK_START_OUTSIDE / rho], n), np.tile(DISK_START_ANGLES, 3))
    white, ring, outside = vals[:n], vals[n : 2 * n], vals[2 * n :]
    if np.count_nonzero(np.isfinite(white)) < n // 2 or np.count_nonzero(np.isfinite(ring)) < n // 2:
        return False
    middle = 0.5 * (_quantile(white[np.isfinite(white)], 50) + _quantile(ring[np.isfinite(ring)], 25))
    return (np.count_nonzero(ring < middle) >= DISK_START_RING_DARK * n
            and np.count_nonzero(outside > middle) >= DISK_START_OUTSIDE_BRIGHT * n)
