"""Concentric ellipse pairs of the dark blobs of a binary image."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect import hole_kernel
from livetrack.estimator.detect.arcs import (
    BOXES_AT_ONCE,
    _ring_around_middle,
    arc_outlines,
    arcs_outline,
    blob_boxes,
    off_notches,
)
from livetrack.estimator.detect.fit_kernel import fit_distances, hull_area
from livetrack.estimator.detect.hole_kernel import closed_with_hole, dark_on_bands
from livetrack.estimator.detect.options import DetectOptions
from livetrack.estimator.detect.threshold import _DISK5, _DISK7, SATURATED_LEVEL

FloatArray = npt.NDArray[np.float64]


# ---------------------------------------------------------------------- ellipse pairs in a binary image
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


def _convex(contour: np.ndarray, area: float) -> bool:
    """Solidity test: an ellipse's pixel boundary fills nearly all of its convex hull (texture blobs do not). The
    hull's area compiled (``fit_kernel.hull_area``: ``cv2.contourArea(cv2.convexHull(...))``'s value)."""
    return area >= 0.9 * hull_area(contour) - 2.0


def _ratio_bounds(x: float, ratio: float, bias_px: float, tol: float) -> tuple[float, float]:
    """Range of (inner / outer) semi-axis ratios accepted for an outer semi-axis of x pixels: each edge may
    move by ``bias_px`` toward either side, plus a relative tolerance ``tol``."""
    lo = (ratio * x - bias_px) / (x + bias_px) * (1.0 - tol)
    hi = (ratio * x + bias_px) / max(x - bias_px, 1e-9) * (1.0 + tol)
    return lo, hi


def _ratio_ok(outer: Ellipse, inner: Ellipse, ratio: float, bias_px: float, tol: float,
              max_shift: float = 0.0) -> bool:
    """Both semi-axis ratios within ``_ratio_bounds``, or (``max_shift`` > 0) within what an exposure shift of
    each edge by up to ``max_shift`` outer radii gives, ``(ratio + d) / (1 - d)`` for ``|d| <= max_shift``, with
    the relative tolerance ``tol``."""
    s_lo, s_hi = (ratio - max_shift) / (1.0 + max_shift), (ratio + max_shift) / (1.0 - max_shift)
    for xo, xi in ((outer.a, inner.a), (outer.b, inner.b)):
        lo, hi = _ratio_bounds(xo, ratio, bias_px, tol)
        if max_shift > 0.0:
            lo, hi = min(lo, s_lo * (1.0 - tol)), max(hi, s_hi * (1.0 + tol))
        if not lo <= xi / xo <= hi:
            return False
    return True


def _contours(binary: np.ndarray, box: tuple[int, int, int, int] | None = None
              ) -> tuple[tuple[np.ndarray, ...], np.ndarray | None]:
    """``cv2.findContours`` (two-level hierarchy, all points) of a binary image. On a large image, or given
    ``box``, only over the bounding box of its non-zero pixels with a 1 px margin (points shifted back): the same
    contours in the same order, without the scan of (and copy of) the empty rest, which costs more than the box
    when the dark pixels are clustered (``cv2.boundingRect`` of the image: ~10 us per 2 Mpx, against ~0.17 ms for
    two numpy max-reductions).

    ``box``: (x0, y0, x1, y1; exclusive ends, clipped to the image here) outside which ``binary`` is zero, e.g.
    the threshold's box of its dark pixels: no ``cv2.boundingRect`` scan then (~0.2 ms at 1920x1200). Any such
    box gives the same contours: the crop's raster order is the image's, and its margin is zero as the image's
    pixels there are."""
    if box is None:
        if binary.size < 100_000:
            return cv2.findContours(binary, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
        bx, by, bw, bh = cv2.boundingRect(binary)
        box = (bx, by, bx + bw, by + bh)
    if box[2] <= box[0] or box[3] <= box[1]:
        return (), None
    y0, y1 = max(box[1] - 1, 0), min(box[3] + 1, binary.shape[0])
    x0, x1 = max(box[0] - 1, 0), min(box[2] + 1, binary.shape[1])
    if x1 <= x0 or y1 <= y0:
        return (), None
    return cv2.findContours(binary[y0:y1, x0:x1], cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE, offset=(x0, y0))


def _pairs(binary: np.ndarray, a_lo: float, a_hi: float, ratios: list[float], bias_px: float,
           opts: DetectOptions, closed_retry: list[tuple[Ellipse, Ellipse]] | None = None,
           note: Callable[[float, float, float, str], None] | None = None,
           from_holes: list[tuple[Ellipse, Ellipse, str]] | None = None,
           small_blobs: SmallBlobs | None = None, trim: bool = False,
           close_own: bool = False, box: tuple[int, int, int, int] | None = None,
           open_rings: list[Ellipse] | None = None,
           hole_ratios: list[float] | None = None, large_holes: bool = True,
           trimmed: list[tuple[Ellipse, Ellipse]] | None = None,
           disks: bool = False, disk_holes: bool = False) -> list[tuple[Ellipse, Ellipse]]:
    """Concentric (outer boundary, hole) ellipse pairs of the dark blobs in ``binary`` (255 = dark) whose outer
    semi-axes a >= b have a >= a_lo, b <= a_hi, a <= 3 a_hi (pixels; an oblique target is searched where its
    minor axis fits), and whose semi-axis ratios match one of ``ratios``.

    ``closed_retry`` (a list): a blob with a hole that gives no pair is tried once more on its own crop with white
    gaps up to ~4 px closed (a disk of 5 px), and what that finds is appended to ``closed_retry`` (the caller
    ranks it after the plain pairs): on a small target the thin black band between the inner disk and a code dot
    gives way (blur, over-exposure) and the hole is the disk with a dot attached; closing cuts the neck and fills
    the dot. Only such blobs pay for it (a closing pass over the whole level cost half as much again).

    ``note`` (a diagnostic): called with (centre x, y, half size, reason) for every dark blob of about the
    searched size that gives no pair (``TraceEvent``).

    ``from_holes`` (a list): a blob too big for a pair, or whose outline is no ellipse, or whose holes are off its
    middle (a ring merged with dark ground, a target printed without a sheet), is also tried from each of its
    holes alone (``_hole_pairs``); what that finds is appended to ``from_holes`` with how its outer edge was
    placed (the caller reads their codes more strictly). ``hole_ratios``: the radius ratios tried from the holes
    (default ``ratios``); ``large_holes``: False: not from the holes of blobs too big for a pair; ``disk_holes``:
    also the tiny rings' inner disks (``_hole_pairs(disks=True)``). ``disks``: the closed retry's crops give those
    (``disk_holes``).

    ``small_blobs``: the outline ellipses of the dark blobs of the searched size up to its ``max_radius_px``,
    with or without holes, that give no pair and look like a ring around a brighter middle, are appended to its
    ``found`` (the caller tries them again with their own threshold: ``refine._small_blob_pair``).

    ``trim``: an outer boundary that fits no ellipse is fitted once more without its points far off a first fit
    (``_fit_trimmed``: a fleck of texture joined to the ring by a closing).

    ``trimmed`` (a list): as ``trim``, but the pairs whose outer ellipse needed it are appended to ``trimmed``
    instead of returned (the caller re-places them on the grey image's edges: fitted to what is left of an
    outline that texture joined, a large ring's ellipse came out 3-15 % too big and up to 10 px off-centre).

    ``close_own``: the closed retry closes a small blob's own pixels first (``_pairs_closed``'s ``outline``; the
    caller asks it on the full-resolution level, where a sheet's margin of a few pixels still shows).

    ``box``: (x0, y0, x1, y1; exclusive ends) outside which ``binary`` is zero, when the caller knows one (the
    threshold's box of the dark pixels, a closing's crop): ``_contours`` then skips its scan for it.

    ``open_rings`` (a list): the outer ellipses of the blobs without a hole that are the arc of a ring cut open
    (``arcs.arc_outlines``) are appended to it."""
    contours, hierarchy = _contours(binary, box)
    if hierarchy is None or not contours:
        return []
    hier = hierarchy.reshape(-1, 4)
    lengths = np.fromiter(map(len, contours), dtype=np.int64, count=len(contours))
    min_len = max(12, int(3.5 * a_lo))
    tops = np.flatnonzero((hier[:, 3] < 0) & (hier[:, 2] >= 0) & (lengths >= min_len))
    if note is not None:
        _note_skipped(contours, hier, lengths, min_len, a_lo, a_hi, note)
    pairs = []
    # the boxes of the blobs without a hole, for both of their tests (each tests them all at once first)
    boxes = (blob_boxes(contours, np.flatnonzero((hier[:, 3] < 0) & (hier[:, 2] < 0) & (lengths >= min_len)))
             if small_blobs is not None or open_rings is not None else None)
    if small_blobs is not None:
        small_blobs.add_without_hole(contours, hier, lengths, min_len, a_lo, opts, boxes)
    if open_rings is not None:
        open_rings.extend(arc_outlines(binary, contours, hier, lengths, min_len, a_lo, a_hi, opts.min_aspect,
                                       boxes=boxes))
    least, widest, longest = 0.8 * a_lo, 1.25 * a_hi + 1, 3.2 * a_hi
    for i in tops.tolist():
        x, y, w, h = cv2.boundingRect(contours[i])
        if 0.5 * max(w, h) < least:
            continue
        if 0.5 * min(w, h) > widest or 0.5 * max(w, h) > longest:
            if note is not None:
                note(x + 0.5 * w, y + 0.5 * h, 0.5 * max(w, h), "size")
            if from_holes is not None and large_holes:
                from_holes.extend(_hole_pairs(binary, contours, hier, lengths, i, a_lo, a_hi, hole_ratios or ratios,
                                              opts, disk_holes))
            continue
        pair = _pair_of(contours, hier, lengths, i, (x, y, w, h), a_lo, a_hi, ratios, bias_px, opts, trim)
        if pair == "outer fit" and trimmed is not None:
            again = _pair_of(contours, hier, lengths, i, (x, y, w, h), a_lo, a_hi, ratios, bias_px, opts, True)
            if not isinstance(again, str):
                trimmed.append(again)
                continue
        if not isinstance(pair, str):
            pairs.append(pair)
            continue
        if from_holes is not None and pair in ("hole area/centre", "holes too small", "outer fit"):
            from_holes.extend(_hole_pairs(binary, contours, hier, lengths, i, a_lo, a_hi, hole_ratios or ratios,
                                          opts, disk_holes))
        if open_rings is not None and pair in ("hole area/centre", "holes too small"):
            # a ring cut open whose dots left holes in it (``arcs``): its inner disk is no hole
            open_rings.extend(arc_outlines(binary, contours, hier, lengths, min_len, a_lo, a_hi, opts.min_aspect,
                                           blobs=[i]))
        if note is not None:
            note(x + 0.5 * w, y + 0.5 * h, 0.5 * max(w, h), pair)
        if (small_blobs is not None and 0.5 * min(w, h) <= small_blobs.max_radius_px + 1.0
                and pair in ("inner fit/ratio", "holes too small")):
            # a notched outline only with holes too small for an inner disk. Not "hole area/centre": a 9 px
            # target at 70 deg (its ring cut off-centre) was found so, at +15-40 % of detect's CPU on text,
            # foliage and bright noise (texture blobs with holes)
            small_blobs.add(contours[i], (x, y, w, h), a_lo, opts, solid=pair != "holes too small")
        if small_blobs is not None and pair == "hole area/centre":
            small_blobs.add_arc((x, y, w, h))  # a piece of a ring cut by grown dots that still holds its inner disk
        if closed_retry is not None and min(w, h) >= 2 * a_lo - 2:
            closed_retry.extend(_pairs_closed(binary, (x, y, w, h), a_lo, a_hi, ratios, bias_px, opts,
                                              from_holes, contours[i] if close_own else None, disks))
    return pairs


@dataclass
class SmallBlobs:
    """For ``_pairs``: collects small dark blobs that gave no pair but may be a target (see ``add``)."""

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


DISK_PAIR_MAX_RADIUS_PX = 16.0
"""The largest outer semi-minor axis (full-resolution pixels) of a pair placed from its inner disk alone
(``_hole_pairs(disks=True)``, ``refine.pair_from_disk``): a tiny target printed without a sheet on texture
(9-14 px), whose ring the local threshold joins to dark ground and whose 2-3 px bands between the inner disk and
the code dots give way, keeps a clean inner disk in the grey image; its hole, where a closing gives one, is closed
rounder than the disk, the outer ellipse scaled from it too round for the band tests (seed 9's no-sheet-005, id 3:
the closed hole 5.8 x 4.9 px for the disk's 5.5 x 3.7, its scaled outer ellipse dark on 7 of 32 points at 0.95)."""
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
    outline, ``_outer_on_outline``) or "hole" (the hole scaled).

    ``disks`` (the full-resolution level): a hole that fails the band tests but is dark on the inner band, whose
    outer ellipse is at most ``DISK_PAIR_MAX_RADIUS_PX``, gives its pair as "disk" (the caller re-places it on the
    grey image's edges: ``refine.pair_from_disk``)."""
    out: list[tuple[Ellipse, Ellipse, str]] = []
    boxes: dict = {}  # ``_outline_near``'s per-blob boxes and outline
    # a hole of n outline points has at most n^2 / (2 pi) px^2 (see ``_pair_of``): its mean radius at most
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
        if not fits or not _convex(contours[hole], area):
            continue
        inner = _fit(contours[hole], -0.5, opts.min_aspect)
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
                out.append((outer, inner, "outline" if seen else "hole"))
                break
            if disks and dark[0] >= HOLE_PAIR_DARK_FRACTION and outer.b <= DISK_PAIR_MAX_RADIUS_PX:
                # dark around the hole, not at the scaled outer edge: a tiny ring's inner disk, its hole closed
                # rounder than the disk, placed on the grey image's edges (``DISK_PAIR_MAX_RADIUS_PX``)
                out.append((outer, inner, "disk"))
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
        joined = boxes[key] = (np.array(ids, dtype=np.int64), rects, outline, points, start, np.empty(n_max),
                               np.empty(n_max))
    holes, rects, outline, points, start, u, v = joined
    cx, cy = inner.centre_px.tolist()
    a, b = inner.semi_axes_px.tolist()
    n, median = hole_kernel._ring_on_outline(
        outline, points, start, rects, holes, int(hole), cx, cy, math.cos(inner.angle_rad), math.sin(inner.angle_rad),
        a, b, rho, 1.15 * a / rho + 2.0, max(0.02, 0.35 * rho / b), u, v)
    if n < 0:
        return None
    # the directions seen, of 32 (``np.unique``'s count: the values lie in 0..31)
    seen = np.count_nonzero(np.bincount((np.arctan2(v[:n], u[:n]) * (16.0 / math.pi)).astype(np.int64) % 32,
                                        minlength=32))
    if seen < HOLE_PAIR_EDGE_COVERAGE * 32:
        return None
    return inner.scaled(median / rho, 0.5), seen / 32


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


def _note_skipped(contours, hier: np.ndarray, lengths: np.ndarray, min_len: int, a_lo: float, a_hi: float,
                  note: Callable[[float, float, float, str], None]) -> None:
    """For ``_pairs``' diagnostic: the top-level blobs of about the searched size that its first filter drops
    (no hole, or a boundary too short)."""
    for i in np.flatnonzero((hier[:, 3] < 0) & ((hier[:, 2] < 0) | (lengths < min_len)) & (lengths >= 8)):
        x, y, w, h = cv2.boundingRect(contours[i])
        if 0.5 * a_lo <= 0.5 * max(w, h) <= 3.2 * a_hi:
            note(x + 0.5 * w, y + 0.5 * h, 0.5 * max(w, h), "no hole" if hier[i, 2] < 0 else "short contour")


def _pairs_closed(binary: np.ndarray, rect: tuple[int, int, int, int], a_lo: float, a_hi: float,
                  ratios: list[float], bias_px: float, opts: DetectOptions,
                  from_holes: list[tuple[Ellipse, Ellipse, str]] | None = None,
                  outline: np.ndarray | None = None, disks: bool = False) -> list[tuple[Ellipse, Ellipse]]:
    """``_pairs`` on the crop ``rect`` (x, y, w, h) of ``binary`` grown by 3 px, after closing its white gaps
    with a 5 px disk; ellipses in ``binary``'s pixels. With ``from_holes``, pairs from the closed crop's holes
    alone are appended to it (``_hole_pairs``): the closing parts an inner disk from a code dot it touched, and
    the ring is found from its hole when its outline, merged with texture, is no ellipse (a 19 px target on
    foliage, missed at x0.25-x16).

    ``outline``: the blob's outer boundary. A small blob's own pixels (``CLOSED_OWN_MAX_PX``) are closed first,
    alone, so that the closing does not join it to the dark ground beyond a thin white margin (a 12 x 19 px
    target on a small sheet on black ground at x4, its ring cut by a grown dot, the sheet's margin 1-3 px: the
    closed crop joined the ring to the ground), with a 5 px disk and then a 7 px one (the dot's gap there was
    5-6 px wide). When that gives no pair, the whole crop as before (a ring whose closed neighbour completes
    it). ``disks``: ``_pairs``' (pairs from the tiny rings' inner disks)."""
    x, y, w, h = rect
    x0, y0 = max(x - 3, 0), max(y - 3, 0)
    crop = binary[y0 : y + h + 3, x0 : x + w + 3]
    shift = np.array([x0, y0], dtype=np.float64)
    if outline is not None and min(w, h) <= CLOSED_OWN_MAX_PX:
        own = np.zeros_like(crop)
        cv2.drawContours(own, [outline], -1, 255, cv2.FILLED, offset=(-x0, -y0))
        own = cv2.bitwise_and(crop, own, dst=own)
        for disk in (_DISK5, _DISK7):
            pairs = _closed_crop_pairs(own, disk, shift, a_lo, a_hi, ratios, bias_px, opts, from_holes, disks)
            if pairs:
                return pairs
    return _closed_crop_pairs(crop, _DISK5, shift, a_lo, a_hi, ratios, bias_px, opts, from_holes, disks)


CLOSED_OWN_MAX_PX = 48
"""``_pairs_closed`` closes a blob's own pixels first only when its box's smaller side is at most this (level
pixels): a sheet's margin of a few pixels matters beside a small ring; a 300 px target at 0.4 m, closed alone on
level 3, gave a pair 60 px off its centre (its rings far from concentric in the image) and a failed pose. Only
on level 0 (``_pairs(close_own=...)``): a 390 px target on level 4, a 24 px blob there, gave a pair 10 % too
large and a pose 7 % short; on level 1, a 40 x 64 px target in foliage at x8 (held-out seed 5) a pair nearer
the truth than the whole crop's, from which its pose fit converged 4.7 % short (1.0 % from the other)."""


def _closed_crop_pairs(crop: np.ndarray, disk: np.ndarray, shift: FloatArray, a_lo: float, a_hi: float,
                       ratios: list[float], bias_px: float, opts: DetectOptions,
                       from_holes: list[tuple[Ellipse, Ellipse, str]] | None,
                       disks: bool = False) -> list[tuple[Ellipse, Ellipse]]:
    """``_pairs_closed``'s work on one crop (its origin ``shift`` in the binary image), closed with ``disk``."""
    # closed, or None without a hole: no blob with a hole, no pair (most of these crops on textured ground)
    closed = closed_with_hole(crop, disk)
    if closed is None:
        return []
    holes: list[tuple[Ellipse, Ellipse, str]] | None = None if from_holes is None else []
    pairs = _shift_pairs(_pairs(closed, a_lo, a_hi, ratios, bias_px, opts, trim=True, from_holes=holes,
                                disk_holes=disks), shift)
    if holes:
        shifted = _shift_pairs([(o, i) for o, i, _ in holes], shift)
        from_holes.extend((o, i, how) for (o, i), (_, _, how) in zip(shifted, holes, strict=True))
    return pairs


def _pairs_of_arcs(binary: np.ndarray, rects: list[tuple[int, int, int, int]], a_lo: float, a_hi: float,
                   ratios: list[float], bias_px: float, opts: DetectOptions,
                   outlines: list[Ellipse] | None = None) -> list[tuple[Ellipse, Ellipse]]:
    """``_pairs`` around each group of overlapping ``rects`` (x, y, w, h; the arcs of ``SmallBlobs``), on the crop
    of ``binary`` grown by half the group's size, after closing white gaps up to ~6 px (a 7 px disk: grown dots
    of an over-exposed target of 12-30 px); ellipses in ``binary``'s pixels.

    ``outlines`` (a list): where that gives no pair, the outer ellipse of two or more of the group's arcs together
    (``arcs.arcs_outline``: a ring cut through by grown dots in two places, its pieces each under half of it) is
    appended to it (the caller re-places it on the grey image's edges as a ring cut open)."""
    out: list[tuple[Ellipse, Ellipse]] = []
    groups: list[tuple[list[int], list[tuple[int, int, int, int]]]] = []
    for rect in rects:  # merge overlapping boxes (grown by a quarter of their size)
        x, y, w, h = rect
        box = [x - w // 4, y - h // 4, x + w + w // 4, y + h + h // 4]
        for g, members in groups:
            if box[0] <= g[2] and g[0] <= box[2] and box[1] <= g[3] and g[1] <= box[3]:
                g[:] = [min(g[0], box[0]), min(g[1], box[1]), max(g[2], box[2]), max(g[3], box[3])]
                members.append(rect)
                break
        else:
            groups.append((box, [rect]))
    for (gx0, gy0, gx1, gy1), members in groups:
        m = max(gx1 - gx0, gy1 - gy0) // 2 + 3
        x0, y0 = max(gx0 - m, 0), max(gy0 - m, 0)
        crop = binary[y0 : gy1 + m, x0 : gx1 + m]
        closed = closed_with_hole(crop, _DISK7)
        pairs = [] if closed is None else _pairs(closed, a_lo, a_hi, ratios, bias_px, opts, trim=True)
        shift = np.array([x0, y0], dtype=np.float64)
        out += _shift_pairs(pairs, shift)
        if not pairs and outlines is not None:
            outer = _outline_of_pieces(crop, [(x - x0, y - y0, w, h) for x, y, w, h in set(members)], opts)
            if outer is not None and outer.a >= a_lo - 0.5 and outer.b <= a_hi:
                outlines.append(Ellipse(outer.centre_px + shift, outer.semi_axes_px, outer.angle_rad))
    return out


def _outline_of_pieces(crop: np.ndarray, rects: list[tuple[int, int, int, int]], opts: DetectOptions
                       ) -> Ellipse | None:
    """``arcs.arcs_outline`` of the blobs of ``crop`` whose bounding boxes are ``rects`` (x, y, w, h in the crop)
    with every other blob inside the crop of at least ``PIECE_MIN_SHARE`` of the largest one's outline (the
    other pieces of the ring need not be arcs of ``SmallBlobs``: a half ring's box has a dark middle), else with
    each of those alone."""
    contours, _ = cv2.findContours(crop, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    wanted = set(rects)
    own = [c for c in contours if cv2.boundingRect(c) in wanted]
    if not own:
        return None
    least = PIECE_MIN_SHARE * max(len(c) for c in own)
    h, w = crop.shape
    ox0, oy0 = min(r[0] for r in wanted), min(r[1] for r in wanted)
    ox1, oy1 = max(r[0] + r[2] for r in wanted), max(r[1] + r[3] for r in wanted)
    grow = max(ox1 - ox0, oy1 - oy0) // 4 + 1
    others = []
    for c in contours:
        if len(c) < least:
            continue
        x, y, cw, ch = cv2.boundingRect(c)
        if ((x, y, cw, ch) not in wanted and x > 0 and y > 0 and x + cw < w and y + ch < h
                and x <= ox1 + grow and ox0 - grow <= x + cw and y <= oy1 + grow and oy0 - grow <= y + ch):
            others.append(c)
    if len(others) > PIECE_MAX_OTHERS or len(own) + len(others) < 2:
        return None
    for group in [own + others] + ([own + [o] for o in others] if len(others) > 1 else []):
        # (cheap first: the pieces' joint box must have a bright middle ringed by dark probes)
        boxes = np.array([cv2.boundingRect(c) for c in group])
        x0, y0 = boxes[:, :2].min(axis=0)
        x1, y1 = (boxes[:, :2] + boxes[:, 2:]).max(axis=0)
        if not _ring_around_middle(crop, int(x0), int(y0), int(x1 - x0), int(y1 - y0)):
            continue
        outer = arcs_outline(group, crop, opts.min_aspect)
        if outer is not None:
            return outer
    return None


PIECE_MIN_SHARE = 0.3
PIECE_MAX_OTHERS = 4
"""``_outline_of_pieces``: the other blobs taken are those of at least ``PIECE_MIN_SHARE`` of the largest arc's
outline points whose boxes reach within a quarter of the arcs' box of it, at most ``PIECE_MAX_OTHERS`` of them
(more: texture, not a ring's pieces)."""


def _shift_pairs(pairs: list[tuple[Ellipse, Ellipse]], shift: FloatArray) -> list[tuple[Ellipse, Ellipse]]:
    return [(Ellipse(o.centre_px + shift, o.semi_axes_px, o.angle_rad),
             Ellipse(i.centre_px + shift, i.semi_axes_px, i.angle_rad)) for o, i in pairs]


def _pair_of(contours, hier: np.ndarray, lengths: np.ndarray, i: int, rect: tuple[int, int, int, int],
             a_lo: float, a_hi: float, ratios: list[float], bias_px: float,
             opts: DetectOptions, trim: bool = False) -> tuple[Ellipse, Ellipse] | str:
    """For ``_pairs``: the pair of the top-level contour ``i`` (bounding ``rect``) and its best hole, or why
    there is none."""
    x, y, w, h = rect
    # Cheap tests before any fit: a hole near the blob's middle whose area is about (r/R)^2 of the blob's
    # (pixel-centre contours sit half a pixel inside the dark blob, hence the +-1 px).
    area = abs(cv2.contourArea(contours[i]))
    radius = math.sqrt(area / math.pi)
    bounds = [_ratio_bounds(radius, r, bias_px + 1.0, opts.ratio_tolerance) for r in ratios]
    lo2, hi2 = min(lo for lo, _ in bounds) ** 2, max(hi for _, hi in bounds) ** 2
    mid_x, mid_y, tol = x + 0.5 * w, y + 0.5 * h, opts.centre_tolerance * 0.5 * max(w, h) + 2.0
    holes = []
    small_only = True
    # a hole's area is taken only where it can matter: a hole of n outline points (neighbours: steps of at most
    # sqrt(2) px) has at most n^2 / (2 pi) px^2 (the isoperimetric inequality), under lo2 of the blob's below
    # ``small_n2``; one of under 6 points counts only while every hole so far is small (textured blobs: a
    # thousand holes a frame, most of a few points)
    least_area = max(area, 1.0)
    small_n2 = lo2 * least_area * (2.0 * math.pi) * (1.0 - 1e-6)
    j = hier.item(i, 2)
    while j >= 0:
        n = lengths.item(j)
        if n * n >= small_n2 and (n >= 6 or small_only):
            share = abs(cv2.contourArea(contours[j])) / least_area
            small_only = small_only and share < lo2
            if n >= 6 and lo2 <= share <= hi2:
                hx, hy, hw, hh = cv2.boundingRect(contours[j])
                if abs(hx + 0.5 * hw - mid_x) <= tol and abs(hy + 0.5 * hh - mid_y) <= tol:
                    holes.append(j)
        j = hier.item(j, 0)
    if not holes:
        return "holes too small" if small_only else "hole area/centre"
    if _convex(contours[i], area):
        outer = _fit(contours[i], 0.5, opts.min_aspect)
    else:  # notched (white dots grown into the outer edge, or a cut ring closed by the closing pass)
        outer = _fit_without_notches(contours[i], 0.5, opts.min_aspect)
    if outer is None and trim:
        outer = _fit_trimmed(contours[i], 0.5, opts.min_aspect)
    if outer is None:
        return "outer fit"
    if outer.a < a_lo - 0.5 or outer.b > a_hi or outer.a > 3.0 * a_hi:
        return "outer size"
    best: Ellipse | None = None
    for j in holes:
        if not _convex(contours[j], abs(cv2.contourArea(contours[j]))):
            continue
        inner = _fit(contours[j], -0.5, opts.min_aspect)
        if (inner is not None
                and np.hypot(inner.centre_px[0] - outer.centre_px[0], inner.centre_px[1] - outer.centre_px[1])
                <= opts.centre_tolerance * outer.a + 1.0
                and any(_ratio_ok(outer, inner, r, bias_px, opts.ratio_tolerance) for r in ratios)
                and (best is None or inner.a > best.a)):
            best = inner
    return "inner fit/ratio" if best is None else (outer, best)


def _same_place(e1: Ellipse, e2: Ellipse, size_ratio: float = 1.4) -> bool:
    """Whether two ellipses lie at one place: their centres within a quarter of the smaller semi-minor axis plus a
    pixel, and ``e1``'s semi-major axis within ``size_ratio`` of ``e2``'s either way (``_places_match``)."""
    return _places_match(_place(e1), _place(e2), size_ratio)


def _place(e: Ellipse) -> tuple[float, float, float, float]:
    """An ellipse's centre and semi-axes as plain floats (x, y, a, b), for ``_places_match`` in a loop."""
    x, y = e.centre_px.tolist()
    a, b = e.semi_axes_px.tolist()
    return x, y, a, b


def _places_match(p: tuple[float, float, float, float], q: tuple[float, float, float, float],
                  size_ratio: float = 1.4) -> bool:
    """``_same_place`` of two ``_place``s: the distance between the centres is numpy's hypot as before, taken only
    when each of its components is within the reach (it is at least either), and the size test first: the same
    answers on plain floats (the deduplication of a textured frame's ~50 pairs made ~1600 of these tests with
    numpy scalars, ~2 ms)."""
    dx, dy = p[0] - q[0], p[1] - q[1]
    reach = 0.25 * min(p[3], q[3]) + 1.0
    return (abs(dx) <= reach and abs(dy) <= reach and 1.0 / size_ratio <= p[2] / q[2] <= size_ratio
            and bool(np.hypot(dx, dy) <= reach))


def _dedupe_ellipses(ellipses: list[Ellipse]) -> list[Ellipse]:
    """``ellipses`` in order without those at ``_same_place`` as one kept before; the test on plain floats (numpy
    scalars made it ~10x slower: a thousand small blobs of foliage cost ~14 ms a frame), against the kept ones near
    enough to pass it only (``_PlaceGrid``: the test against every kept one cost ~25 ms on a frame of printed
    text)."""
    kept: list[Ellipse] = []
    grid = _PlaceGrid()
    for e in ellipses:
        cx, cy = e.centre_px.tolist()
        a, b = e.semi_axes_px.tolist()
        for kx, ky, ka, kb in grid.near(cx, cy, b):
            dx, dy, reach = cx - kx, cy - ky, 0.25 * min(b, kb) + 1.0  # hypot is at least |dx| and |dy|
            if (abs(dx) <= reach and abs(dy) <= reach and math.hypot(dx, dy) <= reach
                    and 1.0 / 1.4 <= a / ka <= 1.4):
                break
        else:
            kept.append(e)
            grid.add((cx, cy, a, b))
    return kept


def _dedupe_pairs(pairs: list[tuple[int, Ellipse, Ellipse, str]]) -> list[tuple[int, Ellipse, Ellipse, str]]:
    """``pairs`` by level (stable) without those whose outer ellipse is at ``_same_place`` as a kept one's (tested
    against the kept ones near enough only: ``_PlaceGrid``)."""
    kept: list[tuple[int, Ellipse, Ellipse, str]] = []
    grid = _PlaceGrid()
    for pair in sorted(pairs, key=lambda p: p[0]):
        place = _place(pair[1])
        if not grid.matches(place):
            kept.append(pair)
            grid.add(place)
    return kept


class _PlaceGrid:
    """Places (x, y, a, b: ``_place``) by the square of ``PLACE_CELL_PX`` their centre lies in, for the tests of
    ``_places_match`` and ``_dedupe_ellipses`` against many kept places: both need each centre offset within
    0.25 min(b, b') + 1 <= 0.25 b + 1 (b: the semi-minor axis of the place tested), so only the places in the
    squares within that reach of its centre, and one square more each way (against the subtraction's rounding),
    can pass; ``near`` returns those (a superset, in no particular order: the tests only ask whether any passes).
    A reach or centre that is not finite, or that spans more squares than are filled, reads every place, and so
    do fewer than ``PLACE_GRID_FROM`` places (not filed by square: the bench's frames keep a dozen)."""

    def __init__(self, places: list[tuple[float, float, float, float]] = ()) -> None:
        self.cells: dict[tuple[int, int], list[tuple[float, float, float, float]]] | None = None
        self.every: list[tuple[float, float, float, float]] = []
        for place in places:
            self.add(place)

    def add(self, place: tuple[float, float, float, float]) -> None:
        self.every.append(place)
        if self.cells is None:  # the squares only from PLACE_GRID_FROM places on (below, reading all costs less)
            if len(self.every) < PLACE_GRID_FROM:
                return
            self.cells = {}
            for kept in self.every:
                self._file(kept)
        else:
            self._file(place)

    def _file(self, place: tuple[float, float, float, float]) -> None:
        x, y = place[0], place[1]
        if math.isfinite(x) and math.isfinite(y):  # (a place off every square matches no finite reach)
            key = (math.floor(x / PLACE_CELL_PX), math.floor(y / PLACE_CELL_PX))
            cell = self.cells.get(key)
            if cell is None:
                self.cells[key] = [place]
            else:
                cell.append(place)

    def matches(self, place: tuple[float, float, float, float]) -> bool:
        """Whether ``_places_match(place, k)`` for a kept place k."""
        return any(_places_match(place, k) for k in self.near(place[0], place[1], place[3]))

    def near(self, x: float, y: float, b: float) -> list[tuple[float, float, float, float]]:
        reach = 0.25 * b + 1.0
        if self.cells is None or not (math.isfinite(x) and math.isfinite(y) and math.isfinite(reach)):
            return self.every
        c0, c1 = math.floor((x - reach) / PLACE_CELL_PX) - 1, math.floor((x + reach) / PLACE_CELL_PX) + 1
        r0, r1 = math.floor((y - reach) / PLACE_CELL_PX) - 1, math.floor((y + reach) / PLACE_CELL_PX) + 1
        if (c1 - c0 + 1) * (r1 - r0 + 1) > len(self.cells):
            return self.every
        out: list[tuple[float, float, float, float]] = []
        cells = self.cells
        for col in range(c0, c1 + 1):
            for row in range(r0, r1 + 1):
                cell = cells.get((col, row))
                if cell is not None:
                    out += cell
        return out


PLACE_CELL_PX = 16.0
PLACE_GRID_FROM = 32
"""``_PlaceGrid``'s square side (pixels of the level or image the places are in), and how many places it keeps
before it files them by square (fewer are read all)."""
