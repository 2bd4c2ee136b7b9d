"""A printed grid of black disks on white paper, for the simulator (``PlanarTexture`` / ``EdgeTexture``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from livetrack.sim.texture import INK_BLACK, PAPER_WHITE, square_fraction_within

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class DiskGridTexture:
    """Black disks of ``radius_m`` on a square lattice of ``pitch_m`` (a disk centred on the origin), printed on
    a sheet ``half_size_m`` on each side of the origin (target-plane metres, x right, y down).

    white, black : reflectances of paper and ink (defaults 0.85 and 0.04).
    """

    pitch_m: float
    radius_m: float
    half_size_m: float
    white: float = PAPER_WHITE
    black: float = INK_BLACK

    def __post_init__(self) -> None:
        if not 0 < self.radius_m < 0.5 * self.pitch_m:
            raise ValueError(f"need 0 < radius_m < pitch_m / 2, got {self.radius_m}, {self.pitch_m}")

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        h = self.half_size_m
        return (-h, h, -h, h)

    def _nearest(self, x: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Offsets (dx, dy) from the nearest disk centre."""
        p = self.pitch_m
        return x - p * np.round(x / p), y - p * np.round(y / p)

    def reflectance(self, x_m: FloatArray, y_m: FloatArray) -> FloatArray:
        dx, dy = self._nearest(np.asarray(x_m, dtype=np.float64), np.asarray(y_m, dtype=np.float64))
        return np.where(dx * dx + dy * dy <= self.radius_m**2, self.black, self.white)

    def edge_distance_m(self, x_m: FloatArray, y_m: FloatArray) -> FloatArray:
        dx, dy = self._nearest(np.asarray(x_m, dtype=np.float64), np.asarray(y_m, dtype=np.float64))
        return np.abs(np.hypot(dx, dy) - self.radius_m)

    def cell_average(self, x_m: FloatArray, y_m: FloatArray, jac: FloatArray, side_px: float) -> FloatArray:
        """Nearest circle linearised through ``jac`` (exact for straight edges; the curvature error is about
        side^3 / (12 rho) px^2 for a circle imaged with radius rho px)."""
        x = np.asarray(x_m, dtype=np.float64).ravel()
        y = np.asarray(y_m, dtype=np.float64).ravel()
        jac = np.asarray(jac, dtype=np.float64).reshape(-1, 2, 2)
        dx, dy = self._nearest(x, y)
        dist = np.hypot(dx, dy)
        safe = np.where(dist > 0, dist, 1.0)
        nx, ny = np.where(dist > 0, dx / safe, 1.0), np.where(dist > 0, dy / safe, 0.0)
        gx = jac[:, 0, 0] * nx + jac[:, 1, 0] * ny
        gy = jac[:, 0, 1] * nx + jac[:, 1, 1] * ny
        gn = np.maximum(np.hypot(gx, gy), 1e-30)
        e = dist - self.radius_m
        t_px = np.abs(e) / gn
        here = np.where(e <= 0, self.black, self.white)
        across = self.black + self.white - here
        keep = square_fraction_within(t_px, gx / gn, gy / gn, side_px)
        return here * keep + across * (1.0 - keep)
