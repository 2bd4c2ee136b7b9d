"""The paper's experiment in simulation: one target at many poses, each seen at a range of exposures.

For each pose step of a scenario (e.g. ``paper-lab``: 20 poses x 7 exposures from x0.25 to x16) the ring target
is rendered, and so are an ArUco and an AprilTag marker at the same pose, same outer size (black square side =
2 R), same exposure and the same noise seed. Every method estimates the pose; the errors against the truth give
accuracy (mean |distance error|), precision (spread of the distance across the exposures of one pose) and the
orientation error (angle between the estimated and true plane normals). The Cramér-Rao bound on the distance
comes from the simulator's own derivatives and noise model (``livetrack.evaluation.crb``).

``livetrack+fitted`` is livetrack's estimator told the camera's fitted optics (a camera file from ``livetrack model
--camera-out``: PSF core, halo, saturated-pixel noise; ``livetrack.camera.optics``), run beside ``livetrack`` on the
same frames: the gain of closing the loop from model check to estimator.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from livetrack.baselines.common import PoseEstimate
from livetrack.baselines.naive import NaiveEllipseMethod
from livetrack.baselines.square_markers import (
    AprilTagMethod,
    ArucoMethod,
    apriltag_marker_image,
    aruco_marker_image,
    texture_side_m,
)
from livetrack.camera.optics import CameraOptics, tracker_options_with_optics
from livetrack.estimator.tracker import Tracker, TrackerOptions
from livetrack.evaluation.crb import pose_bounds
from livetrack.geometry import Pose
from livetrack.sim.coverage import Placement
from livetrack.sim.scenario import Scenario
from livetrack.sim.texture import ImageTexture

log = logging.getLogger(__name__)

FITTED_METHOD = "livetrack+fitted"
"""livetrack with a camera's fitted optics; needs ``fitted_optics`` (not in ``ALL_METHODS``, the default set)."""
RING_METHODS = ("livetrack", "rigorous-no-compensation", "naive-ellipse", FITTED_METHOD)
MARKER_METHODS = ("aruco", "apriltag")
ALL_METHODS = tuple(m for m in RING_METHODS if m != FITTED_METHOD) + MARKER_METHODS


class TrackerMethod:
    """livetrack's estimator (or its delta = 0 baseline) behind the baselines' ``PoseMethod`` interface."""

    def __init__(self, name: str, tracker: Tracker):
        self.name = name
        self.tracker = tracker

    def estimate(self, image: np.ndarray) -> list[PoseEstimate]:
        result = self.tracker.process(image)
        return [PoseEstimate(target_id=t.target_id, pose=t.pose, delta_px=t.delta_px, quality=t.fit.residual_rms_px)
                for t in result.targets if t.fit.ok]


@dataclass(frozen=True)
class Observation:
    """One method on one frame: the estimate (None if not found) against the truth."""

    method: str
    step: int
    exposure_factor: float
    true_distance_m: float
    distance_m: float | None
    normal_error_deg: float | None
    delta_px: float | None
    seconds: float

    @property
    def distance_error(self) -> float | None:
        """Relative distance error (estimated / true - 1), or None if not detected."""
        return None if self.distance_m is None else self.distance_m / self.true_distance_m - 1.0


@dataclass
class SweepResult:
    scenario: str
    exposure_factors: list[float]
    observations: list[Observation] = field(default_factory=list)
    crb_distance_rel: dict[int, list[float]] = field(default_factory=dict)  # step -> per exposure, relative

    # ------------------------------------------------------------------ summaries
    def by_method(self, method: str) -> list[Observation]:
        return [o for o in self.observations if o.method == method]

    def summary(self) -> dict[str, dict[str, float | None]]:
        out: dict[str, dict[str, float | None]] = {}
        steps = sorted({o.step for o in self.observations})
        crb_per_step = {s: float(np.mean(v)) for s, v in self.crb_distance_rel.items()}
        for method in dict.fromkeys(o.method for o in self.observations):
            obs = self.by_method(method)
            found = [o for o in obs if o.distance_m is not None]
            errors = np.array([o.distance_error for o in found])
            spreads, crbs = [], []
            for s in steps:
                d = np.array([o.distance_m for o in found if o.step == s])
                if len(d) >= 2:
                    true = next(o.true_distance_m for o in obs if o.step == s)
                    spreads.append(np.std(d, ddof=1) / true)
                    if s in crb_per_step:
                        crbs.append(crb_per_step[s])
            normals = np.array([o.normal_error_deg for o in found])
            out[method] = {
                "detection_rate": len(found) / max(len(obs), 1),
                "accuracy_mean_abs_distance_error_pct": _pct(np.mean(np.abs(errors))) if len(found) else None,
                "mean_signed_distance_error_pct": _pct(np.mean(errors)) if len(found) else None,
                "max_abs_distance_error_pct": _pct(np.max(np.abs(errors))) if len(found) else None,
                "precision_spread_across_exposures_pct": _pct(np.mean(spreads)) if spreads else None,
                "orientation_error_mean_deg": float(np.mean(normals)) if len(found) else None,
                "crb_distance_std_pct": _pct(np.mean(crbs)) if crbs else None,
                "spread_over_crb": float(np.mean(spreads) / np.mean(crbs)) if spreads and crbs else None,
                "median_seconds_per_frame": float(np.median([o.seconds for o in obs])) if obs else None,
            }
        return out

    def error_curve(self, method: str) -> tuple[list[float], list[float | None], list[float | None]]:
        """Per exposure factor: median signed distance error (%) and median |error| (%) over the poses."""
        med, med_abs = [], []
        for f in self.exposure_factors:
            e = [o.distance_error for o in self.by_method(method) if o.exposure_factor == f and o.distance_m]
            med.append(_pct(np.median(e)) if e else None)
            med_abs.append(_pct(np.median(np.abs(e))) if e else None)
        return self.exposure_factors, med, med_abs


def _pct(x: float) -> float:
    return float(100.0 * x)


def normal_error_deg(estimate: Pose, truth: Pose) -> float:
    c = float(np.clip(estimate.R[:, 2] @ truth.R[:, 2], -1.0, 1.0))
    return float(np.degrees(np.arccos(c)))


def marker_placement(kind: str, pose: Pose, outer_radius_m: float, sheet_side_m: float, marker_id: int,
                     white: float, black: float) -> Placement:
    """An ArUco or AprilTag marker whose black square side is 2R, on a white sheet as large as the ring's."""
    image = aruco_marker_image(marker_id) if kind == "aruco" else apriltag_marker_image(marker_id)
    side = texture_side_m(image, 2.0 * outer_radius_m)
    margin = max(0.5 * (sheet_side_m - side), 0.0)
    return Placement(pose, ImageTexture(image=image, size_m=side, margin_m=margin, white=white, black=black))


def run_sweep(scenario: Scenario, methods: Sequence[str] = ALL_METHODS, max_steps: int | None = None,
              with_crb: bool = True, progress: Callable[[str], None] | None = None,
              fitted_optics: CameraOptics | None = None, tracker_options: TrackerOptions | None = None,
              first_step: int = 0) -> SweepResult:
    """Run every method on every frame of ``scenario`` (single target per step). ``fitted_optics``: the camera
    optics of the ``livetrack+fitted`` method (required for it; only the optics are used, the intrinsics are the
    scenario's). ``tracker_options``: the options the livetrack methods start from (default ``TrackerOptions()``;
    each sets its own ``compensate_exposure`` and, for ``livetrack+fitted``, the optics). ``first_step``: start at
    that pose step (a batch task's range is ``first_step`` to ``max_steps - 1``; the estimators start fresh there)."""
    camera = scenario.camera
    targets = list(scenario.targets)
    if len(targets) != 1:
        raise ValueError("the exposure sweep needs a scenario with exactly one target")
    spec = targets[0]
    if FITTED_METHOD in methods and fitted_optics is None:
        raise ValueError(f"method {FITTED_METHOD!r} needs fitted_optics (a camera file with an optics section)")
    factors = list(scenario.exposure_factors)
    n_exp = len(factors)
    result = SweepResult(scenario=scenario.name, exposure_factors=factors)
    base = TrackerOptions() if tracker_options is None else tracker_options
    estimators = {
        "livetrack": TrackerMethod("livetrack", Tracker(camera, targets, replace(base, compensate_exposure=True))),
        "rigorous-no-compensation": TrackerMethod(
            "rigorous-no-compensation", Tracker(camera, targets, replace(base, compensate_exposure=False))),
        "naive-ellipse": NaiveEllipseMethod(camera, targets),
        FITTED_METHOD: TrackerMethod(FITTED_METHOD, Tracker(camera, targets, tracker_options_with_optics(
            replace(base, compensate_exposure=True), fitted_optics))),
        "aruco": ArucoMethod(camera, marker_size_m=2.0 * spec.outer_radius_m),
        "apriltag": AprilTagMethod(camera, tag_size_m=2.0 * spec.outer_radius_m),
    }
    n_steps = len(scenario.steps) if max_steps is None else min(max_steps, len(scenario.steps))
    formation = scenario.formation
    for step in range(first_step, n_steps):
        first = step * n_exp
        ring = scenario.placements_for(first)[0]
        truth = ring.pose
        sheet_side = ring.texture.bounds_m[1] - ring.texture.bounds_m[0]
        scenes = {"ring": formation.optical_image([ring])}
        for kind in MARKER_METHODS:
            if kind in methods:
                placement = marker_placement(kind, truth, spec.outer_radius_m, sheet_side, spec.id,
                                             scenario.scene.white_reflectance, scenario.scene.black_reflectance)
                scenes[kind] = formation.optical_image([placement])
        if with_crb:
            bounds = pose_bounds(formation, ring, list(scenario.exposures_us), scenario.gain_db)
            result.crb_distance_rel[step] = [b.distance_std_m / truth.distance_m for b in bounds]
        for e, factor in enumerate(factors):
            index = first + e
            images = {name: scenario.render_frame(index, optical=optical).image for name, optical in scenes.items()}
            for method in methods:
                image = images["ring" if method in RING_METHODS else method]
                t0 = time.perf_counter()
                estimates = [x for x in estimators[method].estimate(image) if x.target_id == spec.id]
                seconds = time.perf_counter() - t0
                best = estimates[0] if estimates else None
                result.observations.append(Observation(
                    method=method, step=step, exposure_factor=factor, true_distance_m=truth.distance_m,
                    distance_m=best.pose.distance_m if best else None,
                    normal_error_deg=normal_error_deg(best.pose, truth) if best else None,
                    delta_px=best.delta_px if best else None, seconds=seconds))
        if progress:
            progress(f"step {step + 1}/{n_steps}: distance {truth.distance_m:.2f} m")
    return result
