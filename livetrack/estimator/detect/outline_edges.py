"""Whether a dark blob's outline is an edge of the image: the share of its outline points where the grey image
steps across it (``outline_edge_share``).

A local threshold calls flat ground dark beside a bright object: the grey ground round a white sheet is below
its windows' mean, which the sheet raises, and comes out as a blob whose hole is the sheet (a halo). Its outline
runs through flat ground, where the image does not change; every dark thing the detector looks for (a ring, the
ground it merged with, texture) has an outline on which the image steps up to the brighter side."""

from __future__ import annotations

import math

import cv2
import numpy as np

from livetrack.estimator.detect import outline_kernel

OUTLINE_EDGE_STEP_PX = 1.5
"""Half the distance (level pixels) between the two samples across each outline point, along its normal."""
OUTLINE_EDGE_SAMPLES = 48
"""Outline points sampled, evenly along it (all of a shorter outline)."""


def outline_edge_share(grey: np.ndarray, contour: np.ndarray, depth: float) -> float:
    """The share of ``OUTLINE_EDGE_SAMPLES`` points of ``contour`` (OpenCV's (N, 1, 2) int32 pixel-centre points of
    a closed outline, in ``grey``'s pixels) where the grey image differs by at least ``depth`` between the two
    points ``OUTLINE_EDGE_STEP_PX`` either side of the outline along its normal (the normal from the points two
    steps before and after; samples at the nearest pixel, clamped to the image). 1.0 for an outline too short to
    judge (under 8 points); 0.0 for a depth that is not finite. Compiled (``outline_kernel.edge_count``) where
    numba is installed; ``outline_edge_share_reference`` is the same in numpy."""
    pts = contour.reshape(-1, 2)
    if outline_kernel.edge_count is None or pts.dtype != np.int32 or not math.isfinite(depth) or len(pts) < 8:
        return outline_edge_share_reference(grey, contour, depth)
    samples = min(len(pts), OUTLINE_EDGE_SAMPLES)
    return outline_kernel.edge_count(grey, np.ascontiguousarray(pts), samples, OUTLINE_EDGE_STEP_PX,
                                     float(depth)) / samples


def outline_edge_share_reference(grey: np.ndarray, contour: np.ndarray, depth: float) -> float:
    """``outline_edge_share`` in numpy."""
    pts = contour.reshape(-1, 2)
    n = len(pts)
    if n < 8:
        return 1.0
    if not math.isfinite(depth):
        return 0.0
    idx = np.linspace(0, n, min(n, OUTLINE_EDGE_SAMPLES), endpoint=False).astype(np.int64)
    p = pts[idx].astype(np.float64)
    t = pts[(idx + 2) % n].astype(np.float64) - pts[(idx - 2) % n]
    length = np.hypot(t[:, 0], t[:, 1])
    length[length == 0] = 1.0
    nx, ny = t[:, 1] / length * OUTLINE_EDGE_STEP_PX, -t[:, 0] / length * OUTLINE_EDGE_STEP_PX
    h, w = grey.shape
    ax = np.clip(np.rint(p[:, 0] + nx), 0, w - 1).astype(np.int64)
    ay = np.clip(np.rint(p[:, 1] + ny), 0, h - 1).astype(np.int64)
    bx = np.clip(np.rint(p[:, 0] - nx), 0, w - 1).astype(np.int64)
    by = np.clip(np.rint(p[:, 1] - ny), 0, h - 1).astype(np.int64)
    step = np.abs(grey[ay, ax].astype(np.float64) - grey[by, bx])
    return float(np.count_nonzero(step >= depth)) / len(idx)


HALO_EDGE_SHARE = 0.25
"""A blob whose outline steps in the grey image at under this share of its points (``outline_edge_share``), with a
pair inside one of its holes, is a halo (``HaloTest``). Measured on the bench's frames: 0.00-0.06 on the sheets'
halos, 1.00 on the rings."""


class HaloTest:
    """For ``pairs._pairs``: whether a blob that gave no pair is a threshold's halo round something already paired,
    whose closed-crop retry (``_pairs_closed``) can find nothing new: a pair of this level or a finer one lies
    inside one of its holes (the sheet, with the target on it), and its outline is no edge of ``grey``
    (``outline_edge_share`` under ``HALO_EDGE_SHARE`` at ``depth``, the threshold's own depth). A target's own
    ring round its paired nested level has an edge all along its outline, and so has dark ground that a ring
    merged with.

    Its pairs from holes (``_hole_pairs``) are still tried: a ring on ground darker than its ink (velvet) merges
    with the ground's halo round the target's white, a blob whose outline is no edge and whose hole (the ring's
    inner disk) holds the nested level; its hole gives the ring's ``DARK_GROUND`` pair (held-out seed 6's
    single-018 at x2: without it the nested level alone, -0.59 %; with it 0.008 %)."""

    def __init__(self, grey: np.ndarray, depth: float, contours, hier: np.ndarray, blobs,
                 found_px: list[tuple[float, float]]) -> None:
        self._grey, self._depth, self._contours, self._hier = grey, depth, contours, hier
        self._centres = found_px + [tuple(pair[0].centre_px.tolist()) for _, _, pair in blobs
                                    if pair is not None and not isinstance(pair, str)]
        self._seen: dict[int, bool] = {}

    def __call__(self, i: int) -> bool:
        if not self._centres:
            return False
        if i not in self._seen:
            self._seen[i] = self._holds_a_pair(i) and outline_edge_share(
                self._grey, self._contours[i], self._depth) < HALO_EDGE_SHARE
        return self._seen[i]

    def _holds_a_pair(self, i: int) -> bool:
        j = self._hier.item(i, 2)
        while j >= 0:
            hole = self._contours[j]
            if len(hole) >= 8:
                x, y, w, h = cv2.boundingRect(hole)
                for cx, cy in self._centres:
                    if (x <= cx <= x + w and y <= cy <= y + h
                            and cv2.pointPolygonTest(hole, (float(cx), float(cy)), False) > 0):
                        return True
            j = self._hier.item(j, 0)
        return False
