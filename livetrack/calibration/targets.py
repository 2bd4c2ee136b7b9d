"""Calibration from views of livetrack ring targets: a joint bundle adjustment over the sub-pixel edge points of
every circle, with an exposure bias per target per view (Cledat et al. 2021's compensation, applied to
calibration).

Parameters: the intrinsics (fx, fy, cx, cy), the distortion (k1, k2; p1, p2 and k3 optional, else held at their
start), one pose per target per view (translation and the two tilt angles: the rotation about the target normal
changes no circle and is held) and the exposure bias ``delta_px`` (edges move by delta along their black-to-white
image normal; one per target per view, or one per view; ``compensate=False`` holds it at 0: the baseline).
Residual: the distance of each edge point to its circle projected through the full camera model, along the
normal, plus delta -- exactly the pose fit's residual (``livetrack.estimator.pose_fit``), whose model functions
are reused. Solved by Levenberg-Marquardt (``scipy.optimize.least_squares``) with a central-difference Jacobian
over column groups that follow its sparsity (the intrinsics touch every residual, a pose only its target's points
in its view, a delta only its own points). A first solution's outliers are dropped once.

The start comes from the tracker's per-view poses under an initial camera (e.g. f from the image size). Pure:
no I/O.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from livetrack.calibration.edges import EdgeOptions, measure_edges
from livetrack.calibration.report import CalibrationResult, CameraUncertainty, RejectedView
from livetrack.camera import CameraModel
from livetrack.estimator.clip_level import frame_saturation_dn
from livetrack.estimator.pose_fit import CircleEdgePoints, _model, _residuals
from livetrack.estimator.tracker import CLIP_MARGIN_FRACTION, Tracker, TrackerOptions
from livetrack.geometry import Pose, rotation_from_rotvec
from livetrack.targets.spec import TargetSpec

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

CAMERA_PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class TargetView:
    """Edge points of one target in one view, assigned to their circles, and the tracker's pose (the start)."""

    view: int
    target_id: int
    edges: CircleEdgePoints
    pose: Pose
    delta_px: float = 0.0


@dataclass(frozen=True)
class TargetCalibrationOptions:
    """compensate : estimate the exposure biases (False: delta held at 0, the uncompensated baseline).
    fit_tangential, fit_k3 : also estimate p1, p2 / k3 (default: held at the initial camera's values).
    same_focal : one focal length (fx = fy).
    delta_per_target : one exposure bias per target per view (default) instead of one per view. In the
        16-view simulation of docs/calibration.md one per view left RMS 0.053 px and fx +0.60 % at x16, one per
        target 0.021 px and +0.31 % (x4: +0.36 -> +0.32 %; x1 similar): the estimator's edges are not biased
        alike on two targets at different distances and tilts.
    own_delta, own_delta_min_points : after the edges are measured again the exposure bias is one per exposure
        time, except (default True) when the profiles are clipped (a blur was estimated) for a target measured on
        at least two circles with ``own_delta_min_points`` (30) points each, which keeps one of its own: at x16
        the clipped profiles' edges of one target move together by a few hundredths of a pixel (its shared
        contrast, read from noisy clipped profiles; one bias per view: sd 0.03-0.04 px over 16 views), and with
        one bias per exposure that was left to the camera (16 views, x16, two noise draws: k1 +0.91 / -0.98 % with
        one bias per exposure, +0.36 / +0.17 % with one per target). Not for unclipped views: at x0.25 one bias
        per target read fx +0.054 +- 0.011 % (7 draws; one per exposure +0.02 +- 0.02 %). A target with one
        circle keeps its exposure's bias (its own would trade with its distance).
    outlier_sigmas : after a first solution, edge points whose residual exceeds this many robust standard
        deviations (1.4826 x MAD), and at most 1 % of them, are left out and the adjustment continues
        (outliers: clutter next to an edge, a code dot); None: keep all. Default 5.
    reject_factor, reject_min_px : a view whose RMS is above reject_factor x the median view RMS and above
        reject_min_px is dropped and the adjustment run again (the worst first; at least ``min_views`` kept).
    max_nfev : cap on the Levenberg-Marquardt iterations' function evaluations (each Jacobian costs 2 x (camera
        parameters + 6) more).
    refine_edges : (``calibrate_targets``) after a first adjustment on the tracker's edge points, measure the
        edges again where its camera and poses put the circles, only where a profile stays clear of the design's
        other edges (``livetrack.calibration.edges``), and adjust again from its solution. Default True: in the
        16-view simulation fx went from +0.32 % to within 0.05 % at x4 (the tracker's profiles reach the code dots
        and the nested level, more on the far side of a tilted target). Costs a few seconds of CPU.
    refine_passes : how many times at least (default 2): the blur estimate of over-exposed views needs the edges
        sampled where they are, which the first adjustment (on the tracker's edges) gives only to ~0.2 px (x16 in
        the 16-view simulation: blur 1.10 px from the first adjustment's poses, 0.81 px from the true ones; PSF
        0.8).
    max_refine_passes, blur_tolerance_px : further passes, up to ``max_refine_passes`` (default 4) in all, while
        the blur found moved by more than ``blur_tolerance_px`` (default 0.01 px) since the pass before. The
        edges are sampled where the previous pass put them, moved by its exposure bias, and on clipped profiles
        that bias follows the blur: after a pass whose blur changed the solution has not settled (x16, one noise
        draw: blur 0.79 -> 0.861 -> 0.860 -> 0.863 px over 4 passes, k1 error +0.00 / -1.18 / -0.51 / -0.57 %).
    edges : the options of that measurement (``EdgeOptions``; its ``sigma_px`` None: the blur of profiles
        clipped on their white side is chosen by ``estimate_blur``).
    blur_uncertainty : when the blur of clipped profiles was estimated (over-exposed views), add its uncertainty
        to the reported 1-sigma (default True): sigma_blur from a jackknife over the views of the blur estimate
        (``estimate_blur_with_std``), d(camera)/d(blur) by central differences (the edges measured again at the
        blur +- ``blur_step_px`` and adjusted again from the solution: two more measurements and adjustments),
        and each parameter's variance increased by (d p / d blur x sigma_blur)^2. In the 16-view simulation at
        x16 k1 errors were 2.4 x the 1-sigma without this.
    blur_step_px, blur_passes : the step of that difference (default 0.05 px), and how many passes of measuring
        and adjusting on each side (default 2: one pass alone, at the solution's sampling, misses how the
        exposure bias, and with it where the edges are sampled, follows the blur).
    """

    compensate: bool = True
    fit_tangential: bool = False
    fit_k3: bool = False
    same_focal: bool = False
    delta_per_target: bool = True
    outlier_sigmas: float | None = 5.0
    reject_factor: float = 3.0
    reject_min_px: float = 0.5
    min_views: int = 3
    max_nfev: int = 100
    refine_edges: bool = True
    refine_passes: int = 2
    max_refine_passes: int = 4
    blur_tolerance_px: float = 0.01
    edges: EdgeOptions = field(default_factory=EdgeOptions)
    own_delta: bool = True
    own_delta_min_points: int = 30
    blur_uncertainty: bool = True
    blur_step_px: float = 0.05
    blur_passes: int = 2


# ---------------------------------------------------------------------- observations
def circles_of(spec: TargetSpec) -> list[tuple[float, bool]]:
    """(radius_m, white_outside) of every black/white circle of a target, all fractal levels: the outer edge of
    each black disk (white outside) and the edge of its white inner disk (white inside)."""
    out: list[tuple[float, bool]] = []
    level: TargetSpec | None = spec
    while level is not None:
        out += [(level.outer_radius_m, True), (level.inner_radius_m, False)]
        level = level.child
    return out


def assign_circles(camera: CameraModel, points_px: FloatArray, pose: Pose, spec: TargetSpec,
                   max_relative_gap: float = 0.15) -> CircleEdgePoints:
    """Edge points (N, 2) of one target -> CircleEdgePoints: each point goes to the circle whose radius is nearest
    its back-projected radius on the target plane under ``pose``; points further than ``max_relative_gap`` of that
    radius from it are dropped. Uniform weights (std 1 px: the adjustment's scale comes from the residuals)."""
    circles = circles_of(spec)
    radii = np.array([c[0] for c in circles])
    rays = camera.unproject(points_px)
    n = pose.R[:, 2]
    along = rays @ n
    ok = along > 1e-9
    X = rays * ((n @ pose.t) / np.where(ok, along, 1.0))[:, None]
    q = (X - pose.t) @ pose.R
    rho = np.hypot(q[:, 0], q[:, 1])
    nearest = np.argmin(np.abs(rho[:, None] - radii[None, :]), axis=1)
    keep = ok & (np.abs(rho - radii[nearest]) < max_relative_gap * radii[nearest])
    outside = np.array([c[1] for c in circles])
    return CircleEdgePoints(points_px=np.asarray(points_px, dtype=np.float64)[keep], radius_m=radii[nearest[keep]],
                            white_outside=outside[nearest[keep]], std_px=np.ones(int(keep.sum())))


def observe(images: list[npt.NDArray], exposures_us: list[float | None] | None, camera: CameraModel,
            targets: list[TargetSpec], options: TrackerOptions | None = None,
            min_points: int = 30) -> tuple[list[TargetView], list[RejectedView]]:
    """Detect the targets in every image with ``Tracker`` (whole-frame search each time) under the initial
    ``camera``; return their edge points assigned to circles with the tracker's poses, and the views that gave
    none (with the reason)."""
    options = options or TrackerOptions()
    by_id = {t.id: t for t in targets}
    views: list[TargetView] = []
    missing: list[RejectedView] = []
    for i, image in enumerate(images):
        tracker = Tracker(camera, targets, options)
        result = tracker.process(image, None if exposures_us is None else exposures_us[i])
        found = 0
        for target in result.targets:
            if not target.fit or target.target_id not in by_id:
                continue
            edges = assign_circles(camera, target.edge_points_px, target.pose, by_id[target.target_id])
            if len(edges) < min_points:
                continue
            views.append(TargetView(i, target.target_id, edges, target.pose, float(target.delta_px)))
            found += 1
        if not found:
            reasons = "; ".join(f"{f.target_id}: {f.stage}: {f.reason}" for f in result.failures)
            missing.append(RejectedView(str(i), float("nan"), "no target with a pose" + (f" ({reasons})"
                                                                                          if reasons else "")))
    return views, missing


# ---------------------------------------------------------------------- the adjustment
@dataclass
class _Layout:
    """Where each parameter sits in the adjustment's vector."""

    free_camera: list[str]
    n_delta: int  # exposure-bias parameters: one per view, or one per target per view
    n_obs: int
    compensate: bool
    base_camera: CameraModel
    delta_slot: list[int] = field(default_factory=list)  # per obs: its exposure-bias parameter
    frames: list[tuple[FloatArray, FloatArray]] = field(default_factory=list)  # per obs: R0, tilt axes (3, 2)

    @property
    def n_camera(self) -> int:
        return len(self.free_camera)

    def pose_slice(self, k: int) -> slice:
        start = self.n_camera + 5 * k
        return slice(start, start + 5)

    def delta_index(self, slot: int) -> int:
        return self.n_camera + 5 * self.n_obs + slot

    @property
    def size(self) -> int:
        return self.n_camera + 5 * self.n_obs + (self.n_delta if self.compensate else 0)

    def camera(self, x: FloatArray) -> CameraModel:
        values = dict(zip(CAMERA_PARAMS, [self.base_camera.fx, self.base_camera.fy, self.base_camera.cx,
                                          self.base_camera.cy, *self.base_camera.dist], strict=True))
        for name, value in zip(self.free_camera, x[:self.n_camera], strict=True):
            values[name] = float(value)
        if "fy" not in self.free_camera and "fx" in self.free_camera:  # one focal length
            values["fy"] = values["fx"]
        return CameraModel(width=self.base_camera.width, height=self.base_camera.height, fx=values["fx"],
                           fy=values["fy"], cx=values["cx"], cy=values["cy"],
                           dist=tuple(values[k] for k in ("k1", "k2", "p1", "p2", "k3")),  # type: ignore[arg-type]
                           bit_depth=self.base_camera.bit_depth)

    def pose(self, x: FloatArray, k: int) -> tuple[FloatArray, FloatArray]:
        p = x[self.pose_slice(k)]
        R0, axes = self.frames[k]
        return rotation_from_rotvec(axes @ p[:2]) @ R0, p[2:5]

    def delta(self, x: FloatArray, k: int) -> float:
        """The exposure bias of obs ``k``."""
        return float(x[self.delta_index(self.delta_slot[k])]) if self.compensate else 0.0


def _residual_vector(x: FloatArray, layout: _Layout, obs: list[TargetView]) -> FloatArray:
    camera = layout.camera(x)
    out = []
    for k, o in enumerate(obs):
        R, t = layout.pose(x, k)
        if t[2] <= 1e-6:
            out.append(np.full(len(o.edges), 1e3))
            continue
        rays = camera.unproject(o.edges.points_px)
        r, valid = _residuals(camera, rays, o.edges, R, t, layout.delta(x, k))
        out.append(np.where(valid & np.isfinite(r), r, 1e3))
    return np.concatenate(out)


def bundle_adjust(obs: list[TargetView], initial: CameraModel, n_views: int,
                  options: TargetCalibrationOptions | None = None, view_names: list[str] | None = None
                  ) -> CalibrationResult:
    """Jointly refine the camera, the target poses and the per-view exposure biases from ``obs`` (the edge points
    of every target in every view, e.g. from :func:`observe`), starting from ``initial`` and the poses in
    ``obs``. Views with large residuals are dropped (``options``) and the adjustment run again."""
    return _bundle_adjust(obs, initial, n_views, options, view_names)[0]


def _bundle_adjust(obs: list[TargetView], initial: CameraModel, n_views: int,
                   options: TargetCalibrationOptions | None = None, view_names: list[str] | None = None,
                   delta_groups: list[int] | None = None, own_delta: set[tuple[int, int]] | None = None
                   ) -> tuple[CalibrationResult, list[TargetView]]:
    """:func:`bundle_adjust`, and the observations of the views kept with their fitted poses and exposure
    biases. ``delta_groups`` (one entry per view): views with the same entry share one exposure bias (overrides
    ``options.delta_per_target``), except the (view, target id) pairs of ``own_delta``, which have one each.
    """
    options = options or TargetCalibrationOptions()
    names = view_names or [f"view{i}" for i in range(n_views)]
    rejected: list[RejectedView] = []
    keep_views = sorted({o.view for o in obs})
    camera = initial
    while True:
        if len(keep_views) < options.min_views:
            raise ValueError(f"{len(keep_views)} views with targets, at least {options.min_views} needed")
        used = [o for o in obs if o.view in keep_views]
        fit = _adjust(used, camera, n_views, options, delta_groups, own_delta)
        used = fit["obs"]  # without the outliers
        per_view = {v: float(np.sqrt(np.mean(np.concatenate(
            [fit["residuals"][k] for k, o in enumerate(used) if o.view == v]) ** 2))) for v in keep_views}
        median = float(np.median(list(per_view.values())))
        worst = max(per_view, key=per_view.get)  # type: ignore[arg-type]
        limit = max(options.reject_factor * median, options.reject_min_px)
        if per_view[worst] <= limit or len(keep_views) <= options.min_views:
            break
        reason = (f"RMS {per_view[worst]:.3f} px > {limit:.3f} px ({options.reject_factor:g} x the median "
                  f"{median:.3f} px)")
        log.warning("view %s rejected: %s; adjusting again", names[worst], reason)
        rejected.append(RejectedView(names[worst], per_view[worst], reason))
        keep_views.remove(worst)
        camera = fit["camera"]
    points = [np.concatenate([o.edges.points_px for o in used if o.view == v]) for v in keep_views]
    residuals = [np.concatenate([fit["residual_vectors"][k] for k, o in enumerate(used) if o.view == v])
                 for v in keep_views]
    all_r = np.concatenate(fit["residuals"])
    deltas = {names[v]: fit["deltas"][v] for v in keep_views}
    extra = {"delta_px": deltas, "compensated": options.compensate, "evaluations": fit["nfev"],
             "uncertainty_views": fit["uncertainty_views"].to_dict(),
             "neighbour_correlation": fit["neighbour_correlation"],
             "edge_points": int(len(all_r)), "targets_in_views": len(used)}
    result = CalibrationResult(camera=fit["camera"], uncertainty=fit["uncertainty"],
                               rms_px=float(np.sqrt(np.mean(all_r ** 2))),
                               view_names=[names[v] for v in keep_views],
                               per_view_rms_px=np.array([per_view[v] for v in keep_views]), points_px=points,
                               residuals_px=residuals, rejected=rejected, extra=extra)
    return result, fit["fitted"]


def _adjust(obs: list[TargetView], initial: CameraModel, n_views: int, options: TargetCalibrationOptions,
            delta_groups: list[int] | None = None, own_delta: set[tuple[int, int]] | None = None) -> dict:
    free = ["fx"] if options.same_focal else ["fx", "fy"]
    free += ["cx", "cy", "k1", "k2"]
    if options.fit_tangential:
        free += ["p1", "p2"]
    if options.fit_k3:
        free += ["k3"]
    start_camera = initial
    if options.same_focal:
        f = 0.5 * (initial.fx + initial.fy)
        start_camera = CameraModel(initial.width, initial.height, f, f, initial.cx, initial.cy, initial.dist,
                                   initial.bit_depth)
    if delta_groups is not None:  # shared by the views of a group, numbered 0.. over the groups present; a
        # (view, target) in own_delta has one of its own
        own = own_delta or set()
        keys = [(1, o.view, o.target_id) if (o.view, o.target_id) in own else (0, delta_groups[o.view], 0)
                for o in obs]
        present = sorted(set(keys))
        slots = [present.index(k) for k in keys]
    else:
        slots = list(range(len(obs))) if options.delta_per_target else [o.view for o in obs]
    layout = _Layout(free, max(slots, default=-1) + 1, len(obs), options.compensate, start_camera, slots)
    values = {"fx": start_camera.fx, "fy": start_camera.fy, "cx": start_camera.cx, "cy": start_camera.cy,
              **dict(zip(("k1", "k2", "p1", "p2", "k3"), start_camera.dist, strict=True))}
    x0 = np.zeros(layout.size)
    x0[:layout.n_camera] = [values[k] for k in free]
    for k, o in enumerate(obs):
        R0 = o.pose.R
        layout.frames.append((R0, R0[:, :2]))  # tilt about the target's own x and y axes
        x0[layout.pose_slice(k)] = [0.0, 0.0, *o.pose.t]
    if options.compensate:  # each view's delta starts from its targets' (the tracker's pose fits)
        for slot in range(layout.n_delta):
            d = [o.delta_px for o, s in zip(obs, slots, strict=True) if s == slot]
            x0[layout.delta_index(slot)] = float(np.median(d)) if d else 0.0
    # typical parameter changes: px for fx..cy, 1e-2 for the distortion, mrad and mm for poses, 0.1 px for delta
    typical = {"fx": 1.0, "fy": 1.0, "cx": 1.0, "cy": 1.0, "k1": 1e-2, "k2": 1e-2, "p1": 1e-3, "p2": 1e-3,
               "k3": 1e-2}
    x_scale = np.full(layout.size, 0.1)
    x_scale[:layout.n_camera] = [typical[k] for k in free]
    for k in range(len(obs)):
        x_scale[layout.pose_slice(k)] = [1e-3] * 5
    sol = _solve(x0, x_scale, layout, obs, options.max_nfev)
    if options.outlier_sigmas is not None:  # drop the outliers (code dots, clutter next to an edge), solve again
        r = _residual_vector(sol.x, layout, obs)
        robust_sd = 1.4826 * float(np.median(np.abs(r - np.median(r))))
        # at most 1 % of the points: a biased fit (delta held at 0 on an over-exposed view) must not lose whole
        # circles as "outliers"
        limit = max(options.outlier_sigmas * robust_sd, float(np.quantile(np.abs(r), 0.99)), 1e-3)
        offsets = np.cumsum([0] + [len(o.edges) for o in obs])
        inliers = [np.abs(r[a:b]) <= limit for a, b in zip(offsets[:-1], offsets[1:], strict=True)]
        n_out = sum(int((~m).sum()) for m in inliers)
        if n_out:
            log.info("%d of %d edge points beyond %.3f px left out", n_out, len(r), limit)
            obs = [TargetView(o.view, o.target_id, o.edges.subset(m), o.pose, o.delta_px)
                   for o, m in zip(obs, inliers, strict=True)]
            sol = _solve(sol.x, x_scale, layout, obs, options.max_nfev)
    x = sol.x
    camera = layout.camera(x)
    residuals, vectors = [], []
    for k, o in enumerate(obs):
        R, t = layout.pose(x, k)
        rays = camera.unproject(o.edges.points_px)
        r, _ = _residuals(camera, rays, o.edges, R, t, layout.delta(x, k))
        _, normal_bw, _ = _model(camera, rays, o.edges, R, t)
        residuals.append(r)
        vectors.append(normal_bw * r[:, None])  # measured minus model edge, along the black-to-white normal
    # covariance of the camera parameters: (J^T J)^-1 scaled by the residual variance (the Huber weights left out)
    # and by the correlation of neighbouring edge points (see neighbour_correlation)
    J = np.asarray(sol.jac)
    all_r = np.concatenate(residuals)
    dof = max(len(all_r) - layout.size, 1)
    s2 = float(np.sum(all_r ** 2) / dof)
    rho = neighbour_correlation(residuals)
    try:
        inverse = np.linalg.pinv(J.T @ J)
        cov = inverse * s2 * (1.0 + 2.0 * rho)
        std = np.sqrt(np.clip(np.diag(cov)[:layout.n_camera], 0, None))
        std_views = _view_clustered_std(J, residuals, [o.view for o in obs], inverse)[:layout.n_camera]
    except np.linalg.LinAlgError:
        std = std_views = np.full(layout.n_camera, np.nan)
    by_name = dict(zip(free, std, strict=True))
    if options.same_focal:
        by_name["fy"] = by_name["fx"]
    uncertainty = CameraUncertainty.from_vector(np.array([by_name.get(k, 0.0) for k in CAMERA_PARAMS]))
    deltas = {v: float(np.mean([layout.delta(x, k) for k, o in enumerate(obs) if o.view == v]))
              for v in sorted({o.view for o in obs})}
    fitted = []
    for k, o in enumerate(obs):
        R, t = layout.pose(x, k)
        fitted.append(TargetView(o.view, o.target_id, o.edges, Pose(R, np.asarray(t, dtype=np.float64)),
                                 layout.delta(x, k)))
    by_name_views = dict(zip(free, std_views, strict=True))
    if options.same_focal:
        by_name_views["fy"] = by_name_views["fx"]
    uncertainty_views = CameraUncertainty.from_vector(np.array([by_name_views.get(k, 0.0) for k in CAMERA_PARAMS]))
    return {"camera": camera, "uncertainty": uncertainty, "uncertainty_views": uncertainty_views,
            "residuals": residuals, "residual_vectors": vectors,
            "deltas": deltas, "nfev": int(sol.nfev), "obs": obs, "fitted": fitted, "neighbour_correlation": rho}


def _view_clustered_std(J: FloatArray, residuals: list[FloatArray], views: list[int],
                        inverse: FloatArray) -> FloatArray:
    """1-sigma of every parameter from the views' scatter (a cluster-robust "sandwich" covariance, each view one
    cluster): (J^T J)^-1 (sum over views of g_v g_v^T) (J^T J)^-1 x V / (V - 1), g_v = J_v^T r_v. Any correlation
    of the errors within a view (neighbouring profiles, a target's shared contrast) is in it; noisy with few
    views."""
    offsets = np.cumsum([0] + [len(r) for r in residuals])
    scores: dict[int, FloatArray] = {}
    for k, view in enumerate(views):
        g = J[offsets[k]:offsets[k + 1]].T @ residuals[k]
        scores[view] = scores.get(view, 0.0) + g
    n = len(scores)
    if n < 2:
        return np.full(J.shape[1], np.nan)
    G = np.array(list(scores.values()))
    cov = inverse @ (G.T @ G) @ inverse * (n / (n - 1))
    return np.sqrt(np.clip(np.diag(cov), 0, None))


def neighbour_correlation(residuals: list[FloatArray], limit: float = 0.5) -> float:
    """The correlation of consecutive edge points' residuals (each array in its points' order: along each circle
    for the edges measured again), clipped to [0, ``limit``]. Neighbouring edge profiles (1.5 px apart, each a
    strip 0.5 px to either side of its normal, sampled by bilinear interpolation) share pixels, so their noise is
    correlated and the points carry less information than as many independent ones: for a pattern that varies
    slowly along the circles (what sets the focal length, the distortion) the variance is (1 + 2 rho) times the
    independent one (lag 2 and beyond measured at 0.00 +- 0.005). In the 16-view simulation (x0.25, true camera
    and poses, 12 noise draws) rho = 0.26; the calibrations' errors over 10 noise draws were 1.09-1.46 times their
    unscaled 1-sigma (RMS z-score) at x0.25-x4, the same points with independent noise 1.08 times."""
    num = den_a = den_b = 0.0
    for r in residuals:
        if len(r) < 3:
            continue
        a, b = r[:-1] - r.mean(), r[1:] - r.mean()
        num += float(a @ b)
        den_a += float(a @ a)
        den_b += float(b @ b)
    if den_a <= 0 or den_b <= 0:
        return 0.0
    return float(np.clip(num / np.sqrt(den_a * den_b), 0.0, limit))


def _solve(x0: FloatArray, x_scale: FloatArray, layout: _Layout, obs: list[TargetView], max_nfev: int):
    """Levenberg-Marquardt (MINPACK) with the Jacobian by central differences over column groups: every camera
    column alone, then each of the 5 pose parameters of every target at once (their rows are disjoint), then all
    the deltas at once: 2 x (n_camera + 6) evaluations per Jacobian, however many views."""
    steps = 1e-4 * x_scale
    groups: list[list[int]] = [[j] for j in range(layout.n_camera)]
    groups += [[layout.pose_slice(k).start + j for k in range(layout.n_obs)] for j in range(5)]
    if layout.compensate:
        groups.append([layout.delta_index(slot) for slot in range(layout.n_delta)])
    rows = np.concatenate([np.full(len(o.edges), k) for k, o in enumerate(obs)])
    slot_of_row = np.array(layout.delta_slot)[rows]

    def jacobian(x: FloatArray, *_: object) -> FloatArray:
        J = np.zeros((len(rows), layout.size))
        for group in groups:
            dx = np.zeros_like(x)
            dx[group] = steps[group]
            diff = (_residual_vector(x + dx, layout, obs) - _residual_vector(x - dx, layout, obs))
            if len(group) == 1:
                J[:, group[0]] = diff / (2 * steps[group[0]])
                continue
            for column in group:  # each row belongs to the one column of its own target / view in the group
                if column >= layout.n_camera + 5 * layout.n_obs:
                    mine = slot_of_row == column - (layout.n_camera + 5 * layout.n_obs)
                else:
                    mine = rows == (column - layout.n_camera) // 5
                J[mine, column] = diff[mine] / (2 * steps[column])
        return J

    sol = least_squares(_residual_vector, x0, jac=jacobian, args=(layout, obs), method="lm", x_scale=x_scale,
                        max_nfev=max_nfev, xtol=1e-10, ftol=1e-12)
    log.info("bundle adjustment: %s (%d evaluations, %d Jacobians, cost %.4g)", sol.message, sol.nfev, sol.njev,
             sol.cost)
    return sol


def calibrate_targets(images: list[npt.NDArray], targets: list[TargetSpec], initial: CameraModel,
                      exposures_us: list[float | None] | None = None, names: list[str] | None = None,
                      options: TargetCalibrationOptions | None = None,
                      tracker_options: TrackerOptions | None = None) -> CalibrationResult:
    """Detect the targets in ``images`` under ``initial`` (the tracker's poses start the adjustment), then
    :func:`bundle_adjust`; with ``options.refine_edges`` the edges are measured again under that solution
    (:func:`refine_observations`) and adjusted again. Views without a usable target are reported in
    ``rejected``."""
    options = options or TargetCalibrationOptions()
    names = names or [f"view{i}" for i in range(len(images))]
    tracker_options = tracker_options or TrackerOptions(compensate_exposure=options.compensate)
    obs, missing = observe(images, exposures_us, initial, targets, tracker_options)
    missing = [RejectedView(names[int(m.name)], m.rms_px, m.reason) for m in missing]
    for m in missing:
        log.warning("view %s rejected: %s", m.name, m.reason)
    result, fitted = _bundle_adjust(obs, initial, len(images), options, names)
    first_fx, rejected = result.camera.fx, list(result.rejected)
    margin = tracker_options.clip_margin_dn
    level = float(initial.saturation_level)
    margin_dn = CLIP_MARGIN_FRACTION * level if margin is None else float(margin)
    # the camera's level, or lower where the views show its pixels clip lower (``clip_level``)
    saturation = min([frame_saturation_dn(im, level, margin_dn) for im in images], default=level) - margin_dn
    # one exposure bias per exposure time (per view when unknown): the edges are now measured alike on every
    # circle, so what is left of the bias depends on the exposure and the optics, not on the target; and a
    # target whose inner circle is too close to the design's other edges to be measured keeps only its outer
    # circle, where a bias of its own would be a second scale (in the 12-view test scene of
    # tests/test_calibrate_targets.py such deltas went to -4 and +0.9 px)
    groups = _exposure_groups(exposures_us, len(images))
    blur, blur_std, edge_options = None, None, options.edges
    passes, planned = 0, options.refine_passes if options.refine_edges else 0
    while passes < planned:
        passes += 1
        edge_options, previous = options.edges, blur
        if edge_options.sigma_px is None:
            blur, blur_std = estimate_blur_with_std(images, fitted, result.camera, targets, saturation,
                                                    edge_options)
            edge_options = replace(edge_options, sigma_px=blur)
        refined = refine_observations(images, fitted, result.camera, targets, saturation, edge_options)
        own = _own_delta(refined, options) if blur is not None else set()
        result, fitted = _bundle_adjust(refined, result.camera, len(images), options, names, groups, own)
        rejected += result.rejected
        result = CalibrationResult(**{**result.__dict__, "extra": {
            **result.extra, "refined_edges": True, "blur_px": edge_options.sigma_px, "first_pass_fx": first_fx,
            "refine_passes": passes, "own_delta_targets": len(own)}})
        moved = blur is not None and previous is not None and abs(blur - previous) > options.blur_tolerance_px
        if passes == planned and moved and passes < options.max_refine_passes:
            planned += 1
    if blur is not None and blur_std is not None and options.blur_uncertainty:
        result = _with_blur_uncertainty(result, images, fitted, targets, saturation, edge_options, blur, blur_std,
                                        options, names, groups, own)
    result = CalibrationResult(**{**result.__dict__, "rejected": rejected})
    return CalibrationResult(**{**result.__dict__, "rejected": missing + result.rejected})


def _with_blur_uncertainty(result: CalibrationResult, images: list[npt.NDArray], fitted: list[TargetView],
                           targets: list[TargetSpec], saturation: float, edge_options: EdgeOptions, blur: float,
                           blur_std: float, options: TargetCalibrationOptions, names: list[str],
                           groups: list[int], own: set[tuple[int, int]]) -> CalibrationResult:
    """``result`` with the blur estimate's uncertainty added to its 1-sigma (``options.blur_uncertainty``): the
    camera's change per px of blur, by central differences (the edges measured again at blur +- h where the
    solution puts them and adjusted again from it, ``options.blur_passes`` times), times ``blur_std``, added in
    quadrature. The derivative, the
    blur's 1-sigma and the 1-sigma without it go to ``extra``."""
    h = options.blur_step_px
    cameras = []
    for sigma in (blur - h, blur + h):
        camera, views = result.camera, fitted
        for _ in range(max(options.blur_passes, 1)):
            refined = refine_observations(images, views, camera, targets, saturation,
                                          replace(edge_options, sigma_px=sigma))
            side, views = _bundle_adjust(refined, camera, len(images), options, names, groups, own)
            camera = side.camera
        cameras.append(camera)
    lo, hi = (_camera_vector(c) for c in cameras)
    slope = (hi - lo) / (2 * h)  # per px of blur; 0 for the parameters held fixed
    before = _uncertainty_vector(result.uncertainty)
    after = np.sqrt(before ** 2 + (slope * blur_std) ** 2)
    after[before == 0] = 0.0  # held fixed
    log.info("blur %.3f +- %.3f px: 1-sigma fx %.4f -> %.4f px, k1 %.6f -> %.6f", blur, blur_std, before[0],
             after[0], before[4], after[4])
    extra = {**result.extra, "blur_std_px": blur_std,
             "d_camera_d_blur": dict(zip(CAMERA_PARAMS, slope.tolist(), strict=True)),
             "uncertainty_without_blur": result.uncertainty.to_dict()}
    return CalibrationResult(**{**result.__dict__, "uncertainty": CameraUncertainty.from_vector(after),
                                "extra": extra})


def _own_delta(observations: list[TargetView], options: TargetCalibrationOptions) -> set[tuple[int, int]]:
    """(view, target id) of the targets whose edges were measured on at least two circles with
    ``options.own_delta_min_points`` points each: with ``options.own_delta`` they get an exposure bias of their own
    in the adjustments of clipped views after the edges are measured again (a target with one circle keeps its
    exposure's: its own bias would trade with its distance, a second scale)."""
    if not options.own_delta:
        return set()
    out = set()
    for o in observations:
        _, counts = np.unique(o.edges.radius_m, return_counts=True)
        if int(np.sum(counts >= options.own_delta_min_points)) >= 2:
            out.add((o.view, o.target_id))
    return out


def _camera_vector(camera: CameraModel) -> FloatArray:
    """(fx, fy, cx, cy, k1, k2, p1, p2, k3), the order of ``CAMERA_PARAMS``."""
    return np.array([camera.fx, camera.fy, camera.cx, camera.cy, *camera.dist], dtype=np.float64)


def _uncertainty_vector(u: CameraUncertainty) -> FloatArray:
    return np.array([u.fx, u.fy, u.cx, u.cy, *u.dist], dtype=np.float64)


def _exposure_groups(exposures_us: list[float | None] | None, n_views: int) -> list[int]:
    """Per view its group: views with the same exposure time share one; a view without one is alone."""
    out, seen = [], {}
    for i in range(n_views):
        e = None if exposures_us is None else exposures_us[i]
        key = ("view", i) if e is None else ("us", round(float(e), 3))
        out.append(seen.setdefault(key, len(seen)))
    return out


def refine_observations(images: list[npt.NDArray], fitted: list[TargetView], camera: CameraModel,
                        targets: list[TargetSpec], saturation: float, options: EdgeOptions,
                        min_points: int = 30) -> list[TargetView]:
    """The edge points of every target of every view measured again where ``camera`` and each fitted pose put
    its circles (``livetrack.calibration.edges.measure_edges``), with the fitted pose and exposure bias as the
    next adjustment's start; a target left with fewer than ``min_points`` is left out (its earlier points carry
    the errors this avoids)."""
    by_id = {t.id: t for t in targets}
    out = []
    for o in fitted:
        got = measure_edges(images[o.view], camera, o.pose, by_id[o.target_id], saturation, o.delta_px, options)
        if len(got.edges) >= min_points:
            out.append(TargetView(o.view, o.target_id, got.edges, o.pose, o.delta_px))
        else:
            log.info("view %d target %d: %d edge points clear of the design's other edges, left out", o.view,
                     o.target_id, len(got.edges))
    return out


BLUR_GRID_PX = (0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.2, 1.5)
"""Blur widths tried by :func:`estimate_blur` (px)."""


def estimate_blur(images: list[npt.NDArray], fitted: list[TargetView], camera: CameraModel,
                  targets: list[TargetSpec], saturation: float, options: EdgeOptions,
                  min_clipped_share: float = 0.2) -> float | None:
    """The PSF width (px) for profiles clipped on one side, where the edge fit cannot measure it per point: the
    value of ``BLUR_GRID_PX`` (refined by a parabola through its neighbours) that gives the smallest mean squared
    profile residual over the points of every target of every view that fit ok at every value tried (a mean over
    the ok fits alone chose 0.5 px at x16: the profiles that fail there leave the cost). None when fewer than
    ``min_clipped_share`` of the profiles are clipped (the edge fit then takes the median blur of the unclipped
    ones itself). In the 16-view simulation (PSF 0.8 px) the residual has a clear minimum at 0.8 px at x4 and a
    shallow one at x16; with the tracker's fallback of 1.0 px the edges' errors vary with the curvature (0.014 px
    RMS) and fx moved by +0.15 % at x4 (true camera and poses, noise-free)."""
    return estimate_blur_with_std(images, fitted, camera, targets, saturation, options, min_clipped_share)[0]


def estimate_blur_with_std(images: list[npt.NDArray], fitted: list[TargetView], camera: CameraModel,
                           targets: list[TargetSpec], saturation: float, options: EdgeOptions,
                           min_clipped_share: float = 0.2) -> tuple[float | None, float | None]:
    """:func:`estimate_blur` and its 1-sigma (px) from a jackknife over the views: the estimate made again
    without each view in turn (the same profile residuals, no new measurement), variance (V - 1) / V times the
    sum of the squared deviations from their mean. None for the 1-sigma when fewer than 3 views have points."""
    by_id = {t.id: t for t in targets}
    # only profiles clear of other edges by the full margin on both sides: on the white side of a clipped edge
    # the shorter margin is enough for its position, not for the residual's dependence on the blur
    options = replace(options, clipped_white_margin_px=options.margin_px)

    def measure(sigma: float) -> tuple[FloatArray, FloatArray, int]:
        """Every sampled point's profile residual RMS (NaN where not ok), its view, how many ok profiles were
        clipped."""
        got = [measure_edges(images[o.view], camera, o.pose, by_id[o.target_id], saturation, o.delta_px,
                             replace(options, sigma_px=sigma)) for o in fitted]
        views = [np.full(len(g.residual_rms), o.view) for g, o in zip(got, fitted, strict=True)]
        return (np.concatenate([g.residual_rms for g in got] or [np.zeros(0)]),
                np.concatenate(views or [np.zeros(0, dtype=int)]), sum(g.clipped for g in got))

    first, view_of, clipped = measure(BLUR_GRID_PX[3])
    ok = np.isfinite(first)
    if not ok.any() or clipped < min_clipped_share * int(ok.sum()):
        return None, None
    rms = np.array([measure(s)[0] if k != 3 else first for k, s in enumerate(BLUR_GRID_PX)])
    common = np.isfinite(rms).all(axis=0)  # the points every blur fits: a failed fit must not lower the cost
    if not common.any():
        return None, None
    blur = _blur_vertex(np.mean(rms[:, common] ** 2, axis=1))
    views = np.unique(view_of[common])
    if len(views) < 3:
        return blur, None
    leave_out = np.array([_blur_vertex(np.mean(rms[:, common & (view_of != v)] ** 2, axis=1)) for v in views])
    n = len(views)
    return blur, float(np.sqrt((n - 1) / n * np.sum((leave_out - leave_out.mean()) ** 2)))


def _blur_vertex(costs: FloatArray) -> float:
    """The blur of the smallest cost over ``BLUR_GRID_PX``, refined by the vertex of the parabola through the
    three points around it."""
    best = int(np.argmin(costs))
    if 0 < best < len(BLUR_GRID_PX) - 1:
        x, y = np.array(BLUR_GRID_PX[best - 1:best + 2]), np.array(costs[best - 1:best + 2])
        a, b, _ = np.polyfit(x, y, 2)
        if a > 0:
            return float(np.clip(-b / (2 * a), x[0], x[2]))
    return float(BLUR_GRID_PX[best])
