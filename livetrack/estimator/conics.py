"""Ellipses in the image and their conic matrices.

Pixel convention: points are (x, y), (0, 0) the centre of the top-left pixel, y down (the convention of
OpenCV's contour points and of ``cv2.fitEllipse`` centres). Angles are in radians, from +x toward +y.

An ellipse is stored by its centre, its semi-axes ``(a, b)`` with ``a >= b`` and the angle of the major axis
(in [0, pi)). Its conic is the symmetric (3, 3) matrix ``Q`` with ``[x, y, 1] Q [x, y, 1]^T = 0`` on the ellipse,
negative inside, scaled to unit Frobenius norm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
_FLOAT64 = np.dtype(np.float64)


@dataclass(frozen=True, eq=False)
class Ellipse:
    """An image ellipse.

    ``centre_px``: (2,) float64 (x, y); ``semi_axes_px``: (2,) float64 (a, b), a >= b > 0;
    ``angle_rad``: direction of the major axis a, from +x toward +y, in [0, pi).
    """

    centre_px: FloatArray
    semi_axes_px: FloatArray
    angle_rad: float

    def __post_init__(self) -> None:  # scalar math: detection builds ~70 ellipses per frame (~1.5 us each)
        # (2,) float64 arrays (the usual arguments) as they are: ``np.asarray(...).reshape(2)`` of them is a view
        # of the same values, at ~0.2 us each
        centre, axes = self.centre_px, self.semi_axes_px
        if type(centre) is not np.ndarray or centre.shape != (2,) or centre.dtype != _FLOAT64:
            centre = np.asarray(centre, dtype=np.float64).reshape(2)
        if type(axes) is not np.ndarray or axes.shape != (2,) or axes.dtype != _FLOAT64:
            axes = np.asarray(axes, dtype=np.float64).reshape(2)
        a, b = axes.tolist()
        angle = float(self.angle_rad)
        cx, cy = centre.tolist()
        if not (math.isfinite(cx) and math.isfinite(cy) and math.isfinite(a) and math.isfinite(b)
                and math.isfinite(angle)):
            raise ValueError("ellipse parameters must be finite")
        if a <= 0 or b <= 0:
            raise ValueError(f"semi-axes must be positive, got {a}, {b}")
        if b > a:
            a, b, angle = b, a, angle + math.pi / 2
        object.__setattr__(self, "centre_px", centre)
        object.__setattr__(self, "semi_axes_px", np.array([a, b]))
        # Python's float % is numpy's np.mod for floats (fmod, then + pi for a negative remainder, +0.0 for 0)
        object.__setattr__(self, "angle_rad", angle % math.pi)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_cv(cls, box: tuple[tuple[float, float], tuple[float, float], float]) -> Ellipse:
        """From ``cv2.fitEllipse``'s ``((cx, cy), (width, height), angle_deg)``: width and height are FULL axes,
        width lies along ``angle_deg`` (degrees, from +x toward +y), height perpendicular to it."""
        (cx, cy), (w, h), angle_deg = box
        return cls(np.array([cx, cy], dtype=np.float64), np.array([w / 2.0, h / 2.0]), np.deg2rad(angle_deg))

    @classmethod
    def from_conic(cls, Q: FloatArray) -> Ellipse:
        """From any non-degenerate real ellipse conic (3, 3), of any scale and sign. Raises ``ValueError`` if
        ``Q`` is not a real ellipse."""
        Q = np.asarray(Q, dtype=np.float64)
        Q = 0.5 * (Q + Q.T)
        M, q, f = Q[:2, :2], Q[:2, 2], Q[2, 2]
        if not np.all(np.isfinite(Q)) or abs(np.linalg.det(M)) < 1e-300:
            raise ValueError("not a central conic")
        centre = -np.linalg.solve(M, q)
        k = -(f + q @ centre)  # d^T M d = k on the ellipse, d = x - centre
        if k == 0:
            raise ValueError("degenerate conic (a point)")
        evals, evecs = np.linalg.eigh(M / k)
        if evals[0] <= 0:
            raise ValueError("not a real ellipse")
        a, b = 1.0 / np.sqrt(evals[0]), 1.0 / np.sqrt(evals[1])
        angle = float(np.arctan2(evecs[1, 0], evecs[0, 0]))
        return cls(centre, np.array([a, b]), angle)

    # ------------------------------------------------------------------ properties
    @property
    def a(self) -> float:
        return float(self.semi_axes_px[0])

    @property
    def b(self) -> float:
        return float(self.semi_axes_px[1])

    def rotation(self) -> FloatArray:
        """(2, 2) rotation whose first column is the major-axis direction."""
        c, s = np.cos(self.angle_rad), np.sin(self.angle_rad)
        return np.array([[c, -s], [s, c]])

    def half_extent_px(self) -> FloatArray:
        """(2,) half width and half height of the axis-aligned bounding box."""
        c, s = np.cos(self.angle_rad), np.sin(self.angle_rad)
        a, b = self.a, self.b
        return np.array([np.hypot(a * c, b * s), np.hypot(a * s, b * c)])

    def to_conic(self) -> FloatArray:
        """(3, 3) symmetric conic, negative inside, unit Frobenius norm."""
        R = self.rotation()
        M = R @ np.diag([1.0 / self.a**2, 1.0 / self.b**2]) @ R.T
        c = self.centre_px
        Q = np.empty((3, 3))
        Q[:2, :2] = M
        Q[:2, 2] = Q[2, :2] = -M @ c
        Q[2, 2] = c @ M @ c - 1.0
        return Q / np.linalg.norm(Q)

    def scaled(self, factor: float, offset_px: float = 0.0) -> Ellipse:
        """Same centre and angle, semi-axes ``factor * (a, b) + offset_px``."""
        return Ellipse(self.centre_px, self.semi_axes_px * factor + offset_px, self.angle_rad)

    # ------------------------------------------------------------------ sampling
    def points(self, angles: npt.ArrayLike) -> FloatArray:
        """(M, 2) points at parametric angles (M,) (radians; t = 0 at the end of the major axis)."""
        t = np.asarray(angles, dtype=np.float64).reshape(-1)
        local = np.column_stack([self.a * np.cos(t), self.b * np.sin(t)])
        return self.centre_px + local @ self.rotation().T

    def normals(self, angles: npt.ArrayLike) -> FloatArray:
        """(M, 2) outward unit normals at the parametric angles (M,)."""
        t = np.asarray(angles, dtype=np.float64).reshape(-1)
        local = np.column_stack([np.cos(t) / self.a, np.sin(t) / self.b])
        local /= np.linalg.norm(local, axis=1, keepdims=True)
        return local @ self.rotation().T

    # ------------------------------------------------------------------ distances
    def algebraic_distance(self, points: npt.ArrayLike) -> FloatArray:
        """(M,) ``p^T Q p`` with the normalised conic: 0 on the ellipse, negative inside (no unit)."""
        p = _homogeneous(points)
        return np.einsum("ij,jk,ik->i", p, self.to_conic(), p)

    def sampson_distance(self, points: npt.ArrayLike) -> FloatArray:
        """(M,) first-order signed geometric distance in pixels (positive outside): ``p^T Q p / |grad|``.

        Accurate to first order near the curve; exact on it."""
        p = _homogeneous(points)
        Q = self.to_conic()
        Qp = p @ Q
        value = np.einsum("ij,ij->i", Qp, p)
        grad = 2.0 * np.linalg.norm(Qp[:, :2], axis=1)
        return value / np.maximum(grad, 1e-300)


def _homogeneous(points: npt.ArrayLike) -> FloatArray:
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return np.column_stack([p, np.ones(len(p))])
