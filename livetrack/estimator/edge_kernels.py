"""Compiled (numba) per-point kernels of the edge fits: the edge-profile model with its Jacobian and the
Levenberg-Marquardt of :mod:`livetrack.estimator.edges`, one point at a time, without (N, 4, K) temporaries
(the pose's Gauss-Newton is in :mod:`livetrack.estimator.pose_kernels`; the kernel choice, the compilation and
the cache described here hold for both).

The maths are those of the numpy reference, which stays the specification and the test oracle:
:func:`~livetrack.estimator.edge_model.edge_response_rows` (the response at the 4 pixel-footprint corners of
each sample), ``edges._evaluate`` / ``edges._normal_equations`` (clipping, curvature shift, halo) and the loop
of ``edges._fit`` (Nielsen's damping, the blind last step, the straggler stop). Compiled and reference fits
agree to ~1e-12 px (tests/test_kernels.py asserts 1e-9 px); only rounding differs (the normal CDF from a table of
``erfcx`` polynomials and the pdf's ``exp`` (:func:`_cdf_pdf`, within 8e-16 of scipy's ``ndtr``, the reference's),
a 4x4 Gaussian elimination for LAPACK's solve, summation order).

Which path runs: ``LIVETRACK_KERNELS`` = ``numba`` (default) or ``numpy`` (the reference), read at the first fit
and cached (:func:`kernels`; :func:`reset_kernels` makes it read again); ``numba`` falls back to ``numpy`` with
one warning in the log when numba cannot be imported.

Compilation: lazily at the first fit of a process (15-45 s of wall-clock on the loaded 2-core development
machine, both kernels), or loaded from numba's on-disk cache (~1-2 s there): ``cache=True`` writes it to
``NUMBA_CACHE_DIR`` where set, else to ``__pycache__`` beside this file, else to numba's user-wide cache
directory. ``scripts/install.sh`` compiles into it (:func:`warm_up`), so a fresh install's first frame loads.
Where no cache directory is writable (a read-only install without a writable home) the kernels are compiled
without a cache, in every process. :func:`warm_up` compiles (or
loads) them on a tiny input so that a caller can pay that at start-up rather than on its first frame;
:func:`cache_stats` says whether the cache was hit.
"""

from __future__ import annotations

import logging
import math
import os

import numpy as np

log = logging.getLogger(__name__)

KERNELS_ENV = "LIVETRACK_KERNELS"
"""Environment variable choosing the kernels: ``numba`` (default, compiled) or ``numpy`` (the reference)."""

try:  # numba is a dependency; without it (a broken install) the reference runs
    import numba

    _HAVE_NUMBA = True
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None
    _HAVE_NUMBA = False

_warned = False


_choice: str | None = None


def kernels() -> str:
    """``"numba"`` or ``"numpy"``: the kernels the edge fits use (``LIVETRACK_KERNELS``, default numba).

    Read from the environment once and then cached (a tracked frame asks ~12 times); whoever changes
    ``LIVETRACK_KERNELS`` within a process afterwards (``bench``'s comparisons, tests) calls :func:`reset_kernels`."""
    global _choice
    if _choice is None:
        _choice = _kernels_from_env()
    return _choice


def reset_kernels() -> None:
    """Forget the cached choice of :func:`kernels`: the next call reads ``LIVETRACK_KERNELS`` again."""
    global _choice
    _choice = None


def _kernels_from_env() -> str:
    global _warned
    choice = os.environ.get(KERNELS_ENV, "numba").strip().lower() or "numba"
    if choice not in ("numba", "numpy"):
        raise ValueError(f"{KERNELS_ENV} must be 'numba' or 'numpy', got {choice!r}")
    if choice == "numba" and not _HAVE_NUMBA:
        if not _warned:
            log.warning("numba is not installed: the edge fits run the numpy reference kernels")
            _warned = True
        return "numpy"
    return choice


def jit_kernel(fn=None, *, inline: bool = False):
    """``numba.njit(cache=True, fastmath=False, nogil=True)``, without the cache where no cache directory is usable.

    ``nogil``: a kernel releases the GIL while it runs, so that the live pipeline's search thread and processing
    thread fit edges and poses at the same time. Safe: the kernels are nopython code that touches no Python
    object, and every array they write is allocated by the call (or by its caller for that call alone).

    ``inline=True`` (``@jit_kernel(inline=True)``): a helper that numba copies into every kernel calling it
    (``inline="always"``) instead of calling it: the same operations in the same order, so the same numbers, without
    a call per sample (LLVM left the per-sample model :func:`_response` and the per-row normal equations
    :func:`_row_normal` out of line: each call passed a dozen array structures, took and dropped references on the
    row views, and spilled every accumulator around it)."""
    if fn is None:
        return lambda f: jit_kernel(f, inline=inline)
    if not _HAVE_NUMBA:
        return fn
    options = {"fastmath": False, "error_model": "numpy", "nogil": True}
    if inline:
        options["inline"] = "always"
    try:
        return numba.njit(cache=True, **options)(fn)
    except RuntimeError as exc:  # "cannot cache function ...: no locator available" (read-only everything)
        log.warning("numba cache unavailable (%s): kernels compile in every process", exc)
        return numba.njit(cache=False, **options)(fn)


# Constants of the reference, repeated here as literals: numba freezes globals into the compiled code and its cache
# follows this file only, so a value changed elsewhere would otherwise keep its old value in a cached kernel.
# ``check_constants`` (called by livetrack.estimator.edges at import) fails loudly when they differ.
_SMALL_B = 1e-2
_LAMBDA_INIT = 1e-3
_LAMBDA_MIN = 1e-12
_LAMBDA_MAX = 1e12
_MAX_LOG_STEP = 1.0
_SQRTH = math.sqrt(0.5)
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


def check_constants(reference: dict[str, float]) -> None:
    """Raise RuntimeError if a constant of the reference (name -> value) differs from this module's copy."""
    mine = {"SMALL_B": _SMALL_B, "LAMBDA_INIT": _LAMBDA_INIT, "LAMBDA_MIN": _LAMBDA_MIN,
            "LAMBDA_MAX": _LAMBDA_MAX, "MAX_LOG_STEP": _MAX_LOG_STEP}
    differ = {k: (v, mine[k]) for k, v in reference.items() if mine[k] != v}
    if differ:
        raise RuntimeError(f"edge_kernels constants differ from the reference (reference, compiled): {differ}; "
                           "update livetrack/estimator/edge_kernels.py")


def _erfcx_table(step: float, x_max: float, degree: int) -> np.ndarray:
    """(M, degree + 1) coefficients of polynomials in t in [-1, 1] (constant term first), one per interval
    [i step, (i + 1) step) of [0, x_max), M = x_max / step: each interpolates the scaled complementary error
    function ``erfcx(x) = exp(x^2) erfc(x)`` (scipy's) at the degree + 1 Chebyshev nodes of its interval, where
    ``x = (i + (t + 1) / 2) step``."""
    from numpy.polynomial import chebyshev
    from scipy.special import erfcx

    m = int(round(x_max / step))
    t = np.cos(np.pi * (np.arange(degree + 1) + 0.5) / (degree + 1))
    x = (np.arange(m)[:, None] + 0.5 * (t + 1.0)) * step
    cheb = chebyshev.chebfit(t, erfcx(x).T, degree).T  # (M, degree + 1) Chebyshev coefficients
    to_monomial = np.zeros((degree + 1, degree + 1))  # row j: the monomial coefficients of T_j
    for j in range(degree + 1):
        to_monomial[j, : j + 1] = chebyshev.cheb2poly(np.eye(j + 1)[j])
    return np.ascontiguousarray(cheb @ to_monomial)


_PHI_STEP = 1.0 / 32.0
_PHI_DEGREE = 6
_PHI_X_MAX = 28.0
_ERFCX = _erfcx_table(_PHI_STEP, _PHI_X_MAX, _PHI_DEGREE)
"""The compiled normal CDF (:func:`_cdf_pdf`) takes ``erfcx`` from this table of 896 polynomials of degree 6 in
``x = |z| / sqrt(2)`` (steps of 1/32 up to 28, beyond which ``exp(-x^2)`` underflows; 43 KB, of which the ~130
rows of |z| < 6 are the ones in use): within 8e-16 of scipy's ``ndtr`` for every z (absolute;
tests/test_kernels.py checks it on a fine grid). Degree 6 on steps of 1/32, evaluated by Estrin's scheme (three
independent pairs, then t^2 and t^4), replaced degree 9 on steps of 1/8 by Horner's rule (4.4e-16), whose chain
of 9 dependent multiply-adds per pixel corner bounded the LM kernel: one model evaluation costs ~59 instead of
~72 ns per sample (a captured tracked frame, evaluation only, the minimum of 40 runs). Derived here at import
from scipy's ``erfcx`` (~10-20 ms); numba freezes it into the compiled kernels and their cache."""


@jit_kernel(inline=True)
def _cdf_pdf(z):
    """The standard normal CDF Phi(z) and exp(-z^2 / 2) (the pdf without its 1/sqrt(2 pi)), with one ``exp``:
    ``Phi(-|z|) = exp(-z^2 / 2) erfcx(|z| / sqrt(2)) / 2`` and erfcx from :data:`_ERFCX` (a table lookup and a
    polynomial, instead of libm's ``erfc``, which costs ~3.5x an ``exp`` and computes its own). The numpy
    reference takes Phi from scipy's ``ndtr`` (cephes: erf near 0, erfc in the tails); they agree within
    8e-16 (absolute), and relatively in the far tail to the rounding of ``exp(-z^2 / 2)`` (~z^2 ulp)."""
    g = math.exp(-0.5 * (z * z))
    # u = x / _PHI_STEP with x = |z| / sqrt(2), in one product: _PHI_STEP is a power of 2, so the same number
    u = abs(z) * (_SQRTH / _PHI_STEP)
    if not u < _PHI_X_MAX / _PHI_STEP:  # exp(-x^2) has underflowed (Phi 0 or 1), or z is NaN (Phi NaN)
        if g != g:
            return g, g
        return (1.0 if z > 0.0 else 0.0), g
    i = int(u)
    t = 2.0 * (u - i) - 1.0
    c = _ERFCX[i]
    t2 = t * t  # Estrin's scheme for degree 6 (_PHI_DEGREE): short dependency chains
    p = ((c[0] + c[1] * t) + (c[2] + c[3] * t) * t2) + (t2 * t2) * ((c[4] + c[5] * t) + c[6] * t2)
    y = 0.5 * g * p
    return (1.0 - y if z > 0.0 else y), g


@jit_kernel(inline=True)
def _response(v, sig, a, b):
    """E, dE/du, dE/dsigma of one sample at distance v (px): ``edge_response_rows`` for one value."""
    b0 = max(b, _SMALL_B)
    hp = 0.5 * (a + b0)
    hm = 0.5 * (a - b0)
    inv_sig = 1.0 / sig
    s2_cdf = 0.0
    cdf_sum = 0.0
    s_pdf = 0.0
    s_cdf = 0.0
    pdf_sum = 0.0
    for j in range(4):  # corners v + hp, v - hp (sign +), v + hm, v - hm (sign -)
        if j == 0:
            s = v + hp
        elif j == 1:
            s = v - hp
        elif j == 2:
            s = v + hm
        else:
            s = v - hm
        cdf, pdf = _cdf_pdf(s * inv_sig)
        sc = s * cdf
        if j < 2:
            s2_cdf += s * sc
            cdf_sum += cdf
            s_pdf += s * pdf
            s_cdf += sc
            pdf_sum += pdf
        else:
            s2_cdf -= s * sc
            cdf_sum -= cdf
            s_pdf -= s * pdf
            s_cdf -= sc
            pdf_sum -= pdf
    inv_ab = 1.0 / (a * b0)
    sig_c = sig * _INV_SQRT_2PI
    e = (0.5 * inv_ab) * (s2_cdf + (sig * sig) * cdf_sum + sig_c * s_pdf)
    e_u = inv_ab * (s_cdf + sig_c * pdf_sum)
    e_uu = inv_ab * cdf_sum
    if b < _SMALL_B:
        c = (b0 * b0 - b * b) / 24.0 * inv_ab
        e -= c * cdf_sum
        e_u -= (c * _INV_SQRT_2PI * inv_sig) * pdf_sum
        e_uu += (c * _INV_SQRT_2PI * inv_sig**3) * s_pdf
    return e, e_u, sig * e_uu


@jit_kernel
def response_rows(v, sig, a, b):
    """Compiled :func:`~livetrack.estimator.edge_model.edge_response_rows`: v (N, K) px, sig, a, b (N,) ->
    E, dE/du, dE/dsigma (N, K)."""
    n, k = v.shape
    e = np.empty((n, k))
    e_u = np.empty((n, k))
    e_s = np.empty((n, k))
    for i in range(n):
        for j in range(k):
            e[i, j], e_u[i, j], e_s[i, j] = _response(v[i, j], sig[i], a[i], b[i])
    return e, e_u, e_s


@jit_kernel(inline=True)
def _row_normal(i, p, u0, data, valid_f, clip_hi, clip_lo, w, top, half_kappa, a, b, sat, fixed_sigma, weighted,
                halo_f, halo_sigma, fixed_contrast, out_a, out_g, out_r):
    """Normal equations of row i at parameters p (4,) (offset, sigma, visible level, log contrast): fills
    out_a (4, 4) = J^T W J and out_g (4,) = J^T W r; returns (weighted cost, sum of squares, live samples).
    out_r (3, >= K): scratch, the core model E, dE/du, dE/dsigma of the row's valid samples.
    ``edges._evaluate`` followed by ``edges._normal_equations`` for one row."""
    d = p[0]
    sig = p[1]
    level = p[2]
    contrast = math.exp(min(p[3], 700.0))
    hk = half_kappa[i]
    shift = hk * (sig * sig + 1.0 / 12.0)
    has_halo = halo_f > 0.0
    shift_h = hk * (halo_sigma * halo_sigma + 1.0 / 12.0)
    keep = 1.0 - halo_f
    # J^T W J's upper triangle and J^T W r, summed sample by sample as in the reference
    a00 = a01 = a02 = a03 = a11 = a12 = a13 = a22 = a23 = a33 = 0.0
    g0 = g1 = g2 = g3 = 0.0
    cost = 0.0
    ssr = 0.0
    n_live = 0.0
    ai = a[i]
    bi = b[i]
    topi = top[i]
    # the model of the row's valid samples first, in a loop of its own, then the sums in another: the same
    # operations on the same values (the same numbers), ~16 % less time per model evaluation than one loop doing
    # both (measured: 47.5 against 57 ns per sample; a loop holding the 15 sums across the 4 calls to ``exp`` per
    # sample, which clobber every vector register, schedules worse)
    for k in range(u0.shape[1]):
        if valid_f[i, k] != 0.0:
            out_r[0, k], out_r[1, k], out_r[2, k] = _response(u0[i, k] - (d + shift), sig, ai, bi)
    for k in range(u0.shape[1]):
        vf = valid_f[i, k]
        if vf == 0.0:
            continue  # an invalid sample: zero residual and Jacobian in the reference
        e, e_u, e_s = out_r[0, k], out_r[1, k], out_r[2, k]
        e_s -= (2.0 * hk * sig) * e_u  # the core's curvature shift moves with sigma
        if has_halo:
            we, we_u, _ = _response(u0[i, k] - (d + shift_h), halo_sigma, ai, bi)
            e = keep * e + halo_f * we
            e_u = keep * e_u + halo_f * we_u
            e_s = keep * e_s
        e -= topi
        m = level + contrast * e
        live = 1.0
        if clip_hi[i, k]:
            if m >= sat:
                live = 0.0
            m = min(m, sat)
        if clip_lo[i, k]:
            if m <= 0.0:
                live = 0.0
            m = max(m, 0.0)
        ce = contrast * live * vf
        res = (data[i, k] - m) * vf
        j0 = -(ce * e_u)
        j1 = 0.0 if fixed_sigma else ce * e_s
        j2 = live * vf
        j3 = 0.0 if fixed_contrast else ce * e
        if weighted:
            wk = w[i, k]
            jr0, jr1, jr2, jr3 = j0 * wk, j1 * wk, j2 * wk, j3 * wk
        else:  # a weight of 1 without its multiplications (x * 1.0 is x: the same numbers)
            jr0, jr1, jr2, jr3 = j0, j1, j2, j3
        g0 += jr0 * res
        a00 += jr0 * j0
        a01 += jr0 * j1
        a02 += jr0 * j2
        a03 += jr0 * j3
        g1 += jr1 * res
        a11 += jr1 * j1
        a12 += jr1 * j2
        a13 += jr1 * j3
        g2 += jr2 * res
        a22 += jr2 * j2
        a23 += jr2 * j3
        g3 += jr3 * res
        a33 += jr3 * j3
        r2 = res * res
        ssr += r2
        cost += wk * r2 if weighted else r2
        n_live += j2
    out_g[0], out_g[1], out_g[2], out_g[3] = g0, g1, g2, g3
    out_a[0, 0], out_a[0, 1], out_a[0, 2], out_a[0, 3] = a00, a01, a02, a03
    out_a[1, 0], out_a[1, 1], out_a[1, 2], out_a[1, 3] = a01, a11, a12, a13
    out_a[2, 0], out_a[2, 1], out_a[2, 2], out_a[2, 3] = a02, a12, a22, a23
    out_a[3, 0], out_a[3, 1], out_a[3, 2], out_a[3, 3] = a03, a13, a23, a33
    return cost, ssr, n_live


@jit_kernel
def _solve4(m, rhs, out):
    """out = m^-1 rhs for a 4x4 m by Gaussian elimination with partial pivoting (m and rhs are overwritten)."""
    for col in range(4):
        piv = col
        best = abs(m[col, col])
        for r in range(col + 1, 4):
            if abs(m[r, col]) > best:
                best = abs(m[r, col])
                piv = r
        if piv != col:
            for c in range(4):
                tmp = m[col, c]
                m[col, c] = m[piv, c]
                m[piv, c] = tmp
            tmp = rhs[col]
            rhs[col] = rhs[piv]
            rhs[piv] = tmp
        pv = m[col, col]
        for r in range(col + 1, 4):
            f = m[r, col] / pv
            if f != 0.0:
                for c in range(col, 4):
                    m[r, c] -= f * m[col, c]
                rhs[r] -= f * rhs[col]
    for r in range(3, -1, -1):
        acc = rhs[r]
        for c in range(r + 1, 4):
            acc -= m[r, c] * out[c]
        out[r] = acc / m[r, r]


@jit_kernel
def evaluate_normal(params, u0, data, valid_f, clip_hi, clip_lo, w, top, half_kappa, a, b, sat, fixed_sigma,
                    weighted, halo_f, halo_sigma, fixed_contrast):
    """Compiled ``edges._evaluate_normal`` of all rows: A (N, 4, 4), g (N, 4), cost, ssr, live samples (N,)."""
    n = params.shape[0]
    a_mat = np.empty((n, 4, 4))
    g = np.empty((n, 4))
    cost = np.empty(n)
    ssr = np.empty(n)
    n_live = np.empty(n)
    scratch = np.empty((3, u0.shape[1]))
    for i in range(n):
        cost[i], ssr[i], n_live[i] = _row_normal(i, params[i], u0, data, valid_f, clip_hi, clip_lo, w, top,
                                                 half_kappa, a, b, sat, fixed_sigma, weighted, halo_f, halo_sigma,
                                                 fixed_contrast, a_mat[i], g[i], scratch)
    return a_mat, g, cost, ssr, n_live


@jit_kernel
def levenberg_marquardt(params, u0, data, valid_f, clip_hi, clip_lo, w, top, half_kappa, a, b, sat, fixed_sigma,
                        weighted, halo_f, halo_sigma, fixed_contrast, half_width_px, s_lo, s_hi, iterations,
                        blind_step_px, straggler_after, straggler_fraction):
    """The iterations of ``edges._fit`` for all rows, params (N, 4) updated in place.

    The points iterate in lock step, as in the reference: each iteration every active point proposes a damped
    step; a point whose step after an accepted one is below ``blind_step_px`` takes it unevaluated and stops; the
    others evaluate their trial and update Nielsen's damping; the iterations end early once at most
    ``straggler_fraction`` of the points are active after ``straggler_after`` steps.
    Returns A (N, 4, 4), g (N, 4), cost, ssr, live samples, blind offset step (N,).
    """
    n = params.shape[0]
    a_mat, g, cost, ssr, n_live = evaluate_normal(params, u0, data, valid_f, clip_hi, clip_lo, w, top, half_kappa,
                                                  a, b, sat, fixed_sigma, weighted, halo_f, halo_sigma,
                                                  fixed_contrast)
    lam = np.full(n, _LAMBDA_INIT)
    nu = np.full(n, 2.0)
    active = np.ones(n, dtype=np.bool_)
    accepted = np.ones(n, dtype=np.bool_)
    blind = np.zeros(n)
    m = np.empty((4, 4))
    rhs = np.empty(4)
    step = np.empty(4)
    damp = np.empty(4)
    trial = np.empty(4)
    t_a = np.empty((4, 4))
    t_g = np.empty(4)
    scratch = np.empty((3, u0.shape[1]))
    n_active = n
    for it in range(iterations + 1):
        if n_active == 0 or (it >= straggler_after and n_active <= straggler_fraction * n):
            break
        for i in range(n):
            if not active[i]:
                continue
            # the Marquardt step (A + lam diag(A)) step = g, zero diagonals floored (edges._damped_solve)
            row_max = max(max(a_mat[i, 0, 0], a_mat[i, 1, 1]), max(a_mat[i, 2, 2], a_mat[i, 3, 3]))
            floor = 1e-12 * row_max if row_max > 0 else 1.0
            for r in range(4):
                damp[r] = lam[i] * max(a_mat[i, r, r], floor)
                rhs[r] = g[i, r]
                for c in range(4):
                    m[r, c] = a_mat[i, r, c]
                m[r, r] += damp[r]
            if fixed_sigma:
                m[1, 1] = 1.0
            if fixed_contrast:
                m[3, 3] = 1.0
            _solve4(m, rhs, step)
            step[3] = min(max(step[3], -_MAX_LOG_STEP), _MAX_LOG_STEP)
            level_scale = math.exp(min(params[i, 3], 700.0))
            small = (abs(step[0]) < blind_step_px and abs(step[1]) < blind_step_px
                     and abs(step[2]) < blind_step_px * level_scale and abs(step[3]) < blind_step_px)
            if accepted[i] and small:  # converged: the small step is taken without being evaluated
                for r in range(4):
                    params[i, r] += step[r]
                params[i, 0] = min(max(params[i, 0], -half_width_px), half_width_px)
                params[i, 1] = min(max(params[i, 1], s_lo), s_hi)
                blind[i] = step[0]
                active[i] = False
                n_active -= 1
                continue
            if it == iterations:
                continue
            for r in range(4):
                trial[r] = params[i, r] + step[r]
            trial[0] = min(max(trial[0], -half_width_px), half_width_px)
            if not fixed_sigma:
                trial[1] = min(max(trial[1], s_lo), s_hi)
            t_cost, t_ssr, t_live = _row_normal(i, trial, u0, data, valid_f, clip_hi, clip_lo, w, top, half_kappa,
                                                a, b, sat, fixed_sigma, weighted, halo_f, halo_sigma, fixed_contrast,
                                                t_a, t_g, scratch)
            old_cost = cost[i]
            predicted = 0.0
            for r in range(4):
                predicted += step[r] * (g[i, r] + damp[r] * step[r])
            rho = (old_cost - t_cost) / predicted
            accept = math.isfinite(t_cost) and t_cost <= old_cost
            good = accept and rho > 0.0
            if accept:
                for r in range(4):
                    params[i, r] = trial[r]
                    g[i, r] = t_g[r]
                    for c in range(4):
                        a_mat[i, r, c] = t_a[r, c]
                cost[i] = t_cost
                ssr[i] = t_ssr
                n_live[i] = t_live
            if good:
                t = 2.0 * rho - 1.0
                lam_i = lam[i] * max(1.0 / 3.0, 1.0 - t * t * t)
                nu[i] = 2.0
            else:
                lam_i = lam[i] * nu[i]
                nu[i] = nu[i] * 2.0
            lam[i] = min(max(lam_i, _LAMBDA_MIN), _LAMBDA_MAX)
            accepted[i] = accept
            if lam[i] >= _LAMBDA_MAX or cost[i] == 0.0:
                active[i] = False
                n_active -= 1
    return a_mat, g, cost, ssr, n_live, blind


def _warm_functions() -> tuple:
    from livetrack.estimator import edge_glue_kernels, pose_kernels, surround_kernels

    return (response_rows, evaluate_normal, levenberg_marquardt, pose_kernels.gauss_newton,
            pose_kernels.pose_covariance, *edge_glue_kernels.glue_kernels(), *surround_kernels.warm_functions())


def warm_up() -> float:
    """Compile (or load from the cache) the kernels the fits use (the edge LM, the pose Gauss-Newton and
    :mod:`~livetrack.estimator.edge_glue_kernels`; not
    :func:`response_rows`, which only the tests call) on a tiny input; returns the seconds it took (0 when the
    numpy kernels are in use). Idempotent: later calls cost microseconds. ``scripts/install.sh`` calls it, so that
    an installed tree's first frame loads the kernels from the cache instead of compiling them."""
    import time

    if kernels() != "numba":
        return 0.0
    t0 = time.perf_counter()
    u0 = np.array([[-1.0, 0.0, 1.0]])
    one = np.ones(1)
    valid_f = np.ones((1, 3))
    no = np.zeros((1, 3), dtype=np.bool_)
    zero = np.zeros(1)
    params = np.array([[0.0, 1.0, 10.0, math.log(100.0)]])
    levenberg_marquardt(params, u0, np.array([[10.0, 60.0, 110.0]]), valid_f, no, no, valid_f, zero, zero, one,
                        0.5 * one, 255.0, False, False, 0.0, 1.0, False, 4.0, 0.3, 5.0, 8, 3e-3, 3, 0.01)
    from livetrack.estimator import pose_kernels

    n = 12  # points of a circle of radius 0.1 m seen frontally from 2 m, focal length 1000 px
    phi = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    px, py = 0.05 * np.cos(phi), 0.05 * np.sin(phi)
    a_diag, a_off = np.full(n, 1000.0), np.zeros(n)
    R, _, _, r, J, _, _, _ = pose_kernels.gauss_newton(np.eye(3), np.array([0.0, 0.0, 2.0]), 0.0, px, py, a_diag,
                                                       a_off, a_off, a_diag, np.full(n, 0.1), np.ones(n), np.ones(n),
                                                       np.ones(n), 3.0, True, 15, 1e-6)
    pose_kernels.pose_covariance(J, np.ones(n), r, 6, R, 0.1, True)
    from livetrack.estimator import edge_glue_kernels, surround_kernels

    edge_glue_kernels.warm_up()
    surround_kernels.warm_up()
    return time.perf_counter() - t0


def cache_stats() -> dict[str, int]:
    """Numba's cache hits and misses (compilations) of the kernels in this process: ``{"hits": .., "misses": ..}``
    (zeros for the numpy kernels)."""
    return cache_stats_of(_warm_functions())


def cache_stats_of(functions) -> dict[str, int]:
    """Numba's cache hits and misses of ``functions`` in this process (functions without numba stats count 0)."""
    hits = misses = 0
    for fn in functions:
        stats = getattr(fn, "stats", None)
        if stats is not None:
            hits += sum(stats.cache_hits.values())
            misses += sum(stats.cache_misses.values())
    return {"hits": hits, "misses": misses}
