"""Pinhole camera with OpenCV's five distortion coefficients (k1, k2, p1, p2, k3).

Conventions (see README "Conventions"): pixel coordinates (x, y) with (0, 0) the centre of the top-left pixel;
camera frame x right, y down, z forward. "Normalized" coordinates are (X/Z, Y/Z) before distortion.
All functions are vectorised over leading array dimensions; points are (..., 2) or (..., 3) float64 arrays.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from livetrack.camera.encoding import LINEAR, canonical, encoding_problem
from livetrack.config import checks as cc

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics of one camera. ``dist`` = (k1, k2, p1, p2, k3) as in OpenCV."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    bit_depth: int = 8
    encoding: str = "linear"
    """How pixel values encode light: "linear" (machine-vision cameras), "srgb" or "gamma G" (webcams, phones,
    renderers): ``livetrack.camera.encoding``; the tracker linearises the frames of a camera that is not linear."""
    extra: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)
    """Optional fitted image-formation parameters (PSF, response); free-form, kept on round trips."""

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_dict(cls, data: Any, path: str = "camera") -> CameraModel:
        keys = ["width", "height", "fx", "fy", "cx", "cy"]
        cc.mapping(data, path, required=keys, optional=["dist", "bit_depth", "encoding", "image_formation"])
        width = cc.integer(data, "width", path, ge=1)
        height = cc.integer(data, "height", path, ge=1)
        dist = cc.number_list(data, "dist", path, length=5, default=[0.0] * 5)
        formation = data.get("image_formation")
        if formation is not None and not isinstance(formation, dict):
            raise cc.ConfigError(cc.join(path, "image_formation"),
                                 f"must be a mapping, got {type(formation).__name__}")
        return cls(
            width=width,
            height=height,
            fx=cc.number(data, "fx", path, gt=0),
            fy=cc.number(data, "fy", path, gt=0),
            cx=cc.number(data, "cx", path),
            cy=cc.number(data, "cy", path),
            dist=tuple(dist),  # type: ignore[arg-type]
            bit_depth=cc.integer(data, "bit_depth", path, default=8, choices=range(8, 17)),
            encoding=_encoding(data, path),
            extra=dict(formation or {}),
        )

    def __post_init__(self) -> None:
        problem = encoding_problem(self.encoding)
        if problem is not None:
            raise ValueError(f"CameraModel.encoding {problem}")

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "width": self.width,
            "height": self.height,
            "fx": float(self.fx),
            "fy": float(self.fy),
            "cx": float(self.cx),
            "cy": float(self.cy),
            "dist": [float(d) for d in self.dist],
            "bit_depth": self.bit_depth,
        }
        if self.encoding != LINEAR:
            out["encoding"] = self.encoding
        if self.extra:
            out["image_formation"] = dict(self.extra)
        return out

    @property
    def K(self) -> FloatArray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_array(self) -> FloatArray:
        return np.asarray(self.dist, dtype=np.float64)

    @property
    def has_distortion(self) -> bool:
        return any(d != 0.0 for d in self.dist)

    @property
    def saturation_level(self) -> int:
        """Largest digital number the sensor delivers."""
        return (1 << self.bit_depth) - 1

    # ------------------------------------------------------------------ distortion in normalized coordinates
    def distort(self, xy: FloatArray) -> FloatArray:
        """Undistorted normalized (..., 2) -> distorted normalized (..., 2)."""
        xy = np.asarray(xy, dtype=np.float64)
        if not self.has_distortion:
            return xy.copy()
        k1, k2, p1, p2, k3 = self.dist
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def _distort_jacobian(self, xy: FloatArray) -> FloatArray:
        """d(distorted)/d(undistorted), shape (..., 2, 2)."""
        k1, k2, p1, p2, k3 = self.dist
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial_dr2 = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
        j = np.empty(xy.shape[:-1] + (2, 2))
        j[..., 0, 0] = radial + x * dradial_dr2 * 2 * x + 2 * p1 * y + p2 * 6 * x
        j[..., 0, 1] = x * dradial_dr2 * 2 * y + 2 * p1 * x + p2 * 2 * y
        j[..., 1, 0] = y * dradial_dr2 * 2 * x + p1 * 2 * x + 2 * p2 * y
        j[..., 1, 1] = radial + y * dradial_dr2 * 2 * y + p1 * 6 * y + 2 * p2 * x
        return j

    def undistort(self, xy_distorted: FloatArray, iterations: int = 20, tol: float = 1e-14) -> FloatArray:
        """Distorted normalized (..., 2) -> undistorted normalized (..., 2), by Newton's method.

        Converges to machine precision within the image for any realistic lens (unlike OpenCV's default of
        five fixed-point steps in ``undistortPoints``).
        """
        xy_d = np.asarray(xy_distorted, dtype=np.float64)
        if not self.has_distortion:
            return xy_d.copy()
        k1, k2, _, _, k3 = self.dist
        # Start from a one-step radial inverse, then Newton.
        r2 = np.sum(xy_d * xy_d, axis=-1, keepdims=True)
        xy = xy_d / (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
        for _ in range(iterations):
            residual = self.distort(xy) - xy_d
            jac = self._distort_jacobian(xy)
            det = jac[..., 0, 0] * jac[..., 1, 1] - jac[..., 0, 1] * jac[..., 1, 0]
            dx = (jac[..., 1, 1] * residual[..., 0] - jac[..., 0, 1] * residual[..., 1]) / det
            dy = (-jac[..., 1, 0] * residual[..., 0] + jac[..., 0, 0] * residual[..., 1]) / det
            xy = xy - np.stack([dx, dy], axis=-1)
            if np.nanmax(np.abs(residual), initial=0.0) < tol:
                break
        return xy

    # ------------------------------------------------------------------ pixels
    def normalized_to_pixels(self, xy: FloatArray) -> FloatArray:
        """Undistorted normalized (..., 2) -> pixel (..., 2)."""
        xd = self.distort(xy)
        return np.stack([self.fx * xd[..., 0] + self.cx, self.fy * xd[..., 1] + self.cy], axis=-1)

    def pixels_to_normalized(self, pixels: FloatArray) -> FloatArray:
        """Pixel (..., 2) -> undistorted normalized (..., 2)."""
        pixels = np.asarray(pixels, dtype=np.float64)
        xd = np.stack([(pixels[..., 0] - self.cx) / self.fx, (pixels[..., 1] - self.cy) / self.fy], axis=-1)
        return self.undistort(xd)

    def project(self, points_cam: FloatArray) -> FloatArray:
        """Camera-frame points (..., 3) in metres -> pixel (..., 2). Points need z > 0."""
        points_cam = np.asarray(points_cam, dtype=np.float64)
        xy = points_cam[..., :2] / points_cam[..., 2:3]
        return self.normalized_to_pixels(xy)

    def unproject(self, pixels: FloatArray) -> FloatArray:
        """Pixel (..., 2) -> unit viewing rays (..., 3) in the camera frame."""
        xy = self.pixels_to_normalized(pixels)
        rays = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
        return rays / np.linalg.norm(rays, axis=-1, keepdims=True)

    def contains(self, pixels: FloatArray, margin_px: float = 0.0) -> npt.NDArray[np.bool_]:
        """True where a pixel position lies inside the image, ``margin_px`` away from the border."""
        pixels = np.asarray(pixels, dtype=np.float64)
        x, y = pixels[..., 0], pixels[..., 1]
        lo = -0.5 + margin_px
        return (x >= lo) & (y >= lo) & (x <= self.width - 0.5 - margin_px) & (y <= self.height - 0.5 - margin_px)

    def scaled(self, factor: float) -> CameraModel:
        """The same lens on an image resampled by ``factor`` (pixel centres stay on integers)."""
        return CameraModel(
            width=round(self.width * factor), height=round(self.height * factor),
            fx=self.fx * factor, fy=self.fy * factor,
            cx=(self.cx + 0.5) * factor - 0.5, cy=(self.cy + 0.5) * factor - 0.5,
            dist=self.dist, bit_depth=self.bit_depth, extra=self.extra,
        )


def _encoding(data: Mapping[str, Any], path: str) -> str:
    """The ``encoding`` key of a camera mapping (default linear; any case), in its canonical spelling."""
    value = data.get("encoding", LINEAR)
    known = canonical(value) if isinstance(value, str) else None
    if known is None:
        raise cc.ConfigError(cc.join(path, "encoding"), str(encoding_problem(value)))
    return known
