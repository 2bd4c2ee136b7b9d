"""Rays cast out from a hole of a binary image, compiled (numba): where each leaves the dark for good. The
coarse detector asks this of every hole of a target's inner-disk size that might be a ring merged with dark
surroundings (``detect._pair_from_hole``), hundreds per textured frame: numpy's per-call overhead (~40 us a hole)
cost more than the rest of the detector there; compiled, a hole costs ~2 us. ``ray_exits_numpy`` is the
reference (the same samples and rule; tests hold the two equal). The same compilation and cache rules as
:mod:`livetrack.estimator.edge_kernels` (``cache=True``, ``nogil``).

Geometry: the rays start at the centre (cx, cy) of an ellipse of semi-axes (a, b) whose major axis points along
(cos_angle, sin_angle); ray j has direction (cos_t[j], sin_t[j]) in the ellipse's unit frame, and its sample k lies
at radius rho_k = 1 + k step (units of the ellipse: 1 is on it), pixel (rint(x), rint(y)); pixel convention as in
``detect`` ((0, 0) the centre of the top-left pixel, ``binary[y, x]``, 0 = white)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

try:  # numba is a dependency; without it (a broken install) the numpy reference runs
    import numba
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None

FloatArray = npt.NDArray[np.float64]


def ray_exits_numpy(binary: npt.NDArray[np.uint8], frame: tuple[float, float, float, float, float, float],
                    cos_t: FloatArray, sin_t: FloatArray, step: float, count: int, reach: float,
                    length: int) -> FloatArray:
    """(R,) the radius where each ray leaves the dark: half a step before the first run of ``length`` white
    samples (inside the image) that starts at a radius <= ``reach``; NaN for a ray that does not. ``frame`` =
    (cx, cy, a, b, cos_angle, sin_angle); ``count`` samples per ray."""
    cx, cy, a, b, c, s = frame
    rho = 1.0 + step * np.arange(count)
    u, v = a * cos_t[:, None] * rho, b * sin_t[:, None] * rho
    xs = np.rint(cx + c * u - s * v)
    ys = np.rint(cy + s * u + c * v)
    h, w = binary.shape
    inside = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
    white = np.zeros(xs.shape, np.int64)
    white[inside] = binary[ys[inside].astype(np.intp), xs[inside].astype(np.intp)] == 0
    sums = np.cumsum(white, axis=1)
    before = np.concatenate([np.zeros((len(cos_t), 1), np.int64), sums[:, :-length]], axis=1)
    window = sums[:, length - 1 :] - before  # white samples in the run starting at each k
    full = (window == length) & (rho[None, : window.shape[1]] <= reach)
    out = np.full(len(cos_t), np.nan)
    leaves = full.any(axis=1)
    k = np.argmax(full, axis=1)
    out[leaves] = rho[k[leaves]] - 0.5 * step
    return out


if numba is not None:

    @numba.njit(cache=True, nogil=True)
    def _ray_exits_compiled(binary, cx, cy, a, b, c, s, cos_t, sin_t, step, count, reach, length, out):
        # pragma: no cover - compiled
        h, w = binary.shape
        for j in range(cos_t.size):
            out[j] = np.nan
            run = 0
            for k in range(count):
                rho = 1.0 + step * k
                u = a * cos_t[j] * rho
                v = b * sin_t[j] * rho
                x = np.rint(cx + c * u - s * v)
                y = np.rint(cy + s * u + c * v)
                if x >= 0 and x < w and y >= 0 and y < h and binary[int(y), int(x)] == 0:
                    run += 1
                else:
                    run = 0
                if run == length:
                    start = k - length + 1
                    if 1.0 + step * start <= reach:
                        out[j] = 1.0 + step * start - 0.5 * step
                    break


def ring_exits_numpy(binary: npt.NDArray[np.uint8], frame: tuple[float, float, float, float, float, float],
                     cos_t: FloatArray, sin_t: FloatArray, bins: npt.NDArray[np.int64], step: float, count: int,
                     start: float, reach: float, length: int, least: int) -> FloatArray | None:
    """``ray_exits_numpy``, kept only when they look like a ring's outer edge round the hole: exits from ``start``
    on (sooner: through a thin wall) on at least ``least`` rays covering at least ``least`` distinct ``bins``
    (the rays' direction bins), and at least ``least`` of them within 20 % of their median radius. The exits
    (NaN for rays that do not leave or leave too soon), or None."""
    at = ray_exits_numpy(binary, frame, cos_t, sin_t, step, count, reach, length)
    at[~(at >= start)] = np.nan
    leaves = np.isfinite(at)
    if np.count_nonzero(leaves) < least or np.unique(bins[leaves]).size < least:
        return None
    middle = float(np.median(at[leaves]))
    if np.count_nonzero(np.abs(at[leaves] - middle) <= 0.2 * middle) < least:
        return None
    return at


if numba is not None:

    @numba.njit(cache=True, nogil=True)
    def _ring_test_compiled(at, bins, start, least):  # pragma: no cover - compiled
        n = 0
        seen = np.zeros(bins.max() + 1, np.bool_)
        for j in range(at.size):
            if at[j] >= start:
                n += 1
                seen[bins[j]] = True
            else:
                at[j] = np.nan
        if n < least or np.count_nonzero(seen) < least:
            return False
        kept = np.empty(n)
        i = 0
        for j in range(at.size):
            if at[j] == at[j]:
                kept[i] = at[j]
                i += 1
        middle = np.median(kept)
        close = 0
        for v in kept:
            if abs(v - middle) <= 0.2 * middle:
                close += 1
        return close >= least


def ring_exits(binary: npt.NDArray[np.uint8], frame: tuple[float, float, float, float, float, float],
               cos_t: FloatArray, sin_t: FloatArray, bins: npt.NDArray[np.int64], step: float, count: int,
               start: float, reach: float, length: int, least: int) -> FloatArray | None:
    """``ring_exits_numpy``, compiled."""
    if numba is None:  # pragma: no cover - numba is installed by pyproject.toml
        return ring_exits_numpy(binary, frame, cos_t, sin_t, bins, step, count, start, reach, length, least)
    at = ray_exits(binary, frame, cos_t, sin_t, step, count, reach, length)
    return at if _ring_test_compiled(at, bins, float(start), int(least)) else None


def ray_exits(binary: npt.NDArray[np.uint8], frame: tuple[float, float, float, float, float, float],
              cos_t: FloatArray, sin_t: FloatArray, step: float, count: int, reach: float, length: int) -> FloatArray:
    """``ray_exits_numpy``, compiled (the numpy reference where numba is missing)."""
    if numba is None:  # pragma: no cover - numba is installed by pyproject.toml
        return ray_exits_numpy(binary, frame, cos_t, sin_t, step, count, reach, length)
    out = np.empty(len(cos_t))
    cx, cy, a, b, c, s = frame
    _ray_exits_compiled(binary, float(cx), float(cy), float(a), float(b), float(c), float(s), cos_t, sin_t,
                        float(step), int(count), float(reach), int(length), out)
    return out


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernel on a tiny input (``scripts/install.sh`` calls it, so that
    a fresh install's first textured frame loads it instead of compiling it, ~1 s). Idempotent; nothing without
    numba."""
    binary = np.zeros((8, 8), np.uint8)
    binary[3:5, 3:5] = 255
    t = np.array([0.0, 1.0])
    ring_exits(binary, (4.0, 4.0, 1.0, 1.0, 1.0, 0.0), t, t[::-1].copy(), np.arange(2), 0.5, 8, 1.0, 4.0, 2, 1)
