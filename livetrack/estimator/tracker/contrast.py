"""The black-to-white contrast shared by a target's clipped edge profiles (``TrackerOptions.clipped_shared_contrast``):
which profiles share one, what a frame measured, and the hint a tracked frame starts from."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from livetrack.estimator.edge_glue_kernels import median_where
from livetrack.estimator.edges import EdgeFits
from livetrack.estimator.tracker.tracks import _Track

FloatArray = npt.NDArray[np.float64]


def _contrast_groups(radius_m: FloatArray) -> npt.NDArray[np.int64]:
    """Which bright side each edge point has: 1 for the outermost circle used (its outside is the sheet, or the
    ground of a target printed without one; or its ring, against darker ground: ``Candidate.darker_outside``),
    0 for every other circle (the target's own white)."""
    return (radius_m >= radius_m.max()).astype(np.int64)


def _clipped_contrast(edges: EdgeFits, groups: npt.NDArray[np.int64]) -> FloatArray | None:
    """The median black-to-white contrast of the ok clipped edge profiles of each contrast group (NaN for a group
    with fewer than 5), None when no group has 5."""
    clipped_ok = edges.ok & (edges.n_clipped > 0)
    if not clipped_ok.any():  # no group has 5 (the common case: a well-exposed frame)
        return None
    contrast = edges.white_level - edges.black_level
    out = np.full(2, np.nan)
    for g in range(2):
        mine = clipped_ok & (groups == g)
        if mine.sum() >= 5:
            out[g] = median_where(contrast, mine)
    return None if np.isnan(out).all() else out


def _split_contrast(edges: EdgeFits, groups: npt.NDArray[np.int64]) -> FloatArray | None:
    """(N,) per point, the contrast its group's clipped profiles were fitted with, where the groups were fitted with
    contrasts of their own (``_clipped_contrast`` differs between them: ground clearly darker than the white); None
    otherwise. A search re-samples its profiles centred on their first fits' edges (``Tracker._estimate``): the
    white's deeply clipped profiles, centred on edges already in the clip, then show fewer unclipped samples, and
    their contrast sample may fall under the least count (10 fits) it needs to stand apart: all groups then shared
    the ground's contrast (a 40 x 40 px target without a sheet on grey ground at x16: 9 of 65 sampled white-side
    fits ok against 45 before, one contrast of 7888 for the white's 40630, distance -0.79 %). Handed to the second
    fit as its hint, the first fit's split is kept (-0.07 %); the fit measures again where the hint does not fit."""
    measured = _clipped_contrast(edges, groups)
    if measured is None or not np.all(np.isfinite(measured)) or measured[0] == measured[1]:
        return None
    return measured[groups]


def _ground_split(edges: EdgeFits, groups: npt.NDArray[np.int64], ground_apart: bool) -> FloatArray | None:
    """``_split_contrast`` where the pose took the ground apart (``ground_apart``: its outer circle's share of the
    exposure bias from ``_outer_bias_share``, the ground's contrast clearly under the white's and the white's black
    well below the clip), else None: the hint for fitting again the profiles a target's surround reaches
    (``Tracker._estimate``). Without a hint they were measured again, all clipped ones sharing one contrast where
    their sample no longer split: a 13 px target without a sheet on ground of 0.6 at x4 (the detection sweep's seed 9
    no-sheet-001) split 597 / 400 at first, then shared 419, and every edge took the white's whole bias (-1.55 %;
    with the split kept +0.04 %). A split the pose did not act on stays open to the new measurement: a 26 px target on
    a sheet at x16 (sRGB, 8 bit, its ink 70 levels under the clip: seed 3's encoded-004) split 634 / 252 at first, a
    sheet read as ground; kept, it moved the distance from +0.01 to +1.22 %."""
    return _split_contrast(edges, groups) if ground_apart else None


def _contrast_hint(track: _Track, exposure_us: float | None) -> FloatArray | None:
    """The contrast of a tracked target's clipped edges in this frame: the last clipped frame's, scaled by the
    exposure ratio when both exposures are known (the signal is linear in exposure time; a gain change is not seen here,
    and the edge fit measures the contrast again when the hint does not fit)."""
    last, then_us = track.clipped_contrast, track.contrast_exposure_us
    if last is None or exposure_us is None or then_us is None or not (exposure_us > 0 and then_us > 0):
        return last
    return last * float(exposure_us) / float(then_us)


OUTER_GROUND_RATIO = 0.7
OUTER_SHARE_MIN_FITS = 5
OUTER_SHARE_MIN_ROOM = 0.5
OUTER_SHARE_EVEN = 0.1
"""``_outer_bias_share``: the outermost circle's share of the exposure bias is set apart when its median contrast is
under ``OUTER_GROUND_RATIO`` of the other circles' (its bright side ground clearly darker than the target's white),
each with at least ``OUTER_SHARE_MIN_FITS`` ok fits, the white's black at least ``OUTER_SHARE_MIN_ROOM`` of the
clip level below it, and the outer profiles clipped or not alike (all but ``OUTER_SHARE_EVEN`` of them: even ground)."""


def _outer_differs(edges: EdgeFits, radius_m: FloatArray, ok: npt.NDArray[np.bool_]) -> bool:
    """Whether the edge fits show the outermost circle's bright side clearly darker than the target's white: its
    median contrast under ``OUTER_GROUND_RATIO`` of the other circles', each with ``OUTER_SHARE_MIN_FITS`` ok fits
    (a target printed without a sheet; a sheet's clipped profiles sharing one contrast with the white's read 1)."""
    if not ok.any():
        return False
    groups = _contrast_groups(radius_m[ok])
    contrast = edges.white_level[ok] - edges.black_level[ok]
    with np.errstate(invalid="ignore"):
        good = np.isfinite(contrast) & (contrast > 0)
    white_side, outer = good & (groups == 0), good & (groups == 1)
    if white_side.sum() < OUTER_SHARE_MIN_FITS or outer.sum() < OUTER_SHARE_MIN_FITS:
        return False
    return bool(median_where(contrast, outer) < OUTER_GROUND_RATIO * median_where(contrast, white_side))


def _outer_bias_share(edges: EdgeFits, radius_m: FloatArray, ok: npt.NDArray[np.bool_],
                      clip_level: float) -> FloatArray | None:
    """(ok.sum(),) the share of the exposure bias ``delta`` of each ok edge point (``pose_fit.bias_weights``), or
    None where every point takes it whole.

    ``delta`` is the white's bias: over-exposure clips an edge's profile a share ``q = (clip - black) / contrast``
    up its step, and what of the true blur (PSF tails, halo, the renderer's pixel integration) the clipped model
    does not hold moves the edge the more, the deeper the clip. The outermost circle of a target printed without a
    sheet has grey ground on its bright side, clipped far less deeply than the white (on ground at 0.2 the white
    clips at x2, the ground at x9): each of its profiles takes ``ln(1/q) / ln(1/q_white)`` of the white's bias (its
    own q from its fitted levels; the white's from the median of the other circles'), 0 while its ground is not
    clipped, about 1 for a white sheet (clipped as deep as the white). Measured on sheetless
    targets on grey ground (simulator, 40-64 px, true pose): the outer edge moved 0.1-0.2 of the white's
    displacement at x16 and 0.37-0.57 at x32, where this gives 0.25 and 0.43; taking the white's whole bias put
    those targets' distance -0.1 to -1.0 % off."""
    if not ok.any():
        return None
    groups = _contrast_groups(radius_m[ok])
    contrast = edges.white_level[ok] - edges.black_level[ok]
    black = edges.black_level[ok]
    with np.errstate(invalid="ignore"):
        good = np.isfinite(contrast) & (contrast > 0) & np.isfinite(black)
    white_side, outer = good & (groups == 0), good & (groups == 1)
    if white_side.sum() < OUTER_SHARE_MIN_FITS or outer.sum() < OUTER_SHARE_MIN_FITS:
        return None
    c_white, c_outer = median_where(contrast, white_side), median_where(contrast, outer)
    if not c_outer < OUTER_GROUND_RATIO * c_white:
        return None
    clipped = float(np.mean(edges.n_clipped[ok][outer] > 0))
    if OUTER_SHARE_EVEN < clipped < 1.0 - OUTER_SHARE_EVEN:
        # ground clipped here and not there: textured, its level differs from profile to profile, and the one
        # contrast its clipped profiles share says little of each one's depth (a photo behind a target at x16:
        # 45 % of them clipped at a shared contrast that put their white under the clip, each read unclipped)
        return None
    room = clip_level - median_where(black, white_side)
    if not OUTER_SHARE_MIN_ROOM * clip_level <= room < c_white:
        # the white not clipped (no clipping bias to share), or the ink itself lifted near the clip (x32 with glare:
        # every contrast measured on a few levels of room, the outer one read at 0.5 of the white's on a sheet)
        return None
    # each outer profile by its own levels: one not clipped (its fitted white under the clip: q > 1) takes none,
    # a clipped one its clip depth's share (with the ground's own contrast where the fit gave it one; with the
    # white's, shared, about all of it)
    depth = -np.log(room / c_white)
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.clip(np.log(contrast / (clip_level - black)) / depth, 0.0, 1.0)
    return np.where((groups == 1) & good & (black < clip_level), share, 1.0)
