"""The residual check of ``fits._fit_once`` in one compiled pass: each contour point's first-order (Sampson)
distance to the fitted ellipse, and the largest of them in absolute value. The numpy expression it replaces
(``fit_distances_reference``) costs ~20-25 us per fit in a dozen small numpy calls (~30 fits per paper-lab frame);
this, ~1-2 us.

The arithmetic is numpy's, in its order: the two 2x2 matrix products of the reference run through OpenBLAS's
``dgemm``, which on x86-64 with FMA computes each element as ``fma(a1, b1, a0 * b0)``; the kernel calls LLVM's
``fma`` likewise, so on this project's machines the distances are the reference's bit for bit
(``tests/test_detect_fit_kernel.py`` holds them to it; on a BLAS that rounds otherwise they differ in the last
bit, and a fit's verdict could differ only for a residual within that of its bound). The sum of squares is left to
numpy's ``dot`` (its summation order is BLAS's).

Also the area of a contour's convex hull (``fits._convex``'s solidity test, ~40 a frame): the hull of an integer
contour is that of each row's leftmost and rightmost points, which come sorted by row, so one monotone-chain pass
finds it without a sort; its area is exact in integers, as ``cv2.contourArea`` of ``cv2.convexHull``'s hull is (its
terms and partial sums are integers under 2^53 in float64, so their order does not matter): the same float.
~1-3 against ~6-45 us for 200-2000 points."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

try:  # numba is a dependency; without it (a broken install) the numpy reference runs
    import numba
    from llvmlite import ir
    from numba.extending import intrinsic
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None

FloatArray = npt.NDArray[np.float64]


def fit_distances_reference(contour: np.ndarray, cx: float, cy: float, c: float, s: float, a: float,
                            b: float) -> FloatArray:
    """The first-order distances of ``contour``'s points (N, 1, 2) to the ellipse (centre (cx, cy), semi-axes a,
    b, direction (c, s) of a): ``((u/a)^2 + (v/b)^2 ... )`` as ``fits._fit_once`` computed them in numpy."""
    uv = (contour.reshape(-1, 2) - (cx, cy)) @ np.array([[c / a, -s / b], [s / a, c / b]])
    uv *= uv
    sq = uv @ np.array([[1.0, 1.0 / (a * a)], [1.0, 1.0 / (b * b)]])  # u^2 + v^2, (u/a)^2 + (v/b)^2
    return (sq[:, 0] - 1.0) / np.maximum(2.0 * np.sqrt(sq[:, 1]), 1e-12)


if numba is not None:

    @intrinsic
    def _fma(typingctx, x, y, z):  # pragma: no cover - compiled
        """``x * y + z`` rounded once (LLVM's ``llvm.fma.f64``)."""
        sig = numba.types.float64(numba.types.float64, numba.types.float64, numba.types.float64)

        def codegen(context, builder, signature, args):
            f64 = ir.DoubleType()
            fn = builder.module.declare_intrinsic("llvm.fma", [f64], ir.FunctionType(f64, [f64, f64, f64]))
            return builder.call(fn, args)

        return sig, codegen

    @numba.njit(cache=True, nogil=True, inline="always")
    def _distance(x, y, m00, m01, m10, m11, ia2, ib2):  # pragma: no cover - compiled
        """One point's first-order distance, its offset (x, y) from the centre given, in the reference's order."""
        u = _fma(y, m10, x * m00)
        v = _fma(y, m11, x * m01)
        u = u * u
        v = v * v
        return (_fma(v, 1.0, u * 1.0) - 1.0) / max(2.0 * np.sqrt(_fma(v, ib2, u * ia2)), 1e-12)

    @numba.njit(cache=True, nogil=True)
    def _fit_distances(contour, cx, cy, m00, m01, m10, m11, ia2, ib2, dist):  # pragma: no cover - compiled
        """Fills ``dist`` (N,) from ``contour`` (N, 1, 2); returns the largest |distance| (0 for none)."""
        worst = 0.0
        for i in range(contour.shape[0]):
            d = _distance(np.float64(contour[i, 0, 0]) - cx, np.float64(contour[i, 0, 1]) - cy, m00, m01, m10, m11,
                          ia2, ib2)
            dist[i] = d
            d = abs(d)
            worst = d if d > worst else worst
        return worst

    @numba.njit(cache=True, nogil=True)
    def _near_count(points, cx, cy, m00, m01, m10, m11, ia2, ib2, reach):  # pragma: no cover - compiled
        """How many of ``points`` (N, 2) lie within ``reach`` of the ellipse (|distance| <= reach)."""
        count = 0
        for i in range(points.shape[0]):
            d = _distance(points[i, 0] - cx, points[i, 1] - cy, m00, m01, m10, m11, ia2, ib2)
            if abs(d) <= reach:
                count += 1
        return count


def fit_distances(contour: np.ndarray, cx: float, cy: float, c: float, s: float, a: float,
                  b: float) -> tuple[FloatArray, float]:
    """``fit_distances_reference`` and the largest of its absolute values, compiled for an (N, 1, 2) int32
    contour (``cv2.findContours``'s) where numba is installed."""
    if numba is None or contour.dtype != np.int32 or contour.ndim != 3:
        dist = fit_distances_reference(contour, cx, cy, c, s, a, b)
        return dist, max(float(dist.max()), -float(dist.min()))
    dist = np.empty(contour.shape[0])
    worst = _fit_distances(contour, cx, cy, c / a, -s / b, s / a, c / b, 1.0 / (a * a), 1.0 / (b * b), dist)
    return dist, float(worst)


def near_count(points: np.ndarray, cx: float, cy: float, c: float, s: float, a: float, b: float,
               reach: float) -> int:
    """How many of ``points`` have ``|fit_distances_reference(points, ...)| <= reach``, compiled for (N, 2) float64
    points (``refine._sampled_start``'s, ~200 ellipses through 5 of them each: ~12 us a try in numpy, ~1 here)
    where numba is installed: the same distances (see the module's docstring), so the same count."""
    if numba is None or points.dtype != np.float64 or points.ndim != 2 or not points.flags.c_contiguous:
        return int(np.count_nonzero(np.abs(fit_distances_reference(points, cx, cy, c, s, a, b)) <= reach))
    return int(_near_count(points, cx, cy, c / a, -s / b, s / a, c / b, 1.0 / (a * a), 1.0 / (b * b), reach))


def hull_area(contour: np.ndarray) -> float:
    """``abs(cv2.contourArea(cv2.convexHull(contour)))``, compiled for an (N, 1, 2) int32 contour
    (``cv2.findContours``'s) where numba is installed: the same value (exact in both)."""
    if numba is None or contour.dtype != np.int32 or contour.ndim != 3 or len(contour) == 0:
        return abs(cv2.contourArea(cv2.convexHull(contour)))
    return _hull_area(contour)


if numba is not None:

    @numba.njit(cache=True, nogil=True)
    def _hull_area(contour):  # pragma: no cover - compiled
        """Twice the hull's area in int64 from each row's extreme points (Andrew's monotone chain over them, in
        (row, column) order), halved."""
        n = contour.shape[0]
        y0 = y1 = np.int64(contour[0, 0, 1])
        for i in range(n):
            y = np.int64(contour[i, 0, 1])
            y0 = min(y0, y)
            y1 = max(y1, y)
        rows = y1 - y0 + 1
        lo = np.empty(rows, np.int64)
        hi = np.empty(rows, np.int64)
        seen = np.zeros(rows, np.bool_)
        for i in range(n):
            x, r = np.int64(contour[i, 0, 0]), np.int64(contour[i, 0, 1]) - y0
            if not seen[r]:
                seen[r] = True
                lo[r] = hi[r] = x
            else:
                lo[r] = min(lo[r], x)
                hi[r] = max(hi[r], x)
        px = np.empty(2 * rows, np.int64)
        py = np.empty(2 * rows, np.int64)
        m = 0
        for r in range(rows):
            if seen[r]:
                px[m], py[m] = lo[r], r
                m += 1
                if hi[r] != lo[r]:
                    px[m], py[m] = hi[r], r
                    m += 1
        if m < 3:
            return 0.0
        hx = np.empty(2 * m, np.int64)
        hy = np.empty(2 * m, np.int64)
        k = 0
        for i in range(m):  # one chain, then the other (back over the points), dropping points that do not turn
            while k >= 2 and ((hx[k - 1] - hx[k - 2]) * (py[i] - hy[k - 2])
                              - (hy[k - 1] - hy[k - 2]) * (px[i] - hx[k - 2])) <= 0:
                k -= 1
            hx[k], hy[k] = px[i], py[i]
            k += 1
        t = k + 1
        for i in range(m - 2, -1, -1):
            while k >= t and ((hx[k - 1] - hx[k - 2]) * (py[i] - hy[k - 2])
                              - (hy[k - 1] - hy[k - 2]) * (px[i] - hx[k - 2])) <= 0:
                k -= 1
            hx[k], hy[k] = px[i], py[i]
            k += 1
        twice = np.int64(0)
        for i in range(k - 1):  # the last point is the first again
            twice += hx[i] * hy[i + 1] - hx[i + 1] * hy[i]
        return abs(twice) * 0.5
