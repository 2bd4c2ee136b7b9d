"""The target's design seen through a pose, pixel by pixel, and its derivatives: the compiled (numba) kernel of
:mod:`livetrack.estimator.target_model` and its numpy reference (``LIVETRACK_KERNELS=numpy``; tests hold them
together within 1e-9).

Each pixel's centre (normalized coordinates, undistorted) is taken to the target's plane through the inverse of the
pose's homography ``H = [r1 r2 t]``: ``q = H^-1 (u, v, 1)``, ``(x, y) = (q0, q1) / q2`` in metres. The pixel's size in
the plane, ``s`` (m), is the square root of the area of its image there (central differences of ``x, y`` over the
pixel grid, one-sided at the window's border, as ``np.gradient``). Every circle of the design is a ramp one pixel wide
at its edge: ``clip(0.5 + (r - |(x, y) - c|) / s, 0, 1)``, the share of the pixel inside it. The black is the sum over
the design's circles in ``circles`` (rows ``cx, cy, r, sign``: +1 the black disks, -1 the white holes and dots, in
the design's order) clipped to [0, 1]; a pixel's white is ``outer - black + (1 - outer) around`` (``outer`` the
outermost circle's ramp, ``around`` the share of white outside the target: the image's clipped pixels).

The derivatives are those of a pose moved by a small rotation ``w`` in the camera frame (``R -> exp([w]x) R``) and a
translation ``dt``, the order ``w, dt``: ``dH q = w x (q0 r1 + q1 r2) + q2 dt``, ``dq = -H^-1 dH q``, ``dx = (dq0 -
x dq2) / q2`` (the same for ``y``), and each ramp's derivative is ``-d|(x, y) - c| / s`` inside its open ramp (the
change of ``s`` with the pose, second order at the ramp's middle, left out).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from livetrack.estimator.edge_kernels import jit_kernel

FloatArray = npt.NDArray[np.float64]


def plane_coordinates(un: FloatArray, vn: FloatArray, inverse: FloatArray
                      ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """(numpy) The pixels' places in the target's plane ``x, y`` (m), their size ``s`` there (m; inf where not
    finite or zero) and ``q2`` (the homogeneous scale), each (h, w), for the pixel centres ``un, vn`` (h, w)."""
    q0 = inverse[0, 0] * un + inverse[0, 1] * vn + inverse[0, 2]
    q1 = inverse[1, 0] * un + inverse[1, 1] * vn + inverse[1, 2]
    q2 = inverse[2, 0] * un + inverse[2, 1] * vn + inverse[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = q0 / q2, q1 / q2
        size = np.sqrt(np.abs(np.gradient(x, axis=1) * np.gradient(y, axis=0)
                              - np.gradient(y, axis=1) * np.gradient(x, axis=0)))
    size = np.where(np.isfinite(size) & (size > 0), size, np.inf)
    return x, y, size, q2


def white_numpy(un: FloatArray, vn: FloatArray, around: FloatArray, inverse: FloatArray, R: FloatArray,
                circles: FloatArray, derivatives: bool) -> tuple[FloatArray, FloatArray | None]:
    """(numpy reference) Each pixel's share of white (h, w) and, with ``derivatives``, its derivatives (6, h, w) by
    the pose's small rotation and translation (module docstring). ``circles`` (n, 4): the outermost first."""
    x, y, size, q2 = plane_coordinates(un, vn, inverse)
    if derivatives:
        q0, q1 = x * q2, y * q2
        dx, dy = np.empty((6,) + x.shape), np.empty((6,) + x.shape)
        p = q0[None] * R[:, 0, None, None] + q1[None] * R[:, 1, None, None]  # (3, h, w): q0 r1 + q1 r2
        for k in range(6):
            if k < 3:  # e_k x p
                a, b = (k + 1) % 3, (k + 2) % 3
                dhq = np.zeros((3,) + x.shape)
                dhq[b] = p[a]
                dhq[a] = -p[b]
            else:
                dhq = np.zeros((3,) + x.shape)
                dhq[k - 3] = q2
            dq = -np.tensordot(inverse, dhq, axes=1)
            with np.errstate(divide="ignore", invalid="ignore"):
                dx[k] = (dq[0] - x * dq[2]) / q2
                dy[k] = (dq[1] - y * dq[2]) / q2
    black = np.zeros(x.shape)
    d_black = np.zeros((6,) + x.shape) if derivatives else None
    outer = d_outer = None
    for cx, cy, radius, sign in circles:
        with np.errstate(invalid="ignore"):
            ex, ey = x - cx, y - cy
            dist = np.hypot(ex, ey)
            share = np.clip(0.5 + (radius - dist) / size, 0.0, 1.0)
        if outer is None:
            outer = share
        else:
            black += sign * share
        if derivatives:
            ramp = (share > 0.0) & (share < 1.0) & (dist > 0.0)
            with np.errstate(divide="ignore", invalid="ignore"):
                d_share = np.where(ramp, -(ex * dx + ey * dy) / (dist * size), 0.0)
            if d_outer is None:
                d_outer = d_share
            else:
                d_black += sign * d_share
    black_sum = black
    black = np.clip(black_sum, 0.0, 1.0)
    white = (outer - black) + (1.0 - outer) * around
    if not derivatives:
        return white, None
    d_black = np.where((black_sum > 0.0) & (black_sum < 1.0), d_black, 0.0)
    return white, d_outer - d_black - d_outer * around


@jit_kernel
def white_kernel(un, vn, around, inverse, R, circles, derivatives):
    """(compiled) :func:`white_numpy`: the same operations pixel by pixel (``derivatives`` (6, h, w), or (6, 0, 0)
    without)."""
    h, w = un.shape
    x = np.empty((h, w))
    y = np.empty((h, w))
    q2 = np.empty((h, w))
    for i in range(h):
        for j in range(w):
            a = inverse[0, 0] * un[i, j] + inverse[0, 1] * vn[i, j] + inverse[0, 2]
            b = inverse[1, 0] * un[i, j] + inverse[1, 1] * vn[i, j] + inverse[1, 2]
            c = inverse[2, 0] * un[i, j] + inverse[2, 1] * vn[i, j] + inverse[2, 2]
            x[i, j] = a / c
            y[i, j] = b / c
            q2[i, j] = c
    white = np.empty((h, w))
    d_white = np.zeros((6, h, w)) if derivatives else np.zeros((6, 0, 0))
    dx = np.zeros(6)
    dy = np.zeros(6)
    d_outer = np.zeros(6)
    d_black = np.zeros(6)
    n = circles.shape[0]
    for i in range(h):
        for j in range(w):
            xi = x[i, j]
            yi = y[i, j]
            gxx = _gradient(x, i, j, h, w, 1)
            gyy = _gradient(y, i, j, h, w, 0)
            gyx = _gradient(y, i, j, h, w, 1)
            gxy = _gradient(x, i, j, h, w, 0)
            size = math.sqrt(abs(gxx * gyy - gyx * gxy))
            if not (math.isfinite(size) and size > 0.0):
                size = math.inf
            radius = circles[0, 2]
            dist = math.hypot(xi - circles[0, 0], yi - circles[0, 1])
            outer = min(max(0.5 + (radius - dist) / size, 0.0), 1.0)
            if outer == 0.0:  # beyond the outer circle's ramp: so is every circle of the design, the white is around's
                white[i, j] = around[i, j]
                continue
            have_dxy = False
            if derivatives:
                for k in range(6):
                    d_outer[k] = 0.0
                    d_black[k] = 0.0
            black = 0.0
            half = 0.5 * size
            for m in range(n):
                cx = circles[m, 0]
                cy = circles[m, 1]
                radius = circles[m, 2]
                sign = circles[m, 3]
                ex = xi - cx
                ey = yi - cy
                if m > 0 and (abs(ex) >= radius + half or abs(ey) >= radius + half):
                    continue  # outside this circle's ramp: a share of 0 exactly
                dist = math.hypot(ex, ey)
                share = min(max(0.5 + (radius - dist) / size, 0.0), 1.0)
                if m > 0:
                    black += sign * share
                if derivatives and share > 0.0 and share < 1.0 and dist > 0.0:
                    if not have_dxy:
                        _plane_derivatives(xi, yi, q2[i, j], R, inverse, dx, dy)
                        have_dxy = True
                    for k in range(6):
                        d_share = -(ex * dx[k] + ey * dy[k]) / (dist * size)
                        if m == 0:
                            d_outer[k] = d_share
                        else:
                            d_black[k] += sign * d_share
            clipped = min(max(black, 0.0), 1.0)
            white[i, j] = (outer - clipped) + (1.0 - outer) * around[i, j]
            if have_dxy:
                inside = black > 0.0 and black < 1.0
                for k in range(6):
                    db = d_black[k] if inside else 0.0
                    d_white[k, i, j] = d_outer[k] - db - d_outer[k] * around[i, j]
    return white, d_white


@jit_kernel(inline=True)
def _plane_derivatives(x, y, q2, R, inverse, dx, dy):
    """``dx, dy`` (6,): the derivatives of a pixel's place ``x, y`` in the plane by the pose's small rotation and
    translation (module docstring), from its place and homogeneous scale ``q2``."""
    q0 = x * q2
    q1 = y * q2
    p0 = q0 * R[0, 0] + q1 * R[0, 1]
    p1 = q0 * R[1, 0] + q1 * R[1, 1]
    p2 = q0 * R[2, 0] + q1 * R[2, 1]
    for k in range(6):
        h0 = 0.0
        h1 = 0.0
        h2 = 0.0
        if k == 0:  # e_k x p
            h1 = -p2
            h2 = p1
        elif k == 1:
            h0 = p2
            h2 = -p0
        elif k == 2:
            h0 = -p1
            h1 = p0
        elif k == 3:
            h0 = q2
        elif k == 4:
            h1 = q2
        else:
            h2 = q2
        dq0 = -(inverse[0, 0] * h0 + inverse[0, 1] * h1 + inverse[0, 2] * h2)
        dq1 = -(inverse[1, 0] * h0 + inverse[1, 1] * h1 + inverse[1, 2] * h2)
        dq2 = -(inverse[2, 0] * h0 + inverse[2, 1] * h1 + inverse[2, 2] * h2)
        dx[k] = (dq0 - x * dq2) / q2
        dy[k] = (dq1 - y * dq2) / q2


@jit_kernel(inline=True)
def _gradient(f, i, j, h, w, axis):
    """``np.gradient(f, axis=axis)[i, j]`` at unit spacing: central inside, one-sided at the border."""
    if axis == 1:
        if w < 2:
            return math.nan
        if j == 0:
            return f[i, 1] - f[i, 0]
        if j == w - 1:
            return f[i, w - 1] - f[i, w - 2]
        return (f[i, j + 1] - f[i, j - 1]) / 2.0
    if h < 2:
        return math.nan
    if i == 0:
        return f[1, j] - f[0, j]
    if i == h - 1:
        return f[h - 1, j] - f[h - 2, j]
    return (f[i + 1, j] - f[i - 1, j]) / 2.0
