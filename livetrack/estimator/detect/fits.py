"""Ellipses fitted to the contours of a binary image's dark blobs, with the checks that make a fit count.

``_fit`` fits a blob's outer boundary or a hole (pixel-centre contours, moved half a pixel to the pixel edge) and
refuses what is no ellipse (residual and area tests); ``_fit_without_notches`` and ``_fit_trimmed`` fit what is left
of an outline that grown code dots notched or texture joined; ``_convex`` is the cheap solidity test run before
any fit. The fits are remembered within a frame (``_FIT_MEMO``, emptied by ``Detector.detect``): a blob that a
closing leaves as it was is fitted once. Used by the main pairing (``pairs``), the small blobs (``small_blobs``) and
the pairs from holes (``hole_pairs``)."""

from __future__ import annotations

import math

import cv2
import numpy as np

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect.arcs import off_notches
from livetrack.estimator.detect.fit_kernel import fit_distances, hull_area


def _fit(contour: np.ndarray, offset_px: float, min_aspect: float, area_px: float | None = None) -> Ellipse | None:
    """Ellipse through a contour of pixel centres, its semi-axes moved by ``offset_px`` to the pixel edge
    (+0.5 for the outer boundary of a dark blob, -0.5 for a hole), or None if it is not an ellipse: first-order
    (Sampson) residual RMS above 0.5 px + 3 % of sqrt(ab) or largest above 2 px + 12 % of sqrt(ab), or area off
    by more than 6 % + 1.5 px / b (the contour's own area, or ``area_px``).

    Remembered within a frame (``_FIT_MEMO``, emptied by ``Detector.detect`` at each call, so that timings of
    the same frame again stay those of a new frame): a blob the closing leaves as it was has the same outline in
    the plain and the closed binary image; its fit is looked up (a fifth of a paper-lab frame's fits, each ~30 us
    for ``cv2.fitEllipse`` on a few hundred points)."""
    if len(contour) < 6:
        return None
    if len(contour) > FIT_MEMO_MAX_POINTS:
        return _fit_once(contour, offset_px, min_aspect, area_px)
    key = (contour.dtype.str, contour.tobytes(), offset_px, min_aspect, area_px)
    fitted = _FIT_MEMO.get(key, _NOT_FITTED)  # one lookup: another thread's Detector may empty the memo meanwhile
    if fitted is _NOT_FITTED:
        if len(_FIT_MEMO) >= FIT_MEMO_SIZE:
            _FIT_MEMO.clear()
        fitted = _FIT_MEMO[key] = _fit_once(contour, offset_px, min_aspect, area_px)
    return fitted


_FIT_MEMO: dict[tuple, Ellipse | None] = {}
_NOT_FITTED = object()
"""``_fit``'s results by (contour dtype and bytes, offset, least aspect, area). A pure function's, so one memo
serves every Detector and thread (dict operations are atomic; a Detector in another thread emptying it costs only
misses); emptied when it reaches ``FIT_MEMO_SIZE`` entries. Contours of over ``FIT_MEMO_MAX_POINTS`` points are not
kept (the memo stays under ~16 MB)."""
FIT_MEMO_SIZE = 1024
FIT_MEMO_MAX_POINTS = 2048


def _fit_once(contour: np.ndarray, offset_px: float, min_aspect: float, area_px: float | None) -> Ellipse | None:
    """``_fit`` without the memo."""
    try:
        (cx, cy), (w, h), angle_deg = cv2.fitEllipse(contour)
    except cv2.error:
        return None
    a, b = 0.5 * max(w, h), 0.5 * min(w, h)
    if not (math.isfinite(a) and math.isfinite(b)) or b < 1.0 or b / a < min_aspect or b + offset_px <= 0.5:
        return None
    theta = math.radians(angle_deg) + (0.0 if w >= h else 0.5 * math.pi)
    # the points' first-order distances to the ellipse and the largest of them (compiled: ``fit_kernel``)
    dist, worst = fit_distances(contour, cx, cy, math.cos(theta), math.sin(theta), a, b)
    size = math.sqrt(a * b)  # a tilted target's outline strays with its length too (distortion, blur, JPEG)
    if worst > 2.0 + 0.12 * size or math.sqrt(float(dist @ dist) / len(dist)) > 0.5 + 0.03 * size:
        return None
    area = abs(cv2.contourArea(contour)) if area_px is None else area_px
    if abs(area / (math.pi * a * b) - 1.0) > 0.06 + 1.5 / b:
        return None
    return Ellipse(np.array([cx, cy]), np.array([a + offset_px, b + offset_px]), theta)


def _fit_without_notches(contour: np.ndarray, offset_px: float, min_aspect: float) -> Ellipse | None:
    """``_fit`` of a dark blob's outer boundary with its notches left out: a small or over-exposed target's
    white code dots, grown into the black ring's outer edge, cut notches into it (a blob that fails the solidity
    test). The points along each convexity defect deeper than 1.5 px are dropped; at least 60 % of the boundary
    must remain and fit an ellipse, and the convex hull's area must match it as ``_fit`` asks of a clean
    boundary."""
    if len(contour) < 12:
        return None
    notches = off_notches(contour, 1.5)
    if notches is None or notches[1] is None:
        return None
    keep, _, hull = notches
    n = len(contour)
    if keep.sum() < 0.6 * n or keep.all():
        return None
    fitted = _fit(contour[keep], offset_px, min_aspect, area_px=abs(cv2.contourArea(contour[hull.ravel()])))
    return fitted


def _fit_trimmed(contour: np.ndarray, offset_px: float, min_aspect: float) -> Ellipse | None:
    """``_fit`` of the points of ``contour`` within 1.5 px + 5 % of sqrt(ab) of a first ellipse through all of
    them, when they are at least 70 % of the points."""
    if len(contour) < 12:
        return None
    pts = contour.reshape(-1, 2).astype(np.float64)
    try:
        first = Ellipse.from_cv(cv2.fitEllipse(contour))
    except (cv2.error, ValueError):
        return None
    keep = np.abs(first.sampson_distance(pts)) <= 1.5 + 0.05 * math.sqrt(first.a * first.b)
    if keep.sum() < 0.7 * len(pts) or keep.all():
        return None
    kept = contour[keep]
    return _fit(kept, offset_px, min_aspect, area_px=abs(cv2.contourArea(kept)))


HOLE_BUMPS_MIN_SOLIDITY = 0.7
"""``_fit_without_bumps`` tries a hole whose area is at least this share of its convex hull's (``_convex`` asks
0.9): a disk with two or three dots joined to it fills ~0.8 of its hull, most texture holes far less."""
HOLE_BUMPS_KEPT = 0.55
"""``_fit_without_bumps``: the least share of a hole's outline on its ellipse (the rest on the joined dots)."""


def _fit_without_bumps(contour: np.ndarray, area: float, offset_px: float, min_aspect: float,
                       max_bumps: int | None = None) -> Ellipse | None:
    """``_fit`` of a hole's outline with its bumps left out: a white inner disk whose code dots joined it (grown
    by over-exposure, or across a band that a strong tilt thinned below the blur) is a hole with bumps, not convex
    (``_convex``). From an ellipse through every point, the points more than 1 px + 3 % of sqrt(ab) outside the
    ellipse through the rest are dropped, four times at most (the bumps lie outside, the disk's points inside the
    first ellipse). At least ``HOLE_BUMPS_KEPT`` of the outline must remain and pass ``_fit``'s tests, and the hole
    (``area``, px^2) must hold the ellipse: the bumps only add to it. ``max_bumps``: at most this many runs of
    dropped points along the outline (None: any)."""
    if len(contour) < 12 or area < HOLE_BUMPS_MIN_SOLIDITY * hull_area(contour):
        return None
    pts = contour.reshape(-1, 2).astype(np.float64)
    keep = np.ones(len(pts), dtype=bool)
    for _ in range(4):
        try:
            first = Ellipse.from_cv(cv2.fitEllipse(contour[keep]))
        except (cv2.error, ValueError):
            return None
        if not (math.isfinite(first.a) and math.isfinite(first.b)) or first.b < 1.0:
            return None
        inside = first.sampson_distance(pts) <= 1.0 + 0.03 * math.sqrt(first.a * first.b)
        if inside.sum() < HOLE_BUMPS_KEPT * len(pts):
            return None
        if np.array_equal(inside, keep):
            break
        keep = inside
    if keep.all():
        return None
    if max_bumps is not None and int(np.count_nonzero(~keep & np.roll(keep, 1))) > max_bumps:
        return None
    kept = contour[keep]
    fitted = _fit(kept, offset_px, min_aspect, area_px=abs(cv2.contourArea(kept)))
    if fitted is None or area < 0.97 * math.pi * (fitted.a - offset_px) * (fitted.b - offset_px):
        return None
    return fitted


DOT_NECK_MAX_SOLIDITY = 0.93
DOT_NECK_MAX_BUMPS = 2
"""``_fit_with_a_dot`` tries a hole that passed ``_convex`` (solidity 0.9 and up) only below this solidity, and
keeps its fit only with at most ``DOT_NECK_MAX_BUMPS`` runs of points left out: an inner disk joined by one dot across
a band a 70 deg tilt thinned (seed 9's no-sheet-004 at x2, seed 4's no-sheet-000 at x1: solidity 0.90, one run) has
a neck; a chessboard's white squares (0.94-0.97, four runs: their corners) have none, and tried as such a disk cost
~5x detect's time on chessboard frames (1200 squares a frame) and gave two false id 1s."""


def _fit_with_a_dot(contour: np.ndarray, area: float, offset_px: float, min_aspect: float) -> Ellipse | None:
    """``_fit_without_bumps`` of a hole convex enough for ``_convex`` that ``_fit`` refused: one or two code dots
    joined to the inner disk through a neck (``DOT_NECK_MAX_SOLIDITY``, ``DOT_NECK_MAX_BUMPS``)."""
    if len(contour) < 12 or area >= DOT_NECK_MAX_SOLIDITY * hull_area(contour):
        return None
    return _fit_without_bumps(contour, area, offset_px, min_aspect, max_bumps=DOT_NECK_MAX_BUMPS)


def _convex(contour: np.ndarray, area: float) -> bool:
    """Solidity test: an ellipse's pixel boundary fills nearly all of its convex hull (texture blobs do not). The
    hull's area compiled (``fit_kernel.hull_area``: ``cv2.contourArea(cv2.convexHull(...))``'s value)."""
    return area >= 0.9 * hull_area(contour) - 2.0

