"""Ellipse pairs of a dark blob from its holes alone: a ring merged with dark ground (a target printed without a
sheet, or on a sheet whose margin the threshold lost) is no ellipse and no pair, but its white inner disk is still
a convex elliptical hole of the merged blob.

``_hole_pairs`` scales each such hole by the designs' radius ratios to an outer ellipse, or reads the outer edge
off the blob's outline where the ring borders bright ground (``_ring_on_outline``, compiled in
``hole_kernel._ring_on_outline``; ``_outer_on_outline(_outline_near(...))`` is its reference), and keeps it when
the binary image is dark on the ring's bands around it and bright enough outside. Called by the main pairing
(``pairs._pairs(from_holes=...)``); the caller reads the codes of these pairs with the stricter rules
``HOLE_PAIR_MAX_CODE_DISTANCE``, ``HOLE_PAIR_MIN_CODE_MARGIN`` and ``HOLE_PAIR_MIN_DOTS``. A tiny ring's inner
disk gives a "disk" pair (``DISK_PAIR_MAX_RADIUS_PX``) that the caller re-places on the grey image's edges."""

from __future__ import annotations

import itertools
import math

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect import hole_kernel
from livetrack.estimator.detect.fits import _convex, _fit, _fit_with_a_dot, _fit_without_bumps
from livetrack.estimator.detect.hole_kernel import dark_on_bands
from livetrack.estimator.detect.options import DetectOptions

FloatArray = npt.NDArray[np.float64]


DISK_PAIR_MAX_RADIUS_PX = 16.0
"""The largest outer semi-minor axis (full-resolution pixels) of a pair placed from its inner disk alone
(``_hole_pairs(disks=True)``, ``refine.pair_from_disk``): a tiny target printed without a sheet on texture
(9-14 px), whose ring the local threshold joins to dark ground and whose 2-3 px bands between the inner disk and
the code dots give way, keeps a clean inner disk in the grey image; its hole, where a closing gives one, is closed
rounder than the disk, the outer ellipse scaled from it too round for the band tests (seed 9's no-sheet-005, id 3:
the closed hole 5.8 x 4.9 px for the disk's 5.5 x 3.7, its scaled outer ellipse dark on 7 of 32 points at 0.95)."""
BUMPS = ", bumps"
"""Appended to how a pair was found from a hole that is no ellipse but one with bumps (its dots joined to it,
``fits._fit_without_bumps``): such pairs are read as a last resort (``detector.LAST_RESORT``), then as their kind
without it. Read with the others first, they moved two found targets' poses (seed 4's no-sheet-000 x2: 0.52 ->
0.66 %) for two found more."""
HOLE_PAIR_DARK_FRACTION = 0.8
HOLE_PAIR_MAX_CODE_DISTANCE = 0.5
HOLE_PAIR_MIN_CODE_MARGIN = 1.0
HOLE_PAIR_MIN_DOTS = 3
HOLE_PAIR_MAX_RADIUS_PX = 128.0
"""Codes read from a pair found from a hole alone (``_hole_pairs``) must match within
``HOLE_PAIR_MAX_CODE_DISTANCE`` slots, ``HOLE_PAIR_MIN_CODE_MARGIN`` ahead of the next code, and have at least
``HOLE_PAIR_MIN_DOTS`` dots: around round holes in dark foliage, two bright flecks at the right angles read as the
two-dot code of id 1 (seed-0 sweep: 7 false positives on frames without targets and 11 beside targets with the
usual code rules; 2 and 3 with the stricter match alone; 0 with both)."""
HOLE_PAIR_MEAN_RADIUS = 2.2
"""``_hole_pairs`` tries a hole whose mean radius over a design's radius ratio is up to this many times the
searched semi-minor axis (``a_hi``): the outer ellipse it gives must have b <= a_hi and a <= 3 a_hi, whose mean
radius sqrt(ab) reaches sqrt(3) a_hi (a 31 x 99 px ring at 70 deg: its hole, 24.6 px in mean radius, was not tried on
the full-resolution level, whose a_hi is 32 px: 1.25 a_hi there, and the ring came apart on the coarser ones)."""
DARK_GROUND = "dark ground"
DARK_GROUND_OUTSIDE_DARK_FRACTION = 0.9
"""A hole whose ring's bands are dark and whose ground at ``HOLE_PAIR_OUTSIDE`` R is dark in this share of the
directions gives a ``DARK_GROUND`` pair: a target printed without a sheet on ground darker than its ink (black
velvet, a shadow), whose ring the threshold cannot tell from the ground; the caller keeps it only where the grey
image shows the ring brighter than the ground (``code.darker_outside``), its outer edge a fall
(``refine.pair_from_edges(darker_ground=True)``)."""
HOLE_PAIR_OUTSIDE = 1.2
HOLE_PAIR_OUTSIDE_BRIGHT_FRACTION = 0.35
HOLE_PAIR_ANGLES = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
HOLE_PAIR_ANGLES.flags.writeable = False


def _hole_pairs(binary: np.ndarray, contours, hier: np.ndarray, lengths: np.ndarray, i: int, a_lo: float,
                a_hi: float, ratios: list[float], opts: DetectOptions,
                disks: bool = False) -> list[tuple[Ellipse, Ellipse, str]]:
    """Pairs of the blob ``i`` from its holes alone: each convex elliptical hole whose size, over a design's
    radius ratio r/R, is that of a searched outer ellipse gives the outer ellipse of that shape (concentric,
    scaled by R/r) when the binary image is dark on ``HOLE_PAIR_DARK_FRACTION`` of the samples of the black ring
    around it (between the hole and the code dots, and between the dots and the outer edge), and bright on
    ``HOLE_PAIR_OUTSIDE_BRIGHT_FRACTION`` of those at ``HOLE_PAIR_OUTSIDE`` R (a merged ring still shows part of
    its outer edge; a round hole deep in dark foliage with one bright fleck read as a one-dot code otherwise). The
    code read next decides. Each pair comes with how its outer edge was placed: "outline" (read off the blob's
    outline, ``_outer_on_outline``) or "hole" (the hole scaled); ``BUMPS`` appended when the hole is no ellipse
    but one with its dots joined to it (``fits._fit_without_bumps``).

    ``disks`` (the full-resolution level): a hole that fails the band tests but is dark on the inner band, whose
    outer ellipse is at most ``DISK_PAIR_MAX_RADIUS_PX``, gives its pair as "disk" (the caller re-places it on the
    grey image's edges: ``refine.pair_from_disk``)."""
    out: list[tuple[Ellipse, Ellipse, str]] = []
    boxes: dict = {}  # ``_outline_near``'s per-blob boxes and outline
    # a hole of n outline points has at most n^2 / (2 pi) px^2 (see ``pairs._pair_of``): its mean radius at most
    # n / (pi sqrt 2), which for a few points fits no design's ratio (no area taken then)
    least_n = 0.8 * a_lo * min(ratios) * math.pi * math.sqrt(2.0) * (1.0 - 1e-6) if ratios else math.inf
    j = hier.item(i, 2)
    while j >= 0:
        hole, j = j, hier.item(j, 0)
        n = lengths.item(hole)
        if n < 6 or n < least_n:
            continue
        area = abs(cv2.contourArea(contours[hole]))
        r_px = math.sqrt(area / math.pi)
        fits = [rho for rho in ratios if 0.8 * a_lo <= r_px / rho <= HOLE_PAIR_MEAN_RADIUS * a_hi]
        if not fits:
            continue
        bumps = not _convex(contours[hole], area)  # an inner disk with grown dots joined to it
        inner = (_fit_without_bumps(contours[hole], area, -0.5, opts.min_aspect) if bumps
                 else _fit(contours[hole], -0.5, opts.min_aspect))
        if inner is None and not bumps:
            # convex enough for ``_convex`` but no ellipse: one dot joined where a tilt thins the band (seed 9's
            # no-sheet-004 at x2: 13.8 px at 70 deg on a chessboard, its 20 x 31 px hole one dot longer than the disk)
            inner = _fit_with_a_dot(contours[hole], area, -0.5, opts.min_aspect)
            bumps = inner is not None
        kind = BUMPS if bumps else ""
        if inner is None:
            continue
        for rho in fits:
            outlined = _ring_on_outline(contours, hier, i, hole, inner, rho, boxes)
            outer = inner.scaled(1.0 / rho) if outlined is None else outlined[0]
            if outer.a < a_lo - 0.5 or outer.b > a_hi or outer.a > 3.0 * a_hi:
                continue
            seen = min(inner.a / outer.a, 0.9)  # the hole's ratio to the outer edge as seen (exposure moves both)
            dark = [n / len(HOLE_PAIR_ANGLES) for n in dark_on_bands(
                binary, outer, (seen + 0.2 * (1.0 - seen), 0.95, HOLE_PAIR_OUTSIDE), HOLE_PAIR_ANGLES)]
            if (dark[0] + dark[1] >= 2 * HOLE_PAIR_DARK_FRACTION
                    and 1.0 - dark[2] >= HOLE_PAIR_OUTSIDE_BRIGHT_FRACTION):
                seen = outlined is not None and any(outlined[1] >= share and inner.b >= hole_px
                                                    for share, hole_px in HOLE_PAIR_OUTLINE_SEEN)
                out.append((outer, inner, ("outline" if seen else "hole") + kind))
                break
            if disks and dark[0] >= HOLE_PAIR_DARK_FRACTION and outer.b <= DISK_PAIR_MAX_RADIUS_PX:
                # dark around the hole, not at the scaled outer edge: a tiny ring's inner disk, its hole closed
                # rounder than the disk, placed on the grey image's edges (``DISK_PAIR_MAX_RADIUS_PX``)
                out.append((outer, inner, "disk" + kind))
                break
            if (dark[0] + dark[1] >= 2 * HOLE_PAIR_DARK_FRACTION and dark[2] >= DARK_GROUND_OUTSIDE_DARK_FRACTION
                    and outlined is None):
                # dark all round, beyond the ring too: a ring on darker ground, or a round hole in dark texture
                # (the caller tells them apart on the grey image)
                out.append((outer, inner, DARK_GROUND + kind))
                break
    return out


def _blob_holes(contours, hier: np.ndarray, i: int, boxes: dict) -> tuple[np.ndarray, FloatArray, np.ndarray]:
    """Blob ``i``'s holes (indices), their bounding boxes (x, y, w, h as floats) and its outline points (N, 2),
    computed once per blob into ``boxes``."""
    if i not in boxes:
        holes = []
        j = hier[i, 2]
        while j >= 0:
            holes.append(j)
            j = hier[j, 0]
        rects = np.array([cv2.boundingRect(contours[j]) for j in holes], dtype=np.float64).reshape(-1, 4)
        boxes[i] = (np.array(holes, dtype=np.int64), rects, contours[i].reshape(-1, 2))
    return boxes[i]


def _ring_on_outline(contours, hier: np.ndarray, i: int, hole: int, inner: Ellipse, rho: float,
                     boxes: dict) -> tuple[Ellipse, float] | None:
    """``_outer_on_outline(_outline_near(...), inner, rho)``, compiled (``hole_kernel._ring_on_outline``: the
    same arithmetic, point by point, in the same order; the directions' ``np.arctan2`` stays numpy's, and their
    count is that of ``np.unique``), where numba is installed. ``boxes``: as ``_outline_near``'s, with the blob's
    hole points joined and the kernel's output arrays (once per blob: its ~5 holes' outlines are tried for each
    hole that fits, and this glue cost ~30 us a call against ~9 us for the kernel)."""
    if hole_kernel.numba is None:
        return _outer_on_outline(_outline_near(contours, hier, i, hole, inner, rho, boxes), inner, rho)
    key = ("joined", i)
    joined = boxes.get(key)
    if joined is None:  # (``_blob_holes``' arrays, built here in fewer numpy calls: ~1 call per blob)
        ids = []
        j = hier.item(i, 2)
        while j >= 0:
            ids.append(j)
            j = hier.item(j, 0)
        segments = [contours[j] for j in ids]
        start = np.array([0, *itertools.accumulate(map(len, segments))], dtype=np.int64)
        points = np.concatenate(segments).reshape(-1, 2) if ids else np.empty((0, 2), np.int32)
        rects = np.array(list(map(cv2.boundingRect, segments)), dtype=np.float64).reshape(-1, 4)
        outline = contours[i].reshape(-1, 2)
        n_max = len(outline) + len(points)  # the kernel's output (u, v), consumed before the next call
        by_x = np.argsort(outline[:, 0], kind="stable")  # (the outline's points near a hole: ``_near_x``)
        joined = boxes[key] = (np.array(ids, dtype=np.int64), rects, outline, points, start, np.empty(n_max),
                               np.empty(n_max), by_x, outline[by_x, 0])
    holes, rects, outline, points, start, u, v, by_x, xs = joined
    cx, cy = inner.centre_px.tolist()
    a, b = inner.semi_axes_px.tolist()
    reach = 1.15 * a / rho + 2.0
    n, median = hole_kernel._ring_on_outline(
        _near_x(outline, by_x, xs, cx, reach), points, start, rects, holes, int(hole), cx, cy,
        math.cos(inner.angle_rad), math.sin(inner.angle_rad), a, b, rho, reach, max(0.02, 0.35 * rho / b), u, v)
    if n < 0:
        return None
    # the directions seen, of 32 (``np.unique``'s count: the values lie in 0..31); the angles numpy's arctan2
    directions = np.arctan2(v[:n], u[:n])
    seen = hole_kernel.directions_seen(directions, 16.0 / math.pi)
    if seen < 0:
        seen = hole_kernel.directions_seen_reference(directions, 16.0 / math.pi)
    if seen < HOLE_PAIR_EDGE_COVERAGE * 32:
        return None
    return inner.scaled(median / rho, 0.5), seen / 32


NEAR_X_FROM_POINTS = 256
"""``_near_x``: outlines of at least this many points are cut to the hole's reach first."""


def _near_x(outline: np.ndarray, by_x: np.ndarray, xs: np.ndarray, cx: float, reach: float) -> np.ndarray:
    """The points of ``outline`` (N, 2) within ``reach`` of ``cx`` in x, in their order (the kernel keeps no other:
    ``hole_kernel._keep_near``'s own test), found by bisection of ``xs`` (the outline's x sorted, ``by_x`` its
    order): a blob of textured ground in a 16 MP photo has an outline of ~10^5 points and ~10^3 holes, each tried
    against the whole outline (2.9 s of an 18 s photo). Short outlines are passed whole."""
    if len(outline) < NEAR_X_FROM_POINTS:
        return outline
    lo, hi = np.searchsorted(xs, cx - reach - 1.0, "left"), np.searchsorted(xs, cx + reach + 1.0, "right")
    return outline[np.sort(by_x[lo:hi])]


def _outline_near(contours, hier: np.ndarray, i: int, hole: int, inner: Ellipse, rho: float,
                  boxes: dict | None = None) -> np.ndarray:
    """The points (N, 2) of blob ``i``'s outline where a ring around its hole ``hole`` (fitted: ``inner``) may show
    its outer edge: the blob's outer boundary, and the boundaries of its other holes that lie beyond the ring
    (their boxes' centres beyond the hole scaled by 1 / rho): a ring on a small sheet on dark ground, joined to
    the ground where the sheet's margin is under a pixel, borders its sheet's pieces, which are holes of the
    merged blob (the code dots, holes too, lie within the ring).

    Only points within ``_outer_on_outline``'s reach (k < 1.15: within 1.15 a / rho of the centre, a square of
    that half side) can count, so only those are returned: the same result, without a pass over every hole and
    point of a blob that texture has merged across a 16 Mpx photo for each of its holes (88 s for one photo).
    ``boxes``: a dict the caller keeps per blob (its holes' boxes and its outline, computed once)."""
    holes, rects, outline = _blob_holes(contours, hier, i, {} if boxes is None else boxes)
    reach = 1.15 * inner.a / rho + 2.0
    cx, cy = float(inner.centre_px[0]), float(inner.centre_px[1])

    def near(points: np.ndarray) -> np.ndarray:
        keep = (np.abs(points[:, 0] - cx) <= reach) & (np.abs(points[:, 1] - cy) <= reach)
        return points if keep.all() else points[keep]

    parts = [near(outline)]
    if len(holes):
        c, s = math.cos(inner.angle_rad), math.sin(inner.angle_rad)
        x, y, w, h = rects.T
        dx, dy = x + 0.5 * (w - 1) - cx, y + 0.5 * (h - 1) - cy
        beyond = np.hypot((dx * c + dy * s) / inner.a, (dy * c - dx * s) / inner.b) * rho >= 1.0
        overlaps = (x - 1 <= cx + reach) & (x + w >= cx - reach) & (y - 1 <= cy + reach) & (y + h >= cy - reach)
        for j in holes[beyond & overlaps & (holes != hole)]:
            parts.append(near(contours[j].reshape(-1, 2)))
    return parts[0] if len(parts) == 1 else np.vstack(parts)


HOLE_PAIR_EDGE_COVERAGE = 0.3
"""``_outer_on_outline``: the share of directions (of 32) in which a merged blob's outline must run at the ring's
outer edge for that edge to be read off it."""


HOLE_PAIR_OUTLINE_SEEN = ((0.6, 4.0), (0.4, 6.0))
"""A pair from a hole whose outer edge runs along its blob's outline in at least the share of directions of one of
these (share, least semi-minor axis of the hole in level pixels) counts as seen ("outline": the caller then
accepts sparse codes from it). The window the outline must fall in is +-0.35 px, a narrower share of the radius
around a larger hole, so a chance alignment needs fewer directions to be ruled out there. Measured: targets merged
with chessboard squares, 21 of 32 directions around a 7.4 px hole, 15 of 32 around 8.9 and 8.5 px ones; over-exposed
foliage (x16) gave 16 of 32 around a 3.3 px hole (id 1's two dots read there), and 10-12 of 32 around 2.5 px holes,
from the pixel grid alone."""


def _outer_on_outline(contour: np.ndarray, inner: Ellipse, rho: float) -> tuple[Ellipse, float] | None:
    """The outer edge of a ring whose blob merged with dark ground, read off the blob's outline, with the share
    of directions it covers, or None: where the ring borders bright ground the outline runs along its outer
    edge, concentric with the hole and of its shape (the affine view of two concentric circles). Each outline
    point gets its radius ``k`` in the hole's frame scaled by the design ratio ``rho`` (1 on the hole scaled by
    1 / rho); the densest window of +-0.35 px in k in [0.8, 1.15] is the outer edge when its points cover
    ``HOLE_PAIR_EDGE_COVERAGE`` of the directions.
    Exposure moves the hole and the outer edge opposite ways, so the hole scaled by 1 / rho alone misses the edge
    by 1 / rho - 1 times the shift (at x8, a 20 px ring's edge by 0.9 px: its dark band checks then fail)."""
    pts = contour.reshape(-1, 2).astype(np.float64) - inner.centre_px
    c, s = math.cos(inner.angle_rad), math.sin(inner.angle_rad)
    u = (pts[:, 0] * c + pts[:, 1] * s) / inner.a
    v = (pts[:, 1] * c - pts[:, 0] * s) / inner.b
    k = np.hypot(u, v) * rho
    keep = (k > 0.8) & (k < 1.15)
    if np.count_nonzero(keep) < 6:
        return None
    half = max(0.02, 0.35 * rho / inner.b)
    ks = np.sort(k[keep])
    counts = np.searchsorted(ks, ks + 2.0 * half, side="right") - np.arange(len(ks))
    best = int(np.argmax(counts))
    near = keep & (np.abs(k - (ks[best] + half)) <= half)
    directions = np.unique((np.arctan2(v[near], u[near]) * (16.0 / math.pi)).astype(np.int64) % 32)
    if len(directions) < HOLE_PAIR_EDGE_COVERAGE * 32:
        return None
    # outline pixel centres: half a pixel inside the dark
    return inner.scaled(float(np.median(k[near])) / rho, 0.5), len(directions) / 32

