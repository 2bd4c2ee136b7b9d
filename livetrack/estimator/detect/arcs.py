"""Rings cut open: the outline of a dark blob without a hole that is the arc of a target's black ring.

Over-exposure grows a target's white code dots until they cut its black ring through: its inner disk joins the
ground, and the threshold image holds a C (or arcs) and no hole, on every level (a 18 x 29 px target at x32 on grey
ground: one C over three quarters of the ring and two fragments). Blur and a steep tilt do the same to a small
ring's thin bands. The C's outer boundary still runs along the ring's outer edge: this module fits an ellipse to
it, left of the C's opening and notches (its convexity defects), and ``Detector`` re-places the pair on the grey
image's edges (``refine.pair_from_edges``) and reads its code with the strict rules of a pair from a hole alone.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect import hole_kernel
from livetrack.estimator.detect.fit_kernel import fit_distances

ARC_MIN_COVERAGE = 0.5
"""The least share of 32 directions (about the fitted ellipse's centre, in its frame) the kept outline must cover:
a C over more than half the ring (a chance arc of texture, a third of an ellipse, fits almost anything)."""
ARC_NOTCH_PX = 1.5
"""Convexity defects deeper than this (pixels of the level) are left out of the fit: the C's opening (its inner
boundary runs inside the hull) and notches cut by grown dots."""
ARC_DARK_SHARE = (0.1, 0.7)
"""The share of its bounding box the blob's dark pixels cover: a ring of inner radius 0.4 fills 0.66 of it, less
its dots and its opening; a thin arc of 1-2 px across a 30 px box fills under 0.1."""
ARC_MAX_PER_LEVEL = 48
"""At most this many arcs per level and binary image are handed on (the largest first): each costs a grey-level
re-placement (~0.2 ms)."""


def arc_outlines(binary: np.ndarray, contours, hier: np.ndarray, lengths: np.ndarray, min_len: int, a_lo: float,
                 a_hi: float, min_aspect: float, blobs: list[int] | None = None,
                 boxes: tuple[np.ndarray, np.ndarray] | None = None) -> list[Ellipse]:
    """The outer ellipses (pixel edge, level pixels) of the top-level blobs of ``binary`` (255 = dark) without a
    hole (or of ``blobs``, indices of the contours), of about the searched size (as ``pairs._pairs``: semi-axes
    a >= a_lo, b <= a_hi, a <= 3 a_hi), whose middle is not dark and whose outline, without its deep notches, is an
    arc of an ellipse over ``ARC_MIN_COVERAGE`` of the directions (``arc_outline``).

    ``boxes``: those blobs' ``blob_boxes``, when the caller has them. Without ``blobs``, the size and middle tests
    run on all the boxes at once first when they are ``BOXES_AT_ONCE`` or more (a textured level holds thousands
    of such blobs, a few percent of them pass), and again in the loop on those that pass."""
    found: list[tuple[float, Ellipse]] = []
    if blobs is None:
        if boxes is None:
            boxes = blob_boxes(contours, np.flatnonzero((hier[:, 3] < 0) & (hier[:, 2] < 0) & (lengths >= min_len)))
        ids, rects = boxes
        if len(ids) >= BOXES_AT_ONCE:
            x, y, w, h = rects.T
            larger, smaller = 0.5 * np.maximum(w, h), 0.5 * np.minimum(w, h)
            keep = (larger >= 0.8 * a_lo) & (smaller <= 1.25 * a_hi + 1) & (larger <= 3.2 * a_hi)
            keep[keep] = binary[y[keep] + h[keep] // 2, x[keep] + w[keep] // 2] == 0
            ids, rects = ids[keep], rects[keep]
        candidates = zip(ids.tolist(), map(tuple, rects.tolist()), strict=True)
    else:
        candidates = ((i, cv2.boundingRect(contours[i])) for i in blobs)
    for i, rect in candidates:
        x, y, w, h = rect
        if 0.5 * max(w, h) < 0.8 * a_lo or 0.5 * min(w, h) > 1.25 * a_hi + 1 or 0.5 * max(w, h) > 3.2 * a_hi:
            continue
        if binary[y + h // 2, x + w // 2] or not (_ring_around_middle(binary, x, y, w, h)  # (the cheap test first)
                                                   or _ring_around_middle_turned(binary, contours[i])):
            continue
        ellipse = arc_outline(contours[i], rect, binary, min_aspect)
        if ellipse is not None and ellipse.a >= a_lo - 0.5 and ellipse.b <= a_hi and ellipse.a <= 3.0 * a_hi:
            found.append((w * h, ellipse))
    found.sort(key=lambda item: -item[0])
    return [e for _, e in found[:ARC_MAX_PER_LEVEL]]


def open_middles(binary: np.ndarray, boxes: tuple[np.ndarray, np.ndarray], a_lo: float, a_hi: float
                 ) -> list[tuple[int, int, int, int]]:
    """The boxes (x, y, w, h) among ``boxes`` (``blob_boxes`` of blobs without a hole) of about the searched size
    (as ``arc_outlines``'s) whose middle pixel is not dark: pieces of a ring cut through, each maybe under half of
    it (``arc_pairs._pairs_of_arcs`` groups them)."""
    ids, rects = boxes
    if not len(ids):
        return []
    x, y, w, h = rects.T
    larger, smaller = 0.5 * np.maximum(w, h), 0.5 * np.minimum(w, h)
    keep = (larger >= 0.8 * a_lo) & (smaller <= 1.25 * a_hi + 1) & (larger <= 3.2 * a_hi)
    keep[keep] = binary[y[keep] + h[keep] // 2, x[keep] + w[keep] // 2] == 0
    return [tuple(r) for r in rects[keep].tolist()]


BOXES_AT_ONCE = 64
"""Boxes tested at once in numpy (``arc_outlines``, ``small_blobs.SmallBlobs.add_without_hole``) from this many on:
below it the numpy calls' own cost exceeds the loop's (~20 us a call on the bench's frames, a dozen calls a frame)."""


def blob_boxes(contours, blobs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``blobs`` (indices of ``contours``) and their bounding boxes (K, 4: x, y, w, h as ``cv2.boundingRect`` gives
    them, int64), for the tests of many boxes at once (``arc_outlines``,
    ``small_blobs.SmallBlobs.add_without_hole``)."""
    rects = np.array([cv2.boundingRect(contours[i]) for i in blobs.tolist()], dtype=np.int64).reshape(-1, 4)
    return blobs, rects


_PROBES = tuple((math.cos(k * math.pi / 4), math.sin(k * math.pi / 4)) for k in range(8))
ARC_RING_PROBES = 4
"""``_ring_around_middle``: of 8 probes at 0.7 of the box's half sides, at least this many must be dark (a ring
cut open through one or two dots; a tilted one's diagonal probes can fall outside it)."""


_PROBE_DX = np.array([d[0] for d in _PROBES])
_PROBE_DY = np.array([d[1] for d in _PROBES])
_PROBE_DX.flags.writeable = _PROBE_DY.flags.writeable = False


def _ring_around_middle(binary: np.ndarray, x: int, y: int, w: int, h: int) -> bool:
    """``_ring_around_middle_reference``, compiled (``hole_kernel.ring_around_middle``: the same arithmetic, ~0.5 us
    against ~10) where numba is installed."""
    if hole_kernel.numba is None:
        return _ring_around_middle_reference(binary, x, y, w, h)
    return hole_kernel.ring_around_middle(binary, x, y, w, h, _PROBE_DX, _PROBE_DY, ARC_RING_PROBES)


def _ring_around_middle_reference(binary: np.ndarray, x: int, y: int, w: int, h: int) -> bool:
    """A cheap first test of a blob's box (x, y, w, h) in ``binary``: its middle and 3 of 4 probes at 0.2 of its
    half sides are not dark (an inner disk), and ``ARC_RING_PROBES`` of 8 at 0.7 are (its ring)."""
    cx, cy, hw, hh = x + 0.5 * (w - 1), y + 0.5 * (h - 1), 0.5 * w, 0.5 * h
    if binary[int(cy + 0.5), int(cx + 0.5)]:
        return False
    rows, cols = binary.shape
    inner = ring = 0
    for k, (dx, dy) in enumerate(_PROBES):
        if k % 2 == 0:
            r, c = int(cy + 0.2 * hh * dy + 0.5), int(cx + 0.2 * hw * dx + 0.5)
            inner += 0 <= r < rows and 0 <= c < cols and not binary[r, c]
        r, c = int(cy + 0.7 * hh * dy + 0.5), int(cx + 0.7 * hw * dx + 0.5)
        ring += 0 <= r < rows and 0 <= c < cols and bool(binary[r, c])
    return inner >= 3 and ring >= ARC_RING_PROBES


ARC_TURNED_MIN_ELONGATION = 1.3
"""``_ring_around_middle_turned``: only blobs whose least-area rectangle is at least this much longer than wide
(a round blob's box is its own frame already)."""


def _ring_around_middle_turned(binary: np.ndarray, contour: np.ndarray) -> bool:
    """``_ring_around_middle_reference``'s test with its probes in the frame of the blob's least-area rectangle
    (``cv2.minAreaRect``) instead of its bounding box: an elongated ring (a strong tilt) that runs along a diagonal
    of the image fills its box along one diagonal only, and the box's probes fall off it on the sheet (seed 9's
    single-001 at x8, a 10 x 30 px ring at 70 deg turned 45 deg, cut open by a grown dot: 2 of 8 ring probes
    dark). None of this for blobs that are about round (``ARC_TURNED_MIN_ELONGATION``)."""
    (cx, cy), (rw, rh), angle_deg = cv2.minAreaRect(contour)
    if max(rw, rh) < ARC_TURNED_MIN_ELONGATION * max(min(rw, rh), 1.0):
        return False
    t = math.radians(angle_deg)
    ux, uy, vx, vy = math.cos(t), math.sin(t), -math.sin(t), math.cos(t)
    rows, cols = binary.shape
    inner = ring = 0
    for k, (dx, dy) in enumerate(_PROBES):
        for share in ((0.2, 0.7) if k % 2 == 0 else (0.7,)):
            du, dv = share * 0.5 * rw * dx, share * 0.5 * rh * dy
            r, c = int(cy + du * uy + dv * vy + 0.5), int(cx + du * ux + dv * vx + 0.5)
            dark = 0 <= r < rows and 0 <= c < cols and bool(binary[r, c])
            if share == 0.2:
                inner += 0 <= r < rows and 0 <= c < cols and not dark
            else:
                ring += dark
    centre_r, centre_c = int(cy + 0.5), int(cx + 0.5)
    middle_bright = 0 <= centre_r < rows and 0 <= centre_c < cols and not binary[centre_r, centre_c]
    return middle_bright and inner >= 3 and ring >= ARC_RING_PROBES


def off_notches(contour: np.ndarray, depth_px: float) -> tuple[np.ndarray, np.ndarray | None, np.ndarray] | None:
    """A mask of the points of ``contour`` (a closed outline) outside its convexity defects deeper than
    ``depth_px``, the defects (K, 4: start, end, farthest point, depth in 1/256 px; None without any) and the
    convex hull's point indices; None when OpenCV refuses the contour (a self-touching one: non-monotonic hull
    indices)."""
    try:
        hull = cv2.convexHull(contour, returnPoints=False)
        defects = cv2.convexityDefects(contour, hull)
    except cv2.error:
        return None
    keep = np.ones(len(contour), dtype=bool)
    if defects is not None:
        defects = defects.reshape(-1, 4)
        # deeper than depth_px (OpenCV's depth is fixed-point, 1/256 px)
        for start, end, _, _ in defects[defects[:, 3] > depth_px * 256].tolist():
            if start <= end:
                keep[start + 1 : end] = False
            else:  # the defect wraps around the contour's start
                keep[start + 1 :] = False
                keep[:end] = False
    return keep, defects, hull


def arc_outline(contour: np.ndarray, rect: tuple[int, int, int, int], binary: np.ndarray,
                min_aspect: float) -> Ellipse | None:
    """The ellipse (semi-axes moved half a pixel out, to the dark pixels' edge) through ``contour`` (a dark blob's
    outer boundary, pixel centres, bounding ``rect``) without the points along its convexity defects deeper than
    ``ARC_NOTCH_PX``, or None: when the blob's dark share of its box is off ``ARC_DARK_SHARE``, fewer than 12 points
    remain, they stray from the ellipse more than ``fits._fit`` allows a clean outline, cover less than
    ``ARC_MIN_COVERAGE`` of the directions about it, or its centre falls on a dark pixel."""
    x, y, w, h = rect
    area = abs(cv2.contourArea(contour))
    if not ARC_DARK_SHARE[0] <= area / max(w * h, 1) <= ARC_DARK_SHARE[1] or len(contour) < 12:
        return None
    notches = off_notches(contour, ARC_NOTCH_PX)
    if notches is None:
        return None
    points = contour[notches[0]]
    return _ellipse_through(points, binary, min_aspect, ARC_MIN_COVERAGE) if len(points) >= 12 else None


def _ellipse_through(points: np.ndarray, binary: np.ndarray, min_aspect: float, min_coverage: float
                     ) -> Ellipse | None:
    """``arc_outline``'s and ``arcs_outline``'s ellipse through ``points`` (N, 1, 2 int32: kept outline points),
    semi-axes moved half a pixel out, or None: when it strays from them more than ``fits._fit`` allows a clean
    outline, they cover less than ``min_coverage`` of 32 directions about it, or its centre is dark."""
    try:
        (cx, cy), (fw, fh), angle_deg = cv2.fitEllipse(points)
    except cv2.error:
        return None
    a, b = 0.5 * max(fw, fh), 0.5 * min(fw, fh)
    if not (math.isfinite(a) and math.isfinite(b)) or b < 2.0 or b / a < min_aspect:
        return None
    theta = math.radians(angle_deg) + (0.0 if fw >= fh else 0.5 * math.pi)
    c, s = math.cos(theta), math.sin(theta)
    dist, worst = fit_distances(points, cx, cy, c, s, a, b)
    size = math.sqrt(a * b)
    if worst > 2.0 + 0.12 * size or math.sqrt(float(dist @ dist) / len(dist)) > 0.5 + 0.03 * size:
        return None
    p = points.reshape(-1, 2).astype(np.float64) - (cx, cy)
    u, v = (p[:, 0] * c + p[:, 1] * s) / a, (p[:, 1] * c - p[:, 0] * s) / b
    directions = np.unique((np.arctan2(v, u) * (16.0 / math.pi)).astype(np.int64) % 32)
    if len(directions) < min_coverage * 32:
        return None
    row, col = int(cy + 0.5), int(cx + 0.5)
    if not (0 <= row < binary.shape[0] and 0 <= col < binary.shape[1]) or binary[row, col]:
        return None
    return Ellipse(np.array([cx, cy]), np.array([a + 0.5, b + 0.5]), theta)


ARCS_MIN_COVERAGE = 0.6
"""``arcs_outline``: the least share of 32 directions the pieces' kept outline points must cover together."""


def arcs_outline(pieces: list[np.ndarray], binary: np.ndarray, min_aspect: float) -> Ellipse | None:
    """The ellipse (semi-axes moved half a pixel out, to the dark pixels' edge) through the outer boundary of
    several dark blobs together (``pieces``: their outer contours, pixel centres), or None: a ring cut through in
    two or more places (a 14 x 40 px target at 70 deg, x16: its white disk grown into two dots on either side, the
    ring two arcs of under half of it each, whose closing with a 7 px disk still left a hole no ellipse).

    The outline points kept are those within ``ARC_NOTCH_PX`` of the pieces' joint convex hull (the ring's outer
    edge; not their inner boundaries, nor the cut ends' sides beyond that depth); the ellipse through them must
    fit them as ``arc_outline``'s must, cover ``ARCS_MIN_COVERAGE`` of the directions about it and have its centre
    on a pixel that is not dark (the inner disk)."""
    points = np.concatenate([p.reshape(-1, 2) for p in pieces]).astype(np.int32)
    if len(points) < 12:
        return None
    kept = points[_depth_in_hull(points) <= ARC_NOTCH_PX]
    if len(kept) < 12:
        return None
    return _ellipse_through(kept.reshape(-1, 1, 2), binary, min_aspect, ARCS_MIN_COVERAGE)


def _depth_in_hull(points: np.ndarray) -> np.ndarray:
    """The distance (pixels) of each of ``points`` (N, 2) inside their convex hull to its boundary: the least
    distance to the hull's edges (``cv2.pointPolygonTest``'s value for points inside, at once)."""
    hull = cv2.convexHull(points).reshape(-1, 2).astype(np.float64)
    if len(hull) < 3:
        return np.zeros(len(points))
    start, edge = hull, np.roll(hull, -1, axis=0) - hull
    p = points.astype(np.float64)[:, None, :] - start[None, :, :]  # (N, M, 2)
    t = np.clip((p * edge).sum(axis=2) / np.maximum((edge * edge).sum(axis=1), 1e-12), 0.0, 1.0)
    d = p - t[:, :, None] * edge[None, :, :]
    return np.sqrt((d * d).sum(axis=2).min(axis=1))
