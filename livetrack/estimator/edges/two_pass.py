"""Edge fits in passes: clean profiles with free blur, clipped ones with the frame's blur and (optionally) one
shared contrast, started from earlier fits in tracking (:func:`fit_edges_two_pass`)."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import numpy.typing as npt

from livetrack.estimator.edge_samples import check_points, sample_profiles
from livetrack.estimator.edges import surround
from livetrack.estimator.edges.solver import EdgeFits, _check_halo, _fit

IntArray = npt.NDArray[np.int64]


def fit_edges_two_pass(
    image: npt.ArrayLike,
    points_px: npt.ArrayLike,
    normals: npt.ArrayLike,
    saturation: float,
    min_clean_fits: int = 5,
    curvature_per_px: npt.ArrayLike | None = None,
    start: EdgeFits | None = None,
    sigma_fallback_px: float | None = None,
    contrast_hint: float | npt.ArrayLike | None = None,
    contrast_groups: npt.ArrayLike | None = None,
    reach_px: npt.ArrayLike | None = None,
    white_step_px: npt.ArrayLike | None = None,
    white_disks: surround.WhiteDisks | None = None,
    start_fits_these: bool = False,
    memo: dict | None = None,
    **options,
) -> EdgeFits:
    """:func:`fit_edges` with the blur of clipped profiles taken from the well-exposed ones of the frame.

    Pass 1 fits the points whose sampled profile has no clipped pixel with free sigma; pass 2 fits the
    others with ``fix_sigma`` = the median sigma of the ok pass-1 fits (or ``sigma_init_px`` when fewer
    than ``min_clean_fits`` (default 5) are ok).  Assumes one PSF width for the whole frame (or region:
    call it per target).  The pixels are sampled once for both passes; pass 2 is cheaper than a free-sigma
    fit of clipped profiles, which also converges far more slowly.

    start: None (default), or earlier fits of the same N points (e.g. the last frame's), ``offset_px``
    relative to ``points_px``: each ok point of pass 1 starts at that fit's blur, and, if its mid-level
    crossing is within 0.1 px of that fit (the edge has not moved), at its offset and levels, instead of the
    data-driven start (crossing, min/max levels, ``sigma_init_px``).  At the solution already (a static
    target) such a point costs one model evaluation instead of ~3-4 and gives the same fit.  Pass 2
    (clipped profiles) always starts from its data: started from a fit of a moved edge, its slow valley
    (position against contrast) left ~10 % of the points unconverged.

    sigma_fallback_px: the blur of pass 2 when fewer than ``min_clean_fits`` are ok; None (default):
    ``sigma_init_px``.  Lets a caller start pass 1 from a known blur without changing that fallback.

    shared_contrast (option): False (default) or True: pass 3 refits the clipped profiles with the contrast
    fixed at the median of ok pass-2 fits, i.e. one black-to-white contrast for all the points of the call (one
    target, evenly lit, the same black and white paper on both sides of every edge).  A clipped profile shows
    only the tail of its edge, where position and contrast trade off: per point the position scatters ~0.2 px
    at 16x (paper-lab, known PSF) and the nonlinear fit biases it differently on different circles; with the
    shared contrast the scatter falls to ~0.02 px and an error of the shared value (or of the blur, or an
    unmodelled halo) moves every edge alike, which the pose's exposure bias delta absorbs.  (One contrast per
    circle instead let those errors differ between circles: in the paper-lab exposure sweep the mean distance
    error grew from 0.007 % to 0.031 %.)  Contrast that really varies over the call (uneven light) moves the
    edges where it differs from the shared value: a 5 % error moves an edge by 0.06 px at 2x, 0.03 px at 4x
    and 0.02 px at 16x over-exposure (sigma 0.8 px, measured).  Pass 2 runs on an even subsample of the
    clipped profiles (``_CONTRAST_SAMPLE_ROWS``; with fewer than ``min_clean_fits`` ok fits the per-point fits
    of all of them are kept instead); pass 3 fits every clipped profile with the shared value, from the offset
    that contrast gives its transition samples (one candidate of the ``_initial_params`` scan), or from
    ``start`` where that fit lies within 0.1 px of it.

    contrast_groups: None (default: one group), or an (N,) integer label per point: with ``shared_contrast``,
    which bright side each point has, 0 the target's own white, others what lies around it. A group clearly
    darker than group 0 (``CONTRAST_SPLIT_RATIO``) gets a contrast of its own, otherwise all share one. A target
    printed without a white sheet has the ground, not its white, outside its outer circle: one contrast for all
    put that circle's clipped edges off (grey ground at 16x over-exposure: distance -0.8 to -1.6 %).

    contrast_hint: None (default), or the shared contrast known beforehand (scalar, or (N,) per point; e.g. the
    last frame's, scaled by the exposure ratio): with ``shared_contrast``, passes 2 and 3 are replaced by one
    fit with the hint, kept unless fewer than ``_HINT_MIN_OK`` (80 %) of the clipped profiles then fit ok or
    (with ``start``) their median residual grows by more than ``_HINT_MAX_RESIDUAL_GROWTH``; otherwise the
    contrast is measured as without a hint.  At a static target and constant exposure this makes a clipped
    frame about as cheap as a clean one.

    reach_px: None, or (N, 2) how far each profile may reach toward its black and its white side (pixels, on top
    of ``half_width_px``): the room to the target's next edge on either side (see ``sample_profiles``).

    white_step_px: None, or (N,) the distance (px, along the normal, from each edge) of the design's next edge on
    its white side, where the white band ends in a step back to the black (inf: none; e.g. the nested level's ring
    inside an inner circle). That step is modelled (:mod:`~livetrack.estimator.edges.surround`): the profiles it
    reaches are fitted again with its blurred share, taken at the first fit (or at ``start``), added back to their
    unclipped samples. Without it a 12 px target's inner circle read ~0.1 px into the black.

    white_disks: None, or the design's white disks near the edges (the code dots, placed by a pose), modelled
    alike: their blurred share taken off the samples of the profiles they reach.

    start_fits_these: ``start`` are fits of these very profiles (this image, these points: a search's fits, made
    before the code dots were placed): with ``white_step_px`` or ``white_disks``, the surround's share is taken
    from them and only the profiles it reaches are fitted again (the others' samples change by less than
    ``surround.NEGLIGIBLE_SHARE`` of their contrast, and they keep ``start``'s fits), but for the clipped ones:
    their shared contrast is measured again from its sample of per-point fits, of which only those the share
    reaches are made again (see ``memo``), and all are fitted with it. The fits made again while the share
    settles (after the first fit, or when a ``start``'s share was not kept) are restricted alike.

    memo: None, or a dict the caller keeps between calls on the same profiles: this call leaves in it the fits it
    returns and its clipped profiles' contrast sample (the per-point fits whose median is the shared contrast);
    with ``start_fits_these`` and a ``start`` that is the fits it holds, that sample is reused (without it, a
    frame with clipped profiles has every profile fitted again).

    Arguments as :func:`fit_edges` (``options`` are passed on, ``halo`` to both passes; ``fix_sigma`` is not
    accepted).
    Returns an :class:`EdgeFits` in the order of ``points_px``.
    """
    if "fix_sigma" in options:
        raise ValueError("fit_edges_two_pass chooses fix_sigma itself; call fit_edges to fix it")
    if start is not None and len(start) != len(np.asarray(points_px).reshape(-1, 2)):
        raise ValueError(f"start has {len(start)} fits for {len(np.asarray(points_px).reshape(-1, 2))} points")
    unknown = set(options) - _FIT_OPTIONS
    if unknown:
        raise TypeError(f"fit_edges_two_pass got unexpected options {sorted(unknown)}")
    opt = {**_FIT_DEFAULTS, **options}
    pts, nrm = check_points(image, points_px, normals)
    n = len(pts)
    sat = float(saturation)
    s_lo, s_hi = (float(v) for v in opt["sigma_bounds_px"])
    prof, n_samples, n_clipped = sample_profiles(
        np.asarray(image), pts, nrm, sat, opt["half_width_px"], opt["tangent_half_width_px"], opt["noise_model"],
        curvature_per_px, reach_px,
    )
    min_con = 0.02 * sat if opt["min_contrast"] is None else float(opt["min_contrast"])
    weighted = opt["noise_model"] is not None
    halo = _check_halo(opt["halo"])

    state: dict = {}  # the clipped profiles' contrast sample of the last fits (see ``memo``), for ``refit``

    def solve(prof, start):
        """The passes on the profiles ``prof``, started from ``start``."""
        state.clear()
        def run(rows, sig0, fixed):
            begin = None if start is None or fixed else tuple(
                np.asarray(x)[rows] for x in (start.ok, start.offset_px, start.sigma_px, start.black_level,
                                              start.white_level))
            return _fit(prof.take(rows), pts[rows], nrm[rows], sat, sig0, fixed, n_samples[rows], n_clipped[rows],
                        opt["half_width_px"], (s_lo, s_hi), min_con, opt["iterations"], weighted, begin, halo)

        def run_clipped(rows, sig0, begin=None, contrast=None):
            """Pass 2 (and 3): fixed blur (and contrast)."""
            return _fit(prof.take(rows), pts[rows], nrm[rows], sat, sig0, True, n_samples[rows], n_clipped[rows],
                        opt["half_width_px"], (s_lo, s_hi), min_con, opt["iterations"], weighted, begin, halo, contrast)

        sigma_init = float(opt["sigma_init_px"])
        clipped = n_clipped > 0
        sigma_start = min(max(sigma_init, s_lo), s_hi)  # np.clip's number (~3 us less than np.clip on a scalar)
        if not clipped.any():  # every row (a slice: views of the profiles, not copies; the same fits)
            return run(slice(None), np.full(n, sigma_start), False)
        clean_rows, clipped_rows = np.flatnonzero(~clipped), np.flatnonzero(clipped)
        clean = run(clean_rows, np.full(len(clean_rows), sigma_start), False)
        good = clean.ok
        fallback = sigma_init if sigma_fallback_px is None else float(sigma_fallback_px)
        sigma = float(np.median(clean.sigma_px[good])) if good.sum() >= min_clean_fits else fallback
        sigma_rows = np.full(len(clipped_rows), sigma)
        parts = [(clean_rows, clean)]
        if not opt["shared_contrast"]:
            return _merged(n, parts + [(clipped_rows, run_clipped(clipped_rows, sigma_rows))])
        groups = np.zeros(n, dtype=np.int64) if contrast_groups is None else np.asarray(contrast_groups, np.int64)
        if groups.shape != (n,):
            raise ValueError(f"contrast_groups has shape {groups.shape} for {n} points")
        hint = None if contrast_hint is None else np.broadcast_to(np.asarray(contrast_hint, np.float64), (n,))
        if hint is not None and np.all(np.isfinite(hint[clipped_rows]) & (hint[clipped_rows] > 0)):
            begin = None if start is None else tuple(
                np.asarray(x)[clipped_rows] for x in (start.ok, start.offset_px, start.sigma_px, start.black_level,
                                                      start.white_level, start.residual_rms))
            hinted = run_clipped(clipped_rows, sigma_rows, begin, hint[clipped_rows])
            if _hint_fits(hinted, begin):
                return _merged(n, parts + [(clipped_rows, hinted)])
        # the shared contrast: the median of the ok per-point fits of an even subsample, then all fitted with it
        sample = clipped_rows[:: max(1, len(clipped_rows) // _CONTRAST_SAMPLE_ROWS)]
        sampled = run_clipped(sample, np.full(len(sample), sigma))
        if sampled.ok.sum() >= min_clean_fits:
            state.update(sample=sample, sampled=sampled, sigma=sigma)
            contrast = _group_contrasts(sampled, groups[sample], groups[clipped_rows], min_clean_fits, sat)
            return _merged(n, parts + [(clipped_rows, run_clipped(clipped_rows, sigma_rows, None, contrast))])
        # Too few clipped profiles fit with a free contrast (deep over-exposure: each shows only the foot of its
        # edge, where position and contrast cannot be told apart). Any contrast shared by all of them places every
        # edge consistently, off by one amount that the pose's exposure bias delta absorbs: take the one that puts
        # the modelled edge at the clip level (contrast 2 x (clip - black)), where the samples change.
        black = sampled.black_level[np.isfinite(sampled.black_level)]
        if black.size and float(np.median(black)) < sat:
            nominal = 2.0 * (sat - float(np.median(black)))
            shared = run_clipped(clipped_rows, sigma_rows, None, nominal)
            if shared.ok.sum() > run_clipped(sample, np.full(len(sample), sigma)).ok.sum():
                return _merged(n, parts + [(clipped_rows, shared)])
        return _merged(n, parts + [(clipped_rows, run_clipped(clipped_rows, sigma_rows))])

    def remember(fits):
        if memo is not None:
            memo.clear()
            memo.update(fits=fits, state=dict(state))
        return fits

    if white_step_px is None and white_disks is None:
        return remember(solve(prof, start))
    step = None if white_step_px is None else np.broadcast_to(np.asarray(white_step_px, dtype=np.float64), (n,))

    def share_of(fits):
        return surround.surround_share(prof, fits, step, white_disks)

    clipped_row = n_clipped > 0

    def refit_rows(profiles, fits, rows, sigma=None):
        """Rows of ``profiles`` fitted again: clean ones from ``fits`` with a free blur (as ``solve``'s first
        pass), clipped ones of the contrast sample with the blur ``sigma`` fixed, from their data."""
        if sigma is None:
            begin = tuple(np.asarray(x)[rows] for x in (fits.ok, fits.offset_px, fits.sigma_px, fits.black_level,
                                                         fits.white_level))
            sig0, fixed = np.full(len(rows), min(max(float(opt["sigma_init_px"]), s_lo), s_hi)), False
        else:
            begin, sig0, fixed = None, np.full(len(rows), sigma), True
        return _fit(profiles.take(rows), pts[rows], nrm[rows], sat, sig0, fixed, n_samples[rows], n_clipped[rows],
                    opt["half_width_px"], (s_lo, s_hi), min_con, opt["iterations"], weighted, begin, halo)

    def refit(share, fits, touched):
        """``fits`` (of these profiles, made by ``solve`` or by this) fitted again with ``share`` taken off, as
        ``solve(without_surround(prof, share), fits)`` would, but only where the share reaches (``touched``; the
        other rows' data change by under ``NEGLIGIBLE_SHARE`` of their contrast: their fits stay): the touched
        clean rows (each fitted on its own); with clipped rows, the touched ones of the contrast sample (``state``),
        then the shared contrast from the sample and every clipped row with it, as ``solve`` does. Without the
        sample (a contrast hinted or not shared, or the frame's blur changed), every row is fitted again."""
        # (the rows by kind are found here, not per call: a tracked frame whose fits are kept never refits)
        all_clean, all_clipped = np.flatnonzero(~clipped_row), np.flatnonzero(clipped_row)
        row_groups = (np.zeros(n, dtype=np.int64) if contrast_groups is None
                      else np.broadcast_to(np.asarray(contrast_groups, np.int64), (n,)))
        rows = np.flatnonzero(touched | ~fits.ok)  # (a failed fit is made again too, as solve would)
        profiles = surround.without_surround(prof, share)
        clean = rows[~clipped_row[rows]]
        if len(all_clipped) and not state:
            return solve(profiles, fits)
        if len(clean):
            fits = _with_rows(fits, clean, refit_rows(profiles, fits, clean))
        if not len(all_clipped):
            return fits
        good = fits.ok[all_clean]
        fallback = float(opt["sigma_init_px"]) if sigma_fallback_px is None else float(sigma_fallback_px)
        sigma = float(np.median(fits.sigma_px[all_clean][good])) if good.sum() >= min_clean_fits else fallback
        if sigma != state["sigma"]:
            return solve(profiles, fits)
        sample, sampled = state["sample"], state["sampled"]
        again = np.flatnonzero(touched[sample])
        if len(again):
            sampled = _with_rows(sampled, again, refit_rows(profiles, fits, sample[again], sigma))
        if sampled.ok.sum() < min_clean_fits:
            return solve(profiles, fits)
        state["sampled"] = sampled
        contrast = _group_contrasts(sampled, row_groups[sample], row_groups[all_clipped], min_clean_fits, sat)
        final = _fit(profiles.take(all_clipped), pts[all_clipped], nrm[all_clipped], sat,
                     np.full(len(all_clipped), sigma), True, n_samples[all_clipped], n_clipped[all_clipped],
                     opt["half_width_px"], (s_lo, s_hi), min_con, opt["iterations"], weighted, None, halo, contrast)
        return _with_rows(fits, all_clipped, final)

    if start is not None and start_fits_these:  # a search's fits: only what the share reaches fitted again
        if memo is not None and memo.get("fits") is start:
            state.update(memo["state"])
        share = share_of(start)
        touched = surround.reaches(share, start)
        if not touched.any():
            return remember(start)
        fits = refit(share, start, touched)
        kept = touched & start.ok & fits.ok
        if kept.sum() >= 0.5 * (touched & start.ok).sum() and (
                abs(float(np.median(fits.offset_px[kept] - start.offset_px[kept]))) <= _SURROUND_STILL_PX):
            return remember(fits)
    elif start is not None:  # tracking: the last frame's fit gives the surround's share; kept if the edges stayed
        share = share_of(start)
        touched = surround.reaches(share, start)
        if touched.any():
            fits = solve(surround.without_surround(prof, share), start)
            kept = touched & start.ok & fits.ok
            if kept.sum() >= 0.5 * (touched & start.ok).sum() and (
                    abs(float(np.median(fits.offset_px[kept] - start.offset_px[kept]))) <= _SURROUND_STILL_PX):
                return remember(fits)
        else:  # nothing of the surround reaches these profiles (a large target): as without it
            return remember(solve(prof, start))
    else:
        fits = solve(prof, None)
    for _ in range(_SURROUND_REPEATS):
        share = share_of(fits)
        touched = surround.reaches(share, fits)
        if not touched.any():
            break
        fits = refit(share, fits, touched)
    return remember(fits)


_SURROUND_REPEATS = 2
"""With ``white_step_px`` or ``white_disks``, how often the surround's share is taken from the last fits and the
profiles fitted again (without ``start``): the first fit, 0.17 px off on an 11 px target, leaves the repeat's points
up to 0.012 px from the converged ones, the second within 0.0021 px (a point stops iterating at a 0.003 px step)."""

_SURROUND_STILL_PX = 0.05
"""With ``start``, the fits made with the surround's share taken from ``start`` are kept when the profiles it
reaches moved by at most this from ``start``'s offsets (the median of the moves: each point's own scatter, ~0.1 px
on an 11 px target, makes its share's error noise, not bias) and at least half of those ok in ``start`` are ok
again; otherwise the share is taken again from them and the profiles fitted again (a moved or re-exposed edge)."""


CONTRAST_SPLIT_RATIO = 0.7
CONTRAST_SPLIT_RATIO_DEEP = 0.5
CONTRAST_DEEP_CLIP = 3.0
CONTRAST_SPLIT_Z = 5.0
CONTRAST_SPLIT_Z_DEEP = 8.0
CONTRAST_SPLIT_MIN_FITS = 10
"""``contrast_groups``: group 0 is the target's own white, the others what lies around it (a sheet, or the ground
of a target printed without one). A group other than 0 keeps a contrast of its own only when it is clearly darker
than group 0: its median below ``CONTRAST_SPLIT_RATIO`` of group 0's (``CONTRAST_SPLIT_RATIO_DEEP`` when group 0's
contrast is over ``CONTRAST_DEEP_CLIP`` times the room between its black and the clip level) and more than
``CONTRAST_SPLIT_Z`` standard errors (each median's, from its MAD) from it, both measured on at least
``CONTRAST_SPLIT_MIN_FITS`` ok fits; or, that deep, below ``CONTRAST_SPLIT_RATIO`` and more than
``CONTRAST_SPLIT_Z_DEEP`` standard errors from it. Group 0 then has its own median too. Otherwise all share the
median of all.

A clipped profile's contrast is poorly measured (position and contrast trade off), and differently on different
circles of one white paper, the more so the deeper the clip: a 4x4 m-away target on a white sheet at 16x read
its outer circle's at 0.65 of its inner circle's, a 9 px target's blurred inner circle 0.22 of its outer one's.
One contrast for all moves their edges alike, which the pose's exposure bias absorbs. Grey or textured ground
around a target printed without a sheet is 2-5x darker than its white (read 0.2-0.6 of it at 4-16x).

Measured on the detection sweep (seeds 0 and 1, every clipped search): targets on a sheet, clipped deeply, read
their outer circle's contrast at 0.41-1.8 of the inner circle's, never more than 5.5 standard errors below it; a
ground of 0.3-0.45 around a target without a sheet read 0.51-0.62 of its white at x8 (clip depth 3.3-3.6), 11-14
standard errors below it, and sharing one contrast put the distance 0.6-0.8 % short (each circle's edge moved by
the other's contrast error, unlike). With ``CONTRAST_SPLIT_Z_DEEP`` those split: over seeds 0-4 the targets
without a sheet went from 0.142 to 0.138 % mean |distance error| (the four worst of them -0.82 / -0.60 / -0.70 /
-0.17 % -> -0.25 / +0.01 / +0.10 / -0.01 %), those on a sheet unchanged to the fourth decimal."""


def _group_contrasts(sampled: EdgeFits, sample_groups: IntArray, row_groups: IntArray,
                     min_fits: int, saturation: float) -> npt.NDArray[np.float64]:
    """The shared contrast of each clipped row: the median of the ok fits of the sample, or, for groups clearly
    darker than group 0 (``CONTRAST_SPLIT_RATIO``), and then for group 0 itself, its group's median."""
    contrast = sampled.white_level - sampled.black_level
    pooled = float(np.median(contrast[sampled.ok]))
    out = np.full(len(row_groups), pooled)
    measured = _measured_groups(sampled, sample_groups, np.unique(row_groups), min_fits)
    out = _reaching_the_clip(out, contrast, sampled, sample_groups, row_groups, min_fits, saturation)
    if 0 not in measured:
        return out
    darker = _darker_groups(measured, saturation, CONTRAST_SPLIT_Z, CONTRAST_SPLIT_Z_DEEP)
    if darker:
        out[row_groups == 0] = measured[0][0]
        for g in darker:
            out[row_groups == g] = measured[g][0]
    return out


def _measured_groups(sampled: EdgeFits, sample_groups: IntArray, groups: IntArray, min_fits: int
                     ) -> dict[int, tuple[float, float, float]]:
    """Per group of ``groups`` with at least ``max(min_fits, CONTRAST_SPLIT_MIN_FITS)`` ok fits in ``sampled``: the
    median contrast of those fits, its standard error (from their MAD) and their median black level."""
    contrast = sampled.white_level - sampled.black_level
    measured = {}
    for g in groups:
        mine = sampled.ok & (sample_groups == g)
        if mine.sum() >= max(min_fits, CONTRAST_SPLIT_MIN_FITS):
            value = float(np.median(contrast[mine]))
            # standard error of a median from the MAD: 1.4826 MAD / sqrt(n) x sqrt(pi / 2)
            se = 1.858 * float(np.median(np.abs(contrast[mine] - value))) / np.sqrt(mine.sum())
            measured[int(g)] = (value, se, float(np.median(sampled.black_level[mine])))
    return measured


CONTRAST_SPLIT_APART_DIFF = 0.05
CONTRAST_SPLIT_APART_MAX_DIFF = 0.5
CONTRAST_SPLIT_Z_APART = 8.0
"""A group other than 0 also keeps a contrast of its own when its median differs from group 0's by more than
``CONTRAST_SPLIT_APART_DIFF`` of it, darker or brighter, and by more than ``CONTRAST_SPLIT_Z_APART`` standard errors:
a sheet, the same paper as the white, never reads that far apart. Not when it differs by more than
``CONTRAST_SPLIT_APART_MAX_DIFF``: a ground 1.5x brighter than the white is a white read low (the blurred inner
circle of a 9 px target; 8-bit fits settled at the clip level, whose "contrast" is the room to it), and darker than
that the rules above decide.
Measured on the detection sweep (seeds 0 and 1, every clipped search): of the measurements of targets on a sheet
whose two contrasts differ by 5-50 %, none lay more than 6.2 standard errors apart (0.85-1.22 of the white, 1-99 %,
at clip depths under 3; at depths 3-5, 5-10 and over 10, at most 2.8, 3.8 and 4.3 standard errors); grounds around
targets without a sheet (0.92 under a 0.85 white, 0.6, 0.45 noise) read 1.09-1.10 of it at 13-25 standard errors,
0.53-0.69 at 7-35. A renderer apart from livetrack's (bright gradient ground, no sheet, 12 bit, 85 px, x2) read
0.76 at 47 standard errors (truth 0.75); sharing one contrast put the distance 0.26 % short."""


def _darker_groups(measured: dict[int, tuple[float, float, float]], saturation: float, z: float,
                   z_deep: float, measured_apart: bool = True) -> list[int]:
    """The groups other than 0 of ``measured`` (``_measured_groups``, holding group 0) clearly darker than group 0
    (see ``CONTRAST_SPLIT_Z``; ``z`` and ``z_deep`` its two thresholds), or, with ``measured_apart``, measured clearly
    apart from it (``CONTRAST_SPLIT_Z_APART``)."""
    white, white_se, black = measured[0]
    deep = white > CONTRAST_DEEP_CLIP * max(saturation - black, 1e-12)
    ratio = CONTRAST_SPLIT_RATIO_DEEP if deep else CONTRAST_SPLIT_RATIO
    darker = []
    for g, (value, se, _) in measured.items():
        gap = (white - value) / max(float(np.hypot(se, white_se)), 1e-300)
        if g != 0 and ((value < ratio * white and gap > z)
                       or (deep and value < CONTRAST_SPLIT_RATIO * white and gap > z_deep)
                       or (measured_apart
                           and CONTRAST_SPLIT_APART_DIFF * white < abs(value - white)
                           < CONTRAST_SPLIT_APART_MAX_DIFF * white and abs(gap) > CONTRAST_SPLIT_Z_APART)):
            darker.append(g)
    return darker


CONTRAST_SPLIT_UNDECIDED_Z = 1.5
"""``split_undecided``: a darker group that would split at this many standard errors (in place of
``CONTRAST_SPLIT_Z`` and ``CONTRAST_SPLIT_Z_DEEP``) but not at those is a split left undecided."""


def split_undecided(state: dict, groups: IntArray, saturation: float, min_fits: int = 5
                    ) -> npt.NDArray[np.float64] | None:
    """Where the :func:`fit_edges_two_pass` call that left ``state`` (its ``memo``'s "state") shared one contrast
    between the white
    (group 0 of ``groups``, (N,) the call's ``contrast_groups``) and a darker group only because the split fell
    short of its standard errors (ground darker than the white by ``CONTRAST_SPLIT_UNDECIDED_Z`` of them, not
    ``CONTRAST_SPLIT_Z``): the per-point contrasts (N,) of the split (each group its median), for a second fit the
    caller compares with the first; None otherwise (no clipped sample, a split made, or no evidence of one).
    ``saturation`` and ``min_fits``: the call's."""
    sample, sampled = state.get("sample"), state.get("sampled")
    if sample is None or sampled is None:
        return None
    groups = np.asarray(groups, np.int64)
    measured = _measured_groups(sampled, groups[sample], np.unique(groups), min_fits)
    if 0 not in measured or len(measured) < 2:
        return None
    if _darker_groups(measured, saturation, CONTRAST_SPLIT_Z, CONTRAST_SPLIT_Z_DEEP):
        return None  # split
    darker = _darker_groups(measured, saturation, CONTRAST_SPLIT_UNDECIDED_Z, CONTRAST_SPLIT_UNDECIDED_Z,
                            measured_apart=False)
    if not darker:
        return None
    out = np.full(len(groups), measured[0][0])
    for g in darker:
        out[groups == g] = measured[g][0]
    return out


def _reaching_the_clip(out: npt.NDArray[np.float64], contrast: npt.NDArray[np.float64], sampled: EdgeFits,
                       sample_groups: IntArray, row_groups: IntArray, min_fits: int,
                       saturation: float) -> npt.NDArray[np.float64]:
    """``out`` (one shared contrast), or, when it leaves a group's white under the clip level (its black plus it
    below ``saturation``: that group's clipped profiles cannot be explained), the least of the groups' medians that
    reaches the clip for every group. Deep in an 8-bit clip (1 % of the contrast below it) a profile's per-point
    fit settles with its white at the clip level, as good as any higher one within the noise: the inner circles of
    a 380 px target read 28 levels for ~4500, and shared, that value left all 360 profiles of the outer circle,
    whose black lay 7 levels lower, unfitted."""
    blacks, medians = [], []
    for g in np.unique(sample_groups):
        mine = sampled.ok & (sample_groups == g)
        if mine.sum() >= min_fits:
            blacks.append(float(np.median(sampled.black_level[mine])))
            medians.append(float(np.median(contrast[mine])))
    if not blacks:
        return out
    room = saturation - min(blacks)
    if float(out[0]) >= room:
        return out
    reaching = [m for m in medians if m >= room]
    return np.full(len(row_groups), min(reaching)) if reaching else out


def _with_rows(fits: EdgeFits, rows: IntArray, part: EdgeFits) -> EdgeFits:
    """``fits`` with its ``rows`` replaced by ``part`` (fits of those rows, in their order)."""
    out = {}
    for f in fields(EdgeFits):
        values = np.array(getattr(fits, f.name), copy=True)
        values[rows] = getattr(part, f.name)
        out[f.name] = values
    return EdgeFits(**out)


def _merged(n: int, parts: list[tuple[IntArray, EdgeFits]]) -> EdgeFits:
    """One :class:`EdgeFits` of n points from fits of disjoint row sets covering them."""
    merged = {}
    for f in fields(EdgeFits):
        first = getattr(parts[0][1], f.name)
        out = np.empty((n,) + first.shape[1:], dtype=first.dtype)
        for idx, fits in parts:
            out[idx] = getattr(fits, f.name)
        merged[f.name] = out
    return EdgeFits(**merged)


_CONTRAST_SAMPLE_ROWS = 128
"""With ``shared_contrast``, the shared value is the median contrast of per-point fits of at least this many of the
clipped profiles (evenly spread over them; all of them when fewer), not of all of them: these fits are the slow
part (the position-contrast valley)."""

_HINT_MIN_OK = 0.8
"""A ``contrast_hint`` is kept when at least this fraction of the clipped profiles fit ok with it (and their
residuals have not grown, see :func:`_hint_fits`); otherwise the contrast is measured again."""

_HINT_MAX_RESIDUAL_GROWTH = 1.3
"""... and when the median residual RMS of those fits is at most this times that of the ``start`` fits of the
same profiles (a contrast 2x off, e.g. an exposure change the hint missed, raised it ~3x in paper-lab at 4x)."""


def _hint_fits(fits: EdgeFits, start) -> bool:
    """Whether clipped-profile fits with a hinted contrast are kept: enough ok, residuals as small as at ``start``
    (None, or the (ok, offset, sigma, black, white, residual_rms) arrays of earlier fits of these profiles)."""
    if len(fits) == 0 or fits.ok.mean() < _HINT_MIN_OK:
        return False
    if start is None or not start[0].any():
        return True
    before = float(np.median(start[5][start[0]]))
    return float(np.median(fits.residual_rms[fits.ok])) <= _HINT_MAX_RESIDUAL_GROWTH * before + 1e-9


_FIT_DEFAULTS = {
    "half_width_px": 4.0, "sigma_init_px": 1.0, "sigma_bounds_px": (0.3, 5.0), "iterations": 8, "noise_model": None,
    "tangent_half_width_px": 0.5, "min_contrast": None, "halo": None, "shared_contrast": False,
}

_FIT_OPTIONS = set(_FIT_DEFAULTS)
