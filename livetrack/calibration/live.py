"""When to stop collecting calibration views from a live source: image coverage and parameter uncertainties.

Pure: ``check`` takes the points collected so far (and, once a calibration of the views so far has run, its
camera and 1-sigma uncertainties) and says which thresholds are reached. The ``livetrack calibrate --source``
loop (``livetrack.commands.calibrate``) calls it after every new view and stops once ``Progress.done``.

Coverage: the share of the image cells (``report.COVERAGE_CELLS``, 8x6) holding at least one feature point, and
how many of the four corner cells do (the corners constrain the distortion most and are the last to be filled).
Uncertainties: the 1-sigma of fx, cx, cy and k1 from the calibration's Jacobian (``CalibrationResult.uncertainty``),
relative to the value (k1: to ``max(|k1|, k1_floor)``, so that a lens without distortion can reach it too).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from livetrack.calibration.report import COVERAGE_CELLS, CameraUncertainty, CoverageMap, coverage_map
from livetrack.camera import CameraModel

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class StopRule:
    """Thresholds of a live collection (each documented with its default in ``livetrack calibrate --help``).

    coverage : fraction of the 8x6 image cells that must hold a feature point (default 0.6).
    corners : how many of the four corner cells must hold one (default 4).
    fx_rel, cx_rel, cy_rel : largest 1-sigma of fx, cx, cy relative to the value (defaults 0.2 %, 0.4 %, 0.4 %:
        about 1 px of cx on a 480 px wide image).
    k1_rel : largest 1-sigma of k1 relative to max(|k1|, ``k1_floor``) (default 5 %, floor 0.05).
    min_views : no uncertainty check before this many views (the first calibrations are poorly determined and
        their Jacobian's uncertainty is itself unreliable). Default 6.
    """

    coverage: float = 0.6
    corners: int = 4
    fx_rel: float = 0.002
    cx_rel: float = 0.004
    cy_rel: float = 0.004
    k1_rel: float = 0.05
    k1_floor: float = 0.05
    min_views: int = 6

    def __post_init__(self) -> None:
        if not 0 <= self.coverage <= 1:
            raise ValueError(f"coverage must be a fraction in [0, 1], got {self.coverage}")
        if self.corners not in range(5):
            raise ValueError(f"corners must be 0-4, got {self.corners}")
        for name in ("fx_rel", "cx_rel", "cy_rel", "k1_rel", "k1_floor"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive, got {value}")
        if self.min_views < 3:
            raise ValueError(f"min_views must be at least 3, got {self.min_views}")


@dataclass(frozen=True)
class Progress:
    """One check of a collection.

    views : views so far. coverage : fraction of the cells hit; corners : corner cells hit (0-4).
    relative_std : fx, cx, cy, k1 -> 1-sigma relative to the value (k1: to max(|k1|, floor)); None before the first
        calibration of the views so far.
    unmet : one line per threshold not reached (empty: done), e.g. ``"coverage 45 % < 60 %"``.
    """

    views: int
    coverage: float
    corners: int
    relative_std: dict[str, float] | None
    unmet: list[str] = field(default_factory=list)

    @property
    def done(self) -> bool:
        return not self.unmet

    @property
    def coverage_reached(self) -> bool:
        return not any(u.startswith(("coverage", "corner")) for u in self.unmet)

    def text(self) -> str:
        parts = [f"{self.views} views, coverage {self.coverage:.0%}, corners {self.corners}/4"]
        if self.relative_std is not None:
            parts.append("1-sigma " + ", ".join(f"{k} {v:.2%}" for k, v in self.relative_std.items()))
        return "; ".join(parts)


def corner_cells_hit(cov: CoverageMap) -> int:
    """How many of the four corner cells of the coverage grid hold a point."""
    c = cov.counts
    return int(sum(c[i, j] > 0 for i in (0, -1) for j in (0, -1)))


def relative_std(camera: CameraModel, uncertainty: CameraUncertainty, k1_floor: float) -> dict[str, float]:
    """1-sigma of fx, cx, cy relative to their values, of k1 relative to max(|k1|, k1_floor)."""
    return {"fx": uncertainty.fx / abs(camera.fx), "cx": uncertainty.cx / abs(camera.cx),
            "cy": uncertainty.cy / abs(camera.cy),
            "k1": uncertainty.dist[0] / max(abs(camera.dist[0]), k1_floor)}


def check(rule: StopRule, points_px: list[FloatArray], width: int, height: int,
          camera: CameraModel | None = None, uncertainty: CameraUncertainty | None = None) -> Progress:
    """Which thresholds of ``rule`` the views so far reach: ``points_px`` the feature points (N_v, 2) of each view;
    ``camera`` and ``uncertainty`` a calibration of them (None: not yet calibrated, the uncertainties count as not
    reached)."""
    cov = coverage_map(points_px, width, height, COVERAGE_CELLS)
    fraction, corners = cov.covered_fraction, corner_cells_hit(cov)
    unmet = []
    if fraction < rule.coverage:
        unmet.append(f"coverage {fraction:.0%} < {rule.coverage:.0%} of the image cells")
    if corners < rule.corners:
        unmet.append(f"corner cells {corners}/4 < {rule.corners}/4")
    rel = None
    if camera is None or uncertainty is None:
        unmet.append("parameter uncertainties not evaluated yet" if len(points_px) >= rule.min_views else
                     f"parameter uncertainties: {len(points_px)} views < {rule.min_views} (min views)")
    else:
        rel = relative_std(camera, uncertainty, rule.k1_floor)
        limits = {"fx": rule.fx_rel, "cx": rule.cx_rel, "cy": rule.cy_rel, "k1": rule.k1_rel}
        for name, value in rel.items():
            if not (np.isfinite(value) and value <= limits[name]):
                unmet.append(f"1-sigma of {name} {value:.3%} > {limits[name]:.3%}")
    return Progress(views=len(points_px), coverage=fraction, corners=corners, relative_std=rel, unmet=unmet)
