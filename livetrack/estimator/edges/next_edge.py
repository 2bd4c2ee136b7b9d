"""The design's next edge on the white side of an edge profile: its blurred step, known in position, modelled.

On a small target the white band beyond an edge is narrow: the inner disk of a 12 px target ends 2.4 px inside
its inner circle, where the nested level's black ring begins. Blurred (sigma ~1 px), that ring darkens the last
white samples of the inner circle's profiles by 5-15 % of the contrast; a single-step model then reads a lower
white level and puts the edge ~0.1 px into the black (distance -0.6 to -1.1 % on 11-16 px targets, paper-lab
optics; the same targets rendered without the nested level read within 0.1 %).

The profile across an edge at offset ``d`` whose white band ends after ``w`` px (along the normal, measured from
the edge, exposure-free: both edges are printed) is, before the clip,

    I(u) = Lb + C [E(u - d - s) - E(u - d - w - s_n)]

(``E`` the pixel response of :mod:`livetrack.estimator.edge_model`, ``s`` and ``s_n`` the two circles' curvature
shifts). :func:`without_next_edge` adds the second term, evaluated at a fit's ``(d, sigma, C)``, back to the
unclipped samples; the single-step fit of the result is the two-step fit of the data once the evaluation point
stops moving (:func:`~livetrack.estimator.edges.two_pass.fit_edges_two_pass` iterates: the term changes by
<1 % of C per 0.1 px of ``d``, so one repeat from a converged fit suffices). Clipped samples are left alone: a
sample clipped high under the two-step model is clipped under the single step too; one clipped low lies on the
black side, where the term is ~0.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from livetrack.estimator.edge_model import edge_response
from livetrack.estimator.edge_samples import Profiles
from livetrack.estimator.edges.solver import EdgeFits

FloatArray = npt.NDArray[np.float64]

NEGLIGIBLE_SHARE = 1e-4
"""A profile whose samples the next edge darkens by less than this fraction of its contrast is left as it is."""


def next_edge_term(prof: Profiles, fits: EdgeFits, step_px: FloatArray) -> FloatArray:
    """(N, K) the darkening ``C E(u - d - w - s_n)`` of each sample by the next edge, from the fits ``fits`` of
    these N profiles (0 on rows whose fit is not ok or whose ``step_px`` is not finite).

    step_px: (N,) the distance (px, along the normal, from the edge) of the design's next edge on the white side,
    where the white ends in a step back to the black; inf for none. Its curvature shift is the blurred disk's,
    ``kappa_n (sigma^2 + 1/12) / 2`` towards the common centre, with ``kappa_n`` the next circle's curvature
    (``half_kappa`` of the profile scaled by the radii, the circles being concentric).

    The PSF's core only: a wide halo (``fit_edges(halo=...)``, sigma ~6 px) sees the next edge's whole ring (5 px
    wide on a 43 px target, 0.1 of the inner disk's area), not a half-plane; its step modelled as one moved those
    targets' distance at x8 by +-0.01 % either way (paper-lab, known optics), and the small targets whose profiles
    the core's step reaches read the same with or without it."""
    term = np.zeros(prof.data.shape)
    contrast = fits.white_level - fits.black_level
    use = fits.ok & np.isfinite(step_px) & np.isfinite(fits.offset_px) & (contrast > 0)
    if not use.any():
        return term
    rows = np.flatnonzero(use)
    sig = fits.sigma_px[rows, None]
    half_kappa = prof.half_kappa[rows]
    # the next circle's curvature: radius r -/+ w for a centre on the white/black side (half_kappa = +/- 1/(2r))
    radius_px = np.divide(0.5, np.abs(half_kappa), out=np.full_like(half_kappa, np.inf), where=half_kappa != 0)
    next_radius_px = radius_px - np.sign(half_kappa) * step_px[rows, None]
    half_kappa_next = np.divide(np.sign(half_kappa) * 0.5, next_radius_px, out=np.zeros_like(half_kappa),
                                where=np.isfinite(next_radius_px) & (next_radius_px > 0))
    at = fits.offset_px[rows, None] + step_px[rows, None]
    u0, a, b = prof.u0[rows], prof.a[rows], prof.b[rows]
    response = edge_response(u0 - (at + half_kappa_next * (sig * sig + 1.0 / 12.0)), sig, a, b)
    term[rows] = contrast[rows, None] * response * prof.valid[rows]
    return term


def reaches(term: FloatArray, fits: EdgeFits) -> npt.NDArray[np.bool_]:
    """(N,) whether the next edge darkens a sample of a profile by more than ``NEGLIGIBLE_SHARE`` of its contrast."""
    contrast = np.abs(fits.white_level - fits.black_level)
    with np.errstate(invalid="ignore"):
        return term.max(axis=1, initial=0.0) > NEGLIGIBLE_SHARE * np.where(np.isfinite(contrast), contrast, np.inf)


def without_next_edge(prof: Profiles, term: FloatArray) -> Profiles:
    """The profiles with ``term`` added back to their unclipped samples (what a single step would have given)."""
    live = prof.valid & ~prof.clip_hi & ~prof.clip_lo
    out = Profiles(prof.u0, prof.a, prof.b, prof.data + term * live, prof.valid, prof.clip_hi, prof.clip_lo, prof.w,
                   prof.top, prof.half_kappa, prof.valid_f, prof.n_valid, prof.any_clipped, prof.n_span)
    return out
