"""The coarse detector's entry point: pyramid, pairs, refinement, identification (see the package docstring)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect.arc_pairs import _pairs_of_arcs
from livetrack.estimator.detect.fits import _FIT_MEMO
from livetrack.estimator.detect.geometry import _geometry_groups
from livetrack.estimator.detect.hole_pairs import (
    BUMPS,
    DARK_GROUND,
    DISK_PAIR_MAX_RADIUS_PX,
    HOLE_PAIR_MAX_CODE_DISTANCE,
    HOLE_PAIR_MAX_RADIUS_PX,
    HOLE_PAIR_MIN_CODE_MARGIN,
    HOLE_PAIR_MIN_DOTS,
)
from livetrack.estimator.detect.levels import _dedupe_candidates, _nest, _shifted
from livetrack.estimator.detect.options import DetectOptions
from livetrack.estimator.detect.pairs import _pairs
from livetrack.estimator.detect.places import _dedupe_ellipses, _dedupe_pairs, _place, _PlaceGrid
from livetrack.estimator.detect.refine import (
    SMALL_BLOB_MAX_RADIUS_PX,
    _refine,
    _small_blob_pair,
    outer_edge_seen,
    pair_from_disk,
    pair_from_edges,
    ring_above_ground,
)
from livetrack.estimator.detect.results import Candidate, TraceEvent
from livetrack.estimator.detect.small_blobs import SmallBlobs
from livetrack.estimator.detect.threshold import (
    _DISK7,
    _KERNEL3,
    SATURATED_LEVEL,
    _blurred_for_noise,
    _clipped_dark_box,
    _closed,
    _dark_box,
    _fused_blur,
    _noise,
    _normalise_halved,
    _offset,
    _WorkImages,
)
from livetrack.estimator.detect.whole_image import _WholeImageReader
from livetrack.targets.spec import TargetSpec

FloatArray = npt.NDArray[np.float64]

LIFTED = " (lifted)"
"""Appended to how a pair from a hole alone of the lifted binary image was placed (``LIFTED_HOLES``)."""
_LIFTED_KINDS = tuple(kind + bumps + LIFTED for kind in ("hole", "outline", "hole, edges", "disk", DARK_GROUND)
                      for bumps in ("", BUMPS))
FROM_HOLE = ("hole", "outline", "hole, edges", "arc", "arc, over-exposed", "disk", DARK_GROUND) + tuple(
    kind + BUMPS for kind in ("hole", "outline", "hole, edges", "disk", DARK_GROUND)) + _LIFTED_KINDS
"""How a pair found from a hole alone (``_hole_pairs``) had its outer edge placed: scaled from the hole, read off
its blob's outline, or (a tiny ring's inner disk, "disk") on the grey image's edges (``refine.pair_from_disk``).
All are read with the strict code rules; a sparse code (under ``HOLE_PAIR_MIN_DOTS`` dots) only from "outline"
(or with its outer edge seen: ``HOLE_PAIR_EDGE_SEEN``): id 1's two dots on a 36 px target printed without a sheet
on a chessboard (its ring merged with the squares) were refused at every exposure, though its outer edge ran
along the outline in half the directions."""
def _hole_kind(outer: Ellipse, how: str, scale: float) -> str:
    """How a pair from a hole alone (``_hole_pairs``' kind ``how``, its outer ellipse ``outer`` in the pixels of a
    level ``scale`` times coarser) is read: as found, or a large one re-placed on the grey image's edges first
    ("hole, edges", ``LARGE_HOLE_PAIR_EDGE_SEEN``)."""
    if outer.a * scale <= HOLE_PAIR_MAX_RADIUS_PX:
        return how
    return "hole, edges" + (BUMPS if how.endswith(BUMPS) else "")


COARSE_ARC = "arcs, coarse"
"""A pair of a coarse level's pieces of a ring closed on their crop (``COARSE_ARCS``); a ``LAST_RESORT``."""
LAST_RESORT = ("lifted, edges", "disk", "arc, over-exposed", DARK_GROUND, COARSE_ARC) + tuple(
    kind + BUMPS for kind in ("plain", "closed", "hole", "outline", "hole, edges", "disk", DARK_GROUND)) + _LIFTED_KINDS
"""Pairs read only where no other pair gave a candidate (``LIFTED_TRIMMED_OUTER_FROM``, ``refine.pair_from_disk``,
``_pairs_of_open_rings``' over-exposed ratios: read with the usual arcs, they moved two found x32 targets' poses by
0.005-0.02 points, for the worse):
read first, they changed the pose of targets found before (the pair read first sets the edge profiles' start) for
the worse as often as not, and a "disk" pair, kept over a coarser level's hole pair at one place, read no code
where that pair had (seed 2's border-001 x8, lost)."""

MISREAD = ("gaps between slots white", "no code match", "code margin")
"""A pair whose code reading failed with one of these reasons (or whose radius ratio matched no design) is read
again on the grey image's edges (``refine.pair_from_edges``): a ring with a white disk, its code slots sampled off
the dots. Over the detection sweep's seeds 0-3 every pair that re-read found a target had failed so; on textured
1920x1200 frames without targets three quarters of the failed pairs had failed before ("black bands not dark"),
and re-reading every one cost ~18 % of detect there."""

HOLE_MISREAD = ("inner disk not white",)
"""A pair from a hole alone ("hole") whose reading failed with one of these reasons is also read again on the grey
image's edges: its inner ellipse is the hole of a coarse level, pixels off (a 20 px target in dark foliage without a
sheet, paired on level 1 at x1 and x2: the hole 9.9 x 9.2 px for the truth's 8.2-8.6, the white disk's samples on
its blurred edge, "inner disk not white")."""
HOLE_PAIR_EDGE_PLACED = 0.3
"""A "hole" pair's outer ellipse is rescaled to where the image shows its outer edge when it does so in this share
of the directions (``refine.outer_edge_seen``): a 29 px target in dark foliage, paired from its hole on a coarse
level, had its outer ellipse 16 % too large and its code read as none; its edge showed in 12 of 32 directions,
at 0.87 of it (the truth: 0.86). Its code is read next with the strict rules; the rescale alone decides
nothing."""
LARGE_HOLE_PAIR_EDGE_SEEN = 0.5
"""A pair from a hole alone whose outer ellipse exceeds ``HOLE_PAIR_MAX_RADIUS_PX`` ("hole, edges") is kept only
re-placed on the grey image's edges (``refine.pair_from_edges``), its outer edge seen in this share of the
directions at least: the hole scaled misses a large tilted ring's outer edge by pixels (the perspective), and a
ring that large whose outline the threshold could not fit is merged with dark ground around much of it (a 192 px
target at x32 on a chessboard without a sheet, 16 squares joined to its outline: missed before). Its outer edge
is looked for from ``LARGE_HOLE_PAIR_OUTER_FROM`` of the hole scaled: over-exposure grows the hole by its shift,
and the hole scaled by R / r by 2.5 times that (a 217 x 70 px target at 70 deg at x8: its hole 87.6 x 32.4 px,
scaled 219 x 81)."""
LARGE_HOLE_PAIR_OUTER_FROM = 0.75
DARK_GROUND_EDGE_SEEN = 0.5
"""A pair from a hole on dark ground (``hole_pairs.DARK_GROUND``) is kept only re-placed on the grey image's edges
(``refine.pair_from_edges(darker_ground=True)``, looked for from ``LARGE_HOLE_PAIR_OUTER_FROM`` of the hole
scaled), its outer edge seen in this share of the directions at least, and read only where no other pair gave a
candidate (``LAST_RESORT``)."""
COARSE_PAIR_LEVEL = 2
LIFTED_TRIMMED_OUTER_FROM = 0.75
LIFTED_TRIMMED_EDGE_SEEN = 0.5
"""A pair of the over-exposed frames' lifted threshold image (``_clipped_dark_box``) whose outline fits an ellipse
only without the points far off a first fit (``pairs._pairs(trimmed=...)``: black flecks of texture joined to a
ring lifted to ~0.85 of white) is re-placed on the grey image's edges (``pair_from_edges``, its outer edge looked
for from this share of the fitted ellipse: the trimmed fit came out up to 16 % too big) when they show the outer
edge in at least ``LIFTED_TRIMMED_EDGE_SEEN`` of the directions. Held-out seed 6's border-001 at x32 (an 82 x 128 px
ring on foliage, flecks joined to its outline on every level) was missed without the trimmed fit; fitted so, it
came out 148 px long and 10 px off-centre."""
COARSE_PAIR_EDGE_SEEN = 0.8
COARSE_PAIR_OUTER_FROM = 0.7
"""A usual pair found on pyramid level ``COARSE_PAIR_LEVEL`` or coarser whose refinement failed is re-placed on the
grey image's edges (``refine.pair_from_edges``, its outer edge looked for from ``COARSE_PAIR_OUTER_FROM`` of the
outline) when they show its outer edge in ``COARSE_PAIR_EDGE_SEEN`` of the directions and its code reads the same
there. Held-out seed 8's single-019 at x16: 19 px at 70 deg with a 3 % halo, paired on level 3 (8 px a level pixel)
as 60.7 x 23.8 px, where over-exposure left its ring's outer edge at 55.2 x 17.8 (0.78 of the outline); its ring
cut by a grown dot, no refinement; every edge profile (4 px each way: the design's clearance) in the clipped white,
no pose. On its edges: seen all round, found."""
HOLE_PAIR_EDGE_SEEN = 0.7
"""A "hole" pair's sparse code is read all the same when the image shows its outer edge in this share of the
directions (``refine.outer_edge_seen``: the intensity step, not the threshold's outline): a 25 px target without
a sheet on carpet, its ring joined by the threshold to dark patches of the carpet, kept a clear step to the
carpet around most of it and was refused at every exposure (id 1: two dots; its edge showed in 0.75-0.81 of the
directions at x0.25-x4, 0.5 at x8). Round holes in dark foliage, scaled, showed up to 0.53."""

DISK_PAIR_SPARSE_SEEN = 0.6
"""A pair placed from its inner disk alone (``refine.pair_from_disk``: "disk" pairs, small usual pairs whose code
did not read, and small "hole" pairs whose sparse code was refused) reads a sparse code (under
``HOLE_PAIR_MIN_DOTS`` dots) only when its outer ellipse keeps the edge points of this share of the directions
(``refine.pair_from_edges``' share, not ``outer_edge_seen``'s): seed 4's multi-001 id 1 (two dots, 14.4 x 9.0 px
in foliage), placed from the 6.2 x 4.7 px hole of its closed crop: 0.67 at x0.25 (its outer edge showed in 0.34
of the directions by ``outer_edge_seen``: refused there before), 0.64 at x0.5; from its true inner disk 0.78 at
x4."""

WIDE_HOLE_SHIFTS = (0.05, 0.1)
"""The wide closing's blobs (levels 1 and up of frames with clipped pixels) are also paired from their holes alone
(``hole_pairs._hole_pairs``, read with the strict code rules), with each design's radius ratio r/R and the ratios an
over-exposed pair shows, ``(r/R + d) / (1 - d)`` for each edge shift d (units of R) here: its hole is the white
disk grown by d and its ring shrunk by d, so the hole scaled by R / r puts the outer ellipse beyond the ring. A
ring cut open by its grown dots on the plain threshold image is whole there, but joined to dark ground it is no
ellipse (seed 2's multi-004 at x32: id 3, 55 px without a sheet on a chessboard, two squares joined; seed 4's
multi-001 at x16: id 8, 18 px without a sheet in foliage, its hole 0.54 of the ring: both missed before). Not
from the holes of a blob too big for a pair: closed so, a chessboard's dark squares make one blob whose holes are
its hundreds of white squares (seed 3's multi-004 at x16: detect 2.7x as long)."""


# ---------------------------------------------------------------------- entry point
SKIP_KNOWN = True
"""The plain and closed passes skip the blobs whose bounding box is that of a pair found before on a finer level or
by the plain pass of the same level (``pairs._at_known_place``); False (for tests): every blob examined."""
SKIP_HALOS = True
"""The plain and closed passes give ``pairs._pairs`` each level's grey image, so that a blob that is a threshold's
halo round something already paired gets no closed retry (``outline_edges.HaloTest``: the grey ground round a
white sheet; on the bench's frames ~0.3 ms of detect's ~5); False (for tests): every blob retried."""


class Detector:
    """The coarse detector for one set of targets: their geometry groups, the options and the full-size work
    images, kept from one call to the next and overwritten (a fresh multi-megabyte array costs its page faults,
    more than a pass over it). Not thread-safe: one Detector per thread.

    ``Detector(targets, options).detect(image, ...) -> list[Candidate]``; ``detect(image, targets, ...)`` is the
    same with a Detector made for the call."""

    def __init__(self, targets: list[TargetSpec], options: DetectOptions | None = None) -> None:
        self.targets = list(targets)
        self.options = options or DetectOptions()
        self._groups = _geometry_groups(self.targets)
        self._by_id = {t.id: t for t in self.targets}
        self._ratios = sorted({g.ratio for g in self._groups})
        # the radius ratios an over-exposed pair shows (``WIDE_HOLE_SHIFTS``), for the holes of the wide closing
        self._seen_ratios = self._ratios + [(r + d) / (1.0 - d) for d in WIDE_HOLE_SHIFTS for r in self._ratios]
        # pairs from a hole alone (``_hole_pairs``): a code within half a slot of its match, a full slot ahead of
        # the next (dark ground with a few bright flecks around a round hole can read as a sparse code otherwise)
        self._hole_opts = dataclasses.replace(self.options, max_code_distance=HOLE_PAIR_MAX_CODE_DISTANCE,
                                              min_code_margin=HOLE_PAIR_MIN_CODE_MARGIN)
        self._work = _WorkImages()

    def detect(
        self,
        image: npt.ArrayLike,
        saturation: float | None = None,
        min_outer_radius_px: float = 8.0,
        border_margin_px: float = 3.0,
        roi: tuple[int, int, int, int] | None = None,
        trace: list[TraceEvent] | None = None,
    ) -> list[Candidate]:
        """Find the configured targets (every fractal level big enough) in one image.

        image: (H, W) uint8, uint16 or float (any scale); other dtypes are converted to float32.
        saturation: the sensor's clip level in image units (e.g. 4095), or None (then the full scale of the
            data: see ``full_scale``); pixels at or above it count as white. Default None.
        min_outer_radius_px: smallest outer radius found (the code needs about 9 px or more). Above
            ``DetectOptions.level0_max_radius_px`` (32 px) the full-resolution pass is skipped (about 1.7x
            faster). Default 8.
        border_margin_px: a target whose outer ellipse comes closer than this to the image (or ``roi``) border
            is rejected (it may be cut). Default 3.
        roi: (x0, y0, x1, y1) pixel bounds (x1, y1 exclusive, clipped to the image) to search, e.g. around a
            tracked target: cost scales with its area. Results are in full-image pixels. Default None (all).
        trace: a list to which every blob, pair and verification step is appended as a ``TraceEvent`` (a
            diagnostic, slower: every dark blob is examined). Default None.

        Returns candidates sorted by (target_id, level); an empty list when nothing is found (never raises for
        image content: blank, saturated, tiny or odd-sized images give ``[]``).
        """
        opts, work = self.options, self._work
        img = np.asarray(image)
        if img.ndim != 2:
            raise ValueError(f"image must be 2-D (H, W), got shape {img.shape}")
        if img.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
            img = img.astype(np.float32)
        if not self._groups:
            return []
        x0, y0 = 0, 0
        whole = img  # codes and levels are read on the whole image (``_WholeImageReader``), an ROI or not
        if roi is not None:
            x0, y0 = max(int(roi[0]), 0), max(int(roi[1]), 0)
            x1, y1 = min(int(roi[2]), img.shape[1]), min(int(roi[3]), img.shape[0])
            if x1 <= x0 or y1 <= y0:
                return []
            img = img[y0:y1, x0:x1]
        min_r = max(float(min_outer_radius_px), 3.0)
        if min(img.shape) < 2 * min_r + 2:
            return []
        _FIT_MEMO.clear()  # fits are remembered within one call (``fits._fit``)
        # the pyramid's first level computed in the 8-bit map's pass where it can be (the same image)
        half = (work.image("level1", ((img.shape[0] + 1) // 2, (img.shape[1] + 1) // 2))
                if _halve_again(opts, 1, img.shape, img.shape) else None)
        norm = _normalise_halved(img, saturation, work, half)
        if norm is None:
            return []
        img8, full, top, halved = norm
        clipped = top >= SATURATED_LEVEL  # a cost gate only: no decision on what is dark
        pyramid = [img8, half] if halved else [img8]
        while _halve_again(opts, len(pyramid), img.shape, pyramid[-1].shape):
            h, w = pyramid[-1].shape
            level = work.image(f"level{len(pyramid)}", ((h + 1) // 2, (w + 1) // 2))
            pyramid.append(cv2.pyrDown(pyramid[-1], dst=level))
        coarse: list[tuple[int, Ellipse, Ellipse, str]] = []
        open_rings: list[tuple[int, Ellipse]] = []  # (level, outer ellipse of an arc in full-resolution pixels)
        noise = fine_noise = 0.0
        paired_px: list[tuple[float, float]] = []  # every pass's pairs' centres so far (``HaloTest``)
        known_px: list[tuple[float, float, float, float]] = []  # the plain and closed pairs' boxes so far
        for s, level_img in enumerate(pyramid):
            scale = 2.0**s
            note = None if trace is None else _level_note(trace, s, scale, x0, y0)
            a_lo = min_r / scale if s == 0 else max(min_r / scale, opts.min_level_radius_px)
            a_hi = opts.level0_max_radius_px if s == 0 else opts.max_level_radius_px
            if a_lo > a_hi:
                continue
            smooth, blur = level_img, None
            coarse_level = pyramid[s + 2] if s + 2 < len(pyramid) else None
            if s == 0 and opts.level0_blur_px > 0:
                # the same image either way: blurred inside the threshold's comparison (but for the rows the
                # noise figures read, blurred first), or by OpenCV
                blur = _fused_blur(level_img, coarse_level, opts.level0_blur_px)
                smooth = work.image("smooth", level_img.shape)
                if blur is not None:
                    smooth = _blurred_for_noise(blur, smooth, work)
                else:
                    ksize = 3 if opts.level0_blur_px <= 1.0 else 0  # 3x3 holds a sigma <= 1 px well enough
                    smooth = cv2.GaussianBlur(level_img, (ksize, ksize), opts.level0_blur_px, dst=smooth)
            if s == 0 or (s == 1 and noise == 0.0):
                noise, fine_noise = _noise(smooth)
            elif s == 1:
                # Level 1 is a smoothed subsample of level 0: never noisier. An estimate that says it is measured
                # edges, not noise (most of an over-exposed frame clipped, its cleanest unclipped tile a textured
                # one): at x32 it doubled the offset and left a light-grey ring of 200 px undetected.
                noise, fine_noise = (min(a, b) for a, b in zip((noise, fine_noise), _noise(smooth), strict=True))
            # Coarser levels: level 1's estimate (measuring each costs more than it changes).
            depth = _offset(noise, opts)
            halo_grey = level_img if SKIP_HALOS else None  # (level 0's ``smooth`` may be blurred in part only)
            found_px = [(x / scale, y / scale) for x, y in paired_px]
            known = ([(x / scale, y / scale, hx / scale, hy / scale) for x, y, hx, hy in known_px] if SKIP_KNOWN
                     else None)
            binary, box = _dark_box(smooth, coarse_level, depth, opts, work,
                                    saturated_offset=_offset(fine_noise, opts), blur=blur)
            bias = opts.exposure_bias_px / scale + 0.5
            retried: list[tuple[Ellipse, Ellipse]] = []
            holes: list[tuple[Ellipse, Ellipse, str]] = []
            small = SmallBlobs(smooth, binary, SMALL_BLOB_MAX_RADIUS_PX, clipped) if s == 0 else None
            arcs: list[Ellipse] = []
            pieces: list[Ellipse] = []  # the outlines of several arcs together (``_pairs_of_arcs``)
            bumpy: list[tuple[Ellipse, Ellipse]] = []  # pairs whose inner disk had a dot joined (``_pairs``)
            # a coarse level's pieces of rings cut through (``COARSE_ARCS``)
            coarse_arcs: list[tuple[int, int, int, int]] | None = [] if COARSE_ARCS and s >= 1 and clipped else None
            found = [(o, i, "plain") for o, i in _pairs(binary, a_lo, a_hi, self._ratios, bias, opts, retried, note,
                                                        from_holes=holes, small_blobs=small, close_own=s == 0,
                                                        box=box, open_rings=arcs, disks=s == 0, bumpy=bumpy,
                                                        grey=halo_grey, edge_depth=depth, found_px=found_px,
                                                        known=known, arc_boxes=coarse_arcs)]
            if known is not None:  # the closed pass's blobs at this level's plain pairs' places are not examined
                known += [_box_of(o) for o, _, _ in found]
            found += [(o, i, "plain" + BUMPS) for o, i in bumpy]
            # Also with white gaps of 1-2 level pixels closed: a small target's black ring cut by its own white dots
            # (grown by over-exposure, or thinned by tilt) is one ring again. Only added: the same closing fills the
            # thin white gap between a ring and its nested child, so it cannot replace the plain binary.
            closed = _closed(binary, box, _KERNEL3, f"closed{s}", work)  # over the dark pixels' box only
            bumpy.clear()
            found += [(o, i, "closed") for o, i in _pairs(closed, a_lo, a_hi, self._ratios, bias, opts, retried, note,
                                                          box=work.written_box(f"closed{s}"), bumpy=bumpy,
                                                          grey=halo_grey, edge_depth=depth, found_px=found_px,
                                                          known=known)]
            found += [(o, i, "closed" + BUMPS) for o, i in bumpy]
            if s >= 1 and clipped:
                # Over-exposure grows the dots of a small target into its inner disk and past its outer edge:
                # its ring is arcs. Closing white gaps up to ~6 level pixels makes it one ring again (its inner
                # disk, wider, stays open). Only in frames with clipped pixels (a pass costs ~20 % of detect).
                # A ring closed so but joined to dark ground is also paired from its holes (``WIDE_HOLE_SHIFTS``),
                # from the level's own least size: its clean hole is often this closing's alone (a 20 px ring at x16
                # on foliage, its disk joined by a grown dot on level 0, paired on level 1 with an 11 px outer edge)
                wide = _closed(binary, box, _DISK7, f"wide{s}", work)
                found += [(o, i, "wide") for o, i in _pairs(wide, max(a_lo, 12.0), a_hi, self._ratios, bias, opts,
                                                            note=note, box=work.written_box(f"wide{s}"),
                                                            from_holes=holes, hole_ratios=self._seen_ratios,
                                                            large_holes=False, holes_a_lo=a_lo)]
            if clipped:
                # and on the saturated windows' own binary image (``_clipped_dark_box``)
                lifted, lifted_box = _clipped_dark_box(smooth, pyramid[s + 2] if s + 2 < len(pyramid) else None,
                                                       _offset(fine_noise, opts), opts, work)
                trimmed: list[tuple[Ellipse, Ellipse]] = []
                lifted_holes: list[tuple[Ellipse, Ellipse, str]] = []
                found += [(o, i, "lifted") for o, i in _pairs(lifted, a_lo, a_hi, self._ratios, bias, opts,
                                                              note=note, box=lifted_box, open_rings=arcs,
                                                              trimmed=trimmed,
                                                              from_holes=lifted_holes if LIFTED_HOLES else None,
                                                              hole_ratios=self._seen_ratios, large_holes=False)]
                found += [(o, i, _hole_kind(o, how, scale) + LIFTED) for o, i, how in lifted_holes]
                found += [(o, i, "lifted, edges") for o, i in trimmed]
            found += [(o, i, "crop") for o, i in retried]
            if coarse_arcs:
                coarse_arcs = _beside_clipped(level_img, _unpaired(coarse_arcs, found))
                found += [(o, i, COARSE_ARC) for o, i in _pairs_of_arcs(binary, coarse_arcs, a_lo, a_hi,
                                                                         self._ratios, bias, opts, pieces)]
            if small is not None and small.arcs:
                found += [(o, i, "arcs") for o, i in _pairs_of_arcs(binary, small.arcs, a_lo, a_hi, self._ratios,
                                                                     bias, opts, pieces)]
            if small is not None:
                found += [pair + ("small",) for pair in (_small_blob_pair(level_img, e, self._ratios, opts)
                                                         for e in _dedupe_ellipses(small.found)) if pair is not None]
            # the hole's ellipse scaled is the outer one without the perspective, pixels off on a large tilted target
            # (a 235 px one at 50 deg: its pose fit then failed where its nested level alone gave it): a large one
            # is re-placed on the grey image's edges first (``LARGE_HOLE_PAIR``)
            found += [(o, i, _hole_kind(o, how, scale)) for o, i, how in holes]
            paired_px += [(float(o.centre_px[0]) * scale, float(o.centre_px[1]) * scale) for o, _, _ in found]
            known_px += [tuple(v * scale for v in _box_of(o)) for o, _, how in found if how in ("plain", "closed")]
            for outer, inner, how in found:
                if s > 0:
                    outer = Ellipse(outer.centre_px * scale, outer.semi_axes_px * scale, outer.angle_rad)
                    inner = Ellipse(inner.centre_px * scale, inner.semi_axes_px * scale, inner.angle_rad)
                coarse.append((s, outer, inner, how))
            open_rings += [(s, Ellipse(e.centre_px * scale, e.semi_axes_px * scale, e.angle_rad))
                           for e in _dedupe_ellipses(arcs)]
            if pieces:  # a ring's arcs together, where no arc of one piece lies
                seen = _PlaceGrid([_place(e) for _, e in open_rings])
                scaled_pieces = [Ellipse(e.centre_px * scale, e.semi_axes_px * scale, e.angle_rad)
                                 for e in _dedupe_ellipses(pieces)]
                open_rings += [(s, e) for e in scaled_pieces if not seen.matches(_place(e))]
        # rings cut open, once every level's usual pairs are known (a pair from an arc is dropped where one lies)
        last_resort = [p for p in coarse if p[3] in LAST_RESORT]
        coarse = [p for p in coarse if p[3] not in LAST_RESORT]
        usual = [q[1] for q in coarse if q[3] not in FROM_HOLE]
        for s, (o, i), how in _pairs_of_open_rings(img8, open_rings, self._ratios, usual,
                                                   self._seen_ratios[len(self._ratios):] if clipped else ()):
            (last_resort if how in LAST_RESORT else coarse).append((s, o, i, how))
        # pairs from a hole alone (``_hole_pairs``) first only where no pair of the usual kind lies, on any level
        usual = _dedupe_pairs([p for p in coarse if p[3] not in FROM_HOLE])
        usual_places = _PlaceGrid([_place(q[1]) for q in usual])
        alone: list[tuple[int, Ellipse, Ellipse, str]] = []
        deferred: list[tuple[int, Ellipse, Ellipse, str]] = []  # where a usual pair lies: read if it gave nothing
        for p in _dedupe_pairs([p for p in coarse if p[3] in FROM_HOLE]):
            (deferred if usual_places.matches(_place(p[1])) else alone).append(p)
        height, width = img.shape
        reader = _WholeImageReader(whole, x0, y0, self._groups, full)
        candidates: list[Candidate] = []
        from_hole: list[Candidate] = []
        shift = np.array([x0, y0], dtype=np.float64)

        def read(s: int, outer: Ellipse, inner: Ellipse, how: str) -> None:
            if trace is not None:
                trace.append(_event("pair", s, outer, shift, how))
            if how in FROM_HOLE and any(_near_middle(inner, c.outer.centre_px) and not _its_child(how, c)
                                        for c in candidates):
                # what it reads would be dropped below (a target found inside it): not read (``FOUND_INSIDE``)
                if trace is not None:
                    trace.append(_event("code", -1, outer, shift, "a target found inside its inner disk"))
                return
            if how.startswith(DARK_GROUND) and any(_inside_ellipse(c.outer, inner.centre_px) and outer.a < c.outer.a
                                                   for c in candidates):
                return  # a hole of a target found (a code dot, its inner disk): no ring on dark ground of its own
            how = how.removesuffix(LIFTED).removesuffix(BUMPS)  # (read last, then as its kind)
            scaled = (outer, inner)  # (a pair from a hole: its hole scaled)
            if how == "hole, edges":
                edged = pair_from_edges(img8, outer, inner, LARGE_HOLE_PAIR_OUTER_FROM, sampled_start=True)
                if edged is None or edged[2] < LARGE_HOLE_PAIR_EDGE_SEEN:
                    return
                outer, inner = edged[:2]
            elif how == DARK_GROUND:  # its outer edge where the ring falls to the ground, or none
                if not ring_above_ground(img8, outer, inner):
                    return
                edged = pair_from_edges(img8, outer, inner, LARGE_HOLE_PAIR_OUTER_FROM, sampled_start=True,
                                        darker_ground=True)
                if edged is None or edged[2] < DARK_GROUND_EDGE_SEEN:
                    return
                outer, inner = edged[:2]
            elif how == "lifted, edges":
                # an over-exposed ring whose outline texture joined, fitted without the joined points: re-placed
                # on the grey image's edges where they show it (else as fitted)
                edged = pair_from_edges(img8, outer, inner, LIFTED_TRIMMED_OUTER_FROM)
                if edged is not None and edged[2] >= LIFTED_TRIMMED_EDGE_SEEN:
                    outer, inner = edged[:2]
            disk_seen = None
            if how == "disk":  # a tiny ring's inner disk: the pair on the grey image's edges, or none
                placed = pair_from_disk(img8, inner, self._ratios)
                if placed is None:
                    return
                outer, inner, disk_seen = placed
            refined = None if how in ("disk", DARK_GROUND) else _refine(pyramid, outer, inner, self._ratios, opts)
            if refined is not None:
                outer, inner = refined
            if not _inside(outer, width, height, border_margin_px):
                if trace is not None:
                    trace.append(_event("border", -1, outer, shift, ""))
                return
            reasons: list[str] = []
            strict = how in FROM_HOLE  # only a hole behind it: its code must read cleanly
            pair_opts = self._hole_opts if strict else opts
            found_here = reader.identify(outer, inner, pair_opts, reasons)
            if how == DARK_GROUND and not all(c.darker_outside for c in found_here):
                reasons.append("ground not darker than the ring all round")  # a round hole in dark texture
                found_here = []
            if found_here and refined is None and s >= COARSE_PAIR_LEVEL and not strict:
                # a coarse level's outline, not refined (its ring cut by a grown dot leaves no closed ring to a
                # global threshold): pixels off, past the reach of the edge fits' profiles. On the grey image's
                # edges, if its code reads the same there.
                edged = pair_from_edges(img8, outer, inner, COARSE_PAIR_OUTER_FROM)
                if (edged is not None and edged[2] >= COARSE_PAIR_EDGE_SEEN
                        and _inside(edged[0], width, height, border_margin_px)):
                    again = reader.identify(edged[0], edged[1], pair_opts, [])
                    if sorted((c.target_id, c.level) for c in again) == sorted((c.target_id, c.level)
                                                                               for c in found_here):
                        outer, inner, found_here = edged[0], edged[1], again
            misread = (not reasons or any(r.startswith(MISREAD) for r in reasons)
                       or (how == "hole" and any(r.startswith(HOLE_MISREAD) for r in reasons)))
            seen = None
            if how == "hole" and refined is None and not found_here:
                # read again with its outer edge where the image shows it: the hole scaled is off by the
                # exposure's shift of both edges, and by a coarse level's pixels
                seen, k = outer_edge_seen(img8, outer, inner)
                placed = outer.scaled(k)
                if (seen >= HOLE_PAIR_EDGE_PLACED and abs(k - 1.0) >= 0.02
                        and _inside(placed, width, height, border_margin_px)):
                    again = reader.identify(placed, inner, pair_opts, reasons)
                    if again:
                        outer, found_here = placed, again
                if not found_here:  # a strongly tilted target: its outer circle's image off its inner disk's
                    outer, found_here = reader.off_centre(outer, inner, pair_opts, reasons)
            if how == "hole, edges" and not found_here and _inside(scaled[0], width, height, border_margin_px):
                # placed on edges that texture shares (foliage without a sheet: 14 % too large), read as the hole
                # scaled, then off-centre
                placed, found_here = reader.off_centre(scaled[0], scaled[1], pair_opts, reasons,
                                                               centre_first=True)
                if found_here:
                    outer, inner = placed, scaled[1]
            if not found_here and misread and how not in ("disk", DARK_GROUND):
                # read again on the grey image's own edges (``pair_from_edges``): the threshold's outline or hole
                # can be off where the image is not
                edged = pair_from_edges(img8, outer, inner)
                if edged is not None and _inside(edged[0], width, height, border_margin_px):
                    again = reader.identify(edged[0], edged[1], pair_opts, reasons)
                    if again:
                        outer, inner, found_here = edged[0], edged[1], again
                        seen = edged[2] if seen is None else max(seen, edged[2])
            if not found_here and misread and not strict and outer.b <= DISK_PAIR_MAX_RADIUS_PX:
                # a tiny ring whose outline the threshold joined to dark ground (printed text): placed from its
                # inner disk on the grey image's edges, read with the strict rules
                placed = pair_from_disk(img8, inner, self._ratios)
                if placed is not None and _inside(placed[0], width, height, border_margin_px):
                    again = reader.identify(placed[0], placed[1], self._hole_opts, reasons)
                    if again:
                        outer, inner, found_here, disk_seen = placed[0], placed[1], again, placed[2]
            if disk_seen is not None:  # placed from its inner disk
                sparse = [c for c in found_here if _sparse(c)]
                if sparse and disk_seen < DISK_PAIR_SPARSE_SEEN:
                    reasons.append(f"code of under {HOLE_PAIR_MIN_DOTS} dots read from an inner disk alone (its "
                                   f"outer edge kept in {disk_seen:.2f} of the directions)")
                    found_here = [c for c in found_here if c not in sparse]
            elif how == "hole":  # "outline": its outer edge seen, as a usual pair's
                sparse = [c for c in found_here if _sparse(c)]
                if sparse and seen is None:
                    seen = outer_edge_seen(img8, outer, inner)[0]
                if sparse and seen >= HOLE_PAIR_EDGE_SEEN:
                    sparse = []
                if sparse and outer.b <= DISK_PAIR_MAX_RADIUS_PX:
                    # a tiny ring: its sparse code read again placed from its inner disk, as a "disk" pair's
                    placed = pair_from_disk(img8, inner, self._ratios)
                    if (placed is not None and placed[2] >= DISK_PAIR_SPARSE_SEEN
                            and _inside(placed[0], width, height, border_margin_px)):
                        again = reader.identify(placed[0], placed[1], pair_opts, reasons)
                        if again:
                            outer, inner, found_here, sparse = placed[0], placed[1], again, []
                if sparse:
                    reasons.append(f"code of under {HOLE_PAIR_MIN_DOTS} dots read from a hole alone (its outer "
                                   f"edge seen in {seen:.2f} of the directions)")
                found_here = [c for c in found_here if c not in sparse]
            if trace is not None:
                trace.extend(_event("code", -1, outer, shift, r) for r in reasons)
                trace.extend(_event("candidate", -1, outer, shift, f"id {c.target_id} level {c.level}"
                                    + (" ambiguous" if c.level_ambiguous else "")) for c in found_here)
            (from_hole if strict else candidates).extend(found_here)

        for pair in usual + alone:
            read(*pair)
        # A pair from a hole where a usual pair lies that gave no candidate: that pair's outer ellipse can be the
        # ring merged with dark ground beside it (a target printed without a sheet on a chessboard at x32: the
        # blob's outline 14 px off-centre and 30 % too big, no code read), where its clean hole gives the ring.
        taken = _PlaceGrid([_place(c.outer) for c in candidates])
        for pair in deferred:
            if not taken.matches(_place(pair[1])):
                read(*pair)
        if last_resort:  # (``LAST_RESORT``) only where nothing else gave a candidate
            taken = _PlaceGrid([_place(c.outer) for c in candidates + from_hole])
            paired = _PlaceGrid([_place(p[1]) for p in coarse])  # (every pair read before, found or not)
            for pair in _dedupe_pairs(last_resort):
                if not taken.matches(_place(pair[1])) and not (pair[3].endswith(LIFTED)
                                                               and paired.matches(_place(pair[1]))):
                    read(*pair)
        # a pair from a hole alone only where no pair of the usual kind gave a candidate there or inside it (its
        # outer ellipse is the hole's scaled, without the perspective: beside a nested level found alone, an 80 px
        # target's pose fit started 140 % off and failed, where the nested level alone gave the pose)
        candidates += [c for c in from_hole
                       if not any(c.outer.sampson_distance(k.outer.centre_px[None, :])[0] <= 0
                                  and not _nested_in(k, c) for k in candidates)]
        candidates = _without_foreign_inside(_nest(_dedupe_candidates(candidates), self._by_id))
        if x0 or y0:
            candidates = [_shifted(c, shift) for c in candidates]
        return sorted(candidates, key=lambda c: (c.target_id, c.level, c.outer.centre_px[0]))


LIFTED_HOLES = True
"""The lifted binary image's blobs (``_clipped_dark_box``) are also paired from their holes alone (``_hole_pairs``,
with the ratios an over-exposed ring shows), as the plain one's are: at x32 a ring beside black flecks of texture is
dark all round only there, and joined to the flecks its blob's outline is no ellipse and its inner disk off its
middle (held-out seed 6's multi-001, id 12, 29 px in foliage: the plain image held a crescent of it, missed). Read as
a ``LAST_RESORT`` (their kind ends in ``LIFTED``): read with the others, one took the place of the pair a 26 px ring
in foliage had been found from at x8 and put it at -1.9 % instead of -1.1 % (seed 2's border-001); and only where no
other pair lies, read or not: where the plain image's pair from the same hole had read nothing, the lifted one read a
two-dot code in foliage at x16 (seed 1, on its background alone and beside single-004's target)."""
COARSE_ARCS = True
"""In a frame with clipped pixels, the blobs of a coarse level (1 and up) that may be pieces of a ring cut through
(``arcs.open_middles``: not dark in their middle; or with holes that fit no inner disk) and lie beside clipped
pixels are grouped and paired as level 0's small ones are (``arc_pairs._pairs_of_arcs``: closed, a ``COARSE_ARC``
read as a last resort, else the outline of the pieces together, re-placed on the grey image's edges as a ring cut
open). Read first, the closed pairs took the place of usual ones and moved found targets' poses (seed 5's
single-013 at x32: -0.02 -> -0.29 %). A large target at x32 is cut by its halo, not only by
its grown dots: held-out seed 7's single-014 (272 x 115 px at 70 deg on printed text, a 3 % halo, its ring at 0.89
of white) had its ring clipped through beside two dots, a C over half of it and a piece holding two dots on every
level, and was missed."""


def _unpaired(rects: list[tuple[int, int, int, int]], found: list[tuple[Ellipse, Ellipse, str]]
              ) -> list[tuple[int, int, int, int]]:
    """``rects`` (x, y, w, h) whose middle lies inside no outer ellipse of ``found``."""
    return [r for r in dict.fromkeys(rects)
            if not any(_inside_ellipse(o, np.array([r[0] + 0.5 * r[2], r[1] + 0.5 * r[3]])) for o, _, _ in found)]


def _beside_clipped(level_img: np.ndarray, rects: list[tuple[int, int, int, int]]) -> list[tuple[int, int, int, int]]:
    """``rects`` with a clipped pixel (``SATURATED_LEVEL``) within half their size around them."""
    out = []
    for x, y, w, h in rects:
        g = max(w, h) // 2
        if cv2.minMaxLoc(level_img[max(y - g, 0) : y + h + g, max(x - g, 0) : x + w + g])[1] >= SATURATED_LEVEL:
            out.append((x, y, w, h))
    return out


def _pairs_of_open_rings(img8: np.ndarray, arcs: list[tuple[int, Ellipse]], ratios: list[float],
                         taken: list[Ellipse], over_exposed: Sequence[float] = ()
                         ) -> list[tuple[int, tuple[Ellipse, Ellipse], str]]:
    """The pairs (level, (outer, inner) in full-resolution pixels, how: "arc" or "arc, over-exposed") of rings cut
    open, from their arcs' outer ellipses (``arcs``: level and ellipse), re-placed on the grey image's edges
    (``refine.pair_from_edges``) with each design's radius ratio until one gives a pair ("arc"), else with the
    ratios an over-exposed ring shows ("arc, over-exposed"; ``over_exposed``: ``WIDE_HOLE_SHIFTS``' ratios, given
    for frames with clipped pixels; read as a ``LAST_RESORT``); none where an ellipse of ``taken`` lies. The
    edge search reads the ring's contrast at its design's middle, which over-exposure can put in the grown white
    disk: seed 3's multi-002 at x32 (id 1, 20 px on printed text, its two grown dots cutting
    the ring, the ring at 0.83 of white) had its inner edge at 0.58 of the outer, its design's middle (0.52) read
    white, no contrast, and it was missed; with a shift of 0.1 (ratio 0.56) it is found."""
    out = []
    taken_places = _PlaceGrid([_place(t) for t in taken])
    for s, outer in arcs:
        if taken_places.matches(_place(outer)):
            continue
        for k, rho in enumerate([*ratios, *over_exposed]):
            edged = pair_from_edges(img8, outer, outer.scaled(rho))
            if edged is not None:
                out.append((s, edged[:2], "arc" if k < len(ratios) else "arc, over-exposed"))
                break
    return out


FOUND_INSIDE = 0.5
"""A pair from a hole alone is not read when a usual pair's candidate has its centre within this share of the
hole's ellipse: whatever it read would contain that candidate and be dropped (the last filter of
``Detector.detect``), and reading it is not free. A target's white sheet on darker ground is such a hole (its
corners rounded by blur, it passes as an ellipse): scaled to 275-415 px, its pair was re-placed on the grey image's
edges from 200 sampled starts, ~1.5 ms each time, in 2 of the bench's 10 frames, and never read."""


def _its_child(how: str, found: Candidate) -> bool:
    """Whether a pair from a hole (found as ``how``) may be read with ``found`` in its middle: a ring on dark
    ground (``DARK_GROUND``) around a nested level found alone, which it may be the parent of (``_nested_in``)."""
    return how.startswith(DARK_GROUND) and found.level > 0


def _nested_in(child: Candidate, parent: Candidate) -> bool:
    """Whether ``child`` is ``parent``'s nested level and ``parent`` a ring on darker ground: kept together (the
    parent's edges join the child's in the pose: on black velvet at x1-x4 the nested level alone, 7-9 px, put the
    distance 0.1-0.3 % off), where a pair from a hole otherwise gives way to what was found inside it."""
    return parent.darker_outside and child.target_id == parent.target_id and child.level > parent.level


def _near_middle(ellipse: Ellipse, point: FloatArray) -> bool:
    """Whether ``point`` lies within ``FOUND_INSIDE`` of ``ellipse`` (scaled about its centre)."""
    return _inside_ellipse(ellipse, point, FOUND_INSIDE)


def _inside_ellipse(ellipse: Ellipse, point: FloatArray, share: float = 1.0) -> bool:
    """Whether ``point`` lies within ``ellipse`` scaled by ``share`` about its centre."""
    dx, dy = float(point[0] - ellipse.centre_px[0]), float(point[1] - ellipse.centre_px[1])
    c, s = math.cos(ellipse.angle_rad), math.sin(ellipse.angle_rad)
    u, v = (dx * c + dy * s) / ellipse.a, (-dx * s + dy * c) / ellipse.b
    return u * u + v * v <= share * share


def _sparse(c: Candidate) -> bool:
    """Whether a candidate's code has under ``HOLE_PAIR_MIN_DOTS`` dots (or none)."""
    return c.spec.code is None or c.spec.code.bits.count("1") < HOLE_PAIR_MIN_DOTS


def _box_of(e: Ellipse) -> tuple[float, float, float, float]:
    """The centre and half sizes (x, y, half width, half height) of ``e``'s bounding box (``pairs._at_known_place``)."""
    a, b = e.semi_axes_px.tolist()
    c, s = math.cos(e.angle_rad), math.sin(e.angle_rad)
    x, y = e.centre_px.tolist()
    return x, y, math.sqrt(a * a * c * c + b * b * s * s), math.sqrt(a * a * s * s + b * b * c * c)


def _halve_again(opts: DetectOptions, levels: int, shape: tuple[int, ...], last_shape: tuple[int, ...]) -> bool:
    """Whether the pyramid of an image of ``shape`` gets another level after its first ``levels`` (the last of
    ``last_shape``)."""
    return 2 * opts.min_level_radius_px * 2**levels <= min(shape) / 2 and min(last_shape) > 32


def _without_foreign_inside(cands: list[Candidate]) -> list[Candidate]:
    """``cands`` less those whose centre lies in another's inner disk, smaller than it, that are not its nested
    levels (``_nest`` made those its own): a target is not seen through another's white disk. At x32 a piece of a
    nested level's ring cut by its grown dots, with one of them, read as id 1 inside the white disk of a 200 px
    target (a sheet and grey ink, the detection sweep's optics family)."""
    def foreign(x: Candidate, y: Candidate) -> bool:
        return (x is not y and not (x.target_id == y.target_id and x.level > y.level) and x.outer.a < y.inner.a
                and y.inner.sampson_distance(x.outer.centre_px[None, :])[0] < 0)

    return [x for x in cands if not any(foreign(x, y) for y in cands)]


def detect(
    image: npt.ArrayLike,
    targets: list[TargetSpec],
    saturation: float | None = None,
    min_outer_radius_px: float = 8.0,
    border_margin_px: float = 3.0,
    roi: tuple[int, int, int, int] | None = None,
    options: DetectOptions | None = None,
) -> list[Candidate]:
    """``Detector(targets, options).detect(image, ...)`` with a Detector for this call only (its work images
    are allocated anew: a caller that detects frame after frame keeps a Detector)."""
    return Detector(targets, options).detect(image, saturation, min_outer_radius_px, border_margin_px, roi)


def _inside(outer: Ellipse, width: int, height: int, margin_px: float) -> bool:
    """Whether ``outer``'s box lies at least ``margin_px`` inside the image."""
    half = outer.half_extent_px()
    c = outer.centre_px
    return (c[0] - half[0] >= margin_px and c[1] - half[1] >= margin_px
            and c[0] + half[0] <= width - 1 - margin_px and c[1] + half[1] <= height - 1 - margin_px)


def _event(stage: str, level: int, ellipse: Ellipse, shift: FloatArray, detail: str) -> TraceEvent:
    c = ellipse.centre_px + shift
    return TraceEvent(stage, level, (float(c[0]), float(c[1])), float(ellipse.a), detail)


def _level_note(trace: list[TraceEvent], level: int, scale: float, x0: int, y0: int):
    """A recorder for ``_pairs`` on pyramid level ``level``: (centre x, y and half size in level pixels, reason)
    -> a "blob" event in full-image pixels."""
    def note(cx: float, cy: float, half: float, detail: str) -> None:
        trace.append(TraceEvent("blob", level, (cx * scale + x0, cy * scale + y0), half * scale, detail))
    return note
