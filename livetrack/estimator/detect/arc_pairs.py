"""Ellipse pairs around the arcs that ``small_blobs.SmallBlobs`` collected in a clipped frame: a small
over-exposed ring cut into arcs by its grown code dots (its inner disk joined to the ground through them, so no
blob has a hole).

``_pairs_of_arcs`` groups overlapping arcs and runs the main pairing (``pairs._pairs``) on each group's crop after
closing the gaps the dots cut; where that gives no pair, the outer ellipse of the group's pieces together
(``_outline_of_pieces``, ``arcs.arcs_outline``: a ring cut through in two places) is handed back for the caller to
re-place on the grey image's edges."""

from __future__ import annotations

import cv2
import numpy as np

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect.arcs import _ring_around_middle, arcs_outline
from livetrack.estimator.detect.hole_kernel import closed_with_hole
from livetrack.estimator.detect.options import DetectOptions
from livetrack.estimator.detect.pairs import _pairs, _shift_pairs
from livetrack.estimator.detect.threshold import _DISK7


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
