"""The pose covariance allows for edge residuals correlated along their circles (livetrack/estimator/
residual_correlation.py): the compiled sums against their numpy reference, the correlation time of known noise,
and the distance's standard deviation honest (about 99.7 % within 3 sd) on edges whose noise runs along the circle,
where the independent-points covariance claims far too little."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from livetrack.camera import CameraModel
from livetrack.estimator import pose_kernels
from livetrack.estimator import residual_correlation as rc
from livetrack.estimator.pose_fit import CircleEdgePoints, fit_pose
from livetrack.geometry import Pose, look_rotation
from tests.circle_edges import circle_edge_points

CAMERA = CameraModel(1920, 1200, 1800.0, 1800.0, 959.5, 599.5, (-0.1, 0.0, 0.0, 0.0, 0.0), 12)
RADII_M = (0.125, 0.05)
WHITE_OUTSIDE = (True, False)


def ar1(rng: np.random.Generator, n: int, phi: float) -> np.ndarray:
    """Unit-variance AR(1) noise: each value ``phi`` times the last plus fresh noise."""
    e = rng.normal(0.0, np.sqrt(1.0 - phi * phi), n)
    x = np.empty(n)
    x[0] = rng.normal()
    for i in range(1, n):
        x[i] = phi * x[i - 1] + e[i]
    return x


@pytest.mark.parametrize("seed", range(4))
def test_compiled_lagged_sums_are_the_references(seed):
    rng = np.random.default_rng(seed)
    r = rng.normal(size=int(rng.integers(10, 400)))
    cuts = np.sort(rng.choice(np.arange(1, len(r)), size=int(rng.integers(0, 5)), replace=False))
    starts = np.concatenate(([0], cuts, [len(r)])).astype(np.int64)
    want = rc._lagged_sums_numpy(r, starts, 30)
    got = pose_kernels.lagged_sums(r, starts, 30)
    np.testing.assert_allclose(got[0], want[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(got[1], want[1])


def test_circle_starts_are_the_runs_of_one_radius():
    np.testing.assert_array_equal(rc.circle_starts(np.array([0.1, 0.1, 0.05, 0.05, 0.05, 0.02])), [0, 2, 5, 6])
    np.testing.assert_array_equal(rc.circle_starts(np.zeros(0)), [0])


@pytest.mark.parametrize("kernels", ["numba", "numpy"])
def test_correlation_time_of_white_and_of_correlated_noise(kernels, monkeypatch):
    monkeypatch.setenv("LIVETRACK_KERNELS", kernels)
    rng = np.random.default_rng(1)
    radius = np.repeat([0.125, 0.05], 2000)
    assert rc.correlation_time(rng.normal(size=4000), radius) == pytest.approx(1.0, abs=0.15)
    # AR(1) with phi = 0.7: 1 + 2 sum phi^k = (1 + phi) / (1 - phi) = 5.67; the sum stops where phi^k < 0.05
    # (k = 9), which leaves out 2 phi^9 / (1 - phi) ~ 0.27
    r = np.concatenate([ar1(rng, 2000, 0.7), ar1(rng, 2000, 0.7)])
    assert rc.correlation_time(r, radius) == pytest.approx(5.4, rel=0.12)
    # two circles' runs are not joined: a step between them is no correlation within either
    stepped = np.concatenate([rng.normal(size=2000) + 3.0, rng.normal(size=2000) - 3.0])
    assert rc.correlation_time(stepped - stepped.mean(), radius) > 2.0  # each circle offset as a whole: correlated
    assert rc.correlation_time(np.zeros(100), np.full(100, 0.1)) == 1.0
    assert rc.correlation_time(np.full(5, 1.0), np.full(5, 0.1)) == 1.0  # too few points


def correlated_edges(pose: Pose, rng: np.random.Generator, noise_px: float, phi: float, per_circle: int = 400
                     ) -> CircleEdgePoints:
    """Edge points of the two circles in the tracker's order (by angle around each), moved along their normals by
    AR(1) noise of sd ``noise_px`` running along the circle, stated as independent noise of that sd."""
    obs, n_bw = circle_edge_points(CAMERA, pose, RADII_M, WHITE_OUTSIDE, per_circle, noise_px)
    shift = noise_px * np.concatenate([ar1(rng, per_circle, phi) for _ in RADII_M])
    return dataclasses.replace(obs, points_px=obs.points_px + shift[:, None] * n_bw)


def distance_z(fit, pose: Pose) -> float:
    t = fit.pose.t
    sd_m = np.sqrt(t @ fit.covariance[:3, :3] @ t) / np.linalg.norm(t)
    return abs(np.linalg.norm(t) - pose.distance_m) / sd_m


def test_the_distance_sd_is_honest_for_edges_correlated_along_the_circle():
    rng = np.random.default_rng(7)
    plain, allowed, taus = [], [], []
    for _ in range(150):
        pose = Pose(look_rotation(float(rng.uniform(0, 50)), float(rng.uniform(0, 360)), 0.0),
                    np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.uniform(2.0, 5.0)]))
        obs = correlated_edges(pose, rng, 0.1, 0.8)
        fit = fit_pose(CAMERA, obs, pose)
        assert fit.ok
        plain.append(distance_z(fit, pose))
        wide = rc.with_correlated_residuals(fit, obs)
        taus.append(float(wide.covariance[0, 0] / fit.covariance[0, 0]))
        allowed.append(distance_z(wide, pose))
        np.testing.assert_array_equal(wide.pose.t, fit.pose.t)  # the pose itself is untouched
    plain, allowed = np.array(plain), np.array(allowed)
    # independent-points covariance: far too sure (AR(1) at 0.8 has tau = 9: sd ~3x too small)
    assert np.mean(plain <= 3.0) < 0.8
    # with the correlation time: about what a Gaussian gives (99.7 % within 3 sd, median |z| 0.67)
    assert np.mean(allowed <= 3.0) >= 0.96
    assert 0.45 < np.median(allowed) < 0.95
    assert 5.0 < np.median(taus) < 10.0


def test_independent_edges_keep_their_covariance_within_noise():
    rng = np.random.default_rng(8)
    pose = Pose(look_rotation(30.0, 40.0, 0.0), np.array([0.1, 0.05, 3.0]))
    obs = correlated_edges(pose, rng, 0.05, 0.0)
    fit = fit_pose(CAMERA, obs, pose)
    wide = rc.with_correlated_residuals(fit, obs)
    assert 1.0 <= wide.covariance[2, 2] / fit.covariance[2, 2] < 1.2


def test_a_failed_fit_or_mismatched_points_are_left_alone():
    rng = np.random.default_rng(9)
    pose = Pose(look_rotation(20.0, 10.0, 0.0), np.array([0.0, 0.0, 3.0]))
    obs = correlated_edges(pose, rng, 0.1, 0.8)
    fit = fit_pose(CAMERA, obs, pose)
    failed = dataclasses.replace(fit, ok=False, reason="test")
    assert rc.with_correlated_residuals(failed, obs) is failed
    fewer = CircleEdgePoints(obs.points_px[:10], obs.radius_m[:10], obs.white_outside[:10], obs.std_px[:10])
    assert rc.with_correlated_residuals(fit, fewer) is fit


def test_the_tracker_reports_the_wider_covariance_and_finds_the_same_poses(monkeypatch):
    """On paper-lab frames (x1 and x16, searched then tracked), the correlation time changes only the reported
    covariance: the poses and deltas are those of a tracker without it, bit for bit, and the covariance is theirs
    times a factor of at least 1 (above 1 on these real-looking edges)."""
    from livetrack.estimator.tracker import Tracker, TrackerOptions
    from livetrack.estimator.tracker import tracker as tracker_module
    from tests.sweep_frames import paper_lab_frames

    scenario, frames = paper_lab_frames(0, [1.0, 16.0, 1.0, 16.0])

    def run() -> list:
        tracker = Tracker(scenario.camera, scenario.targets, TrackerOptions(compensate_exposure=True, tracking=True,
                                                                            edge_bias_floor_px=0.0))
        return [r for f in frames for r in tracker.process(f.image, f.exposure_us).targets]

    wide = run()
    monkeypatch.setattr(tracker_module, "with_correlated_residuals", lambda fit, obs: fit)
    plain = run()
    assert len(wide) == len(plain) >= 4
    factors = []
    for w, p in zip(wide, plain, strict=True):
        assert w.fit.ok and p.fit.ok
        np.testing.assert_array_equal(w.pose.t, p.pose.t)
        np.testing.assert_array_equal(w.pose.R, p.pose.R)
        assert w.delta_px == p.delta_px
        ratio = w.fit.covariance[:3, :3] / p.fit.covariance[:3, :3]
        factors.append(float(ratio[2, 2]))
        np.testing.assert_allclose(ratio, ratio[2, 2], rtol=1e-9)
    assert min(factors) >= 1.0 and max(factors) > 1.2, factors
