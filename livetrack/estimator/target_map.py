"""Maps from a ring target's plane to the image, found from its two concentric ellipses, and image sampling
through them (the coarse detector's verification and code read).

Target coordinates are in units of the outer radius R, origin at the centre; pixels (x, y) with (0, 0) the
centre of the top-left pixel. The projective map of :func:`centre_homography` is computed in scalar arithmetic
on 3x3 matrices: numpy/LAPACK calls on such small arrays cost ~1 ms per ellipse pair, the scalar form ~45 us;
it follows ``circle_pose.projected_centre`` (tests check that they agree).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.estimator import target_map_kernel
from livetrack.estimator.conics import Ellipse

FloatArray = npt.NDArray[np.float64]


def affine_homography(outer: Ellipse) -> FloatArray:
    """(3, 3) map from target coordinates in units of R to pixels, affine (from the outer ellipse alone)."""
    H = np.eye(3)
    H[:2, :2] = outer.rotation() @ np.diag(outer.semi_axes_px)
    H[:2, 2] = outer.centre_px
    return H


def centre_homography(outer: Ellipse, inner: Ellipse) -> FloatArray:
    """(3, 3) map from target coordinates in units of R to pixels, up to a rotation about the centre: the
    projective map taking the unit circle to ``outer`` and the origin to the image of the common centre of
    ``outer`` and ``inner`` (falls back to the affine map when the pair is degenerate). Its +x axis is turned to
    point along the image +x direction from the centre.

    Scalar arithmetic on 3x3 matrices throughout (numpy/LAPACK calls on 3x3 arrays cost ~1 ms per pair)."""
    H = None
    try:
        H = _projective_homography(outer, inner)
    except (ZeroDivisionError, ValueError, OverflowError):  # degenerate pair: the affine map
        pass
    if H is None:
        H = affine_homography(outer).tolist()
    (h00, h01, h02), (h10, h11, h12), (h20, h21, h22) = H
    # Orientation: the target is seen from the front, so its x -> y turn is the image's x -> y turn (the sign of
    # the Jacobian's determinant at the origin, times w^4 > 0).
    if (h00 * h22 - h02 * h20) * (h11 * h22 - h12 * h21) - (h01 * h22 - h02 * h21) * (h10 * h22 - h12 * h20) < 0:
        h01, h11, h21 = -h01, -h11, -h21
    # Turn the target frame so that its +x axis images along +x from the centre: the probe one pixel right of
    # the centre, mapped back by adj(H) ~ H^-1 (the scale cancels in the division by w).
    x, y = h02 / h22 + 1.0, h12 / h22
    px = (h11 * h22 - h12 * h21) * x + (h02 * h21 - h01 * h22) * y + (h01 * h12 - h02 * h11)
    py = (h12 * h20 - h10 * h22) * x + (h00 * h22 - h02 * h20) * y + (h02 * h10 - h00 * h12)
    pw = (h10 * h21 - h11 * h20) * x + (h01 * h20 - h00 * h21) * y + (h00 * h11 - h01 * h10)
    angle = math.atan2(py / pw, px / pw)
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[h00 * c + h01 * s, h01 * c - h00 * s, h02], [h10 * c + h11 * s, h11 * c - h10 * s, h12],
                     [h20 * c + h21 * s, h21 * c - h20 * s, h22]])


def _projective_homography(outer: Ellipse, inner: Ellipse) -> list[list[float]] | None:
    """The projective map of ``_centre_homography`` (any rotation about the centre), or None when the centre
    or the rectified ellipse is unusable; raises ZeroDivisionError / ValueError / OverflowError on degenerate
    pairs.

    Coordinates centred on the outer ellipse, in units of its semi-major axis (conditioning). The image of the
    common centre is ``circle_pose.projected_centre``'s: with the dual conics D1, D2 (unit Frobenius norm), the
    double generalized eigenvalue lam of (D1, D2) (the mean of the two closest real parts) makes D1 - lam D2 ~
    c c^T, c its dominant eigenvector. The polar of c w.r.t. the outer conic is the vanishing line l; P = [I; l]
    maps it to infinity, where the outer conic becomes an ellipse with an affine map [L | centre] from the unit
    circle (L L^T its shape matrix); the homography is T P^-1 [L | centre]."""
    a, b = outer.a, outer.b
    ox, oy = float(outer.centre_px[0]), float(outer.centre_px[1])
    # Dual conics: outer [[S1, 0], [0, -1]], inner [[S2 - d d^T, -d], [-d^T, -1]] (S: shape matrix R diag(a^2,
    # b^2) R^T of the ellipse, d its centre).
    s1 = _shape(1.0, b / a, outer.angle_rad)
    s2 = _shape(inner.a / a, inner.b / a, inner.angle_rad)
    dx, dy = (float(inner.centre_px[0]) - ox) / a, (float(inner.centre_px[1]) - oy) / a
    D1 = _unit((s1[0], s1[1], 0.0, s1[1], s1[2], 0.0, 0.0, 0.0, -1.0))
    D2 = _unit((s2[0] - dx * dx, s2[1] - dx * dy, -dx, s2[1] - dx * dy, s2[2] - dy * dy, -dy, -dx, -dy, -1.0))
    # det(D1 - lam D2) = det D1 - lam tr(adj(D1) D2) + lam^2 tr(D1 adj(D2)) - lam^3 det D2.
    adj1, adj2 = _adjugate(D1), _adjugate(D2)
    det1 = D1[0] * adj1[0] + D1[1] * adj1[3] + D1[2] * adj1[6]
    det2 = D2[0] * adj2[0] + D2[1] * adj2[3] + D2[2] * adj2[6]
    roots = _cubic_real_parts(-det2, sum(u * v for u, v in zip(D1, adj2, strict=True)),
                              -sum(u * v for u, v in zip(adj1, D2, strict=True)), det1)
    pairs = [(abs(roots[i] - roots[j]), i, j) for i in range(3) for j in range(i + 1, 3)]
    _, i, j = min(pairs)
    lam = 0.5 * (roots[i] + roots[j])
    v = _dominant_eigenvector(tuple(u - lam * w for u, w in zip(D1, D2, strict=True)))
    cx, cy = v[0] / v[2], v[1] / v[2]
    if not (math.isfinite(cx) and math.isfinite(cy) and math.hypot(cx, cy) < 0.5):
        return None
    # Vanishing line: the polar of c w.r.t. the outer conic [[M1, 0], [0, -1]] (M1 = S1^-1), scaled to l.c = 1.
    det_s1 = s1[0] * s1[2] - s1[1] * s1[1]
    m00, m01, m11 = s1[2] / det_s1, -s1[1] / det_s1, s1[0] / det_s1
    lx, ly = m00 * cx + m01 * cy, m01 * cx + m11 * cy
    norm = lx * cx + ly * cy - 1.0
    lx, ly, lw = lx / norm, ly / norm, -1.0 / norm
    # P^-1 = [[I, 0], [g^T, h]]; the rectified conic P^-T Q1 P^-1 = [[M1 - g g^T, -h g], [-h g^T, -h^2]].
    gx, gy, h = -lx / lw, -ly / lw, 1.0 / lw
    r00, r01, r11 = m00 - gx * gx, m01 - gx * gy, m11 - gy * gy
    det_r = r00 * r11 - r01 * r01
    if abs(det_r) < 1e-300:
        return None
    # Centre h Mr^-1 g; shape matrix k Mr^-1 with k = h^2 (1 + g^T Mr^-1 g); positive definite for an ellipse.
    i00, i01, i11 = r11 / det_r, -r01 / det_r, r00 / det_r
    ex, ey = h * (i00 * gx + i01 * gy), h * (i01 * gx + i11 * gy)
    k = h * h + h * (gx * ex + gy * ey)
    p00, p01, p11 = k * i00, k * i01, k * i11
    if not (p00 > 0 and p00 * p11 - p01 * p01 > 0):
        return None
    l00 = math.sqrt(p00)
    l10 = p01 / l00
    l11 = math.sqrt(p11 - l10 * l10)
    # T P^-1 [[L, e], [0, 1]] with T = [[a, 0, ox], [0, a, oy], [0, 0, 1]]; rows of P^-1 [[L, e], [0, 1]]:
    # (l00, 0, ex), (l10, l11, ey), (gx l00 + gy l10, gy l11, gx ex + gy ey + h).
    w0, w1, w2 = gx * l00 + gy * l10, gy * l11, gx * ex + gy * ey + h
    Hp = [[a * l00 + ox * w0, ox * w1, a * ex + ox * w2], [a * l10 + oy * w0, a * l11 + oy * w1, a * ey + oy * w2],
          [w0, w1, w2]]
    Hp = [[x / w2 for x in row] for row in Hp]
    if not all(math.isfinite(x) for row in Hp for x in row):
        return None
    if math.hypot(Hp[0][2] - ox, Hp[1][2] - oy) >= 0.5 * b:
        return None
    return Hp


def _shape(a: float, b: float, angle: float) -> tuple[float, float, float]:
    """(S00, S01, S11) of the shape matrix R diag(a^2, b^2) R^T of an ellipse (semi-axes a, b, angle)."""
    c, s = math.cos(angle), math.sin(angle)
    p, q = a * a, b * b
    return c * c * p + s * s * q, c * s * (p - q), s * s * p + c * c * q


def _unit(m: tuple[float, ...]) -> tuple[float, ...]:
    """A 3x3 matrix (row-major 9-tuple) scaled to unit Frobenius norm."""
    n = math.sqrt(sum(v * v for v in m))
    return tuple(v / n for v in m)


def _adjugate(m: tuple[float, ...]) -> tuple[float, ...]:
    """Adjugate (transposed cofactors) of a 3x3 matrix, row-major 9-tuples: m adj(m) = det(m) I."""
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = m
    return (m4 * m8 - m5 * m7, m2 * m7 - m1 * m8, m1 * m5 - m2 * m4,
            m5 * m6 - m3 * m8, m0 * m8 - m2 * m6, m2 * m3 - m0 * m5,
            m3 * m7 - m4 * m6, m1 * m6 - m0 * m7, m0 * m4 - m1 * m3)


def _cubic_real_parts(c3: float, c2: float, c1: float, c0: float) -> tuple[float, float, float]:
    """Real parts of the three roots of c3 x^3 + c2 x^2 + c1 x + c0 (c3 != 0), in closed form (trigonometric
    for three real roots, else Cardano's real root and the complex pair's common real part)."""
    a, b, c = c2 / c3, c1 / c3, c0 / c3
    q = (a * a - 3.0 * b) / 9.0
    r = (2.0 * a * a * a - 9.0 * a * b + 27.0 * c) / 54.0
    shift = a / 3.0
    if r * r < q * q * q:
        theta = math.acos(max(-1.0, min(1.0, r / math.sqrt(q * q * q))))
        m = -2.0 * math.sqrt(q)
        return (m * math.cos(theta / 3.0) - shift, m * math.cos((theta + 2.0 * math.pi) / 3.0) - shift,
                m * math.cos((theta - 2.0 * math.pi) / 3.0) - shift)
    u = -math.copysign((abs(r) + math.sqrt(r * r - q * q * q)) ** (1.0 / 3.0), r)
    v = q / u if u != 0.0 else 0.0
    return u + v - shift, -0.5 * (u + v) - shift, -0.5 * (u + v) - shift


def _dominant_eigenvector(m: tuple[float, ...]) -> tuple[float, float, float]:
    """Eigenvector of the eigenvalue of largest magnitude of a symmetric 3x3 matrix (row-major 9-tuple): the
    eigenvalues in closed form (trigonometric), the vector as the longest cross product of two rows of
    m - w I."""
    m00, m01, m02, _, m11, m12, _, _, m22 = m
    mean = (m00 + m11 + m22) / 3.0
    off = m01 * m01 + m02 * m02 + m12 * m12
    spread = math.sqrt(((m00 - mean) ** 2 + (m11 - mean) ** 2 + (m22 - mean) ** 2 + 2.0 * off) / 6.0)
    b00, b11, b22 = (m00 - mean) / spread, (m11 - mean) / spread, (m22 - mean) / spread
    b01, b02, b12 = m01 / spread, m02 / spread, m12 / spread
    half_det = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    phi = math.acos(max(-1.0, min(1.0, half_det))) / 3.0
    largest = mean + 2.0 * spread * math.cos(phi)
    smallest = mean + 2.0 * spread * math.cos(phi + 2.0 * math.pi / 3.0)
    w = largest if abs(largest) >= abs(smallest) else smallest
    r0, r1, r2 = (m00 - w, m01, m02), (m01, m11 - w, m12), (m02, m12, m22 - w)
    best, best_n = (0.0, 0.0, 0.0), -1.0
    for p, q in ((r0, r1), (r0, r2), (r1, r2)):
        x = (p[1] * q[2] - p[2] * q[1], p[2] * q[0] - p[0] * q[2], p[0] * q[1] - p[1] * q[0])
        n = x[0] * x[0] + x[1] * x[1] + x[2] * x[2]
        if n > best_n:
            best, best_n = x, n
    return best


def rotation3(angle: float) -> FloatArray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def apply_homography(H: FloatArray, pts: FloatArray) -> FloatArray:
    p = np.column_stack([pts, np.ones(len(pts))]) @ H.T
    return p[:, :2] / p[:, 2:3]


def sample_target(img: np.ndarray, H: FloatArray, radius: FloatArray, angle: FloatArray) -> FloatArray:
    """Bilinear image values at target points (radius in units of R, angle in radians) mapped by ``H``;
    NaN outside the image. Shapes: radius, angle (M,) -> (M,) float64."""
    radius, angle = np.asarray(radius, np.float64), np.asarray(angle, np.float64)
    if radius.shape != angle.shape:
        radius, angle = np.broadcast_arrays(radius, angle)
    radius, angle = radius.ravel(), angle.ravel()
    if angle.size == 0:
        return np.empty(0)
    return sample_target_points(img, H, radius * np.cos(angle), radius * np.sin(angle))


def sample_target_points(img: np.ndarray, H: FloatArray, tx: FloatArray, ty: FloatArray) -> FloatArray:
    """``sample_target`` from the target points themselves, ``tx = radius cos(angle)``, ``ty = radius sin(angle)``
    (M,), for callers that keep them cached. The points' map and inside test compiled where numba is installed
    (``target_map_kernel``: the same numbers as ``sample_target_points_reference``)."""
    if target_map_kernel.numba is None:
        return sample_target_points_reference(img, H, tx, ty)
    xy = np.empty((1, len(tx), 2), np.float32)  # cv2.remap's map
    inside = np.empty(len(tx), np.bool_)
    target_map_kernel.map_points(H, tx, ty, img.shape[1], img.shape[0], xy[0], inside)
    vals = cv2.remap(img, xy, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1)
    return np.where(inside, vals, np.nan)


def sample_target_points_reference(img: np.ndarray, H: FloatArray, tx: FloatArray, ty: FloatArray) -> FloatArray:
    """``sample_target_points`` in numpy (the reference, and installs without numba)."""
    xy = np.empty((1, len(tx), 2), np.float32)  # cv2.remap's map; the point itself in float64 for the test
    w = H[2, 0] * tx + H[2, 1] * ty + H[2, 2]
    x = (H[0, 0] * tx + H[0, 1] * ty + H[0, 2]) / w
    y = (H[1, 0] * tx + H[1, 1] * ty + H[1, 2]) / w
    xy[0, :, 0], xy[0, :, 1] = x, y
    inside = (x >= 0) & (y >= 0) & (x <= img.shape[1] - 1) & (y <= img.shape[0] - 1)
    vals = cv2.remap(img, xy, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1)
    return np.where(inside, vals, np.nan)
