"""Concentric ellipse pairs of the dark blobs of a binary image: the detector's main pairing.

``_pairs`` traces the contours of a binary image (``_contours``) and pairs each dark blob's outer boundary with
its best hole (``_pair_of``: cheap area and centre tests, then the fits of ``fits``, then the radius-ratio test
``_ratio_ok``, which ``code`` also applies); blobs that give no pair are retried on a closed crop
(``_pairs_closed``), from their holes alone (``hole_pairs``), as small blobs (``small_blobs``) or as arcs of a ring
cut open (``arcs``), as the caller asks. The arcs the small blobs collect are paired in ``arc_pairs``;
de-duplication by place is in ``places``."""

from __future__ import annotations

import math
from collections.abc import Callable

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect.arcs import arc_outlines, blob_boxes, open_middles
from livetrack.estimator.detect.blob_kernel import top_blobs
from livetrack.estimator.detect.fits import (
    _convex,
    _fit,
    _fit_trimmed,
    _fit_with_a_dot,
    _fit_without_bumps,
    _fit_without_notches,
)
from livetrack.estimator.detect.hole_kernel import closed_with_hole
from livetrack.estimator.detect.hole_pairs import _hole_pairs
from livetrack.estimator.detect.options import DetectOptions
from livetrack.estimator.detect.outline_edges import HaloTest
from livetrack.estimator.detect.small_blobs import SmallBlobs
from livetrack.estimator.detect.threshold import _DISK5, _DISK7

FloatArray = npt.NDArray[np.float64]


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
           disks: bool = False, disk_holes: bool = False,
           holes_a_lo: float | None = None,
           bumpy: list[tuple[Ellipse, Ellipse]] | None = None,
           grey: np.ndarray | None = None, edge_depth: float = 0.0,
           found_px: list[tuple[float, float]] | None = None,
           known: list[tuple[float, float, float, float]] | None = None,
           arc_boxes: list[tuple[int, int, int, int]] | None = None) -> list[tuple[Ellipse, Ellipse]]:
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
    (``arcs.arc_outlines``) are appended to it.

    ``bumpy`` (a list): a blob whose holes fit no inner ellipse is paired once more with each hole that is no
    ellipse fitted without its bumps (``_pair_of(bumps=True)``: dots joined to the inner disk across a band that a
    strong tilt thinned), and such pairs are appended to it (the caller reads them as a last resort: read
    with the others, one took the place of a found 13.5 px target's pair and lost it, seed 0's border-003 x0.25).

    ``grey`` (the level's grey image, which ``binary`` thresholds), ``edge_depth`` (the threshold's depth, its
    levels) and ``found_px`` (the centres, in ``binary``'s pixels, of pairs found before this call): a blob that is
    a threshold's halo round a pair (``outline_edges.HaloTest``) gets no closed retry. Every blob is paired before
    any is retried, so the pairs of this call count too.

    ``arc_boxes`` (a list): the bounding boxes (x, y, w, h) of the blobs of the searched size that may be a piece of
    a ring cut through (``arc_pairs.arc_like``: not dark in their middle, or paired with no hole fitting their
    middle) are appended to it (the caller groups them: ``arc_pairs._pairs_of_arcs``).

    ``known``: the bounding boxes (centre x, y and half sizes, ``binary``'s pixels) of the outer ellipses of pairs
    already found (a finer level's, this level's plain pass's): a blob whose box is one of them
    (``_at_known_place``) is not examined at all. Its pair would lie at that place and give way to the pair found
    there first (``places._dedupe_pairs`` keeps the finest level's, then the plain pass's)."""
    contours, hierarchy = _contours(binary, box)
    if hierarchy is None or not contours:
        return []
    hier = hierarchy.reshape(-1, 4)
    lengths = np.fromiter(map(len, contours), dtype=np.int64, count=len(contours))
    min_len = max(12, int(3.5 * a_lo))
    tops = top_blobs(hier, lengths, min_len, True)
    if note is not None:
        _note_skipped(contours, hier, lengths, min_len, a_lo, a_hi, note)
    pairs = []
    # the boxes of the blobs without a hole, for both of their tests (each tests them all at once first)
    boxes = (blob_boxes(contours, top_blobs(hier, lengths, min_len, False))
             if small_blobs is not None or open_rings is not None or arc_boxes is not None else None)
    if arc_boxes is not None:
        arc_boxes.extend(open_middles(binary, boxes, a_lo, a_hi))
    if small_blobs is not None:
        small_blobs.add_without_hole(contours, hier, lengths, min_len, a_lo, opts, boxes)
    if open_rings is not None:
        open_rings.extend(arc_outlines(binary, contours, hier, lengths, min_len, a_lo, a_hi, opts.min_aspect,
                                       boxes=boxes))
    least, widest, longest = 0.8 * a_lo, 1.25 * a_hi + 1, 3.2 * a_hi
    blobs: list[tuple[int, tuple[int, int, int, int], tuple[Ellipse, Ellipse] | str | None]] = []
    for i in tops.tolist():
        x, y, w, h = cv2.boundingRect(contours[i])
        if 0.5 * max(w, h) < least:
            continue
        if known and _at_known_place((x, y, w, h), known):
            continue
        too_big = 0.5 * min(w, h) > widest or 0.5 * max(w, h) > longest
        blobs.append((i, (x, y, w, h), None if too_big else
                      _pair_of(contours, hier, lengths, i, (x, y, w, h), a_lo, a_hi, ratios, bias_px, opts, trim)))
    halo = HaloTest(grey, edge_depth, contours, hier, blobs, found_px or []) if grey is not None else None
    for i, (x, y, w, h), pair in blobs:
        if pair is None:
            if note is not None:
                note(x + 0.5 * w, y + 0.5 * h, 0.5 * max(w, h), "size")
            if from_holes is not None and large_holes:
                from_holes.extend(_hole_pairs(binary, contours, hier, lengths, i, holes_a_lo or a_lo, a_hi,
                                              hole_ratios or ratios, opts, disk_holes))
            continue
        if pair == "inner fit/ratio" and bumpy is not None:  # (as well as the retries below)
            again = _pair_of(contours, hier, lengths, i, (x, y, w, h), a_lo, a_hi, ratios, bias_px, opts, trim,
                             bumps=True)
            if not isinstance(again, str):
                bumpy.append(again)
        if pair == "outer fit" and trimmed is not None:
            again = _pair_of(contours, hier, lengths, i, (x, y, w, h), a_lo, a_hi, ratios, bias_px, opts, True)
            if not isinstance(again, str):
                trimmed.append(again)
                continue
        if not isinstance(pair, str):
            pairs.append(pair)
            continue
        if from_holes is not None and pair in ("hole area/centre", "holes too small", "outer fit"):
            from_holes.extend(_hole_pairs(binary, contours, hier, lengths, i, holes_a_lo or a_lo, a_hi,
                                          hole_ratios or ratios, opts, disk_holes))
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
        if arc_boxes is not None and pair in ("hole area/centre", "holes too small", "outer fit"):
            arc_boxes.append((x, y, w, h))
        if small_blobs is not None and pair == "hole area/centre":
            small_blobs.add_arc((x, y, w, h))  # a piece of a ring cut by grown dots that still holds its inner disk
        if closed_retry is not None and min(w, h) >= 2 * a_lo - 2 and not (halo is not None and halo(i)):
            closed_retry.extend(_pairs_closed(binary, (x, y, w, h), a_lo, a_hi, ratios, bias_px, opts,
                                              from_holes, contours[i] if close_own else None, disks))
    return pairs



KNOWN_PLACE_CENTRE = 0.1
KNOWN_PLACE_SIZE = 0.15
"""``_at_known_place``: a blob's bounding box is a known pair's when its centre is within ``KNOWN_PLACE_CENTRE`` of
the pair's half size (the smaller) plus a pixel, and each half side within ``KNOWN_PLACE_SIZE`` of the pair's plus
a pixel: its pair, if any, then lies well within ``places._same_place`` of the known one (centres within a quarter
of the semi-minor axis plus a pixel, semi-major axes within 1.4x)."""


def _at_known_place(rect: tuple[int, int, int, int], known: list[tuple[float, float, float, float]]) -> bool:
    """Whether the box ``rect`` (x, y, w, h of a contour of pixel centres) is one of ``known`` (centre x, y and half
    sizes of an ellipse's bounding box, the same pixels) within ``KNOWN_PLACE_CENTRE`` and ``KNOWN_PLACE_SIZE``."""
    x, y, w, h = rect
    cx, cy, hx, hy = x + 0.5 * (w - 1), y + 0.5 * (h - 1), 0.5 * w, 0.5 * h
    for kx, ky, khx, khy in known:
        reach = KNOWN_PLACE_CENTRE * min(khx, khy) + 1.0
        if (abs(cx - kx) <= reach and abs(cy - ky) <= reach and abs(hx - khx) <= KNOWN_PLACE_SIZE * khx + 1.0
                and abs(hy - khy) <= KNOWN_PLACE_SIZE * khy + 1.0):
            return True
    return False


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


def _shift_pairs(pairs: list[tuple[Ellipse, Ellipse]], shift: FloatArray) -> list[tuple[Ellipse, Ellipse]]:
    return [(Ellipse(o.centre_px + shift, o.semi_axes_px, o.angle_rad),
             Ellipse(i.centre_px + shift, i.semi_axes_px, i.angle_rad)) for o, i in pairs]


def _pair_of(contours, hier: np.ndarray, lengths: np.ndarray, i: int, rect: tuple[int, int, int, int],
             a_lo: float, a_hi: float, ratios: list[float], bias_px: float,
             opts: DetectOptions, trim: bool = False, bumps: bool = False) -> tuple[Ellipse, Ellipse] | str:
    """For ``_pairs``: the pair of the top-level contour ``i`` (bounding ``rect``) and its best hole, or why
    there is none. ``bumps``: a hole that fits no ellipse is fitted without its bumps, a convex one through a neck
    (``fits._fit_with_a_dot``), one that is not convex as a disk with dots joined (``fits._fit_without_bumps``:
    seed 4's no-sheet-000 at x0.5, solidity 0.89); see ``_pairs(bumpy=...)``."""
    x, y, w, h = rect
    # Cheap tests before any fit: a hole near the blob's middle whose area is about (r/R)^2 of the blob's
    # (pixel-centre contours sit half a pixel inside the dark blob, hence the +-1 px).
    area = abs(cv2.contourArea(contours[i]))
    radius = math.sqrt(area / math.pi)
    lo_min = hi_max = None  # the least and greatest bounds over the ratios (as min() and max() of them)
    for r in ratios:
        lo, hi = _ratio_bounds(radius, r, bias_px + 1.0, opts.ratio_tolerance)
        if lo_min is None or lo < lo_min:
            lo_min = lo
        if hi_max is None or hi > hi_max:
            hi_max = hi
    if lo_min is None or hi_max is None:
        raise ValueError("no radius ratio to pair with")  # (min() of no bounds raised so before)
    lo2, hi2 = lo_min**2, hi_max**2
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
        hole_area = abs(cv2.contourArea(contours[j]))
        if not _convex(contours[j], hole_area):
            if not bumps:
                continue
            inner = _fit_without_bumps(contours[j], hole_area, -0.5, opts.min_aspect)  # dots joined to the disk
        else:
            inner = _fit(contours[j], -0.5, opts.min_aspect)
            if inner is None and bumps:
                inner = _fit_with_a_dot(contours[j], hole_area, -0.5, opts.min_aspect)
        if (inner is not None
                and np.hypot(inner.centre_px[0] - outer.centre_px[0], inner.centre_px[1] - outer.centre_px[1])
                <= opts.centre_tolerance * outer.a + 1.0
                and any(_ratio_ok(outer, inner, r, bias_px, opts.ratio_tolerance) for r in ratios)
                and (best is None or inner.a > best.a)):
            best = inner
    return "inner fit/ratio" if best is None else (outer, best)
