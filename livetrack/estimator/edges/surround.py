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

STAND_IN_MIN_FITS = 3
"""``step_share``: the ok fits a call needs for a failed one to take their median blur and contrast."""

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


def step_share(prof: Profiles, fits: EdgeFits, step_px: FloatArray, hole: FloatArray | None = None,
               ratio: FloatArray | None = None) -> FloatArray:
    """(N, K) the darkening of each sample by the next edge, from the fits ``fits`` of these N profiles (0 on rows
    whose ``step_px`` is not finite; a row whose fit is not ok takes the edge where it was sampled, with the median
    blur and contrast of the ok ones, given ``STAND_IN_MIN_FITS`` of them, else 0): ``C`` times the share of the
    sample's blur (a Gaussian of variance ``sigma^2 + 1/12``: the PSF's core and the pixel's footprint) that falls on
    the black beyond the next circle.

    step_px: (N,) the distance (px, along the normal, from the edge point the profile was sampled about) of the
    design's next edge on the white side, where the white ends in a step back to the black; inf for none.
    hole: None, or (N,) where the black beyond a next circle inside ends, as a ratio of that circle's radius (the
    nested level's white disk: its inner radius over its outer one; 0: black to the centre). Not used for a next
    circle outside.
    ratio: None, or (N,) the next circle's radius over this circle's (the design's: 0.5 from an inner circle to the
    nested ring); None: taken from the profile's curvature as if its osculating circle were the circle (face-on).

    Each circle is taken as its osculating circle at the profile (``half_kappa``: radius ``R = 1 / (2 |half_kappa|)``
    through the sampled point, ``R - d`` through the edge fitted at ``d``, its centre on the white side; ``R + d`` on
    the black side): the next circle's is that scaled by ``ratio`` (``k``), at ``w = step_px + (k - 1) d`` beyond
    the fitted edge along the normal (``step_px = |1 - k| h`` from the sampled point at ``h`` from the centre: the
    fitted edge's is ``|1 - k| (h - d)``, or ``+ d`` outside). Its black is a disk (the nested level's ring, inside
    an inner circle: the share is the blurred disk's, ``P(rho, r)`` of :mod:`~livetrack.estimator.surround_kernels`,
    the non-central chi-square CDF, less that of its white disk, the osculating circle scaled by ``hole`` through
    that disk's edge, ``(1 - hole) k h`` farther along the normal) or all beyond a circle (a
    parent's ring outside a nested level: ``1 - P``), at the sample's distance ``r`` from that circle's centre. A
    tilted target's circles are ellipses, whose osculating circles are not concentric: scaling the profile's own
    keeps the next circle's curvature where the profile meets it (a 70 deg, 9 px target's minor-axis ends have an
    osculating radius 9x their distance from the centre; taken as concentric circles, the nested ring came out
    nearly straight there and was over-corrected, +0.15-0.6 %). Straight rows (no curvature) take the half-plane's
    blurred step.

    Before session 42 the step was a half-plane at ``d + step_px`` moved by its curvature, ``kappa_n (sigma^2 +
    1/12) / 2``: on a 13 px target (its nested ring 2.7 px in radius, the blur ~1 px) that read 20-40 % less
    darkening than the nested ring gives (the first-order curvature shift, and the step not moved with the fitted
    edge: the detector's circle 0.15 px too large put it 0.08 px too far), and with the profiles held 1.5 px short
    of it (``surround_geometry.REACH_MARGIN_PX``) the white level was read 3 % low and the inner edge 0.03 px into
    the black: distances -0.16 % at 13 px, -0.1 % at 15 px, -0.03 % at 18 px (sheets, 8 and 12 bit, 16 draws each;
    without the nested ring -0.02 %).

    The PSF's core only: a wide halo (``fit_edges(halo=...)``, sigma ~6 px) sees the next edge's whole ring (5 px
    wide on a 43 px target, 0.1 of the inner disk's area), not a half-plane; its step modelled as one moved those
    targets' distance at x8 by +-0.01 % either way (paper-lab, known optics), and the small targets whose profiles
    the core's step reaches read the same with or without it."""
    contrast = fits.white_level - fits.black_level
    offset, sigma = fits.offset_px, fits.sigma_px
    with np.errstate(invalid="ignore"):
        good = fits.ok & np.isfinite(offset) & (contrast > 0)
    use = good & np.isfinite(step_px)
    stand_in = np.isfinite(step_px) & ~good
    if stand_in.any() and good.sum() >= STAND_IN_MIN_FITS:
        # a profile whose fit failed (reaching the next edge, a single step can settle on its darkening) gets the
        # share of an edge where it was sampled, with the call's typical blur and contrast, and can fit again
        offset = np.where(stand_in, 0.0, offset)
        sigma = np.where(stand_in, float(np.median(sigma[good])), sigma)
        contrast = np.where(stand_in, float(np.median(contrast[good])), contrast)
        use = use | stand_in
    if not use.any():
        return np.zeros(prof.data.shape)
    half_kappa = prof.half_kappa[:, 0]
    sign = np.sign(half_kappa)  # +1: the centre on the white side (the next circle inside), -1: outside
    radius_px = np.divide(0.5, np.abs(half_kappa), out=np.full_like(half_kappa, np.inf), where=half_kappa != 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        # the next circle's radius over this one's: given, else as if the profile's osculating circle were the
        # circle (a target seen face-on)
        k = 1.0 - sign * step_px / radius_px if ratio is None else np.asarray(ratio, dtype=np.float64)
        at = np.where(use, step_px + k * offset, 0.0)  # the next edge, from the fitted one along the normal
        # its osculating circle: this profile's, through the fitted edge, scaled by the ratio
        rho = np.where(use & (half_kappa != 0), np.maximum(k * (radius_px - sign * offset), 0.0), np.inf)
        holes = np.zeros(len(use)) if hole is None else np.where(sign > 0, np.asarray(hole, dtype=np.float64), 0.0)
        # the white disk's edge, (1 - hole) of the next circle's distance from the centre beyond it (that distance
        # along the normal is k h for the fitted edge's h, with step_px = |1 - k| h of the sampled point's)
        hole_at = np.where(holes > 0, at + (1.0 - holes) * k * (step_px / np.abs(1.0 - k) - sign * offset), np.inf)
    if kernels() == "numba":
        return surround_kernels.step_share(prof.u0, prof.valid, use, at, rho, sign, sigma, prof.a[:, 0],
                                           prof.b[:, 0], contrast, STEP_REACH_SIGMA, surround_kernels.disk_table(),
                                           holes, hole_at)
    # only rows whose step comes within STEP_REACH_SIGMA blurs of their last sample (a large target's never does)
    last_u = np.where(prof.valid, prof.u0, -np.inf).max(axis=1, initial=-np.inf)
    with np.errstate(invalid="ignore"):
        use &= at - last_u < STEP_REACH_SIGMA * sigma
    share = np.zeros(prof.data.shape)
    rows = np.flatnonzero(use)
    if len(rows) == 0:
        return share
    sig = sigma[rows, None]
    u0 = prof.u0[rows]
    curved = np.isfinite(rho[rows])
    s_e = np.sqrt(sig * sig + 1.0 / 12.0)
    sg, at_r = sign[rows, None], at[rows, None]
    rho_r = np.where(curved, rho[rows], 0.0)[:, None]
    with np.errstate(invalid="ignore"):
        r = np.abs(rho_r - sg * (u0 - at_r))  # the samples' distance from the next circle's centre
        inside = chndtr((rho_r / s_e) ** 2, 2.0, (r / s_e) ** 2)
        # its own white disk: the osculating circle scaled by ``hole``, through its edge
        rho_h = holes[rows, None] * rho_r
        r_h = np.abs(rho_h - sg * (u0 - np.where(holes[rows] > 0, hole_at[rows], 0.0)[:, None]))
        inside -= np.where(rho_h > 0, chndtr((rho_h / s_e) ** 2, 2.0, (r_h / s_e) ** 2), 0.0)
    disk = np.where(sg > 0, inside, 1.0 - inside)
    plane = edge_response(u0 - at_r, sig, prof.a[rows], prof.b[rows])  # straight rows
    response = np.where(curved[:, None], disk, plane)
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
                   disks: WhiteDisks | None, hole: FloatArray | None = None,
                   ratio: FloatArray | None = None) -> FloatArray:
    """(N, K) what the surround adds to each sample (intensity): the white disks' brightening less the next edge's
    darkening, from the fits ``fits`` of these N profiles."""
    share = None  # (-step) + disks: the values of 0 - step + disks, without the zeros and two (N, K) passes
    if step_px is not None:
        share = -step_share(prof, fits, step_px, hole, ratio)
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
