"""Closed-form pose from the images of two concentric circles (Kim, Gurdjos & Kweon, TPAMI 2005).

Works in undistorted normalized image coordinates (K = I): undistort edge points before fitting the conics.
A conic is a symmetric 3x3 matrix Q with [x, y, 1] Q [x, y, 1]^T = 0 on the curve.

Two concentric circles fix the plane normal uniquely (a single circle leaves two solutions, the "flip"): the
image of the common centre c makes inv(Q1) - lambda inv(Q2) rank one for the double generalized eigenvalue
lambda, the polar of c with respect to either conic is the vanishing line l = Q c, and in normalized coordinates
the plane normal is n ~ l. The distance then follows from the circle's radius.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from livetrack.estimator.conics import Ellipse

FloatArray = npt.NDArray[np.float64]


def fit_conic(points: FloatArray) -> FloatArray:
    """Least-squares conic through points (N >= 5, (N, 2)), Hartley-normalised; returns Q with unit Frobenius
    norm. Use for well-spread points on an ellipse (edge samples around the whole circle)."""
    points = np.asarray(points, dtype=np.float64)
    mean = points.mean(axis=0)
    scale = np.sqrt(2.0) / max(np.sqrt(((points - mean) ** 2).sum(axis=1)).mean(), 1e-300)
    x = (points[:, 0] - mean[0]) * scale
    y = (points[:, 1] - mean[1]) * scale
    design = np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)])
    # the right singular vector of the least singular value, as the eigenvector of the 6 x 6 scatter matrix's
    # least eigenvalue: the same vector (to ~1e-12 on Hartley-normalised points), ~5x faster than the SVD of the
    # N x 6 design (a search's closed form fits two conics of 100-600 points)
    _, vectors = np.linalg.eigh(design.T @ design)
    a, b, c, d, e, f = vectors[:, 0] if vectors[0, 0] + vectors[2, 0] >= 0.0 else -vectors[:, 0]
    q_norm = np.array([[a, b / 2, d / 2], [b / 2, c, e / 2], [d / 2, e / 2, f]])
    T = np.array([[scale, 0, -scale * mean[0]], [0, scale, -scale * mean[1]], [0, 0, 1.0]])
    Q = T.T @ q_norm @ T
    return Q / np.linalg.norm(Q)


def projected_circle(camera, pose, radius_m: float, n: int = 64) -> Ellipse | None:
    """The image ellipse (pixels) of the circle of ``radius_m`` about the target's origin in its z = 0 plane, seen
    from ``pose`` (target to camera) through ``camera`` (a ``CameraModel``: its distortion included): the conic
    through ``n`` of its projected points. None when part of the circle lies behind the camera or the points fit
    no ellipse."""
    angles = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    points = pose.apply(np.column_stack([radius_m * np.cos(angles), radius_m * np.sin(angles), np.zeros(n)]))
    if np.any(points[:, 2] <= 1e-6):
        return None
    pixels = camera.project(points)
    if not np.all(np.isfinite(pixels)):
        return None
    try:
        return Ellipse.from_conic(fit_conic(pixels))
    except ValueError:
        return None


@dataclass(frozen=True)
class ConcentricSolution:
    """Closed-form solution. ``centre_norm``: image of the true centre (normalized coords, (2,));
    ``normal_cam``: unit plane normal pointing away from the camera (target +z); ``t_m``: target centre in the
    camera frame; ``radius_ratio``: r/R seen in the image (pose-free check of the pairing)."""

    centre_norm: FloatArray
    normal_cam: FloatArray
    t_m: FloatArray
    radius_ratio: float


def projected_centre(Q_outer: FloatArray, Q_inner: FloatArray) -> tuple[FloatArray, float]:
    """Image of the common centre (homogeneous, (3,), last coordinate 1) and the apparent radius ratio r/R."""
    D1 = np.linalg.inv(Q_outer)
    D2 = np.linalg.inv(Q_inner)
    D1 = D1 / np.linalg.norm(D1)
    D2 = D2 / np.linalg.norm(D2)
    # the generalised eigenvalues of (D1, D2), those of D2^-1 D1 (a 3 x 3 solve: scipy's generalised solver costs
    # ~10x more in argument handling than the arithmetic)
    eigvals = np.real(np.linalg.eigvals(np.linalg.solve(D2, D1)))
    # The double eigenvalue is the pair of closest values; the third gives the ratio.
    pairs = [(abs(eigvals[i] - eigvals[j]), i, j) for i in range(3) for j in range(i + 1, 3)]
    _, i, j = min(pairs)
    lam = 0.5 * (eigvals[i] + eigvals[j])
    single = eigvals[3 - i - j]
    M = D1 - lam * D2
    # Rank one: M ~ c c^T. Take the dominant eigenvector of the symmetric part.
    w, v = np.linalg.eigh(0.5 * (M + M.T))
    c = v[:, np.argmax(np.abs(w))]
    c = c / c[2]
    ratio = float(np.sqrt(abs(single / lam)))  # dual conics scale with 1/r^2: single/lam = (r2/r1)^2 or inverse
    return c, min(ratio, 1.0 / ratio) if ratio > 0 else float("nan")


def concentric_pose(Q_outer: FloatArray, Q_inner: FloatArray, outer_radius_m: float,
                    inner_radius_m: float | None = None) -> ConcentricSolution:
    """Centre, plane normal and translation from the normalized-coordinate conics of two concentric circles."""
    c, ratio = projected_centre(Q_outer, Q_inner)
    n = Q_outer @ c  # vanishing line = polar of the centre; in normalized coords it is the normal direction
    n = n / np.linalg.norm(n)
    if n @ c < 0:  # the target's +z points away from the camera: same side as the viewing ray
        n = -n
    t = _translation(Q_outer, c, n, outer_radius_m)
    if inner_radius_m is not None:
        t_inner = _translation(Q_inner, c, n, inner_radius_m)
        t = 0.5 * (t + t_inner)
    return ConcentricSolution(centre_norm=c[:2].copy(), normal_cam=n, t_m=t, radius_ratio=ratio)


def _translation(Q: FloatArray, c: FloatArray, n: FloatArray, radius_m: float) -> FloatArray:
    """Scale s of the centre ray t = s c such that circle points t + radius u (u in the plane) lie on Q.

    Since c^T Q u = 0 for every in-plane direction u (u's vanishing point lies on the polar of c),
    s^2 c^T Q c + radius^2 u^T Q u = 0. Averaged over two orthogonal in-plane directions.
    """
    a = _cross(n, (1.0, 0.0, 0.0))
    if np.linalg.norm(a) < 0.1:
        a = _cross(n, (0.0, 1.0, 0.0))
    u1 = a / np.linalg.norm(a)
    u2 = _cross(n, u1)
    cqc = c @ Q @ c
    s2 = -radius_m**2 * 0.5 * (u1 @ Q @ u1 + u2 @ Q @ u2) / cqc
    return np.sqrt(max(s2, 0.0)) * c


def rotation_from_normal(normal_cam: FloatArray, x_axis_hint_cam: FloatArray) -> FloatArray:
    """Target-to-camera rotation whose +z is ``normal_cam`` and whose +x is the hint projected into the plane."""
    z = normal_cam / np.linalg.norm(normal_cam)
    x = x_axis_hint_cam - (x_axis_hint_cam @ z) * z
    if np.linalg.norm(x) < 1e-9:
        x = _cross((0.0, 1.0, 0.0), z)
    x = x / np.linalg.norm(x)
    y = _cross(z, x)
    return np.column_stack([x, y, z])


def _cross(a, b) -> FloatArray:
    """``np.cross`` of two 3-vectors with the same arithmetic (each component a1 b2 - a2 b1: the same numbers),
    without its ~10 us of argument handling (a closed form took ~6 of them)."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
