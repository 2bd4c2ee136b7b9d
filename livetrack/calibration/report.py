"""Calibration results common to both modes: parameter uncertainties, per-view errors, coverage map."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel

FloatArray = npt.NDArray[np.float64]

INTRINSIC_NAMES = ("fx", "fy", "cx", "cy")
COVERAGE_CELLS = (8, 6)
"""(cols, rows) of the coverage grid: the one grid of every mode's printed coverage, ``--json``, ``coverage.png``,
the live collection's stop rule (``livetrack.calibration.live``) and its Rerun view."""
DIST_NAMES = ("k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class CameraUncertainty:
    """One standard deviation of each camera parameter: pixels for fx, fy, cx, cy; dist in its own units
    (k1, k2, p1, p2, k3). A parameter held fixed in the calibration has 0."""

    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float]

    @classmethod
    def from_vector(cls, std: FloatArray) -> CameraUncertainty:
        """From (fx, fy, cx, cy, k1, k2, p1, p2, k3) standard deviations (9,)."""
        s = [float(v) for v in np.asarray(std, dtype=np.float64).ravel()[:9]]
        return cls(fx=s[0], fy=s[1], cx=s[2], cy=s[3], dist=(s[4], s[5], s[6], s[7], s[8]))

    def to_dict(self) -> dict[str, Any]:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy, "dist": list(self.dist)}


@dataclass(frozen=True)
class RejectedView:
    name: str
    rms_px: float
    reason: str


@dataclass(frozen=True)
class CalibrationResult:
    """A calibration and its quality.

    camera : the calibrated camera.
    uncertainty : 1-sigma of each parameter (from the Jacobian at the optimum, scaled by the residual RMS).
    rms_px : RMS reprojection (point-to-feature) error over every point used, pixels.
    view_names : the views used, in order; ``per_view_rms_px`` (V,) their RMS errors.
    points_px : per used view, the measured feature points (N_v, 2) (x, y), pixel centres on integers.
    residuals_px : per used view, measured minus model (N_v, 2) for point features; for edge points of circles
        (``targets`` mode) the signed distance along the edge normal times the normal.
    rejected : views left out, with their error and the reason.
    extra : mode-specific figures (e.g. the per-view exposure bias of the targets mode).
    """

    camera: CameraModel
    uncertainty: CameraUncertainty
    rms_px: float
    view_names: list[str]
    per_view_rms_px: FloatArray
    points_px: list[FloatArray]
    residuals_px: list[FloatArray]
    rejected: list[RejectedView] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)

    def coverage(self, cells: tuple[int, int] = COVERAGE_CELLS) -> CoverageMap:
        return coverage_map(self.points_px, self.camera.width, self.camera.height, cells)

    def to_dict(self) -> dict[str, Any]:
        cov = self.coverage()
        return {
            "camera": self.camera.to_dict(),
            "uncertainty": self.uncertainty.to_dict(),
            "rms_px": self.rms_px,
            "views": [{"name": n, "rms_px": float(e), "points": int(len(p))}
                      for n, e, p in zip(self.view_names, self.per_view_rms_px, self.points_px, strict=True)],
            "rejected": [{"name": r.name, "rms_px": r.rms_px, "reason": r.reason} for r in self.rejected],
            "coverage": cov.to_dict(),
            **self.extra,
        }


@dataclass(frozen=True)
class CoverageMap:
    """Feature points per image cell: ``counts_px`` (rows, cols) over a grid of ``cells`` = (cols, rows)."""

    counts: npt.NDArray[np.int64]
    cell_width_px: float
    cell_height_px: float

    @property
    def covered_fraction(self) -> float:
        """Fraction of the cells holding at least one point."""
        return float(np.count_nonzero(self.counts)) / self.counts.size

    @property
    def cells(self) -> tuple[int, int]:
        """(cols, rows) of the grid."""
        return int(self.counts.shape[1]), int(self.counts.shape[0])

    def text(self) -> str:
        """One line, the same wherever the coverage is shown (console, plot title), e.g. ``"coverage 71 % of the
        8x6 = 48 image cells hold a point"``."""
        cols, rows = self.cells
        return (f"coverage {self.covered_fraction:.0%} of the {cols}x{rows} = {cols * rows} image cells hold a "
                "point")

    def to_dict(self) -> dict[str, Any]:
        return {"cells_cols_rows": [int(self.counts.shape[1]), int(self.counts.shape[0])],
                "covered_fraction": self.covered_fraction, "counts": self.counts.tolist()}


def coverage_map(points_px: list[FloatArray], width: int, height: int,
                 cells: tuple[int, int] = COVERAGE_CELLS) -> CoverageMap:
    """Count the points of every view in a (cols, rows) grid over a width x height image (pixel centres on
    integers: the image spans [-0.5, width - 0.5])."""
    cols, rows = cells
    counts = np.zeros((rows, cols), dtype=np.int64)
    cw, ch = width / cols, height / rows
    for pts in points_px:
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        j = np.clip(np.floor((pts[:, 0] + 0.5) / cw).astype(int), 0, cols - 1)
        i = np.clip(np.floor((pts[:, 1] + 0.5) / ch).astype(int), 0, rows - 1)
        np.add.at(counts, (i, j), 1)
    return CoverageMap(counts=counts, cell_width_px=cw, cell_height_px=ch)


def summary_text(result: CalibrationResult) -> str:
    """Human-readable summary: parameters with their 1-sigma, RMS, per-view errors, coverage, rejections."""
    cam, u = result.camera, result.uncertainty
    lines = [f"{len(result.view_names)} views used, RMS reprojection error {result.rms_px:.4f} px"]
    for name in INTRINSIC_NAMES:
        lines.append(f"  {name} = {getattr(cam, name):.4f} +- {getattr(u, name):.4f} px")
    for name, value, sd in zip(DIST_NAMES, cam.dist, u.dist, strict=True):
        lines.append(f"  {name} = {value:+.6f} +- {sd:.6f}")
    for key, value in result.extra.items():
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            lines.append(f"  {key} = {value:.6g}")
    deltas = result.extra.get("delta_px")
    if isinstance(deltas, dict) and result.extra.get("compensated"):
        lines.append("exposure bias per view (px): " + ", ".join(f"{n} {d:+.3f}" for n, d in deltas.items()))
    lines.append("per-view RMS (px): " + ", ".join(
        f"{n} {e:.3f}" for n, e in zip(result.view_names, result.per_view_rms_px, strict=True)))
    lines.append(result.coverage().text())
    for r in result.rejected:
        lines.append(f"rejected {r.name}: {r.reason}")
    return "\n".join(lines)
