"""Small dark blobs that gave no ellipse pair but may be a target: collected during the main pairing
(``pairs._pairs(small_blobs=...)``) for the caller to try again with their own threshold
(``refine._small_blob_pair``).

A small ring, blurred or over-exposed, loses its hole (its inner disk darkened by blur, or joined to the ground
through a cut where the thin bands beside a code dot gave way); ``SmallBlobs`` keeps the outline ellipses of blobs
of the searched size whose middle is brighter than their darkest pixel (``add``), of Cs that are a ring cut open
(``add_open_ring``), and in a clipped frame the boxes of arcs of a ring cut through by grown dots (``add_arc``:
paired by ``arc_pairs._pairs_of_arcs``). The brightness probes (``_probes``) run compiled where numba is installed
(``hole_kernel.small_blob_probes``), ``_probes_reference`` being their Python reference."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect import hole_kernel
from livetrack.estimator.detect.arcs import BOXES_AT_ONCE, blob_boxes
from livetrack.estimator.detect.fits import _convex, _fit, _fit_without_notches
from livetrack.estimator.detect.options import DetectOptions
from livetrack.estimator.detect.threshold import SATURATED_LEVEL


@dataclass
class SmallBlobs:
    """For ``pairs._pairs``: collects small dark blobs that gave no pair but may be a target (see ``add``)."""

    image: np.ndarray  # the level image the binary was thresholded from (8-bit)
    binary: np.ndarray  # the binary (255 = dark)
    max_radius_px: float
    clipped: bool = False  # the frame has clipped pixels: also collect ``arcs``
    found: list[Ellipse] = field(default_factory=list)
    arcs: list[tuple[int, int, int, int]] = field(default_factory=list)

    def add_without_hole(self, contours, hier: np.ndarray, lengths: np.ndarray, min_len: int, a_lo: float,
                         opts: DetectOptions, boxes: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """The top-level blobs without a hole of the searched size up to ``max_radius_px``; in a clipped frame,
        those not dark in their middle and beside clipped pixels also go to ``arcs`` (bounding boxes): a small
        over-exposed target's ring cut into arcs by its grown dots (its inner disk joins the ground through
        them: no hole anywhere). Those not dark in their middle up to ``OPEN_RING_MAX_RADIUS_PX`` are also tried
        as a ring cut open (``add_open_ring``).

        ``boxes``: the ``arcs.blob_boxes`` of the top-level blobs without a hole of ``min_len`` points or more,
        when the caller has them. The length and size tests run on all the boxes at once first when they are
        ``arcs.BOXES_AT_ONCE`` or more, and again in the loop on those that pass."""
        limit = max(self.max_radius_px, OPEN_RING_MAX_RADIUS_PX)
        if boxes is None:
            boxes = blob_boxes(contours, np.flatnonzero((hier[:, 3] < 0) & (hier[:, 2] < 0) & (lengths >= min_len)))
        ids, rects = boxes
        if len(ids) >= BOXES_AT_ONCE:
            larger, smaller = 0.5 * np.maximum(rects[:, 2], rects[:, 3]), 0.5 * np.minimum(rects[:, 2], rects[:, 3])
            keep = (lengths[ids] <= 2.0 * math.pi * 3.0 * limit) & (larger >= 0.8 * a_lo) & (smaller <= limit + 1)
            ids, rects = ids[keep], rects[keep]
        for i, rect in zip(ids.tolist(), map(tuple, rects.tolist()), strict=True):
            if lengths[i] > 2.0 * math.pi * 3.0 * limit:
                continue
            x, y, w, h = rect
            if not (0.5 * max(w, h) >= 0.8 * a_lo and 0.5 * min(w, h) <= limit + 1):
                continue
            small = 0.5 * min(w, h) <= self.max_radius_px + 1 and lengths[i] <= 2.0 * math.pi * 3.0 * self.max_radius_px
            if self.binary[y + h // 2, x + w // 2]:  # dark in the middle: no C, no crescent
                if small:
                    self.add(contours[i], rect, a_lo, opts, solid=True)
            else:
                self.add_open_ring(contours[i], rect, a_lo, opts)
                if small:
                    self.add_arc(rect)

    def add_arc(self, rect: tuple[int, int, int, int]) -> None:
        """Keeps ``rect`` (x, y, w, h) in ``arcs`` when the frame is clipped and so is some pixel within half the
        box's size around it."""
        if self.clipped:
            x, y, w, h = rect
            g = max(w, h) // 2
            box = self.image[max(y - g, 0) : y + h + g, max(x - g, 0) : x + w + g]
            if cv2.minMaxLoc(box)[1] >= SATURATED_LEVEL:
                self.arcs.append(rect)

    def add(self, contour: np.ndarray, rect: tuple[int, int, int, int], a_lo: float, opts: DetectOptions,
            solid: bool = False) -> None:
        """Keeps the blob's outline ellipse when its middle is brighter than its darkest pixel by at least
        ``SMALL_BLOB_MIDDLE_CONTRAST`` of the contrast to the brighter of its middle and its surroundings (a
        ring's white inner disk, blurred and darkened by its nested level; a texture blob is darkest in its
        middle), and when the outline fits an ellipse of the searched size (``solid``, a blob without hole: a
        convex one)."""
        x, y, w, h = rect
        area = abs(cv2.contourArea(contour))
        if not 0.5 <= area / (0.25 * math.pi * w * h) <= 1.2:  # an ellipse fills pi/4 of its box or more, < 2x less
            return
        # the brightest of 8 probes in the middle (0.15 of the box out), and of 8 in the surroundings (0.65 out),
        # each clamped to the image, and the box's darkest pixel (a few thousand calls per frame on textured ground)
        middle, white, dark = _probes(self.image, rect)
        white = max(white, middle)
        if middle - dark < 6 or middle - dark < SMALL_BLOB_MIDDLE_CONTRAST * (white - dark):
            return
        convex = _convex(contour, area)
        if solid and not convex:
            return
        outer = _fit(contour, 0.5, opts.min_aspect) if convex else _fit_without_notches(contour, 0.5, opts.min_aspect)
        if outer is not None and outer.a >= a_lo - 0.5 and outer.b <= self.max_radius_px:
            self.found.append(outer)


    def add_open_ring(self, contour: np.ndarray, rect: tuple[int, int, int, int], a_lo: float,
                      opts: DetectOptions) -> None:
        """Keeps the outline ellipse of a C: a small ring cut open where the thin bands beside a dot give way
        (blur, motion, a 20 px target's bands of 4 px), its inner disk joined to the ground through the cut. The
        blob must cover a ring's share of its box, its middle be brighter than its darkest pixel by
        ``OPEN_RING_MIDDLE_CONTRAST`` of the contrast to the brighter of its middle and surroundings, its convex
        hull fill an ellipse's share of its box and the blob a ring's share of the hull; the ellipse is fitted
        to the hull (cheapest tests first: C-shaped flecks of texture are many)."""
        x, y, w, h = rect
        area = abs(cv2.contourArea(contour))
        if not OPEN_RING_MIN_SHARE * math.pi / 4 <= area / (w * h) <= 0.95 * math.pi / 4:
            return
        middle, white, dark = _probes(self.image, rect)
        white = max(white, middle)
        if middle - dark < 6 or middle - dark < OPEN_RING_MIDDLE_CONTRAST * (white - dark):
            return
        hull = cv2.convexHull(contour)
        hull_area = abs(cv2.contourArea(hull))
        if not (0.6 <= hull_area / (0.25 * math.pi * w * h) <= 1.2
                and OPEN_RING_MIN_SHARE <= area / max(hull_area, 1.0) <= 0.95):
            return
        outer = _fit(hull, 0.5, opts.min_aspect)
        if outer is not None and outer.a >= a_lo - 0.5 and outer.b <= OPEN_RING_MAX_RADIUS_PX:
            # grown by a tenth: the thin bands that gave way leave the hull inside the outer edge, and the
            # surroundings' samples (``refine._small_blob_pair``) must clear the blurred edge
            self.found.append(outer.scaled(OPEN_RING_GROWTH))


OPEN_RING_GROWTH = 1.1
OPEN_RING_MAX_RADIUS_PX = 24.0
OPEN_RING_MIN_SHARE = 0.3
OPEN_RING_MIDDLE_CONTRAST = 0.6
"""``SmallBlobs.add_open_ring``: the least share of its box's ellipse and of its convex hull a C's dark pixels
cover (a ring of inner radius 0.4: 0.84, less its dots, its cut and the blur's thinning), and how much brighter
than its darkest pixel its middle must be (0.88 of the contrast for a 20 px target at x0.5 whose ring opened)."""


SMALL_BLOB_MIDDLE_CONTRAST = 0.3
_SMALL_PROBES = tuple((f, tuple((math.cos(a), math.sin(a)) for a in (k * math.pi / 4 for k in range(8))))
                      for f in (0.15, 0.65))


_PROBE_DX = np.array([d[0] for d in _SMALL_PROBES[0][1]])
_PROBE_DY = np.array([d[1] for d in _SMALL_PROBES[0][1]])
_PROBE_DX.flags.writeable = _PROBE_DY.flags.writeable = False


def _probes(img: np.ndarray, rect: tuple[int, int, int, int]) -> tuple[int, int, int]:
    """For ``SmallBlobs``: the brightest of ``_SMALL_PROBES``' probes near the middle of the box ``rect`` (x, y, w,
    h) in ``img`` and of those farther out (``_brightest_probe`` each), and the box's darkest pixel; compiled
    (``hole_kernel.small_blob_probes``: the same arithmetic, ~1 us against ~12) where numba is installed."""
    if hole_kernel.numba is None or img.dtype != np.uint8:
        return _probes_reference(img, rect)
    (near, _), (far, _) = _SMALL_PROBES
    return hole_kernel.small_blob_probes(img, *rect, near, far, _PROBE_DX, _PROBE_DY)


def _probes_reference(img: np.ndarray, rect: tuple[int, int, int, int]) -> tuple[int, int, int]:
    """``_probes`` in Python (the reference, and installs without numba)."""
    x, y, w, h = rect
    cx, cy = x + 0.5 * (w - 1), y + 0.5 * (h - 1)
    middle, white = (_brightest_probe(img, cx, cy, f * w, f * h, directions) for f, directions in _SMALL_PROBES)
    return middle, white, int(cv2.minMaxLoc(img[y : y + h, x : x + w])[0])


def _brightest_probe(img: np.ndarray, cx: float, cy: float, reach_x: float, reach_y: float,
                     directions: tuple[tuple[float, float], ...]) -> int:
    """The brightest pixel of ``img`` at (cx + reach_x dx, cy + reach_y dy) for each (dx, dy) of ``directions``,
    rounded half up and clamped to the image (0 for none brighter)."""
    last_row, last_col = img.shape[0] - 1, img.shape[1] - 1
    best = 0
    for dx, dy in directions:
        row, col = int(cy + reach_y * dy + 0.5), int(cx + reach_x * dx + 0.5)
        v = img.item(0 if row < 0 else last_row if row > last_row else row,
                     0 if col < 0 else last_col if col > last_col else col)
        if v > best:
            best = v
    return best
