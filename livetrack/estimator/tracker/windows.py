"""Where the tracker looks and how far its edge profiles reach: a tracked target's search window and the least
radius looked for there, the clearance between a design's edges and the profile half length it allows, and
the grouping of detections into targets (levels of one target, repeats from overlapping windows)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from livetrack.estimator.detect import Candidate
from livetrack.estimator.edge_glue_kernels import bounds_xy, kernel_array
from livetrack.estimator.edge_kernels import kernels

if TYPE_CHECKING:
    from livetrack.estimator.tracker.results import TargetResult


MIN_HALF_WIDTH_PX = 2.5
"""Shortest edge profile half length: about 2.5 blur sd on each side of an edge at the usual 0.8-1 px blur."""


def _clearance_px(group: Sequence[Candidate]) -> float:
    """The least clearance (pixels) between a level's circles and the next feature of its design (the nested
    level inside the inner disk, the code dots on either side of the black band; 0.2 R each in the default
    design), measured along the level's outer semi-minor axis."""
    clearance_px = math.inf
    for cand in group:
        spec = cand.spec
        r_out, r_in = spec.outer_radius_m, spec.inner_radius_m
        gaps = [r_out - r_in]
        if spec.code is not None:
            gaps += [spec.code.ring_radius_m - spec.code.dot_radius_m - r_in,
                     r_out - spec.code.ring_radius_m - spec.code.dot_radius_m]
        if spec.child is not None:
            gaps.append(r_in - spec.child.outer_radius_m)
        clearance_px = min(clearance_px, min(g for g in gaps if g > 0) / r_out * min(cand.outer.semi_axes_px))
    return clearance_px


def _half_width_px(group: Sequence[Candidate], default_px: float) -> float:
    """Edge profile half length for a target: ``default_px``, shortened on a small target so that a profile
    does not reach the next edge of the design (``_clearance_px``), at least ``MIN_HALF_WIDTH_PX``. A 17 px
    target's inner-circle profiles of 4 px read its child's ring and its dots, and too few of them fitted to
    start a pose."""
    return float(min(default_px, max(MIN_HALF_WIDTH_PX, _clearance_px(group))))


WINDOW_MIN_RADIUS_FRACTION = 0.5
"""A tracked target's window search looks for outer radii (semi-major axes, px) down to this fraction of its
smallest detected level's (``_window_min_radius_px``)."""


def _window_min_radius_px(group: Sequence[Candidate]) -> float:
    """The smallest outer radius (semi-major axis, px) the window search of a tracked target looks for:
    ``WINDOW_MIN_RADIUS_FRACTION`` of its smallest detected level's (room for the target to shrink to half until
    the next search), or the expected size of that level's undetected child level if smaller (a child growing
    into view is still found), at least the detector's default of 8 px. For a target whose smallest level is
    over 64 px this skips the detector's full-resolution pass (``DetectOptions.level0_max_radius_px``, 32 px),
    the costliest; smaller, unrelated targets inside the window are then left to the full-frame searches."""
    smallest = min(group, key=lambda c: max(c.outer.semi_axes_px))
    a_px = float(max(smallest.outer.semi_axes_px))
    radius_px = WINDOW_MIN_RADIUS_FRACTION * a_px
    child = smallest.spec.child
    if child is not None:
        radius_px = min(radius_px, a_px * child.outer_radius_m / smallest.spec.outer_radius_m)
    return max(8.0, float(radius_px))


def _window(result: TargetResult, shape: tuple[int, ...], tracking_margin: float) -> tuple[int, int, int, int]:
    """The search window of a tracked target: where its edges are now (not where it was last detected: it may
    have moved since), grown by ``tracking_margin`` x its size on each side and 8 px."""
    points = result.edge_points_px
    if len(points) == 0:
        extent, (cx, cy) = result.candidate.outer.half_extent_px(), result.candidate.outer.centre_px
    else:
        if kernels() == "numba":  # the numpy lines below, compiled (the same numbers, ~15 us less)
            lo_x, lo_y, hi_x, hi_y = bounds_xy(kernel_array(points, np.float64))
            low, high = np.array([lo_x, lo_y]), np.array([hi_x, hi_y])
        else:
            x, y = points[:, 0], points[:, 1]  # per column: numpy's reductions along axis 0 are ~5x slower
            low, high = np.array([x.min(), y.min()]), np.array([x.max(), y.max()])
        extent, (cx, cy) = 0.5 * (high - low), 0.5 * (high + low)
    half = extent * (1.0 + tracking_margin) + 8.0
    return (max(int(cx - half[0]), 0), max(int(cy - half[1]), 0),
            min(int(np.ceil(cx + half[0])) + 1, shape[1]), min(int(np.ceil(cy + half[1])) + 1, shape[0]))


def _unique(candidates: list[Candidate]) -> list[Candidate]:
    """Drop repeated detections of one target level (overlapping tracking windows)."""
    out: list[Candidate] = []
    for cand in candidates:
        if not any(c.target_id == cand.target_id and c.level == cand.level
                   and np.linalg.norm(np.asarray(c.outer.centre_px) - np.asarray(cand.outer.centre_px)) < 2.0
                   for c in out):
            out.append(cand)
    return out


def group_levels(candidates: Sequence[Candidate]) -> list[list[Candidate]]:
    """Group candidates of the same target (same id, nested centres), outermost level first."""
    groups: list[list[Candidate]] = []
    for cand in sorted(candidates, key=lambda c: c.level):
        for group in groups:
            top = group[0]
            if (top.target_id == cand.target_id and cand.level > top.level
                    and np.linalg.norm(np.asarray(cand.outer.centre_px) - np.asarray(top.outer.centre_px))
                    < min(top.inner.semi_axes_px)):
                group.append(cand)
                break
        else:
            groups.append([cand])
    return groups
