"""What the design puts around an edge, modelled in its profile: the next edge on the white side (a nested level's
ring) and the white code dots on the black side, known in position, blurred like the edge.

On a small target the bands beside an edge are narrow. The inner disk of a 12 px target ends 2.4 px inside its
inner circle, where the nested level's black ring begins; blurred (sigma ~1 px), that ring darkens the last white
samples of the inner circle's profiles by 5-15 % of the contrast, and a single-step model then reads a lower white
level and puts the edge ~0.1 px into the black (distance -0.6 to -1.1 % on 11-16 px targets, paper-lab optics;
the same targets rendered without the nested level read within 0.1 %). Likewise the code dots, 0.2 R from both
circles on their black side, lift the black samples of the profiles passing near them.

Blur and pixel integration are linear, so before the clip a profile's samples are the edge's step plus what its
surround adds:

    I(x) = Lb + C [E(u - d - s) - E(u - d - w - s_n) + sum_k P_k(x)]

with ``E`` the pixel response of :mod:`livetrack.estimator.edge_model` (``s``, ``s_n`` the curvature shifts of the
edge and of the next circle, ``w`` the distance to that circle along the normal, exposure-free: both are printed)
and ``P_k`` the blurred disk of white dot k at the sample's pixel. :func:`without_surround` takes what the
surround adds, evaluated at a fit's ``(d, sigma, C)``, off the unclipped samples; the single-step fit of the result
is the fit of the full model once the evaluation point stops moving
(:func:`~livetrack.estimator.edges.two_pass.fit_edges_two_pass` iterates: the share changes by <1 % of C per 0.1
px of ``d``). Clipped samples are left alone: a sample clipped high under the full model is clipped under the
single step too (a dot lies on the black side, a clipped-high sample on the white one); one clipped low lies on the
black side, away from the next edge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.special import chndtr

from livetrack.estimator import surround_kernels
from livetrack.estimator.edge_kernels import kernels
from livetrack.estimator.edge_model import edge_response
from livetrack.estimator.edge_samples import Profiles
from livetrack.estimator.edges.solver import EdgeFits

FloatArray = npt.NDArray[np.float64]

NEGLIGIBLE_SHARE = 1e-4
"""A profile whose samples the surround changes by less than this fraction of its contrast is left as it is."""

DISK_REACH_SIGMA = 4.0
"""A white disk is evaluated at the samples within its radius plus this many blur widths (beyond, its share is under
3e-5 of the contrast: below ``NEGLIGIBLE_SHARE``); the code dots of a level whose dots lie farther than this from
its profiles' ends are not placed at all (``surround_geometry.white_disks``: targets over ~35 px)."""

STEP_REACH_SIGMA = 4.0
"""The next edge's step is evaluated on the profiles whose last sample comes within this many blur widths of it
(beyond, its share is under 3e-5 of the contrast)."""

_ANISOTROPY = 2.0
"""Rows are pre-selected for a disk by the image distance of their middle pixel, with this many times its mean
radius ``g r`` of room for an obliquely seen disk (whose long axis is (1/cos(tilt))^(1/2) times that: 1.5x at
64 deg), plus the disk's blur reach and the row's own span."""


@dataclass(frozen=True)
class WhiteDisks:
    """White disks of the design (code dots) as seen in the image: M disks of radius ``radius_m`` in the target's
    plane, centred at ``centres_px`` (M, 2) (column, row; pixel centres at integers), with ``px_to_m`` (M, 2, 2) the
    inverse of the projection's local Jacobian at each centre (metres in the plane per pixel) and
    ``scale_px_per_m`` (M,) the square root of its determinant (the disk's mean scale); ``turn_rad``: the turn about
    the target's normal they were placed with, relative to the pose that placed them (bookkeeping for the caller)."""

    centres_px: FloatArray
    px_to_m: FloatArray
    radius_m: FloatArray
    scale_px_per_m: FloatArray
    turn_rad: float = 0.0

    def __len__(self) -> int:
        return len(self.centres_px)


def step_share(prof: Profiles, fits: EdgeFits, step_px: FloatArray) -> FloatArray:
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
    contrast = fits.white_level - fits.black_level
    use = fits.ok & np.isfinite(step_px) & np.isfinite(fits.offset_px) & (contrast > 0)
    if not use.any():
        return np.zeros(prof.data.shape)
    compiled = kernels() == "numba"
    if not compiled:  # (the compiled kernel applies this gate row by row, without the (N, K) temporaries)
        # only rows whose step comes within STEP_REACH_SIGMA blurs of their last sample (a large target's never does)
        last_u = np.where(prof.valid, prof.u0, -np.inf).max(axis=1, initial=-np.inf)
        with np.errstate(invalid="ignore"):
            use &= fits.offset_px + step_px - last_u < STEP_REACH_SIGMA * fits.sigma_px
        if not use.any():
            return np.zeros(prof.data.shape)
    # the next circle's curvature: radius r -/+ w for a centre on the white/black side (half_kappa = +/- 1/(2r))
    half_kappa = prof.half_kappa[:, 0]
    radius_px = np.divide(0.5, np.abs(half_kappa), out=np.full_like(half_kappa, np.inf), where=half_kappa != 0)
    with np.errstate(invalid="ignore"):
        next_radius_px = radius_px - np.sign(half_kappa) * step_px
    half_kappa_next = np.divide(np.sign(half_kappa) * 0.5, next_radius_px, out=np.zeros_like(half_kappa),
                                where=use & np.isfinite(next_radius_px) & (next_radius_px > 0))
    at = np.where(use, fits.offset_px + step_px, 0.0)
    if compiled:
        return surround_kernels.step_share(prof.u0, prof.valid, use, at, fits.sigma_px, half_kappa_next,
                                           prof.a[:, 0], prof.b[:, 0], contrast, STEP_REACH_SIGMA)
    share = np.zeros(prof.data.shape)
    rows = np.flatnonzero(use)
    sig = fits.sigma_px[rows, None]
    u0, a, b = prof.u0[rows], prof.a[rows], prof.b[rows]
    response = edge_response(u0 - (at[rows, None] + half_kappa_next[rows, None] * (sig * sig + 1.0 / 12.0)), sig, a,
                             b)
    share[rows] = contrast[rows, None] * response * prof.valid[rows]
    return share


def disks_share(prof: Profiles, fits: EdgeFits, disks: WhiteDisks) -> FloatArray:
    """(N, K) the brightening ``C sum_k P_k(x)`` of each sample by the white disks, from the fits ``fits`` of these
    N profiles (0 on rows whose fit is not ok). ``P_k`` is the share of a Gaussian of variance
    ``sigma^2 + 1/12`` (the PSF's core and the pixel's footprint) centred on the sample's pixel that falls in disk
    k, taken as a circle of the disk's mean scale (the non-central chi-square distribution with 2 degrees of
    freedom; exact for a disk seen face-on, its ellipse otherwise rounded to the mean scale)."""
    share = np.zeros(prof.data.shape)
    contrast = fits.white_level - fits.black_level
    use = fits.ok & np.isfinite(fits.offset_px) & (contrast > 0)
    if len(disks) == 0 or not use.any() or prof.ix is None:
        return share
    sig = np.where(use, fits.sigma_px, 0.0)
    if kernels() == "numba":
        # a row's samples lie within 2 max|u0| + 2 px of each other; in the disks' rounded metric up to the
        # largest stretch of their inverse Jacobians more (bounded by g times its Frobenius norm)
        stretch = float((disks.scale_px_per_m * np.sqrt((disks.px_to_m ** 2).sum(axis=(1, 2)))).max())
        span_px = stretch * (2.0 * float(np.abs(prof.u0).max(initial=0.0)) + 2.0)
        return surround_kernels.disks_share(prof.ix, prof.iy, prof.valid, use, sig, np.where(use, contrast, 0.0),
                                            disks.centres_px, disks.px_to_m, disks.radius_m, disks.scale_px_per_m,
                                            DISK_REACH_SIGMA, surround_kernels.disk_table(), span_px)
    # each row's middle pixel: a disk is evaluated on the rows whose middle lies within its reach plus the row's span
    n_valid = np.maximum(prof.valid.sum(axis=1), 1)
    middle = np.stack([(prof.ix * prof.valid).sum(axis=1), (prof.iy * prof.valid).sum(axis=1)], axis=1)
    middle = middle / n_valid[:, None]
    span_px = np.abs(np.where(prof.valid, prof.u0, 0.0)).max(axis=1) + 1.0
    for c_px, to_m, r_m, g in zip(disks.centres_px, disks.px_to_m, disks.radius_m, disks.scale_px_per_m,
                                  strict=True):
        select_px = _ANISOTROPY * g * r_m + DISK_REACH_SIGMA * np.sqrt(sig * sig + 1.0 / 12.0) + span_px
        rows = np.flatnonzero(use & (np.hypot(*(middle - c_px).T) < select_px))
        if len(rows) == 0:
            continue
        xy = np.stack([prof.ix[rows], prof.iy[rows]], axis=-1).astype(np.float64)
        rel_m = (xy - c_px) @ to_m.T
        dist_px = g * np.hypot(rel_m[..., 0], rel_m[..., 1])
        s2 = sig[rows, None] ** 2 + 1.0 / 12.0
        near = prof.valid[rows] & (dist_px < g * r_m + DISK_REACH_SIGMA * np.sqrt(s2))
        if not near.any():
            continue
        part = np.zeros(dist_px.shape)
        part[near] = chndtr((g * r_m) ** 2 / np.broadcast_to(s2, near.shape)[near], 2.0,
                            dist_px[near] ** 2 / np.broadcast_to(s2, near.shape)[near])
        share[rows] += part
    return share * np.where(use, contrast, 0.0)[:, None]


def surround_share(prof: Profiles, fits: EdgeFits, step_px: FloatArray | None,
                   disks: WhiteDisks | None) -> FloatArray:
    """(N, K) what the surround adds to each sample (intensity): the white disks' brightening less the next edge's
    darkening, from the fits ``fits`` of these N profiles."""
    share = None  # (-step) + disks: the values of 0 - step + disks, without the zeros and two (N, K) passes
    if step_px is not None:
        share = -step_share(prof, fits, step_px)
    if disks is not None:
        dots = disks_share(prof, fits, disks)
        share = dots if share is None else share + dots
    return np.zeros(prof.data.shape) if share is None else share


def reaches(share: FloatArray, fits: EdgeFits) -> npt.NDArray[np.bool_]:
    """(N,) whether the surround changes a sample of a profile by more than ``NEGLIGIBLE_SHARE`` of its contrast."""
    contrast = np.abs(fits.white_level - fits.black_level)
    if kernels() == "numba":  # compiled (surround_kernels.reaches; this numpy its reference): the same booleans
        return surround_kernels.reaches(share, contrast, NEGLIGIBLE_SHARE)
    with np.errstate(invalid="ignore"):
        return np.abs(share).max(axis=1, initial=0.0) > NEGLIGIBLE_SHARE * np.where(np.isfinite(contrast),
                                                                                     contrast, np.inf)


def without_surround(prof: Profiles, share: FloatArray) -> Profiles:
    """The profiles with ``share`` taken off their unclipped samples (what the edge alone would have given)."""
    live = prof.valid & ~prof.clip_hi & ~prof.clip_lo
    return Profiles(prof.u0, prof.a, prof.b, prof.data - share * live, prof.valid, prof.clip_hi, prof.clip_lo,
                    prof.w, prof.top, prof.half_kappa, prof.valid_f, prof.n_valid, prof.any_clipped, prof.n_span,
                    ix=prof.ix, iy=prof.iy)
