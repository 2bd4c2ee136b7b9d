"""The Levenberg-Marquardt of the clipped edge-formation model (see the package docstring): the model and its
Jacobian over (N, K) profiles, the normal equations, the damped steps, and :func:`fit_edges` (one pass); the
iterations run compiled (:mod:`livetrack.estimator.edge_kernels`) or in numpy (the reference)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from livetrack.estimator import edge_glue_kernels, edge_kernels
from livetrack.estimator.edge_glue_kernels import kernel_array
from livetrack.estimator.edge_model import SMALL_B, edge_response_rows, mix_halo_rows
from livetrack.estimator.edge_samples import Profiles, check_points, sample_profiles
from livetrack.estimator.edges.start import _STILL_PX, _initial_params

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]

CONVERGED_STEP_PX = 1e-3
"""``ok`` needs the final undamped Gauss-Newton step to move the edge by less than this (px)."""

BLIND_STEP_PX = 3e-3
"""A point stops iterating, after an accepted step, once the next proposed step would move the edge and the blur by
less than this (px), the log contrast by less than this and the levels by less than this fraction of the contrast:
that step is taken without being evaluated. Gauss-Newton converges quadratically near the solution, so what such a
step leaves is ~(3e-3)^2 / sigma px (far below the noise), and a moving edge is done after 2 model evaluations
from its data start instead of 3 (the third only confirmed a step of ~1e-3 px). Where convergence is only linear
(large systematic residuals, e.g. an unmodelled halo under heavy over-exposure; rate ~0.3) it leaves < 1e-3 px."""

_STRAGGLER_AFTER = 3

_STRAGGLER_FRACTION = 0.01
"""After this many steps the iterations end once at most this fraction of the points is still active: a few
stragglers (profiles a code dot or a neighbouring edge spoils, mostly) do not hold up the whole call with
evaluations of a handful of rows (each costs about as much Python time as a full one); they are left as they are
and the convergence test flags them not ok."""

_LAMBDA_INIT = 1e-3

_MAX_LOG_STEP = 1.0

_LAMBDA_MIN = 1e-12

_LAMBDA_MAX = 1e12
edge_kernels.check_constants({"SMALL_B": SMALL_B, "LAMBDA_INIT": _LAMBDA_INIT, "LAMBDA_MIN": _LAMBDA_MIN,
                               "LAMBDA_MAX": _LAMBDA_MAX, "MAX_LOG_STEP": _MAX_LOG_STEP})


@dataclass(frozen=True)
class EdgeFits:
    """Per-point results of :func:`fit_edges`; every array has length N (one entry per edge point).

    points_px: (N, 2) fitted edge positions (x, y), ``initial point + offset_px * normal``.
    normals: (N, 2) unit normals (the given ones, normalised), pointing from black to white.
    offset_px: (N,) fitted shift along the normal from the initial point (px).
    sigma_px: (N,) fitted (or fixed) Gaussian PSF standard deviation (px).
    black_level, white_level: (N,) fitted levels before clipping (image units; may be < 0 or > saturation).
    position_std_px: (N,) 1-sigma uncertainty of the position along the normal (px): Gauss-Newton covariance
        scaled by the residual variance, or from the given noise model; inf when not identifiable.
    residual_rms: (N,) RMS of the unweighted residuals over the live samples, those not clipped in both the
        data and the model (image units).
    ok: (N,) quality flag: converged, |offset| <= half_width_px - 1, sigma strictly inside its bounds (free
        sigma only), contrast above the minimum, at least n_params + 2 unclipped samples, finite covariance.
    n_samples: (N,) pixels used (inside the image, deduplicated).
    n_clipped: (N,) of those, samples at or above saturation or at or below 0.
    """

    points_px: FloatArray
    normals: FloatArray
    offset_px: FloatArray
    sigma_px: FloatArray
    black_level: FloatArray
    white_level: FloatArray
    position_std_px: FloatArray
    residual_rms: FloatArray
    ok: BoolArray
    n_samples: IntArray
    n_clipped: IntArray

    def __len__(self) -> int:
        return len(self.offset_px)


def _evaluate(params, prof: Profiles, saturation, fixed_sigma, halo=None, fixed_contrast=False):
    """Residuals (N, K) and Jacobian (N, 4, K) of the model w.r.t. the internal parameters.

    Internal parameters per point: (offset, sigma, V, log C) with C = Lw - Lb the contrast and V the level
    seen unclipped: Lb, or Lw where ``top`` is set (profiles clipped at 0 only).  The log contrast
    straightens the curved valley in which a clipped profile trades contrast against position.

    Where the data sample is clipped high (low) the model is clipped at the same level and has no derivative
    once clipped; where the data is unclipped the model is not clipped, since a sample seen unclipped must
    be explained by an unclipped value.  Clipping every model value instead would leave flat directions
    (a model value above S facing unclipped data exerts no pull) and with them spurious minima; at the
    truth both forms agree.

    On a curved edge the blurred profile is, to first order, the straight one shifted towards the centre of
    curvature by ``kappa (sigma^2 + 1/12) / 2`` (PSF and pixel tangential variance); that shift is modelled.

    halo: None, or the known ``(fraction, sigma_px)`` of a wide PSF halo: the response is the mixture of
    :func:`~livetrack.estimator.edge_model.mix_halo_rows`, the halo's part shifted on a curved edge by its own
    ``kappa (sigma_h^2 + 1/12) / 2``.

    fixed_contrast: the contrast is held (its Jacobian column is zero), see :func:`fit_edges_two_pass`.
    """
    d, sig, level, log_c = (params[:, i : i + 1] for i in range(4))
    contrast = np.exp(np.minimum(log_c, 700.0))
    shift = prof.half_kappa * (sig * sig + 1.0 / 12.0)
    e, e_u, e_s = edge_response_rows(prof.u0 - (d + shift), sig, prof.a, prof.b)
    if halo is not None:
        fraction, halo_sigma = halo
        if not fixed_sigma:
            e_s -= (2.0 * prof.half_kappa * sig) * e_u  # the core's shift moves with sigma (before mixing)
        shift_h = prof.half_kappa * (halo_sigma * halo_sigma + 1.0 / 12.0)
        wide = edge_response_rows(prof.u0 - (d + shift_h), np.full_like(sig, halo_sigma), prof.a, prof.b)
        e, e_u, e_s = mix_halo_rows((e, e_u, e_s), wide[:2], fraction)
    if prof.any_top:
        e -= prof.top
    m = level + contrast * e
    valid = prof.valid
    jac = np.empty((len(params), 4, m.shape[1]))
    if prof.any_clipped:
        clip_hi, clip_lo = prof.clip_hi, prof.clip_lo
        live = valid & ~((clip_hi & (m >= saturation)) | (clip_lo & (m <= 0.0)))
        m = np.where(clip_hi, np.minimum(m, saturation), m)
        m = np.where(clip_lo, np.maximum(m, 0.0), m)
        ce = contrast * live
        jac[:, 2] = live
    else:  # no clipped sample in these rows: every valid sample is live
        ce = contrast * prof.valid_f
        jac[:, 2] = prof.valid_f
    resid = prof.data - m
    resid *= prof.valid_f
    np.multiply(ce, e_u, out=jac[:, 0])
    jac[:, 0] *= -1.0
    if fixed_sigma:
        jac[:, 1] = 0.0
    else:
        if halo is None:
            e_s -= (2.0 * prof.half_kappa * sig) * e_u
        np.multiply(ce, e_s, out=jac[:, 1])
    if fixed_contrast:
        jac[:, 3] = 0.0
    else:
        np.multiply(ce, e, out=jac[:, 3])
    return resid, jac


def _levels(params, top):
    """(Lb, Lw) (N,) from internal parameters (see :func:`_evaluate`)."""
    contrast = np.exp(np.minimum(params[:, 3], 700.0))
    lb = np.where(top[:, 0] > 0, params[:, 2] - contrast, params[:, 2])
    return lb, lb + contrast


def _normal_equations(jac, w, resid):
    """J^T W J (N, 4, 4), J^T W r (N, 4), weighted and unweighted sums of squared residuals (N,), and the
    number of live samples (N,), those not clipped in both data and model (``jac[:, 2]`` is 1 there).
    ``w`` None: unit weights (jac and resid are already zero at invalid samples)."""
    jw = jac if w is None else jac * w[:, None, :]
    a_mat = jw @ jac.transpose(0, 2, 1)
    g = (jw @ resid[:, :, None])[:, :, 0]
    r2 = resid * resid
    ssr = r2.sum(axis=1)
    cost = ssr if w is None else (w * r2).sum(axis=1)
    return a_mat, g, cost, ssr, jac[:, 2].sum(axis=1)


_BLOCK_ROWS = 1024
"""Edge points evaluated together: bounds the (5, 4, rows, K) temporaries of the model (~3 MB at K = 20); a
target's points fit in one block (measured: 64-row blocks cost 1.2x, 256-row 1.06x); results do not depend
on it."""


def _evaluate_normal(params, prof, saturation, fixed_sigma, weighted, halo=None, fixed_contrast=False):
    """Normal equations and cost of all rows of ``prof`` at ``params`` (M, 4), block by block (``halo``,
    ``fixed_contrast``: see :func:`_evaluate`).

    Returns A (M, 4, 4), g (M, 4), weighted cost (M,), unweighted sum of squares (M,), live samples (M,).
    """
    m = len(params)
    if m <= _BLOCK_ROWS:
        resid, jac = _evaluate(params, prof, saturation, fixed_sigma, halo, fixed_contrast)
        return _normal_equations(jac, prof.w if weighted else None, resid)
    a_mat, g = np.empty((m, 4, 4)), np.empty((m, 4))
    cost, ssr, n_live = np.empty(m), np.empty(m), np.empty(m)
    for start in range(0, m, _BLOCK_ROWS):
        sl = slice(start, start + _BLOCK_ROWS)
        block = prof.take(sl)
        resid, jac = _evaluate(params[sl], block, saturation, fixed_sigma, halo, fixed_contrast)
        a_mat[sl], g[sl], cost[sl], ssr[sl], n_live[sl] = _normal_equations(
            jac, block.w if weighted else None, resid
        )
    return a_mat, g, cost, ssr, n_live


def _damped_solve(a_mat, g, lam, fixed_sigma, fixed_contrast=False):
    """Marquardt step ``(A + lam diag(A)) step = g``, zero diagonals floored; returns step and lam diag."""
    diag = np.diagonal(a_mat, axis1=1, axis2=2)
    row_max = diag.max(axis=1, keepdims=True)
    diag = np.maximum(diag, np.where(row_max > 0, 1e-12 * row_max, 1.0))
    damp = lam[:, None] * diag
    m = a_mat + damp[:, :, None] * _EYE4
    if fixed_sigma:
        m[:, 1, 1] = 1.0
    if fixed_contrast:
        m[:, 3, 3] = 1.0
    return np.linalg.solve(m, g[:, :, None])[:, :, 0], damp


_EYE4 = np.eye(4)


def fit_edges(
    image: npt.ArrayLike,
    points_px: npt.ArrayLike,
    normals: npt.ArrayLike,
    saturation: float,
    half_width_px: float = 4.0,
    sigma_init_px: float = 1.0,
    sigma_bounds_px: tuple[float, float] = (0.3, 5.0),
    fix_sigma: float | npt.ArrayLike | None = None,
    iterations: int = 8,
    noise_model: tuple[float, float] | None = None,
    tangent_half_width_px: float = 0.5,
    min_contrast: float | None = None,
    curvature_per_px: npt.ArrayLike | None = None,
    halo: tuple[float, float] | None = None,
) -> EdgeFits:
    """Fit the clipped edge-formation model at N edge points at once.

    image: (H, W) any integer or float dtype; pixel (x, y) is ``image[y, x]``, centres on integers.
    points_px: (N, 2) initial edge positions (x, y) in px, e.g. from a detector; within ~1 px of the edge.
    normals: (N, 2) normals pointing from black to white (normalised here).
    saturation: the clip level S (e.g. 255, 4095, 1.0); samples >= S or <= 0 are treated as clipped.
    half_width_px: samples reach this far along the normal on each side (default 4).  Must exceed the
        expected |offset| + ~2.5 sigma; cost is linear in it.  ``ok`` needs |offset| <= half_width_px - 1.
    sigma_init_px: starting blur (default 1.0 px); a good value speeds up clipped fits.
    sigma_bounds_px: (min, max) blur, default (0.3, 5.0) px; a free-sigma fit ending on a bound is not ok.
    fix_sigma: None (default, 4-parameter fit) or the blur in px, scalar or (N,): only offset and levels are
        fitted.  Much steadier for clipped profiles (see the module docstring); biased if the value is wrong.
    iterations: maximum Levenberg-Marquardt iterations (default 8); each costs one model + Jacobian
        evaluation over the points not yet converged (clean edges converge in 2-4, clipped ones with fixed
        sigma in 4-6; free-sigma clipped fits may need 20+ and are flagged not ok until converged).
    noise_model: ``(read_var, gain)``: sample variance ``read_var + gain * I`` (image units^2, I the data),
        giving weighted least squares and an absolute ``position_std_px``.  None (default): unweighted, and
        the covariance is scaled by the residual variance.
    tangent_half_width_px: half width of the sampled strip across the normal (default 0.5 px: ~2 pixels
        per pixel of normal, ~20 pixels per point at half_width_px 4).  0 samples one line: ~25 % cheaper,
        sqrt(2) noisier, and clipped profiles then often keep too few unclipped samples to be ok.  On a
        curved edge without ``curvature_per_px`` the strip adds a bias of ~width^2 / (6 R).
    min_contrast: smallest Lw - Lb for ``ok`` (image units), default ``0.02 * saturation``; ``ok`` also needs
        a contrast of at least 5x the residual RMS.
    curvature_per_px: None (default: straight edges) or the signed curvature 1/R (1/px), scalar or (N,),
        positive when the centre of curvature lies on the bright side; meant for R >> sigma (first-order
        correction, residual ~0.008 px at R = 5 px, sigma = 1.5 px).  Distances are then taken to the
        circle through the point, and the profile is shifted by ``kappa (sigma^2 + 1/12) / 2``, removing the
        curved-edge bias (a blurred disk's edge appears ~(sigma^2 + 1/12) / (2 R) px inside it; 0.04 px at
        R = 10 px, sigma = 0.8 px) to a few thousandths of a pixel.  Cost: negligible.
    halo: None (default: Gaussian PSF) or ``(fraction, sigma_px)``: the PSF is ``(1 - fraction) G(sigma) +
        fraction G(sigma_px)``, a known wide halo (e.g. a camera file's fitted ``optics``); ``sigma`` stays the
        fitted (or fixed) core.  Removes the pull of the halo's tail on over-exposed edges; the halo is a 1-D
        single-edge model (other edges within ~3 sigma_px of the point are not in it).  Cost: ~2x per model
        evaluation.  The fitted ``sigma_px`` is then the core's width.

    Returns an :class:`EdgeFits`.  Failures (flat patches, points near or beyond the border, singular or
    unconverged fits) are flagged in ``ok``, never raised.
    """
    pts, nrm = check_points(image, points_px, normals)
    n = len(pts)
    sat = float(saturation)
    s_lo, s_hi = float(sigma_bounds_px[0]), float(sigma_bounds_px[1])
    if fix_sigma is not None:
        sig0 = np.broadcast_to(np.asarray(fix_sigma, dtype=np.float64), (n,)).copy()
        if not np.all(np.isfinite(sig0) & (sig0 > 0)):
            raise ValueError("fix_sigma must be finite and > 0")
    else:
        sig0 = np.full(n, float(np.clip(sigma_init_px, s_lo, s_hi)))
    prof, n_samples, n_clipped = sample_profiles(
        np.asarray(image), pts, nrm, sat, half_width_px, tangent_half_width_px, noise_model, curvature_per_px
    )
    return _fit(prof, pts, nrm, sat, sig0, fix_sigma is not None, n_samples, n_clipped, half_width_px, (s_lo, s_hi),
                0.02 * sat if min_contrast is None else float(min_contrast), iterations, noise_model is not None,
                halo=_check_halo(halo))


def _fit(prof, pts, nrm, sat, sig0, fixed, n_samples, n_clipped, half_width_px, sigma_bounds, min_con, iterations,
         weighted, start=None, halo=None, contrast=None) -> EdgeFits:
    """Levenberg-Marquardt of the profiles ``prof`` (N rows) from sigma ``sig0`` (N,), fixed or free; ``halo``
    None or the known (fraction, sigma_px) of a wide PSF halo (see :func:`_evaluate`).

    start: None, or (N,) arrays (ok, offset, sigma, black, white) of earlier fits at these points: where ok (and
    the levels are usable) the fit starts at that blur (unless fixed), and at that offset and those levels
    where the edge has not moved (see ``_STILL_PX``).

    contrast: None, or the known contrast Lw - Lb (scalar or (N,)), held fixed (only with ``fixed`` sigma); the
    fit then starts from ``start`` (offset and levels) where it is ok, from the data elsewhere."""
    n = len(pts)
    if n == 0:  # no profile (e.g. the clean pass of a frame whose profiles are all clipped): nothing to fit
        empty = np.zeros(0)
        return EdgeFits(points_px=pts.copy(), normals=nrm.copy(), offset_px=empty, sigma_px=empty.copy(),
                        black_level=empty.copy(), white_level=empty.copy(), position_std_px=empty.copy(),
                        residual_rms=empty.copy(), ok=np.zeros(0, dtype=bool), n_samples=n_samples,
                        n_clipped=n_clipped)
    s_lo, s_hi = sigma_bounds
    fixed_c = contrast is not None
    n_params = (3 if fixed else 4) - (1 if fixed_c else 0)
    top = prof.top
    sig_start = sig0
    if start is None:
        d0, _, lb0, lw0 = _initial_params(prof.u0, prof.data, prof.valid, prof.clip_hi, prof.clip_lo, sat, sig0,
                                          prof.a, prof.b, contrast).T
    elif fixed_c:  # the start where its edge has not moved from the offset the known contrast gives
        s_ok, s_d, _, s_lb, s_lw = start[:5]
        d0, _, lb0, lw0 = _initial_params(prof.u0, prof.data, prof.valid, prof.clip_hi, prof.clip_lo, sat, sig0,
                                          prof.a, prof.b, contrast).T
        use = s_ok & np.isfinite(s_d) & np.isfinite(s_lb) & np.isfinite(s_lw) & (np.abs(s_d - d0) < _STILL_PX)
        d0, lb0, lw0 = np.where(use, s_d, d0), np.where(use, s_lb, lb0), np.where(use, s_lw, lw0)
    elif edge_kernels.kernels() == "numba":  # the branch below, compiled: the same numbers (~25 numpy operations)
        c, f8 = kernel_array, np.float64
        s_ok, s_d, s_sig, s_lb, s_lw = (c(start[0], np.bool_), *(c(x, f8) for x in start[1:]))
        use, sig_start = edge_glue_kernels.start_blur(s_ok, s_sig, s_lb, s_lw, c(sig0, f8), bool(fixed), float(s_lo),
                                                      float(s_hi))
        initial = _initial_params(prof.u0, prof.data, prof.valid, prof.clip_hi, prof.clip_lo, sat, sig_start, prof.a,
                                  prof.b)
        params, contrast0 = edge_glue_kernels.start_params(
            use, s_d, s_lb, s_lw, c(initial, f8), sig_start, c(top[:, 0], f8), float(half_width_px), _STILL_PX,
            1e-9 * max(sat, 1e-300))
        params[:, 3] = np.log(contrast0)
        return _solve(params, prof, pts, nrm, sat, fixed, n_samples, n_clipped, half_width_px, sigma_bounds, min_con,
                      iterations, weighted, halo, None, n_params)
    else:
        s_ok, s_d, s_sig, s_lb, s_lw = start
        use = s_ok & np.isfinite(s_sig) & np.isfinite(s_lb) & np.isfinite(s_lw) & (s_lw > s_lb)
        if not fixed:
            sig_start = np.where(use, np.clip(s_sig, s_lo, s_hi), sig0)
        d0, _, lb0, lw0 = _initial_params(prof.u0, prof.data, prof.valid, prof.clip_hi, prof.clip_lo, sat,
                                          sig_start, prof.a, prof.b).T
        # an edge that has not moved (its crossing within _STILL_PX of the earlier fit) starts at that fit
        still = use & (np.abs(s_d - d0) < _STILL_PX) & (np.abs(s_d) <= half_width_px - 1.0)
        d0, lb0, lw0 = np.where(still, s_d, d0), np.where(still, s_lb, lb0), np.where(still, s_lw, lw0)
    contrast0 = np.maximum(lw0 - lb0, 1e-9 * max(sat, 1e-300))
    if fixed_c:  # keep the level seen unclipped, set the other one from the known contrast
        contrast0 = np.broadcast_to(np.asarray(contrast, dtype=np.float64), (n,))
        lb0, lw0 = np.where(top[:, 0] > 0, lw0 - contrast0, lb0), np.where(top[:, 0] > 0, lw0, lb0 + contrast0)
    params = np.stack([d0, sig_start, np.where(top[:, 0] > 0, lw0, lb0), np.log(contrast0)], axis=1)
    return _solve(params, prof, pts, nrm, sat, fixed, n_samples, n_clipped, half_width_px, sigma_bounds, min_con,
                  iterations, weighted, halo, contrast, n_params)


def _solve(params, prof, pts, nrm, sat, fixed, n_samples, n_clipped, half_width_px, sigma_bounds, min_con,
           iterations, weighted, halo, contrast, n_params) -> EdgeFits:
    """The iterations of :func:`_fit` from its start ``params`` (N, 4) (offset, blur, visible level, log contrast),
    compiled or in numpy, and the fitted points' summary."""
    s_lo, s_hi = sigma_bounds
    fixed_c = contrast is not None
    top = prof.top
    compiled = edge_kernels.kernels() == "numba"
    if compiled:
        params = np.array(params, dtype=np.float64, order="C")
        halo_f, halo_s = (0.0, 1.0) if halo is None else (float(halo[0]), float(halo[1]))
        a_mat, g, cost, ssr, n_live, blind = edge_kernels.levenberg_marquardt(
            params, *_kernel_arrays(prof), sat, bool(fixed), bool(weighted), halo_f, halo_s, bool(fixed_c),
            float(half_width_px), float(s_lo), float(s_hi), int(iterations), BLIND_STEP_PX, _STRAGGLER_AFTER,
            float(_STRAGGLER_FRACTION))
    else:
        params, a_mat, g, cost, ssr, n_live, blind = _iterate_numpy(
            params, prof, n_samples, sat, fixed, weighted, halo, fixed_c, half_width_px, s_lo, s_hi, iterations)
    if compiled:
        lb, lw = _levels(params, top)
        pos_std, residual_rms, ok = edge_glue_kernels.fit_summary(
            params, a_mat, g, cost, ssr, n_live, blind, lb, lw, bool(fixed),
            bool(fixed_c), bool(weighted), n_params, kernel_array(n_samples, np.int64),
            kernel_array(n_clipped, np.int64), float(half_width_px), float(s_lo), float(s_hi), float(min_con),
            CONVERGED_STEP_PX)
    else:
        pos_std, residual_rms, lb, lw, ok = _summary_numpy(
            params, a_mat, g, cost, ssr, n_live, blind, top, fixed, fixed_c, weighted, n_params, n_samples, n_clipped,
            half_width_px, s_lo, s_hi, min_con)
    offset, sig = params[:, 0].copy(), params[:, 1].copy()
    return EdgeFits(
        points_px=pts + offset[:, None] * nrm,
        normals=nrm,
        offset_px=offset,
        sigma_px=sig,
        black_level=lb,
        white_level=lw,
        position_std_px=pos_std,
        residual_rms=residual_rms,
        ok=ok,
        n_samples=n_samples,
        n_clipped=n_clipped,
    )


def _summary_numpy(params, a_mat, g, cost, ssr, n_live, blind, top, fixed, fixed_c, weighted, n_params, n_samples,
                   n_clipped, half_width_px, s_lo, s_hi, min_con):
    """Position standard deviation (px), residual RMS, black and white levels and ``ok`` (N,) of fitted points from
    their internal parameters (N, 4), normal equations A (N, 4, 4) (modified), g (N, 4), weighted cost, sum of
    squares, live samples and blind offset step (N,) at the solution: the reference of the compiled
    :func:`~livetrack.estimator.edge_glue_kernels.fit_summary` (``ok`` as :class:`EdgeFits` says)."""
    # covariance and Gauss-Newton step from the normal equations at the solution, equilibrated
    if fixed:
        a_mat[:, 1, 1] = 1.0
    if fixed_c:
        a_mat[:, 3, 3] = 1.0
    diag = np.diagonal(a_mat, axis1=1, axis2=2)
    scale = np.sqrt(np.maximum(diag, 0.0))
    scale = np.where(scale > 0, scale, 1.0)
    cov_norm = np.linalg.inv(a_mat / (scale[:, :, None] * scale[:, None, :]) + 1e-12 * _EYE4)
    cov00 = cov_norm[:, 0, 0] / scale[:, 0] ** 2
    gn_step = (cov_norm[:, 0, :] * (g / scale)).sum(axis=1) / scale[:, 0] - blind  # what is left of it
    identifiable = diag[:, 0] > 0
    dof = n_live - n_params  # samples clipped in data and model carry no information
    if not weighted:
        var_pos = cov00 * np.where(dof > 0, cost / np.maximum(dof, 1), np.inf)
    else:
        var_pos = cov00
    pos_std = np.where(identifiable & (var_pos >= 0), np.sqrt(np.abs(var_pos)), np.inf)
    residual_rms = np.sqrt(ssr / np.maximum(n_live, 1))
    lb, lw = _levels(params, top)
    contrast = lw - lb
    ok = (
        np.isfinite(params).all(axis=1)
        & np.isfinite(pos_std)
        & identifiable
        & (np.abs(gn_step) < CONVERGED_STEP_PX)
        & (np.abs(params[:, 0]) <= half_width_px - 1.0)
        & (contrast > min_con)
        & (contrast > 5.0 * residual_rms)
        & (n_samples - n_clipped >= n_params + 2)
    )
    if not fixed:
        sig = params[:, 1]
        ok &= (sig > s_lo * (1 + 1e-9)) & (sig < s_hi * (1 - 1e-9))
    return pos_std, residual_rms, lb, lw, ok


def _kernel_arrays(prof: Profiles) -> tuple:
    """The arrays of ``prof`` the compiled kernels take: (N, K) u0, data, valid_f, clip_hi, clip_lo, w and (N,)
    top, half_kappa, a, b, C-contiguous and writeable (one compiled specialisation for all calls)."""

    c = kernel_array
    f8, b1 = np.float64, np.bool_
    return (c(prof.u0, f8), c(prof.data, f8), c(prof.valid_f, f8), c(prof.clip_hi, b1), c(prof.clip_lo, b1),
            c(prof.w, f8), c(prof.top[:, 0], f8), c(prof.half_kappa[:, 0], f8), c(prof.a[:, 0], f8),
            c(prof.b[:, 0], f8))


def _iterate_numpy(params, prof, n_samples, sat, fixed, weighted, halo, fixed_c, half_width_px, s_lo, s_hi,
                   iterations):
    """The Levenberg-Marquardt iterations of :func:`_fit` in numpy, batched over the points (the reference of
    :func:`~livetrack.estimator.edge_kernels.levenberg_marquardt`): params (N, 4) from their start to the
    solution. Returns params, A (N, 4, 4), g (N, 4), cost, ssr, live samples and the blind offset step (N,)."""
    n = len(params)
    # solve in order of sample count, so that blocks of similar points share a short K; undone at the end
    order = np.argsort(n_samples, kind="stable")
    work = prof.take(order)
    params = params[order]
    a_mat, g, cost, ssr, n_live = _evaluate_normal(params, work, sat, fixed, weighted, halo, fixed_c)
    lam = np.full(n, _LAMBDA_INIT)
    nu = np.full(n, 2.0)
    active = np.arange(n)
    accepted = np.ones(n, dtype=bool)  # the last trial of each point was accepted (or none was tried yet)
    blind = np.zeros(n)  # the offset step taken without evaluation by each converged point
    for _ in range(iterations + 1):
        if len(active) == 0 or (_ >= _STRAGGLER_AFTER and len(active) <= _STRAGGLER_FRACTION * n):
            break
        act = active
        step, damp = _damped_solve(a_mat[act], g[act], lam[act], fixed, fixed_c)
        step[:, 3] = np.clip(step[:, 3], -_MAX_LOG_STEP, _MAX_LOG_STEP)
        # converged: the step proposed after an accepted one is below BLIND_STEP_PX; it is taken without being
        # evaluated (in the quadratic regime of Gauss-Newton what it leaves is negligible)
        level_scale = np.exp(np.minimum(params[act, 3], 700.0))
        small = np.abs(step) < BLIND_STEP_PX
        small[:, 2] = np.abs(step[:, 2]) < BLIND_STEP_PX * level_scale
        done = accepted[act] & small.all(axis=1)
        if done.any():
            finished = act[done]
            params[finished] += step[done]
            params[finished, 0] = np.clip(params[finished, 0], -half_width_px, half_width_px)
            params[finished, 1] = np.clip(params[finished, 1], s_lo, s_hi)
            blind[finished] = step[done, 0]
            keep = np.flatnonzero(~done)
            if len(keep) == 0:
                break
            act, step, damp = act[keep], step[keep], damp[keep]
            work = work.take(keep)
        if _ == iterations:
            break
        trial = params[act] + step
        trial[:, 0] = np.clip(trial[:, 0], -half_width_px, half_width_px)
        if not fixed:
            trial[:, 1] = np.clip(trial[:, 1], s_lo, s_hi)
        t_a, t_g, t_cost, t_ssr, t_live = _evaluate_normal(trial, work, sat, fixed, weighted, halo, fixed_c)
        # Nielsen's damping update from the gain ratio (actual / predicted decrease of the cost)
        old_cost = cost[act]
        predicted = (step * (g[act] + damp * step)).sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            rho = (old_cost - t_cost) / predicted
        accept = np.isfinite(t_cost) & (t_cost <= old_cost)
        good = accept & (rho > 0)
        acc = act[accept]
        params[acc] = trial[accept]
        a_mat[acc], g[acc], cost[acc] = t_a[accept], t_g[accept], t_cost[accept]
        ssr[acc], n_live[acc] = t_ssr[accept], t_live[accept]
        lam_act = lam[act]
        lam_act = np.clip(
            np.where(good, lam_act * np.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), lam_act * nu[act]),
            _LAMBDA_MIN,
            _LAMBDA_MAX,
        )
        lam[act] = lam_act
        nu[act] = np.where(good, 2.0, nu[act] * 2.0)
        accepted[act] = accept
        done = (lam_act >= _LAMBDA_MAX) | (cost[act] == 0.0)
        if done.any():
            keep = np.flatnonzero(~done)
            act = act[keep]
            work = work.take(keep)
        active = act

    inverse = np.argsort(order)
    params, a_mat, g, cost, ssr, n_live, blind = (x[inverse] for x in (params, a_mat, g, cost, ssr, n_live, blind))
    return params, a_mat, g, cost, ssr, n_live, blind


def _check_halo(halo) -> tuple[float, float] | None:
    """``halo`` as (fraction, sigma_px) floats, None for none or a zero fraction; ValueError if out of range."""
    if halo is None:
        return None
    fraction, sigma_px = (float(v) for v in halo)
    if not (0.0 <= fraction < 1.0 and np.isfinite(sigma_px) and sigma_px > 0):
        raise ValueError(f"halo must be (fraction in [0, 1), sigma_px > 0), got {halo!r}")
    return None if fraction == 0.0 else (fraction, sigma_px)
