"""Whether a binary image has a hole, in one compiled flood fill: a white (0) region that no 4-connected white path
joins to the image's edge. ``cv2.findContours(..., RETR_CCOMP)`` reports a contour with a parent exactly then (it
takes the image as surrounded by white, holes as 4-connected, dark blobs as 8-connected), so a crop without one
gives no ellipse pair and need not be traced: on textured ground three quarters of the closed crops the detector
retries (``pairs._pairs_closed``, ~900 per frame) have none, and the fill costs ~2 us against ~20 us for tracing
them and walking the contours. Without numba every image counts as having a hole (the caller traces it)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

try:  # numba is a dependency; without it (a broken install) the caller traces every crop
    import numba

    from livetrack.estimator.detect.fit_kernel import _fma
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None


if numba is not None:

    @numba.njit(cache=True, nogil=True)
    def _has_hole(binary):  # pragma: no cover - compiled
        h, w = binary.shape
        # 1 where white (0); the fill turns what it reaches to 2
        state = np.empty((h + 2, w + 2), np.uint8)  # a white frame around: the outside
        state[0, :] = 1
        state[h + 1, :] = 1
        for y in range(h):
            state[y + 1, 0] = 1
            state[y + 1, w + 1] = 1
            for x in range(w):
                state[y + 1, x + 1] = 1 if binary[y, x] == 0 else 0
        stack = np.empty((h + 2) * (w + 2), np.int64)
        stride = w + 2
        flat = state.ravel()
        flat[0] = 2
        stack[0] = 0
        top = 1
        size = flat.size
        while top > 0:  # depth-first fill of the white 4-connected to the outside
            top -= 1
            i = stack[top]
            for j in (i - stride, i + stride, i - 1, i + 1):
                if 0 <= j < size and flat[j] == 1:
                    flat[j] = 2
                    stack[top] = j
                    top += 1
        for i in range(size):  # white out of reach: a hole
            if flat[i] == 1:
                return True
        return False

    @numba.njit(cache=True, nogil=True)
    def _dark_on_bands(binary, cx, cy, a, b, c, s, bands, cos_t, sin_t, out):  # pragma: no cover - compiled
        """For each factor of ``bands``: how many of the points of the ellipse scaled by it at the angles of
        ``cos_t``, ``sin_t`` (rounded half to even) fall on a dark pixel of ``binary`` within it."""
        h, w = binary.shape
        for k in range(bands.size):
            ak, bk = a * bands[k] + 0.0, b * bands[k] + 0.0
            n = 0
            for i in range(cos_t.size):
                u, v = ak * cos_t[i], bk * sin_t[i]
                x = np.int64(np.rint(cx + _fma(v, -s, u * c)))
                y = np.int64(np.rint(cy + _fma(v, c, u * s)))
                if 0 <= x < w and 0 <= y < h and binary[y, x] != 0:
                    n += 1
            out[k] = n

    @numba.njit(cache=True, nogil=True)
    def _keep_near(points, cx, cy, c, s, a, b, rho, reach, u_out, v_out, k_out, m):  # pragma: no cover - compiled
        """Appends to ``u_out``, ``v_out``, ``k_out`` from index ``m`` the hole-frame coordinates and radius of the
        points (N, 2) within ``reach`` of (cx, cy) in x and y whose radius lies in (0.8, 1.15); returns the new
        count."""
        for i in range(points.shape[0]):
            x, y = points[i, 0] - cx, points[i, 1] - cy
            if abs(x) <= reach and abs(y) <= reach:
                u = (x * c + y * s) / a
                v = (y * c - x * s) / b
                k = np.hypot(u, v) * rho
                if 0.8 < k < 1.15:
                    u_out[m], v_out[m], k_out[m] = u, v, k
                    m += 1
        return m

    @numba.njit(cache=True, nogil=True)
    def _ring_on_outline(outline, hole_points, hole_start, rects, hole_ids, skip, cx, cy, c, s, a, b, rho, reach,
                         half, u_out, v_out):  # pragma: no cover - compiled
        """``ring_on_outline``'s work: the densest window's points (their u, v in ``u_out``, ``v_out``, in the
        order of the outline's points, then the holes') and the median of their radii; (-1, 0) for fewer than 6
        points in (0.8, 1.15)."""
        k_all = np.empty(u_out.size)
        m = _keep_near(outline, cx, cy, c, s, a, b, rho, reach, u_out, v_out, k_all, 0)
        for j in range(hole_ids.size):
            x, y, w, h = rects[j, 0], rects[j, 1], rects[j, 2], rects[j, 3]
            dx, dy = x + 0.5 * (w - 1) - cx, y + 0.5 * (h - 1) - cy
            beyond = np.hypot((dx * c + dy * s) / a, (dy * c - dx * s) / b) * rho >= 1.0
            overlaps = x - 1 <= cx + reach and x + w >= cx - reach and y - 1 <= cy + reach and y + h >= cy - reach
            if beyond and overlaps and hole_ids[j] != skip:
                m = _keep_near(hole_points[hole_start[j]: hole_start[j + 1]], cx, cy, c, s, a, b, rho, reach,
                               u_out, v_out, k_all, m)
        if m < 6:
            return -1, 0.0
        ks = np.sort(k_all[:m])
        counts = np.searchsorted(ks, ks + 2.0 * half, side="right") - np.arange(m)
        centre = ks[np.argmax(counts)] + half
        n = 0
        for i in range(m):
            if abs(k_all[i] - centre) <= half:
                u_out[n], v_out[n], k_all[n] = u_out[i], v_out[i], k_all[i]
                n += 1
        if n == 0:  # rounding can leave the window's ends out of it
            return 0, 0.0
        near = np.sort(k_all[:n])
        median = near[n // 2] if n % 2 else (near[n // 2 - 1] + near[n // 2]) / 2.0
        return n, median


    @numba.njit(cache=True, nogil=True)
    def _brightest(img, cx, cy, reach_x, reach_y, dx, dy):  # pragma: no cover - compiled
        """``pairs._brightest_probe``'s arithmetic: the brightest of the pixels at (cx + reach_x dx, cy + reach_y
        dy), rounded half up and clamped to the image, 0 for none brighter."""
        last_row, last_col = img.shape[0] - 1, img.shape[1] - 1
        best = 0
        for k in range(dx.shape[0]):
            row, col = int(cy + reach_y * dy[k] + 0.5), int(cx + reach_x * dx[k] + 0.5)
            row = 0 if row < 0 else last_row if row > last_row else row
            col = 0 if col < 0 else last_col if col > last_col else col
            v = int(img[row, col])
            if v > best:
                best = v
        return best

    @numba.njit(cache=True, nogil=True)
    def small_blob_probes(img, x, y, w, h, near, far, dx, dy):  # pragma: no cover - compiled
        """For a blob's box (x, y, w, h) in ``img``: the brightest of the probes at ``near`` of its size from its
        middle, of those at ``far`` (``pairs._brightest_probe`` each, directions (dx, dy)), and its darkest pixel
        (``cv2.minMaxLoc``'s minimum over the box)."""
        cx, cy = x + 0.5 * (w - 1), y + 0.5 * (h - 1)
        middle = _brightest(img, cx, cy, near * w, near * h, dx, dy)
        white = _brightest(img, cx, cy, far * w, far * h, dx, dy)
        dark = int(img[y, x])
        for r in range(y, y + h):
            for c in range(x, x + w):
                v = int(img[r, c])
                if v < dark:
                    dark = v
        return middle, white, dark

    @numba.njit(cache=True, nogil=True)
    def ring_around_middle(binary, x, y, w, h, dx, dy, min_ring):  # pragma: no cover - compiled
        """``arcs._ring_around_middle_reference``'s test, the same arithmetic: the box's middle and 3 of the probes
        at even indices of (dx, dy) at 0.2 of its half sides not dark, and ``min_ring`` of all at 0.7 dark."""
        cx, cy, hw, hh = x + 0.5 * (w - 1), y + 0.5 * (h - 1), 0.5 * w, 0.5 * h
        if binary[int(cy + 0.5), int(cx + 0.5)]:
            return False
        rows, cols = binary.shape
        inner = 0
        ring = 0
        for k in range(dx.shape[0]):
            if k % 2 == 0:
                r, c = int(cy + 0.2 * hh * dy[k] + 0.5), int(cx + 0.2 * hw * dx[k] + 0.5)
                if 0 <= r < rows and 0 <= c < cols and binary[r, c] == 0:
                    inner += 1
            r, c = int(cy + 0.7 * hh * dy[k] + 0.5), int(cx + 0.7 * hw * dx[k] + 0.5)
            if 0 <= r < rows and 0 <= c < cols and binary[r, c] != 0:
                ring += 1
        return inner >= 3 and ring >= min_ring



def has_hole(binary: npt.NDArray[np.uint8]) -> bool:
    """True when the (H, W) uint8 ``binary`` (0 = white, non-zero = dark) has a white region out of 4-connected
    reach of its edge, i.e. when ``cv2.findContours(binary, RETR_CCOMP, ...)`` reports a hole; always True
    without numba."""
    if numba is None or binary.size == 0:
        return numba is None
    return bool(_has_hole(binary))


def dark_on_bands_reference(binary: npt.NDArray[np.uint8], outer, bands: tuple[float, ...],
                            angles: npt.NDArray[np.float64]) -> list[int]:
    """For each factor of ``bands``: how many of the points ``outer.scaled(factor).points(angles)``, rounded to
    the nearest pixel (half to even), fall on a dark (non-zero) pixel of ``binary`` within it."""
    h, w = binary.shape
    counts = []
    for band in bands:
        p = np.rint(outer.scaled(band).points(angles)).astype(np.int64)
        inside = (p[:, 0] >= 0) & (p[:, 0] < w) & (p[:, 1] >= 0) & (p[:, 1] < h)
        counts.append(int(np.count_nonzero(binary[p[inside, 1], p[inside, 0]])))
    return counts


def dark_on_bands(binary: npt.NDArray[np.uint8], outer, bands: tuple[float, ...],
                  angles: npt.NDArray[np.float64]) -> list[int]:
    """``dark_on_bands_reference`` in one compiled pass (the same points: ``Ellipse.points``' arithmetic, its
    rotation's 2x2 product as OpenBLAS's dgemm rounds it, ``fma(v, r10, u r00)``), for a C-contiguous
    ``binary``; ~3 us against ~45 us for three bands of 32 points."""
    if numba is None or not binary.flags.c_contiguous:
        return dark_on_bands_reference(binary, outer, bands, angles)
    cos_t, sin_t = _cos_sin(angles)
    out = np.empty(len(bands), np.int64)
    cx, cy = outer.centre_px.tolist()
    _dark_on_bands(binary, cx, cy, outer.a, outer.b, float(np.cos(outer.angle_rad)), float(np.sin(outer.angle_rad)),
                   np.array(bands, dtype=np.float64), cos_t, sin_t, out)
    return out.tolist()


_COS_SIN: dict[bytes, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]] = {}


def _cos_sin(angles: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """``np.cos(angles)``, ``np.sin(angles)`` as ``Ellipse.points`` computes them (numpy's own, whose vector
    path may round otherwise than libm), kept per angle set."""
    key = angles.tobytes()
    got = _COS_SIN.get(key)
    if got is None:
        t = np.asarray(angles, dtype=np.float64).reshape(-1)
        got = _COS_SIN[key] = (np.cos(t), np.sin(t))
    return got
