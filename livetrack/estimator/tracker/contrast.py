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


def _contrast_hint(track: _Track, exposure_us: float | None) -> FloatArray | None:
    """The contrast of a tracked target's clipped edges in this frame: the last clipped frame's, scaled by the
    exposure ratio when both exposures are known (the signal is linear in exposure time; a gain change is not seen here,
    and the edge fit measures the contrast again when the hint does not fit)."""
    last, then_us = track.clipped_contrast, track.contrast_exposure_us
    if last is None or exposure_us is None or then_us is None or not (exposure_us > 0 and then_us > 0):
        return last
    return last * float(exposure_us) / float(then_us)
