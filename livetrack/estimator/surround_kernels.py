"""Compiled (numba) kernels of :mod:`livetrack.estimator.edges.surround`: the share of a profile's samples that the
next edge's step and the white code dots add, per sample; the numpy functions of that module are their reference
(``LIVETRACK_KERNELS=numpy``) and the tests hold them together.

The dots' blurred disks use a table of the disk integral: ``P(a, b)``, the share of a unit 2-D Gaussian centred at
distance ``b`` from the centre of a disk of radius ``a`` that falls in it (both in units of the blur; the
non-central chi-square CDF with 2 degrees of freedom, ``scipy.special.chndtr(a^2, 2, b^2)``), on a grid of
``TABLE_STEP`` over ``a < TABLE_A_MAX``, ``b < TABLE_B_MAX``, read bilinearly (within 1e-4 of chndtr, tested);
beyond ``TABLE_A_MAX`` (a disk wider than 16 blurs) the disk is a half-plane shifted by its curvature,
``Phi(a - b - 1 / (2 a))``, and beyond ``TABLE_B_MAX`` the share is 0.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import numpy.typing as npt
from scipy.special import chndtr

from livetrack.estimator.edge_kernels import _cdf_pdf, _response, jit_kernel
from livetrack.estimator.pose_kernels import project

FloatArray = npt.NDArray[np.float64]

TABLE_STEP = 1.0 / 32.0
TABLE_A_MAX = 16.0
TABLE_B_MAX = 24.0


@functools.lru_cache(maxsize=1)
def disk_table() -> FloatArray:
    """(A, B) ``P(a, b)`` on the grid (``a = i TABLE_STEP``, ``b = j TABLE_STEP``), built once (~60 ms)."""
    a = np.arange(0.0, TABLE_A_MAX + 1.5 * TABLE_STEP, TABLE_STEP)
    b = np.arange(0.0, TABLE_B_MAX + 1.5 * TABLE_STEP, TABLE_STEP)
    table = chndtr((a * a)[:, None], 2.0, (b * b)[None, :])
    table.flags.writeable = False
    return table


@jit_kernel
def _disk(a, b, table, inv_step):
    """``P(a, b)`` (see the module's docstring) from the table, or its half-plane form for a wide disk."""
    if a >= TABLE_A_MAX:
        return _cdf_pdf(a - b - 0.5 / a)[0]
    if b >= TABLE_B_MAX:
        return 0.0
    x = a * inv_step
    y = b * inv_step
    i = int(x)
    j = int(y)
    fx = x - i
    fy = y - j
    return ((1.0 - fx) * (1.0 - fy) * table[i, j] + fx * (1.0 - fy) * table[i + 1, j]
            + (1.0 - fx) * fy * table[i, j + 1] + fx * fy * table[i + 1, j + 1])


@jit_kernel
def disks_share(ix, iy, valid, use, sigma, contrast, centres, px_to_m, radius_m, scale, reach_sigma, table,
                span_px):
    """Compiled :func:`~livetrack.estimator.edges.surround.disks_share`: (N, K) pixel columns and rows of the
    samples, their validity, (N,) rows to fill, their blur (px) and contrast; M disks (centres (M, 2) px, px_to_m
    (M, 2, 2), radius_m, scale (M,) px per m); a disk is evaluated within its radius plus ``reach_sigma`` blurs.
    ``span_px``: at least the distance between any two samples of a row (in the disks' rounded metric): a row
    whose first sample lies farther than that beyond a disk's reach is skipped whole."""
    n, k = ix.shape
    out = np.zeros((n, k))
    inv_step = 1.0 / TABLE_STEP
    for r in range(n):
        if not use[r]:
            continue
        first = 0
        while first < k and not valid[r, first]:
            first += 1
        if first == k:
            continue
        s_e = math.sqrt(sigma[r] * sigma[r] + 1.0 / 12.0)
        for m in range(centres.shape[0]):
            rho = scale[m] * radius_m[m]
            reach = rho + reach_sigma * s_e
            a = rho / s_e
            dx = ix[r, first] - centres[m, 0]
            dy = iy[r, first] - centres[m, 1]
            u = px_to_m[m, 0, 0] * dx + px_to_m[m, 0, 1] * dy
            v = px_to_m[m, 1, 0] * dx + px_to_m[m, 1, 1] * dy
            if scale[m] * math.sqrt(u * u + v * v) > reach + span_px:
                continue
            for j in range(first, k):
                if not valid[r, j]:
                    continue
                dx = ix[r, j] - centres[m, 0]
                dy = iy[r, j] - centres[m, 1]
                u = px_to_m[m, 0, 0] * dx + px_to_m[m, 0, 1] * dy
                v = px_to_m[m, 1, 0] * dx + px_to_m[m, 1, 1] * dy
                dist = scale[m] * math.sqrt(u * u + v * v)
                if dist < reach:
                    out[r, j] += contrast[r] * _disk(a, dist / s_e, table, inv_step)
    return out


@jit_kernel
def step_share(u0, valid, use, at, sigma, half_kappa_next, a, b, contrast, reach):
    """Compiled :func:`~livetrack.estimator.edges.surround.step_share`: (N, K) distances and validity of the
    samples, (N,) rows to fill, the step's offset ``d + w``, blur, the next circle's half curvature, footprint
    widths and contrast; of the rows ``use``, those whose step comes within ``reach`` blurs of their last valid
    sample (the reference's gate, row by row: the largest valid ``u0``, NaN if one is)."""
    n, k = u0.shape
    out = np.zeros((n, k))
    for r in range(n):
        if not use[r]:
            continue
        sig = sigma[r]
        last = -math.inf
        for j in range(k):
            if valid[r, j]:
                x = u0[r, j]
                if x != x:
                    last = math.nan
                    break
                if x > last:
                    last = x
        if not (at[r] - last < reach * sig):
            continue
        shifted = at[r] + half_kappa_next[r] * (sig * sig + 1.0 / 12.0)
        for j in range(k):
            if valid[r, j]:
                out[r, j] = contrast[r] * _response(u0[r, j] - shifted, sig, a[r], b[r])[0]
    return out


@jit_kernel
def white_step(points, normals, radius_m, radii, scale, black_beyond):
    """Compiled :func:`~livetrack.estimator.surround_geometry.white_step_px`: (N, 2) edge points and normals and
    (N,) their circles' radii (metres); per circle with a finite room on its white side, (U,) its radius, the room
    over the radius and whether the white ends in black. Returns (N,) the distance to the next edge (inf: none)
    and (N,) whether it is a step to black. The centre is each circle's mean point (summed in order: numpy sums
    pairwise, so the numbers differ by rounding)."""
    n, u = points.shape[0], radii.shape[0]
    group = np.full(n, -1, np.int64)
    sum_x, sum_y, count = np.zeros(u), np.zeros(u), np.zeros(u, np.int64)
    for i in range(n):
        for k in range(u):
            if radius_m[i] == radii[k]:
                group[i] = k
                sum_x[k] += points[i, 0]
                sum_y[k] += points[i, 1]
                count[k] += 1
                break
    step = np.full(n, np.inf)
    black = np.zeros(n, np.bool_)
    for i in range(n):
        k = group[i]
        if k < 0 or count[k] < 3:
            continue
        dx = points[i, 0] - sum_x[k] / count[k]
        dy = points[i, 1] - sum_y[k] / count[k]
        step[i] = scale[k] * abs(dx * normals[i, 0] + dy * normals[i, 1])
        black[i] = black_beyond[k]
    return step, black


@jit_kernel
def reaches(share, contrast, negligible):
    """Compiled :func:`~livetrack.estimator.edges.surround.reaches`: (N, K) share, (N,) ``|white - black|``; (N,)
    whether a row's largest ``|share|`` exceeds ``negligible`` times its contrast (no row with a NaN share, as
    numpy's max propagates it; a contrast not finite: none), without the (N, K) temporaries."""
    n, k = share.shape
    out = np.zeros(n, np.bool_)
    for r in range(n):
        c = contrast[r]
        limit = negligible * c if math.isfinite(c) else math.inf
        top = 0.0
        for j in range(k):
            v = abs(share[r, j])
            if v != v:
                top = math.nan
                break
            if v > top:
                top = v
        out[r] = top > limit
    return out


@jit_kernel
def dots_centroids(image, centres_m, dot_m, gx, gy, R, t, fx, fy, cx, cy, k1, k2, p1, p2, k3, min_contrast):
    """Compiled centroid windows of :func:`~livetrack.estimator.surround_geometry.dots_scale` (its numpy is the
    reference): M dots (centres (M, 2) and radii (M,), metres, in the target's plane), the window's offsets (K,) in
    dot radii, the pose (R, t) and the camera; a dot's window, placed by the pose (:func:`pose_kernels.project`),
    is read bilinearly, its samples above halfway from its darkest to its brightest weighted by their excess, twice
    (the second window about the first centroid); a dot counts while its windows lie in the frame (finite, at least
    0, at most ``w - 1.001`` across and ``h - 1.001`` down) and span ``min_contrast``. Returns the median, over the
    dots counted, of the centroid's distance from the target's centre over the design's; NaN when fewer than two
    count (the reference's None). The window's points are moved into the camera's frame without the reference's
    matrix product (BLAS rounding) and its sums run in order (numpy's pairwise): the same to ~1e-15."""
    h, w = image.shape[0], image.shape[1]
    m, k = centres_m.shape[0], gx.shape[0]
    found = centres_m.copy()
    counted = np.ones(m, np.bool_)
    cam = np.empty((m * k, 3))
    vals = np.empty(k)
    for _ in range(2):
        for i in range(m):
            for j in range(k):
                x = found[i, 0] + dot_m[i] * gx[j]
                y = found[i, 1] + dot_m[i] * gy[j]
                for r in range(3):
                    cam[i * k + j, r] = x * R[r, 0] + y * R[r, 1] + t[r]
        px = project(cam, fx, fy, cx, cy, k1, k2, p1, p2, k3)
        n_in = 0
        for i in range(m):
            if not counted[i]:
                continue
            for j in range(k):
                u, v = px[i * k + j, 0], px[i * k + j, 1]
                if not (u >= 0.0 and v >= 0.0 and u <= w - 1.001 and v <= h - 1.001):
                    counted[i] = False
                    break
            if counted[i]:
                n_in += 1
        if n_in < 2:
            return math.nan
        for i in range(m):
            if not counted[i]:
                continue
            lo, hi = math.inf, -math.inf
            for j in range(k):
                val = _bilinear(image, px[i * k + j, 0], px[i * k + j, 1])
                vals[j] = val
                lo = min(lo, val)
                hi = max(hi, val)
            mid = 0.5 * (lo + hi)
            total, sx, sy = 0.0, 0.0, 0.0
            for j in range(k):
                weight = max(vals[j] - mid, 0.0)
                total += weight
                sx += weight * (found[i, 0] + dot_m[i] * gx[j])
                sy += weight * (found[i, 1] + dot_m[i] * gy[j])
            if not (hi - lo >= min_contrast and total > 0):
                counted[i] = False
                continue
            found[i, 0], found[i, 1] = sx / total, sy / total
    ratio = np.empty(m)
    n = 0
    for i in range(m):
        if counted[i]:
            ratio[n] = math.hypot(found[i, 0], found[i, 1]) / math.hypot(centres_m[i, 0], centres_m[i, 1])
            n += 1
    if n < 2:
        return math.nan
    return np.median(ratio[:n])


@jit_kernel
def dots_brightness(image, centres_m, cos_a, sin_a, R, t, fx, fy, cx, cy, k1, k2, p1, p2, k3):
    """Compiled :func:`~livetrack.estimator.surround_geometry._dots_brightness`: (A,) the sum of the image
    (bilinear, clamped to the frame) at the dots' centres (M, 2), metres, turned by each angle (its cosine and sine,
    (A,)) and placed by the pose (R, t) and the camera (:func:`pose_kernels.project`); NaN for an angle whose
    points do not project (the reference's max is then NaN too)."""
    h, w = image.shape[0], image.shape[1]
    a, m = cos_a.shape[0], centres_m.shape[0]
    cam = np.empty((a * m, 3))
    for i in range(a):
        c, s = cos_a[i], sin_a[i]
        for j in range(m):
            x, y = centres_m[j, 0], centres_m[j, 1]
            xt, yt = x * c - y * s, x * s + y * c
            for r in range(3):
                cam[i * m + j, r] = xt * R[r, 0] + yt * R[r, 1] + t[r]
    px = project(cam, fx, fy, cx, cy, k1, k2, p1, p2, k3)
    out = np.zeros(a)
    for i in range(a):
        for j in range(m):
            u, v = px[i * m + j, 0], px[i * m + j, 1]
            if not (math.isfinite(u) and math.isfinite(v)):
                out[i] = math.nan
                break
            out[i] += _bilinear(image, min(max(u, 0.0), w - 1.001), min(max(v, 0.0), h - 1.001))
    return out


@jit_kernel(inline=True)
def _bilinear(image, u, v):
    """The image at (u, v) (pixels, inside the frame), bilinear: ``surround_geometry._bilinear``'s arithmetic."""
    x0, y0 = int(math.floor(u)), int(math.floor(v))
    fu, fv = u - x0, v - y0
    return ((1 - fu) * (1 - fv) * image[y0, x0] + fu * (1 - fv) * image[y0, x0 + 1]
            + (1 - fu) * fv * image[y0 + 1, x0] + fu * fv * image[y0 + 1, x0 + 1])


def warm_up() -> None:
    """Compile (or load from the cache) the kernels on a tiny input, of the types the fits pass (the samples'
    distances and pixels read-only, as ``edge_samples`` caches them: ``tests/test_warm_up.py``)."""
    white_step(np.zeros((3, 2)), np.ones((3, 2)), np.ones(3), np.ones(1), np.ones(1), np.ones(1, dtype=np.bool_))
    one = np.ones((1, 2))
    one.flags.writeable = False
    yes = np.ones(1, dtype=np.bool_)
    valid = np.ones((1, 2), dtype=np.bool_)
    step_share(one, valid, yes, np.ones(1), np.ones(1), np.zeros(1), np.ones(1), np.zeros(1), np.ones(1), 4.0)
    pixels = np.zeros((1, 2), dtype=np.intp)
    pixels.flags.writeable = False
    disks_share(pixels, pixels, valid, yes, np.ones(1), np.ones(1), np.zeros((1, 2)), np.eye(2)[None], np.ones(1),
                np.ones(1), 4.0, disk_table(), 10.0)
    reaches(np.zeros((1, 2)), np.ones(1), 1e-4)
    window = np.zeros(1)
    window.flags.writeable = False  # as surround_geometry._dots_window's
    for dtype in (np.uint8, np.uint16):  # the frames' types, writeable or read-only
        for writeable in (True, False):
            image = np.zeros((4, 4), dtype)
            image.flags.writeable = writeable
            dots_centroids(image, np.ones((2, 2)), np.ones(2), window, window, np.eye(3), np.array([0.0, 0.0, 1.0]),
                           1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
            dots_brightness(image, np.ones((2, 2)), np.ones(1), np.zeros(1), np.eye(3), np.array([0.0, 0.0, 1.0]),
                            1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def warm_functions() -> tuple:
    """The kernels, for numba's cache statistics."""
    return step_share, disks_share, white_step, reaches, dots_centroids, dots_brightness
