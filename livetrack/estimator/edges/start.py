"""Start values of the edge fits: where each profile crosses its mid level, and for clipped profiles the
offset and contrast their transition samples imply (a scan over candidate contrasts)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.special import ndtr, ndtri

from livetrack.estimator import edge_glue_kernels, edge_kernels
from livetrack.estimator.edge_glue_kernels import kernel_array

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]

_CONTRAST_FACTORS = 1.02 * 1.7 ** np.arange(7)
"""Candidate ratios (true contrast) / (visible contrast) tried to initialise clipped profiles (1.02 to 25,
evenly spaced in log)."""

_STILL_PX = 0.1
"""With a ``start`` fit, a point whose mid-level crossing lies within this of the started offset (px) starts at
that fit (position and levels: one evaluation when nothing changed); a moved edge starts at its crossing and
the data's levels (from 0.5 px away the fit needed ~2 more evaluations than from its crossing)."""


def _crossing(u0, data, valid, level, at_or_below):
    """(N,) position along the normal where each profile crosses ``level`` (N,).

    Linear interpolation between the last sample below and the first above the level, their midpoint if
    the profile is not monotone there, 0 if it does not cross.  Samples equal to the level count as below
    where ``at_or_below`` (N,) is set (crossing of the 0 clip level).
    """
    below = valid & ((data < level[:, None]) | (at_or_below[:, None] & (data <= level[:, None])))
    above = valid & ~below
    i_lo = np.argmax(np.where(below, u0, -np.inf), axis=1)
    i_hi = np.argmin(np.where(above, u0, np.inf), axis=1)
    rows = np.arange(len(u0))
    u_lo, u_hi = u0[rows, i_lo], u0[rows, i_hi]
    y_lo, y_hi = data[rows, i_lo], data[rows, i_hi]
    frac = np.clip((level - y_lo) / np.where(y_hi > y_lo, y_hi - y_lo, 1.0), 0.0, 1.0)
    u_c = np.where(u_hi > u_lo, u_lo + frac * (u_hi - u_lo), 0.5 * (u_lo + u_hi))
    return np.where(below.any(axis=1) & above.any(axis=1), u_c, 0.0)


def _levels_crossing(u0, data, valid, clip_hi, clip_lo, sat):
    """Start levels of N profiles (N, K) and where they cross their mid level (the reference of the compiled
    :func:`~livetrack.estimator.edge_glue_kernels.levels_crossing`): black lb and white lw from the unclipped
    samples' min and max (0 and the clip level where clipped there), the level crossed (the clip level where
    clipped high, 0 where clipped at 0 only, else the mid level), its crossing (N,) px, and whether the profile is
    clipped high / at 0 only (N,) bool."""
    unclipped = valid & ~clip_hi & ~clip_lo
    any_un = unclipped.any(axis=1)
    lb = np.where(any_un, np.where(unclipped, data, np.inf).min(axis=1), 0.0)
    lw = np.where(any_un, np.where(unclipped, data, -np.inf).max(axis=1), sat)
    hi = clip_hi.any(axis=1)
    lo = clip_lo.any(axis=1) & ~hi
    lb = np.where(clip_lo.any(axis=1), np.minimum(lb, 0.0), lb)
    lw = np.where(hi, sat, lw)
    level = np.where(hi, sat, np.where(lo, 0.0, 0.5 * (lb + lw)))
    return lb, lw, level, _crossing(u0, data, valid, level, lo), hi, lo


def _initial_params(u0, data, valid, clip_hi, clip_lo, sat, sig0, a, b, contrast=None):
    """(N, 4) starting (offset, sigma, Lb, Lw); sig0 is (N,); contrast None, or the known Lw - Lb (scalar or (N,)).

    Levels from the min/max of the unclipped samples; unclipped profiles start at their mid-level crossing.
    A clipped profile hides its true contrast C.  With the Gaussian approximation ``E(u) ~ Phi(u / s)``,
    ``s^2 = sigma^2 + (a^2 + b^2) / 12``, each transition sample (unclipped, away from the visible level)
    maps for a given C to an edge position ``u - s Phi^-1((I - Lb) / C)``; their mean is the candidate
    offset.  C is scanned over ``_CONTRAST_FACTORS`` times the visible contrast, each candidate scored by
    its (approximate, clipped) intensity cost over all samples, and refined by a parabola in log C through
    the best three, kept if it scores better.  A known ``contrast`` replaces the scan: one candidate.
    """
    if edge_kernels.kernels() == "numba":
        f8, b1 = np.float64, np.bool_
        lb, lw, _, u_c, hi, lo = edge_glue_kernels.levels_crossing(
            kernel_array(u0, f8), kernel_array(data, f8), kernel_array(valid, b1), kernel_array(clip_hi, b1),
            kernel_array(clip_lo, b1), float(sat))
    else:
        lb, lw, _, u_c, hi, lo = _levels_crossing(u0, data, valid, clip_hi, clip_lo, sat)
    params = np.stack([u_c, sig0, lb, lw], axis=1)
    rows = np.flatnonzero(hi | lo)
    if len(rows) == 0:
        return params
    if contrast is not None and edge_kernels.kernels() == "numba":  # the same numbers, compiled (~10x faster)
        f8, b1 = np.float64, np.bool_
        known = kernel_array(np.broadcast_to(np.asarray(contrast, dtype=f8), (len(u0),)), f8)
        terms, n_trans, black = edge_glue_kernels.hinted_start_terms(
            rows, kernel_array(u0, f8), kernel_array(data, f8), kernel_array(valid, b1), kernel_array(clip_hi, b1),
            kernel_array(clip_lo, b1), lb, lw, hi, known, kernel_array(sig0, f8), kernel_array(a[:, 0], f8),
            kernel_array(b[:, 0], f8), edge_glue_kernels.scipy_ndtri())
        params[rows, 0] = np.where(n_trans > 0, terms.sum(axis=1) / np.maximum(n_trans, 1), u_c[rows])
        params[rows, 2] = black
        params[rows, 3] = black + known[rows]
        return params
    unclipped = valid & ~clip_hi & ~clip_lo
    lb_r, lw_r = lb[rows, None], lw[rows, None]
    visible = lw_r - lb_r
    hi_r = hi[rows, None]
    u_r, y_r, v_r, chi, clo = u0[rows], data[rows], valid[rows], clip_hi[rows], clip_lo[rows]
    trans = unclipped[rows] & np.where(hi_r, y_r > lb_r + 0.05 * visible, y_r < lw_r - 0.05 * visible)
    n_t = max(int(trans.sum(axis=1).max()), 1)
    pick = np.argsort(~trans, axis=1, kind="stable")[:, :n_t]  # transition samples first
    mask = np.take_along_axis(trans, pick, axis=1)
    u_t = np.take_along_axis(u_r, pick, axis=1)
    y_t = np.take_along_axis(y_r, pick, axis=1)
    n_trans = mask.sum(axis=1)
    sig_eff = np.sqrt(sig0[rows, None] ** 2 + (a[rows] ** 2 + b[rows] ** 2) / 12.0)
    u_c_r = u_c[rows]

    def candidate(contrast, scored=True):
        """Offset, black level and cost (M,) for contrasts (M, 1) (the cost None unless ``scored``)."""
        black = np.where(hi_r, lb_r, lw_r - contrast)
        z = ndtri(np.clip((y_t - black) / contrast, 1e-9, 1.0 - 1e-9))
        d_sum = np.where(mask, u_t - sig_eff * z, 0.0).sum(axis=1)
        d = np.where(n_trans > 0, d_sum / np.maximum(n_trans, 1), u_c_r)
        if not scored:
            return d, black[:, 0], None
        m = black + contrast * ndtr((u_r - d[:, None]) / sig_eff)
        m = np.where(chi, np.minimum(m, sat), np.where(clo, np.maximum(m, 0.0), m))
        return d, black[:, 0], np.where(v_r, (y_r - m) ** 2, 0.0).sum(axis=1)

    if contrast is not None:
        known = np.broadcast_to(np.asarray(contrast, dtype=np.float64), (len(u0),))[rows, None]
        d, black, _ = candidate(known, scored=False)  # one candidate: its cost is not needed
        params[rows, 0] = d
        params[rows, 2] = black
        params[rows, 3] = black + known[:, 0]
        return params
    log_k = np.log(_CONTRAST_FACTORS)
    scans = [candidate(k * visible) for k in _CONTRAST_FACTORS]
    costs = np.stack([c for _, _, c in scans], axis=1)
    best = np.argmin(costs, axis=1)
    r = np.arange(len(rows))
    d = np.stack([dd for dd, _, _ in scans], axis=1)[r, best]
    black = np.stack([bb for _, bb, _ in scans], axis=1)[r, best]
    contrast = _CONTRAST_FACTORS[best] * visible[:, 0]
    cost = costs[r, best]
    j = np.clip(best, 1, len(log_k) - 2)
    c0, c1, c2 = costs[r, j - 1], costs[r, j], costs[r, j + 1]
    curv = c0 - 2.0 * c1 + c2
    with np.errstate(invalid="ignore", divide="ignore"):
        shift = np.clip(0.5 * (c0 - c2) / curv, -1.0, 1.0)
    shift = np.where(curv > 0, shift, 0.0)
    refined = np.exp(log_k[j] + shift * (log_k[1] - log_k[0])) * visible[:, 0]
    d_f, black_f, cost_f = candidate(refined[:, None])
    better = cost_f < cost
    d = np.where(better, d_f, d)
    black = np.where(better, black_f, black)
    contrast = np.where(better, refined, contrast)
    params[rows, 0] = d
    params[rows, 2] = black
    params[rows, 3] = black + contrast
    return params
