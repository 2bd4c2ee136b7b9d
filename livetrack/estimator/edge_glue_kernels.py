"""Compiled (numba) kernels of the per-point work around the edge LM of :mod:`livetrack.estimator.edges`: which
pixels each edge profile samples and their distances from the edge (:func:`sample_geometry`), the levels and
mid-level crossing the fit starts from (:func:`levels_crossing`), and the covariance, levels and quality flag of the
fitted points (:func:`fit_summary`). Each is one loop over the points instead of ~10-30 numpy operations on (N, K)
arrays (~1 ms of numpy per tracked target of ~500 points on the development machine; see the README's speed
section).

The numpy reference of each is beside its caller (``edge_samples._geometry_numpy``, ``edges.start._levels_crossing``,
``edges.solver._summary_numpy``); the same kernel choice (``LIVETRACK_KERNELS``), cache, warm-up and GIL release as
:mod:`livetrack.estimator.edge_kernels`. :func:`sample_geometry` and :func:`levels_crossing` do the reference's
arithmetic in its order (the same numbers; tests/test_kernels.py holds them equal); :func:`fit_summary` solves the
4x4 normal equations by Gaussian elimination where the reference inverts them with LAPACK, so its figures agree to
rounding (tests: 1e-9 px, relative 1e-9 for the standard deviations).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from livetrack.estimator.edge_kernels import _solve4, cache_stats_of, jit_kernel, kernels


def kernel_array(x, dtype) -> np.ndarray:
    """``x`` as a C-contiguous, writeable array of ``dtype`` (copied only where it is not): the one array type
    the kernels are compiled (and warmed up) for; a read-only or strided array would compile another
    specialisation at its first call."""
    x = np.asarray(x, dtype=dtype)
    return x if x.flags.c_contiguous and x.flags.writeable else np.array(x, dtype=dtype, order="C")


READ_DTYPES = (np.uint8, np.uint16, np.float32, np.float64)
"""Image dtypes :func:`read_profiles` is compiled for at the warm-up (C-contiguous, writeable or read-only); an
image of another type or layout is read by the numpy reference (the same numbers) rather than compile another
specialisation during a frame."""


@jit_kernel
def sample_geometry(height, width, pts, nrm, kappa, has_kappa, stencil):
    """Pixel indices ix, iy (N, K) int64, validity (N, K), distances u0 (N, K) px and half curvatures (N,) of the
    samples of N points (x, y) (N, 2) with unit normals (N, 2) and curvatures kappa (N,) 1/px (``has_kappa``
    False: straight edges, kappa ignored), stencil (K0, 2) offsets (along the normal, along the tangent) px.

    As ``edge_samples._geometry_numpy``: stencil positions rounded to pixel centres (half to even), those outside
    the image dropped, each row's distinct pixels in ascending row-major order, K the most of any row (at least
    1); invalid entries are pixel (0, 0) with their distance computed all the same. The stencil reaches at most
    ``|s| + |t|`` px from the point along each axis."""
    n = pts.shape[0]
    k0 = stencil.shape[0]
    # a row's pixels lie within +-reach of its rounded point: marked on a local grid, read back in row-major order,
    # which is ascending and distinct (no sort)
    reach = 1
    for j in range(k0):
        reach = max(reach, int(math.ceil(abs(stencil[j, 0]) + abs(stencil[j, 1]))) + 1)
    side = 2 * reach + 1
    mark = np.zeros(side * side, dtype=np.bool_)
    # each row's distinct pixels in row-major order, as offsets on the local grid (int16, side^2 booleans fit in
    # memory: small temporaries, which a 500-point target allocates without page faults)
    # (one spare column: the scan below writes each cell of a row's box at its count, then counts it if marked)
    off_x = np.empty((n, k0 + 1), dtype=np.int16)
    off_y = np.empty((n, k0 + 1), dtype=np.int16)
    counts = np.zeros(n, dtype=np.int64)
    # the stencil's rounded positions of a row first, in a loop of its own that LLVM vectorises, then the marking:
    # the same expressions, so the same pixels
    st_s = np.ascontiguousarray(stencil[:, 0])
    st_t = np.ascontiguousarray(stencil[:, 1])
    sx = np.empty(k0)
    sy = np.empty(k0)
    k = 1
    for i in range(n):
        px, py, nx, ny = pts[i, 0], pts[i, 1], nrm[i, 0], nrm[i, 1]
        cx = np.rint(px)
        cy = np.rint(py)
        lo_x = side
        hi_x = -1
        lo_y = side
        hi_y = -1
        for j in range(k0):
            sx[j] = np.rint(px + st_s[j] * nx - st_t[j] * ny)
            sy[j] = np.rint(py + st_s[j] * ny + st_t[j] * nx)
        for j in range(k0):
            fx = sx[j]
            fy = sy[j]
            if fx >= 0 and fx < width and fy >= 0 and fy < height:
                ox = int(fx - cx) + reach
                oy = int(fy - cy) + reach
                mark[oy * side + ox] = True
                lo_x, hi_x = min(lo_x, ox), max(hi_x, ox)
                lo_y, hi_y = min(lo_y, oy), max(hi_y, oy)
        c = 0
        for oy in range(lo_y, hi_y + 1):  # without a branch per cell (marks are scattered: mispredicted)
            for ox in range(lo_x, hi_x + 1):
                m = mark[oy * side + ox]
                mark[oy * side + ox] = False
                off_x[i, c] = ox
                off_y[i, c] = oy
                c += np.int64(m)
        counts[i] = c
        if c > k:
            k = c
    ix = np.zeros((n, k), dtype=np.int64)
    iy = np.zeros((n, k), dtype=np.int64)
    valid = np.zeros((n, k), dtype=np.bool_)
    u0 = np.empty((n, k))
    half_kappa = np.zeros(n)
    for i in range(n):
        px, py, nx, ny = pts[i, 0], pts[i, 1], nrm[i, 0], nrm[i, 1]
        kap = kappa[i] if has_kappa else 0.0
        if has_kappa:
            half_kappa[i] = 0.5 * kap
        base_x = np.int64(np.rint(px)) - reach
        base_y = np.int64(np.rint(py)) - reach
        for j in range(k):
            if j < counts[i]:
                ix[i, j] = base_x + np.int64(off_x[i, j])
                iy[i, j] = base_y + np.int64(off_y[i, j])
                valid[i, j] = True
            dx = ix[i, j] - px
            dy = iy[i, j] - py
            u = nx * dx + ny * dy
            if has_kappa:
                t = nx * dy - ny * dx
                u = (2.0 * u - kap * (u * u + t * t)) / (1.0 + math.sqrt((1.0 - kap * u) ** 2 + (kap * t) ** 2))
            u0[i, j] = u
    return ix, iy, valid, u0, half_kappa


@jit_kernel
def read_profiles(img, ix, iy, valid, sat, weighted, noise_const, noise_slope):
    """The pixel values of N profiles: data (N, K) float64 (0 where invalid, the clip level / 0 where clipped),
    validity (N, K) (a non-finite pixel is invalid), clipped high / low (N, K), weights (N, K) (``weighted``: from
    the noise model ``noise_const + noise_slope * max(data, 0)``, else valid as 0.0 / 1.0), samples and clipped
    samples per profile (N,) int64, ``top`` (N,) (1.0 where clipped at 0 only), whether any sample is clipped, and
    one past each profile's last valid sample (N,) int64 (``Profiles.n_span``):
    the reference is the numpy part of ``edge_samples.sample_profiles``, the same arithmetic. img (H, W), any
    real dtype; ix, iy (N, K) pixel indices, valid (N, K) the geometry's mask."""
    n, k = ix.shape
    data = np.zeros((n, k))
    ok = np.zeros((n, k), dtype=np.bool_)
    clip_hi = np.zeros((n, k), dtype=np.bool_)
    clip_lo = np.zeros((n, k), dtype=np.bool_)
    w = np.zeros((n, k))
    n_samples = np.zeros(n, dtype=np.int64)
    n_clipped = np.zeros(n, dtype=np.int64)
    top = np.zeros(n)
    span = np.zeros(n, dtype=np.int64)
    var_floor = 1e-12 * max(sat * sat, 1e-300)
    any_clipped = False
    for i in range(n):
        any_hi = False
        any_lo = False
        for j in range(k):
            if not valid[i, j]:
                continue
            v = np.float64(img[iy[i, j], ix[i, j]])
            if not math.isfinite(v):
                continue
            ok[i, j] = True
            n_samples[i] += 1
            span[i] = j + 1
            if v >= sat:
                clip_hi[i, j] = True
                any_hi = True
                v = sat
                n_clipped[i] += 1
            elif v <= 0.0:
                clip_lo[i, j] = True
                any_lo = True
                v = 0.0
                n_clipped[i] += 1
            data[i, j] = v
            if weighted:
                w[i, j] = 1.0 / max(noise_const + noise_slope * max(v, 0.0), var_floor)
            else:
                w[i, j] = 1.0
        if any_lo and not any_hi:
            top[i] = 1.0
        if any_hi or any_lo:
            any_clipped = True
    return data, ok, clip_hi, clip_lo, w, n_samples, n_clipped, top, any_clipped, span


@jit_kernel
def levels_crossing(u0, data, valid, clip_hi, clip_lo, sat):
    """Start levels and crossing of N profiles (N, K): black lb, white lw, the level crossed (N,), where each
    profile crosses it u_c (N,) px, and whether it is clipped high / only low (N,) bool: the reference
    ``edges.start._levels_crossing``, the same arithmetic (the crossing is that of ``edges.start._crossing``)."""
    n, k = u0.shape
    lb = np.empty(n)
    lw = np.empty(n)
    level = np.empty(n)
    u_c = np.zeros(n)
    hi = np.zeros(n, dtype=np.bool_)
    lo = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        any_un = False
        any_lo = False
        mn = np.inf
        mx = -np.inf
        for j in range(k):
            if clip_hi[i, j]:
                hi[i] = True
            if clip_lo[i, j]:
                any_lo = True
            if valid[i, j] and not clip_hi[i, j] and not clip_lo[i, j]:
                any_un = True
                y = data[i, j]
                mn = min(mn, y)
                mx = max(mx, y)
        b = mn if any_un else 0.0
        w = mx if any_un else sat
        lo[i] = any_lo and not hi[i]
        if any_lo:
            b = min(b, 0.0)
        if hi[i]:
            w = sat
        lb[i] = b
        lw[i] = w
        lev = sat if hi[i] else (0.0 if lo[i] else 0.5 * (b + w))
        level[i] = lev
        # the crossing: the highest sample below the level and the lowest above it (first of equals)
        j_lo = -1
        j_hi = -1
        for j in range(k):
            if not valid[i, j]:
                continue
            y = data[i, j]
            below = y < lev or (lo[i] and y <= lev)
            if below:
                if j_lo < 0 or u0[i, j] > u0[i, j_lo]:
                    j_lo = j
            elif j_hi < 0 or u0[i, j] < u0[i, j_hi]:
                j_hi = j
        if j_lo < 0 or j_hi < 0:
            continue  # u_c 0: the profile does not cross
        u_lo, u_hi = u0[i, j_lo], u0[i, j_hi]
        y_lo, y_hi = data[i, j_lo], data[i, j_hi]
        frac = (lev - y_lo) / (y_hi - y_lo if y_hi > y_lo else 1.0)
        frac = min(max(frac, 0.0), 1.0)
        u_c[i] = u_lo + frac * (u_hi - u_lo) if u_hi > u_lo else 0.5 * (u_lo + u_hi)
    return lb, lw, level, u_c, hi, lo


@jit_kernel
def fit_summary(params, a_mat, g, cost, ssr, n_live, blind, lb, lw, fixed_sigma, fixed_contrast, weighted, n_params,
                n_samples, n_clipped, half_width_px, s_lo, s_hi, min_con, converged_step_px):
    """Position standard deviation (px), residual RMS and the ``ok`` flag (N,) of fitted points, from their internal
    parameters (N, 4), normal equations A (N, 4, 4), g (N, 4) at the solution and black and white levels lb, lw
    (N,): the reference ``edges.solver._summary_numpy`` (the equilibrated A's inverse there, Gaussian elimination
    with partial pivoting of its first column here). The levels come from numpy's ``exp`` in both (``_levels``):
    a tracked frame starts from them, so they stay the reference's numbers."""
    n = params.shape[0]
    pos_std = np.empty(n)
    rms = np.empty(n)
    ok = np.empty(n, dtype=np.bool_)
    m = np.empty((4, 4))
    rhs = np.empty(4)
    col = np.empty(4)
    scale = np.empty(4)
    for i in range(n):
        for r in range(4):
            d = a_mat[i, r, r]
            if (r == 1 and fixed_sigma) or (r == 3 and fixed_contrast):
                d = 1.0
            s = math.sqrt(max(d, 0.0))
            scale[r] = s if s > 0 else 1.0
        for r in range(4):
            for c in range(4):
                v = a_mat[i, r, c]
                if r == c and ((r == 1 and fixed_sigma) or (r == 3 and fixed_contrast)):
                    v = 1.0
                m[r, c] = v / (scale[r] * scale[c])
            m[r, r] += 1e-12
            rhs[r] = 1.0 if r == 0 else 0.0
        _solve4(m, rhs, col)  # the LM kernel's 4x4 elimination with partial pivoting
        cov00 = col[0] / scale[0] ** 2
        gn = 0.0
        for r in range(4):
            gn += col[r] * (g[i, r] / scale[r])
        gn_step = gn / scale[0] - blind[i]
        identifiable = a_mat[i, 0, 0] > 0
        dof = n_live[i] - n_params
        if weighted:
            var_pos = cov00
        else:
            var_pos = cov00 * (cost[i] / max(dof, 1) if dof > 0 else np.inf)
        std = math.sqrt(abs(var_pos)) if identifiable and var_pos >= 0 else np.inf
        pos_std[i] = std
        rms[i] = math.sqrt(ssr[i] / max(n_live[i], 1))
        b = lb[i]
        w = lw[i]
        finite = True
        for r in range(4):
            if not math.isfinite(params[i, r]):
                finite = False
        good = (finite and math.isfinite(std) and identifiable and abs(gn_step) < converged_step_px
                and abs(params[i, 0]) <= half_width_px - 1.0 and (w - b) > min_con and (w - b) > 5.0 * rms[i]
                and n_samples[i] - n_clipped[i] >= n_params + 2)
        if not fixed_sigma:
            sig = params[i, 1]
            good = good and sig > s_lo * (1 + 1e-9) and sig < s_hi * (1 - 1e-9)
        ok[i] = good
    return pos_std, rms, ok


@jit_kernel
def hinted_start_terms(rows, u0, data, valid, clip_hi, clip_lo, lb, lw, hi, contrast, sig0, a, b, ndtri):
    """The per-sample part of the start of clipped profiles of known contrast (``edges.start._initial_params``
    with ``contrast``, its numpy reference, the same numbers): for each of the rows ``rows`` (M,) of the (N, K)
    profiles, its transition samples (unclipped, beyond 5 % of the visible contrast from the visible level) in
    column order, each mapped to the edge position ``u - s ndtri((I - black) / C)`` (``s`` the blur with the pixel
    footprint, ``black`` the level the known contrast C puts below the visible one); ``ndtri`` is scipy's
    (``scipy_ndtri``). lb, lw, hi, contrast, sig0, a, b are (N,). Returns those positions (M, T), zero after each
    row's count (T the most of any row, at least 1), the counts (M,) and the black levels (M,): the reference sums
    each row (numpy's summation) and divides by its count."""
    m, k = rows.shape[0], u0.shape[1]
    counts = np.zeros(m, dtype=np.int64)
    black = np.empty(m)
    n_t = 1
    for r in range(m):
        i = rows[r]
        visible = lw[i] - lb[i]
        c = 0
        for j in range(k):
            if valid[i, j] and not clip_hi[i, j] and not clip_lo[i, j]:
                y = data[i, j]
                if (y > lb[i] + 0.05 * visible) if hi[i] else (y < lw[i] - 0.05 * visible):
                    c += 1
        counts[r] = c
        n_t = max(n_t, c)
        black[r] = lb[i] if hi[i] else lw[i] - contrast[i]
    terms = np.zeros((m, n_t))
    for r in range(m):
        i = rows[r]
        visible = lw[i] - lb[i]
        con = contrast[i]
        sig_eff = math.sqrt(sig0[i] * sig0[i] + (a[i] * a[i] + b[i] * b[i]) / 12.0)
        c = 0
        for j in range(k):
            if valid[i, j] and not clip_hi[i, j] and not clip_lo[i, j]:
                y = data[i, j]
                if (y > lb[i] + 0.05 * visible) if hi[i] else (y < lw[i] - 0.05 * visible):
                    z = ndtri(min(max((y - black[r]) / con, 1e-9), 1.0 - 1e-9))
                    terms[r, c] = u0[i, j] - sig_eff * z
                    c += 1
    return terms, counts, black


@functools.lru_cache(maxsize=1)
def scipy_ndtri():
    """scipy's ``ndtri`` (``scipy.special.cython_special``) as a function the kernels can call: the function of
    ``scipy.special.ndtri``, so the same numbers. Passed to them as an argument (a function used as a global
    would make numba refuse to cache the kernel)."""
    import ctypes

    from numba.extending import get_cython_function_address

    address = get_cython_function_address("scipy.special.cython_special", "ndtri")
    return ctypes.CFUNCTYPE(ctypes.c_double, ctypes.c_double)(address)


@jit_kernel
def start_blur(s_ok, s_sig, s_lb, s_lw, sig0, fixed_sigma, s_lo, s_hi):
    """Which earlier fits (N,) a tracked edge fit may start from (ok, finite blur and levels, white above black)
    and the blur each starts at (N,): the earlier fit's, clipped to [s_lo, s_hi], where usable and the blur is
    free, else ``sig0``. The first half of ``edges.solver._fit``'s start from ``start`` (its numpy reference, the
    same numbers)."""
    n = s_ok.shape[0]
    use = np.empty(n, dtype=np.bool_)
    sig_start = np.empty(n)
    for i in range(n):
        u = (s_ok[i] and math.isfinite(s_sig[i]) and math.isfinite(s_lb[i]) and math.isfinite(s_lw[i])
             and s_lw[i] > s_lb[i])
        use[i] = u
        sig_start[i] = min(max(s_sig[i], s_lo), s_hi) if (u and not fixed_sigma) else sig0[i]
    return use, sig_start


@jit_kernel
def start_params(use, s_d, s_lb, s_lw, initial, sig_start, top, half_width_px, still_px, min_contrast):
    """The start of a tracked edge fit (N, 4) (offset, blur, visible level, contrast; the caller takes the log of
    the contrast, numpy's), from the data's start ``initial`` (N, 4) (offset, -, black, white): an edge that has
    not moved (its data start within ``still_px`` of a usable earlier fit, which lies within ``half_width_px`` - 1)
    starts at that fit's offset and levels. The second half of ``edges.solver._fit``'s start from ``start`` (its
    numpy reference, the same numbers); the contrast is floored at ``min_contrast`` (NaN kept, as np.maximum)."""
    n = use.shape[0]
    out = np.empty((n, 4))
    contrast = np.empty(n)
    for i in range(n):
        d0, lb0, lw0 = initial[i, 0], initial[i, 2], initial[i, 3]
        if use[i] and abs(s_d[i] - d0) < still_px and abs(s_d[i]) <= half_width_px - 1.0:
            d0, lb0, lw0 = s_d[i], s_lb[i], s_lw[i]
        c = lw0 - lb0
        contrast[i] = c if (c != c or c > min_contrast) else min_contrast
        out[i, 0] = d0
        out[i, 1] = sig_start[i]
        out[i, 2] = lw0 if top[i] > 0 else lb0
        out[i, 3] = 0.0
    return out, contrast


@jit_kernel
def masked_median(values, mask):
    """``np.median(values[mask])`` of (N,) float values and an (N,) bool mask (its numpy reference), the same
    number: numba's ``np.median`` selects the same element (the mean of the two middle ones for an even count,
    ``(a + b) / 2`` as numpy's mean of two; +0.0 for zeros of either sign); NaN when a selected value is NaN or
    none is selected (numpy also warns then). ~1 us against numpy's 15-20 us for a few hundred values."""
    n = 0
    for i in range(values.shape[0]):
        if mask[i]:
            n += 1
    if n == 0:
        return math.nan
    chosen = np.empty(n)
    j = 0
    for i in range(values.shape[0]):
        if mask[i]:
            if values[i] != values[i]:
                return math.nan
            chosen[j] = values[i]
            j += 1
    return np.median(chosen) + 0.0  # numpy's mean sums from +0.0: a median of -0.0 values is +0.0


def median_where(values, mask) -> float:
    """``float(np.median(values[mask]))``: compiled (:func:`masked_median`) unless ``LIVETRACK_KERNELS=numpy``
    selects numpy (the reference). ``values`` (N,) float, ``mask`` (N,) bool."""
    if kernels() == "numba":
        return float(masked_median(kernel_array(values, np.float64), kernel_array(mask, np.bool_)))
    return float(np.median(np.asarray(values)[np.asarray(mask)]))


@jit_kernel
def unit_normals(nrm):
    """(N, 2) normals divided by their length (by 1 where it is not > 0): ``edge_samples.check_points``'s numpy
    lines, the same arithmetic (``x ** 2`` is numpy's ``x * x``; one rounding each), ~1 us against ~12 for 500."""
    out = np.empty_like(nrm)
    for i in range(nrm.shape[0]):
        norm = math.sqrt(nrm[i, 0] * nrm[i, 0] + nrm[i, 1] * nrm[i, 1])
        d = norm if norm > 0 else 1.0
        out[i, 0] = nrm[i, 0] / d
        out[i, 1] = nrm[i, 1] / d
    return out


@jit_kernel
def bounds_xy(points):
    """(min x, min y, max x, max y) of (N, 2) points, N >= 1; NaN where a coordinate is NaN (as numpy's
    ``min``/``max``): the tracker's search window (``Tracker._window``; its numpy lines are the reference)."""
    lo_x = hi_x = points[0, 0]
    lo_y = hi_y = points[0, 1]
    for i in range(points.shape[0]):
        x = points[i, 0]
        y = points[i, 1]
        if x != x or lo_x != lo_x:
            lo_x = hi_x = math.nan
        else:
            lo_x = min(lo_x, x)
            hi_x = max(hi_x, x)
        if y != y or lo_y != lo_y:
            lo_y = hi_y = math.nan
        else:
            lo_y = min(lo_y, y)
            hi_y = max(hi_y, y)
    return lo_x, lo_y, hi_x, hi_y


def glue_kernels() -> tuple:
    """The kernels of this module (for the warm-up and the cache statistics)."""
    return (sample_geometry, read_profiles, levels_crossing, fit_summary, masked_median, hinted_start_terms,
            start_blur, start_params, unit_normals, bounds_xy)


def warm_up() -> None:
    """Compile (or load from numba's cache) this module's kernels on a tiny input (``edge_kernels.warm_up`` calls
    it, and ``scripts/install.sh`` that). Idempotent. Does nothing without numba."""
    if not hasattr(sample_geometry, "targetoptions"):
        return
    pts = np.array([[5.0, 5.0]])
    nrm = np.array([[1.0, 0.0]])
    stencil = np.array([[-1.0, 0.0], [0.0, 0.0], [1.0, 0.0]])
    for has_kappa in (False, True):
        ix, iy, valid, u0, _ = sample_geometry(10, 10, pts, nrm, np.full(1, 0.1), has_kappa, stencil)
    for x in (ix, iy, valid):
        x.flags.writeable = False  # as edge_samples._geometry caches them
    for dtype in READ_DTYPES:
        img = np.zeros((10, 10), dtype=dtype)
        for writeable in (True, False):
            img.flags.writeable = writeable
            read_profiles(img, ix, iy, valid, 255.0, False, 0.0, 0.0)
    data = np.array([[10.0, 60.0, 110.0]])
    no = np.zeros((1, 3), dtype=np.bool_)
    levels_crossing(u0, data, valid.copy(), no, no, 255.0)
    params = np.array([[0.0, 1.0, 10.0, math.log(100.0)]])
    a_mat = np.eye(4)[None, :, :].copy()
    one = np.ones(1)
    fit_summary(params, a_mat, np.zeros((1, 4)), one, one, np.full(1, 3.0), np.zeros(1), np.full(1, 10.0),
                np.full(1, 110.0), False, False, False, 4, np.full(1, 3, dtype=np.int64), np.zeros(1, dtype=np.int64),
                4.0, 0.3, 5.0, 5.1, 1e-3)
    masked_median(np.array([1.0, 2.0]), np.ones(2, dtype=np.bool_))
    hi = np.ones(1, dtype=np.bool_)
    hinted_start_terms(np.zeros(1, dtype=np.int64), u0, data, valid.copy(), no, no, np.full(1, 10.0), np.full(1, 255.0),
                       hi, np.full(1, 300.0), one, one, 0.5 * one, scipy_ndtri())
    zero_f, white = np.zeros(1), np.full(1, 100.0)
    use, sig_start = start_blur(hi, one, zero_f, white, one, False, 0.3, 5.0)
    start_params(use, zero_f, zero_f, white, np.zeros((1, 4)), sig_start, one, 4.0, 0.1, 1e-6)
    unit_normals(nrm)
    bounds_xy(pts)


def cache_stats() -> dict[str, int]:
    """Numba's cache hits and misses (compilations) of this module's kernels in this process."""
    return cache_stats_of(glue_kernels())
