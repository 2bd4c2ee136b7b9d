"""What the tracker hands out: a target's pose (``TargetResult``) or why it has none (``TargetFailure``), a frame's
results (``FrameResult``), a search's outcome (``SearchOutcome``), and their plain-JSON views."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from livetrack.estimator.detect import Candidate
from livetrack.estimator.pose_fit import PoseFit
from livetrack.estimator.target_model import TargetModelFit
from livetrack.geometry import Pose

if TYPE_CHECKING:
    from livetrack.estimator.tracker.tracks import _Track

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class TargetResult:
    """Pose of one target in one frame. ``fit`` carries covariance and residuals; falsy when it failed."""

    target_id: int
    levels_used: tuple[int, ...]
    fit: PoseFit
    heading_known: bool
    n_edge_points: int
    edge_points_px: FloatArray  # (N, 2) the edge points used (for display)
    candidate: Candidate
    dots_scale: float | None = None  # searches: where the code dots lie relative to the pose (``_dots_agree``,
    # ``_with_dots_disagreement``: in the distance variance of this and the tracked frames up to the next search)
    target_model: TargetModelFit | None = None  # searches with ``fit_target_model``: the 2-D fit that gave the pose
    outer_share: float | None = None  # the outermost circle's share of the exposure bias in the fit (its points'
    # median, ``pose_fit.bias_weights``); None: the whole of it, as every other circle's

    @property
    def pose(self) -> Pose:
        return self.fit.pose

    @property
    def delta_px(self) -> float:
        return self.fit.delta_px


@dataclass(frozen=True)
class TargetFailure:
    """A detected target that gave no usable pose in a frame, and why (in the per-frame loop a failure is a value).

    target_id, level: id and fractal level of the detection (its outermost detected level).
    centre_px: (x, y) centre of that level's outer ellipse, pixels.
    stage: where it failed: ``"edges"`` (too few edge points fitted on a circle for the closed form),
        ``"closed_form"`` (the two circles give no pose in front of the camera) or ``"pose_fit"`` (the rigorous fit
        failed or stopped at its iteration cap; its ``TargetResult``, with the pose it reached, is in
        ``FrameResult.targets`` with ``fit.ok`` False).
    reason: what went wrong, for people.
    """

    target_id: int
    level: int
    centre_px: tuple[float, float]
    stage: str
    reason: str

    @classmethod
    def from_candidate(cls, cand: Candidate, stage: str, reason: str) -> TargetFailure:
        x, y = cand.outer.centre_px
        return cls(cand.target_id, cand.level, (float(x), float(y)), stage, reason)


@dataclass(frozen=True)
class FrameResult:
    """What ``Tracker.process`` found in one frame.

    targets: one result per detected target that reached the pose fit, ok or not (``fit.ok``; a failed fit keeps
        its reason and the pose it reached, which viewers draw as failed and the pose stream flags).
    failures: every detected target without a usable pose, with its stage and reason: those that never reached
        the fit (they are nowhere else) and those whose fit failed (also in ``targets``). Empty when all is well.
    """

    targets: list[TargetResult]
    timings_ms: dict[str, float] = field(default_factory=dict)
    failures: list[TargetFailure] = field(default_factory=list)


@dataclass(frozen=True)
class SearchOutcome:
    """What ``Tracker.search`` found in one frame: the result to hand out and the targets to track from
    (``Tracker.adopt``), found in an image of ``shape``. ``lost_only``: a search for the lost targets only (the
    tracked ones were neither searched nor estimated; ``adopt`` adds what it found to them)."""

    result: FrameResult
    tracks: list[_Track]
    shape: tuple[int, ...]
    lost_only: bool = False


def target_failure_to_dict(failure: TargetFailure) -> dict:
    """Plain-JSON view of a failure."""
    return {"target_id": failure.target_id, "level": failure.level,
            "centre_px": [float(v) for v in failure.centre_px], "stage": failure.stage, "reason": failure.reason}


def target_result_to_dict(result: TargetResult) -> dict:
    """Plain-JSON view of a result (units in the keys; covariance order t (m), rotation vector (rad)); values a
    failed fit does not have (NaN) are None."""
    fit = result.fit
    cov = fit.pose_covariance
    return {
        "target_id": result.target_id,
        "levels": list(result.levels_used),
        "ok": bool(fit.ok),
        "reason": fit.reason,
        "t_m": [_number(v) for v in fit.pose.t],
        "q_xyzw": [_number(v) for v in fit.pose.quaternion],
        "distance_m": _number(fit.pose.distance_m),
        "covariance_t_m_rotvec_rad": [[_number(v) for v in row] for row in cov],
        "delta_px": _number(fit.delta_px),
        "delta_std_px": _number(fit.delta_std_px) if fit.ok else None,
        "heading_known": result.heading_known,
        "residual_rms_px": _number(fit.residual_rms_px),
        "n_edge_points": result.n_edge_points,
        "iterations": fit.iterations,
        "dots_scale": None if result.dots_scale is None else _number(result.dots_scale),
        "outer_share": None if result.outer_share is None else _number(result.outer_share),
        "target_model": None if result.target_model is None else {
            "halo_amplitude": _number(result.target_model.halo.amplitude),
            "halo_sigma_px": _number(result.target_model.halo.sigma_px),
            "black_level": _number(result.target_model.black_level),
            "core_contrast": _number(result.target_model.core_contrast),
            "residual_rms": _number(result.target_model.residual_rms),
            "n_pixels": result.target_model.n_pixels,
            "ground_share": _number(result.target_model.ground_share)},
    }


def _number(value: float) -> float | None:
    """A finite float, or None (JSON null) for NaN and infinities."""
    value = float(value)
    return value if np.isfinite(value) else None
