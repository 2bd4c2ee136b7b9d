"""Compiled (numba) Gauss-Newton of :func:`livetrack.estimator.pose_fit.fit_pose`: the residuals and Jacobian
of the edge points (``pose_fit._LocalModel.evaluate``, the numpy reference) and the iterations (Huber weights,
step halving, the blind last step), one loop over the points per evaluation instead of ~60 numpy operations.

The same kernel choice (``LIVETRACK_KERNELS``), compilation, cache and GIL release (``nogil``) as
:mod:`livetrack.estimator.edge_kernels`.
Compiled and reference fits agree to rounding (tests/test_kernels.py: poses within 1e-9 relative).

Also the camera model on the tracking path (:func:`camera_kernels`): pixels to undistorted normalized
coordinates, projection, and the lens's local Jacobian, with the same arithmetic in the same order as
``CameraModel`` (no operation whose rounding could differ: the same numbers, tests/test_pose.py), ~15x faster
than numpy for a target's ~500 edge points (~0.2 ms each time, twice per tracked frame).
"""

from __future__ import annotations

import math

import numpy as np

from livetrack.estimator.edge_glue_kernels import masked_median
from livetrack.estimator.edge_kernels import cache_stats_of, jit_kernel

FAILED_PLANE = 1
"""Status of :func:`gauss_newton`: the edge rays miss the target plane at the start."""
FAILED_SINGULAR = 2
"""Status of :func:`gauss_newton`: singular normal equations."""


@jit_kernel
def evaluate(R, t, delta, px, py, a00, a01, a10, a11, rho, sign, bias, r, J):
    """Residuals r (N,) px and Jacobian J (N, 6) (t, two tilts, delta) at pose (R, t) and bias delta (each edge's
    share of it ``bias``, (N,): ``pose_fit.bias_weights``), written in
    place; returns False where a ray misses the plane or a model point lies behind the camera (r, J then
    undefined): ``_LocalModel.evaluate`` of the reference, its two ``hypot`` as ``sqrt(a^2 + b^2)`` (~2x cheaper
    than libm's; a rounding difference, no overflow at these magnitudes)."""
    n = px.shape[0]
    nx, ny, nz = R[0, 2], R[1, 2], R[2, 2]
    nt = nx * t[0] + ny * t[1] + nz * t[2]
    for i in range(n):
        denom = px[i] * nx + py[i] * ny + nz
        if denom <= 1e-9:
            return False
        scale = nt / denom
        dx, dy, dz = px[i] * scale - t[0], py[i] * scale - t[1], scale - t[2]
        q0 = R[0, 0] * dx + R[1, 0] * dy + R[2, 0] * dz
        q1 = R[0, 1] * dx + R[1, 1] * dy + R[2, 1] * dz
        length = math.sqrt(q0 * q0 + q1 * q1)
        if length > 0:
            cos, sin = q0 / length, q1 / length
        else:
            cos, sin = 1.0, q1
        rad0 = R[0, 0] * cos + R[0, 1] * sin
        rad1 = R[1, 0] * cos + R[1, 1] * sin
        rad2 = R[2, 0] * cos + R[2, 1] * sin
        tg0 = R[0, 1] * cos - R[0, 0] * sin
        tg1 = R[1, 1] * cos - R[1, 0] * sin
        tg2 = R[2, 1] * cos - R[2, 0] * sin
        v0, v1, v2 = rad0 * rho[i], rad1 * rho[i], rad2 * rho[i]
        z = v2 + t[2]
        if z <= 1e-9:
            return False
        inv_z = 1.0 / z
        m0, m1 = (v0 + t[0]) * inv_z, (v1 + t[1]) * inv_z
        d0, d1 = (tg0 - m0 * tg2) * inv_z, (tg1 - m1 * tg2) * inv_z
        tan0, tan1 = a00[i] * d0 + a01[i] * d1, a10[i] * d0 + a11[i] * d1
        d0, d1 = (rad0 - m0 * rad2) * inv_z, (rad1 - m1 * rad2) * inv_z
        out0, out1 = a00[i] * d0 + a01[i] * d1, a10[i] * d0 + a11[i] * d1
        cross = tan1 * out0 - tan0 * out1
        orient = -1.0 if cross < 0 else 1.0
        k_n = orient * sign[i] / math.sqrt(tan0 * tan0 + tan1 * tan1)
        nb0, nb1 = tan1 * k_n, -tan0 * k_n
        w0, w1 = nb0 * a00[i] + nb1 * a10[i], nb0 * a01[i] + nb1 * a11[i]
        r[i] = w0 * (px[i] - m0) + w1 * (py[i] - m1) + bias[i] * delta
        g0, g1, g2 = -w0 * inv_z, -w1 * inv_z, (w0 * m0 + w1 * m1) * inv_z
        c0, c1, c2 = v1 * g2 - v2 * g1, v2 * g0 - v0 * g2, v0 * g1 - v1 * g0
        J[i, 0], J[i, 1], J[i, 2] = g0, g1, g2
        J[i, 3] = c0 * R[0, 0] + c1 * R[1, 0] + c2 * R[2, 0]
        J[i, 4] = c0 * R[0, 1] + c1 * R[1, 1] + c2 * R[2, 1]
        J[i, 5] = bias[i]
    return True


@jit_kernel
def _rotation(rx, ry, rz):
    """Rodrigues, as ``geometry.rotation_from_rotvec``."""
    theta = math.sqrt(rx * rx + ry * ry + rz * rz)
    out = np.eye(3)
    if theta < 1e-12:
        kx, ky, kz = rx, ry, rz
        s, c1 = 1.0, 0.0
    else:
        kx, ky, kz = rx / theta, ry / theta, rz / theta
        s, c1 = math.sin(theta), 1.0 - math.cos(theta)
    k = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    k2 = k @ k if theta >= 1e-12 else np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] += s * k[i, j] + c1 * k2[i, j]
    return out


@jit_kernel
def _apply(dx, R, t, delta, estimate_delta):
    """The pose and delta moved by the step dx (6,) (t, tilts about R's x and y axes, delta)."""
    rot = _rotation(dx[3] * R[0, 0] + dx[4] * R[0, 1], dx[3] * R[1, 0] + dx[4] * R[1, 1],
                    dx[3] * R[2, 0] + dx[4] * R[2, 1])
    t_new = np.empty(3)
    for k in range(3):
        t_new[k] = t[k] + dx[k]
    return rot @ R, t_new, delta + (dx[5] if estimate_delta else 0.0)


@jit_kernel
def _negligible(d, t, step_tol):
    tol_t = step_tol * max(math.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]), 1.0)
    return (abs(d[0]) < tol_t and abs(d[1]) < tol_t and abs(d[2]) < tol_t and abs(d[3]) < step_tol
            and abs(d[4]) < step_tol)


@jit_kernel
def _solve(m, rhs, n):
    """Solution of the n x n system m x = rhs (partial pivoting; m, rhs overwritten), and False if singular."""
    x = np.zeros(6)
    for col in range(n):
        piv = col
        best = abs(m[col, col])
        for r in range(col + 1, n):
            if abs(m[r, col]) > best:
                best = abs(m[r, col])
                piv = r
        if best == 0.0:
            return x, False
        if piv != col:
            for c in range(n):
                tmp = m[col, c]
                m[col, c] = m[piv, c]
                m[piv, c] = tmp
            tmp = rhs[col]
            rhs[col] = rhs[piv]
            rhs[piv] = tmp
        for r in range(col + 1, n):
            f = m[r, col] / m[col, col]
            if f != 0.0:
                for c in range(col, n):
                    m[r, c] -= f * m[col, c]
                rhs[r] -= f * rhs[col]
    for r in range(n - 1, -1, -1):
        acc = rhs[r]
        for c in range(r + 1, n):
            acc -= m[r, c] * x[c]
        x[r] = acc / m[r, r]
    return x, True


@jit_kernel
def _normal_equations(J, w, r):
    """J^T W J (6, 6), -J^T W r (6,) and the weighted cost of residuals r (N,), Jacobian J (N, 6) and weights w (N,),
    summed point by point in scalars (the upper triangle, mirrored; a caller fitting 5 parameters uses the top-left
    5 x 5 block). Written out element by element on purpose: the same sums as a loop over the triangle into local
    arrays are bitwise equal but 2.8x slower (7 against 20 us for 1000 points: numba keeps these scalars in
    registers, not the arrays); ``tests/test_kernels.py`` holds every element to ``J^T W J``. The edge kernel's
    4 x 4 (``edge_kernels``) is written the same way for the same reason."""
    m00 = m01 = m02 = m03 = m04 = m05 = m11 = m12 = m13 = m14 = m15 = 0.0
    m22 = m23 = m24 = m25 = m33 = m34 = m35 = m44 = m45 = m55 = 0.0
    b0 = b1 = b2 = b3 = b4 = b5 = 0.0
    cost = 0.0
    for i in range(r.shape[0]):
        wi, ri = w[i], r[i]
        j0, j1, j2, j3, j4, j5 = J[i, 0], J[i, 1], J[i, 2], J[i, 3], J[i, 4], J[i, 5]
        ja = j0 * wi
        b0 -= ja * ri
        m00 += ja * j0
        m01 += ja * j1
        m02 += ja * j2
        m03 += ja * j3
        m04 += ja * j4
        m05 += ja * j5
        ja = j1 * wi
        b1 -= ja * ri
        m11 += ja * j1
        m12 += ja * j2
        m13 += ja * j3
        m14 += ja * j4
        m15 += ja * j5
        ja = j2 * wi
        b2 -= ja * ri
        m22 += ja * j2
        m23 += ja * j3
        m24 += ja * j4
        m25 += ja * j5
        ja = j3 * wi
        b3 -= ja * ri
        m33 += ja * j3
        m34 += ja * j4
        m35 += ja * j5
        ja = j4 * wi
        b4 -= ja * ri
        m44 += ja * j4
        m45 += ja * j5
        ja = j5 * wi
        b5 -= ja * ri
        m55 += ja * j5
        cost += wi * ri * ri
    m = np.empty((6, 6))
    m[0, 0], m[0, 1], m[0, 2], m[0, 3], m[0, 4], m[0, 5] = m00, m01, m02, m03, m04, m05
    m[1, 1], m[1, 2], m[1, 3], m[1, 4], m[1, 5] = m11, m12, m13, m14, m15
    m[2, 2], m[2, 3], m[2, 4], m[2, 5] = m22, m23, m24, m25
    m[3, 3], m[3, 4], m[3, 5] = m33, m34, m35
    m[4, 4], m[4, 5] = m44, m45
    m[5, 5] = m55
    for a in range(1, 6):
        for b in range(a):
            m[a, b] = m[b, a]
    rhs = np.empty(6)
    rhs[0], rhs[1], rhs[2], rhs[3], rhs[4], rhs[5] = b0, b1, b2, b3, b4, b5
    return m, rhs, cost


@jit_kernel
def gauss_newton(R, t, delta, px, py, a00, a01, a10, a11, rho, sign, bias, weights0, huber_px, estimate_delta,
                 max_iterations, step_tol):
    """The iterations of ``fit_pose`` from (R, t, delta); ``huber_px`` <= 0 for plain least squares.

    Returns R, t, delta, residuals (N,), Jacobian (N, 6) at the end, iterations, converged, status (0, or
    FAILED_PLANE / FAILED_SINGULAR)."""
    n = px.shape[0]
    n_params = 6 if estimate_delta else 5
    r = np.empty(n)
    J = np.empty((n, 6))
    r_new = np.empty(n)
    J_new = np.empty((n, 6))
    if not evaluate(R, t, delta, px, py, a00, a01, a10, a11, rho, sign, bias, r, J):
        return R, t, delta, r, J, 0, False, FAILED_PLANE
    w = np.empty(n)
    sqrt_w0 = np.sqrt(weights0)
    iterations = 0
    converged = False
    for iteration in range(1, max_iterations + 1):
        iterations = iteration
        for i in range(n):
            w[i] = weights0[i]
            if huber_px > 0:
                zs = abs(r[i]) * sqrt_w0[i]
                if zs > huber_px:
                    w[i] = weights0[i] * huber_px / max(zs, 1e-12)
        m, rhs, cost = _normal_equations(J, w, r)
        dx, ok = _solve(m, rhs, n_params)
        if not ok:
            return R, t, delta, r, J, iterations, False, FAILED_SINGULAR
        if _negligible(dx, t, step_tol):
            converged = True  # below the tolerance: taken, not worth an evaluation
            R, t, delta = _apply(dx, R, t, delta, estimate_delta)
            break
        step = np.zeros(6)
        found = False
        ok_new = False
        new_cost = 0.0
        R_new, t_new, d_new = R, t, delta
        for _ in range(8):
            for a in range(n_params):
                step[a] = dx[a]
            R_new, t_new, d_new = _apply(step, R, t, delta, estimate_delta)
            ok_new = evaluate(R_new, t_new, d_new, px, py, a00, a01, a10, a11, rho, sign, bias, r_new, J_new)
            if ok_new:
                new_cost = 0.0
                for i in range(n):
                    new_cost += w[i] * r_new[i] * r_new[i]
                if new_cost <= cost * (1 + 1e-12):
                    found = True
                    break
            for a in range(6):
                dx[a] *= 0.5
            if _negligible(dx, t, step_tol):
                break
        else:
            converged = True  # no decrease possible: at the optimum within numeric precision
            break
        if not found:
            converged = True
            break
        R, t, delta = R_new, t_new, d_new
        r, r_new = r_new, r
        J, J_new = J_new, J
        if _negligible(step, t, step_tol):
            converged = True
            break
    return R, t, delta, r, J, iterations, converged, 0


@jit_kernel(inline=True)
def _gauss_jordan_inverse(normal, inv, p):
    """``inv`` (the p x p identity on entry) becomes ``normal``'s inverse by Gauss-Jordan elimination with partial
    pivoting (``normal`` is overwritten); False when a pivot is exactly zero (singular, as LAPACK says)."""
    for col in range(p):
        piv = col
        for row in range(col + 1, p):
            if abs(normal[row, col]) > abs(normal[piv, col]):
                piv = row
        if normal[piv, col] == 0.0:
            return False
        if piv != col:
            for c in range(p):
                normal[col, c], normal[piv, c] = normal[piv, c], normal[col, c]
                inv[col, c], inv[piv, c] = inv[piv, c], inv[col, c]
        scale = 1.0 / normal[col, col]
        for c in range(p):
            normal[col, c] *= scale
            inv[col, c] *= scale
        for row in range(p):
            f = normal[row, col]
            if row != col and f != 0.0:
                for c in range(p):
                    normal[row, c] -= f * normal[col, c]
                    inv[row, c] -= f * inv[col, c]
    return True


@jit_kernel
def pose_covariance(J, w, r, n_params, R, yaw_var, estimate_delta):
    """The 7x7 covariance of ``fit_pose`` (t, camera-frame rotation vector, delta) from the Jacobian J (N, 6) of the
    fitted parameters (t, two tilts, delta; the first ``n_params`` used), weights w (N,) and residuals r (N,):
    (J^T W J)^-1 times the a-posteriori variance factor sum(w r^2) / (N - n_params), the tilts mapped onto the
    rotation vector by R's first two columns and the yaw, variance ``yaw_var``, along R's third
    (``pose_fit._expand_covariance``). Returns (covariance, status): status 1 (covariance NaN) when the normal
    matrix is singular (an exactly zero pivot, as LAPACK's). The numpy lines of ``fit_pose`` are the reference:
    the same sums in another order and Gauss-Jordan elimination for LAPACK's inverse, so the figures agree to
    rounding (tests/test_pose.py)."""
    n = J.shape[0]
    p = n_params
    normal = np.zeros((p, p))
    var = 0.0
    for i in range(n):
        wi = w[i]
        var += wi * r[i] * r[i]
        for a in range(p):
            ja = J[i, a] * wi
            for b in range(a + 1):
                normal[a, b] += ja * J[i, b]
    for a in range(p):
        for b in range(a + 1, p):
            normal[a, b] = normal[b, a]
    var /= max(n - p, 1)
    inv = np.eye(p)
    if not _gauss_jordan_inverse(normal, inv, p):
        return np.full((7, 7), np.nan), 1
    # A maps (t, tilt1, tilt2[, delta], yaw) to (t, rotation vector, delta)
    m = p + 1
    amap = np.zeros((7, m))
    for k in range(3):
        amap[k, k] = 1.0
        amap[3 + k, 3] = R[k, 0]
        amap[3 + k, 4] = R[k, 1]
        amap[3 + k, p] = R[k, 2]
    if estimate_delta:
        amap[6, 5] = 1.0
    full = np.zeros((m, m))
    for a in range(p):
        for b in range(p):
            full[a, b] = inv[a, b] * var
    full[p, p] = yaw_var
    cov = np.zeros((7, 7))
    for a in range(7):
        for b in range(7):
            acc = 0.0
            for c in range(m):
                for d in range(m):
                    acc += amap[a, c] * full[c, d] * amap[b, d]
            cov[a, b] = acc
    return cov, 0


@jit_kernel
def circle_bias_gain(J, w, radius_m, n_params):
    """``pose_fit.circle_bias_gain_reference`` compiled: (n_params, C) ``-(J^T W J)^-1 J^T W 1_c`` for the C circles
    (distinct ``radius_m``, ascending) of the points, J (N, >= n_params) and w (N,); returns (gain, status), status
    1 (gain NaN) when the normal matrix is singular. The same sums in another order and Gauss-Jordan for LAPACK's
    solve: the figures agree to rounding (tests/test_shared_edge_bias.py)."""
    n = J.shape[0]
    p = n_params
    radii = np.empty(n)
    n_circles = 0
    for i in range(n):  # the distinct radii (a target has 2-6 circles)
        seen = False
        for c in range(n_circles):
            if radii[c] == radius_m[i]:
                seen = True
                break
        if not seen:
            radii[n_circles] = radius_m[i]
            n_circles += 1
    radii = np.sort(radii[:n_circles])
    normal = np.zeros((p, p))
    sums = np.zeros((p, n_circles))
    for i in range(n):
        c = 0
        while radii[c] != radius_m[i]:
            c += 1
        wi = w[i]
        for a in range(p):
            ja = J[i, a] * wi
            sums[a, c] += ja
            for b in range(a + 1):
                normal[a, b] += ja * J[i, b]
    for a in range(p):
        for b in range(a + 1, p):
            normal[a, b] = normal[b, a]
    inv = np.eye(p)
    if not _gauss_jordan_inverse(normal, inv, p):
        return np.full((p, n_circles), np.nan), 1
    gain = np.zeros((p, n_circles))
    for a in range(p):
        for c in range(n_circles):
            acc = 0.0
            for b in range(p):
                acc += inv[a, b] * sums[b, c]
            gain[a, c] = -acc
    return gain, 0


@jit_kernel
def pixels_to_normalized(points, fx, fy, cx, cy, k1, k2, p1, p2, k3, iterations, tol):
    """Pixels (N, 2) -> undistorted normalized coordinates (N, 2): ``CameraModel.pixels_to_normalized`` (the
    reference) with the same arithmetic in the same order (the one-step radial start, then Newton steps on every
    point until the largest residual of a step, NaN ignored, is below ``tol``), so the same numbers."""
    n = points.shape[0]
    xd, yd = np.empty(n), np.empty(n)
    out = np.empty((n, 2))
    for i in range(n):
        xd[i] = (points[i, 0] - cx) / fx
        yd[i] = (points[i, 1] - cy) / fy
    if k1 == 0.0 and k2 == 0.0 and p1 == 0.0 and p2 == 0.0 and k3 == 0.0:
        for i in range(n):
            out[i, 0], out[i, 1] = xd[i], yd[i]
        return out
    for i in range(n):
        r2 = xd[i] * xd[i] + yd[i] * yd[i]
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        out[i, 0], out[i, 1] = xd[i] / radial, yd[i] / radial
    for _ in range(iterations):
        worst = 0.0
        for i in range(n):
            x, y = out[i, 0], out[i, 1]
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            rx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd[i]
            ry = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd[i]
            d = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
            j00 = radial + x * d * 2.0 * x + 2.0 * p1 * y + p2 * 6.0 * x
            j01 = x * d * 2.0 * y + 2.0 * p1 * x + p2 * 2.0 * y
            j10 = y * d * 2.0 * x + p1 * 2.0 * x + 2.0 * p2 * y
            j11 = radial + y * d * 2.0 * y + p1 * 6.0 * y + 2.0 * p2 * x
            det = j00 * j11 - j01 * j10
            out[i, 0] = x - (j11 * rx - j01 * ry) / det
            out[i, 1] = y - (-j10 * rx + j00 * ry) / det
            if abs(rx) > worst:  # False for NaN: ignored, as by nanmax
                worst = abs(rx)
            if abs(ry) > worst:
                worst = abs(ry)
        if worst < tol:
            break
    return out


@jit_kernel
def project(points_cam, fx, fy, cx, cy, k1, k2, p1, p2, k3):
    """Camera-frame points (N, 3) -> pixels (N, 2): ``CameraModel.project`` (the reference) with the same
    arithmetic in the same order, so the same numbers."""
    n = points_cam.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        x = points_cam[i, 0] / points_cam[i, 2]
        y = points_cam[i, 1] / points_cam[i, 2]
        if k1 == 0.0 and k2 == 0.0 and p1 == 0.0 and p2 == 0.0 and k3 == 0.0:
            out[i, 0], out[i, 1] = fx * x + cx, fy * y + cy
            continue
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        out[i, 0], out[i, 1] = fx * xd + cx, fy * yd + cy
    return out


@jit_kernel
def predict_points(points, fx, fy, cx, cy, k1, k2, p1, p2, k3, iterations, tol, R, t, r_m, t_m):
    """The motion prediction of a tracked target (``Tracker._predicted``'s numpy reference, in one loop): the
    pixels (N, 2) back-projected onto the target plane of the pose (R, t), moved by the camera-frame rigid motion
    X' = r_m X + t_m and projected again. Returns (the moved pixels (N, 2), the median distance they moved (px),
    status): status 0, or 1 when a viewing ray misses the plane in front of the camera or a moved point is not in
    front of it (the pixels and median are then not computed). The undistortion and the projection are
    :func:`pixels_to_normalized` and :func:`project`; the rays, plane and motion are summed in the reference's
    order without its matrix products' (BLAS) rounding, so the pixels agree with it to ~1e-15 relative."""
    n = points.shape[0]
    norm = pixels_to_normalized(points, fx, fy, cx, cy, k1, k2, p1, p2, k3, iterations, tol)
    nx, ny, nz = R[0, 2], R[1, 2], R[2, 2]
    offset = nx * t[0] + ny * t[1] + nz * t[2]
    moved = np.empty((n, 3))
    for i in range(n):
        x, y = norm[i, 0], norm[i, 1]
        length = math.sqrt(x * x + y * y + 1.0)
        rx, ry, rz = x / length, y / length, 1.0 / length
        along = rx * nx + ry * ny + rz * nz
        if not along > 1e-9:
            return np.empty((0, 2)), math.nan, 1
        scale = offset / along
        ox, oy, oz = rx * scale, ry * scale, rz * scale
        for r in range(3):
            moved[i, r] = ox * r_m[r, 0] + oy * r_m[r, 1] + oz * r_m[r, 2] + t_m[r]
        if not moved[i, 2] > 1e-9:
            return np.empty((0, 2)), math.nan, 1
    out = project(moved, fx, fy, cx, cy, k1, k2, p1, p2, k3)
    shift = np.empty(n)
    for i in range(n):
        dx, dy = out[i, 0] - points[i, 0], out[i, 1] - points[i, 1]
        shift[i] = math.sqrt(dx * dx + dy * dy)
    return out, masked_median(shift, np.ones(n, dtype=np.bool_)), 0


@jit_kernel
def lens_jacobian(points_norm, fx, fy, k1, k2, p1, p2, k3):
    """The lens's local Jacobian in pixels per normalized unit at undistorted normalized points (N, 2): (4, N),
    rows a00, a01, a10, a11 (``CameraModel._distort_jacobian`` times (fx, fy) by row, the reference of
    ``pose_fit._LocalModel``; the same arithmetic in the same order, so the same numbers)."""
    n = points_norm.shape[0]
    out = np.empty((4, n))
    for i in range(n):
        x, y = points_norm[i, 0], points_norm[i, 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        d = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
        out[0, i] = (radial + x * d * 2.0 * x + 2.0 * p1 * y + p2 * 6.0 * x) * fx
        out[1, i] = (x * d * 2.0 * y + 2.0 * p1 * x + p2 * 2.0 * y) * fx
        out[2, i] = (y * d * 2.0 * x + p1 * 2.0 * x + 2.0 * p2 * y) * fy
        out[3, i] = (radial + y * d * 2.0 * y + p1 * 6.0 * y + 2.0 * p2 * x) * fy
    return out


def camera_kernels() -> tuple:
    """The camera-model kernels above (used by ``pose_fit.pixels_to_normalized``, ``project`` and ``_LocalModel``)
    , :func:`lagged_sums` and :func:`circle_bias_gain`, which :func:`livetrack.estimator.edge_kernels.warm_up` does not
    compile: :func:`warm_up` does."""
    return pixels_to_normalized, project, lens_jacobian, predict_points, lagged_sums, circle_bias_gain


@jit_kernel
def lagged_sums(r, starts, max_lag):
    """For each lag k in 0..max_lag, the sum of ``r[i] * r[i + k]`` over the pairs of points within one run
    ``r[starts[j]:starts[j + 1]]`` (a circle's residuals), and the number of such pairs: the correlation of the edge
    residuals along their circles (``residual_correlation.correlation_time``; its ``_lagged_sums_numpy`` is the
    reference, the same sums to rounding)."""
    sums = np.zeros(max_lag + 1)
    counts = np.zeros(max_lag + 1)
    for j in range(starts.shape[0] - 1):
        a, b = starts[j], starts[j + 1]
        for k in range(min(max_lag, b - a - 1) + 1):
            acc = 0.0
            for i in range(a, b - k):
                acc += r[i] * r[i + k]
            sums[k] += acc
            counts[k] += b - a - k
    return sums, counts


def warm_up() -> None:
    """Compile (or load from numba's cache) :func:`camera_kernels` on a tiny input (``scripts/install.sh`` calls it
    after ``edge_kernels.warm_up``, so that a fresh install's first frame loads them instead of compiling them,
    ~1-2 s). Idempotent. Does nothing without numba."""
    if not hasattr(pixels_to_normalized, "targetoptions"):
        return
    points = np.array([[10.0, 20.0]])
    norm = pixels_to_normalized(points, 1000.0, 1000.0, 5.0, 5.0, -0.1, 0.0, 0.0, 0.0, 0.0, 20, 1e-14)
    project(np.array([[0.1, 0.2, 2.0]]), 1000.0, 1000.0, 5.0, 5.0, -0.1, 0.0, 0.0, 0.0, 0.0)
    lens_jacobian(norm, 1000.0, 1000.0, -0.1, 0.0, 0.0, 0.0, 0.0)
    eye, t = np.eye(3), np.array([0.0, 0.0, 2.0])
    predict_points(points, 1000.0, 1000.0, 5.0, 5.0, -0.1, 0.0, 0.0, 0.0, 0.0, 20, 1e-14, eye, t, eye, 0.01 * t)
    lagged_sums(np.zeros(3), np.array([0, 3], dtype=np.int64), 2)
    circle_bias_gain(np.eye(3), np.ones(3), np.array([0.1, 0.1, 0.05]), 2)


def cache_stats() -> dict[str, int]:
    """Numba's cache hits and misses (compilations) of :func:`camera_kernels` in this process."""
    return cache_stats_of(camera_kernels())
