"""A bias shared by all the edges of one circle, in the pose covariance (livetrack/estimator/shared_edge_bias.py):
the fit's gain against re-solved fits, a bias common to every circle moving delta alone, the distance's
standard deviation honest on edges whose circles are each offset as a whole (which the residuals cannot show), and
the tracker reporting the wider covariance with the same poses."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from livetrack.camera import CameraModel
from livetrack.estimator import pose_kernels
from livetrack.estimator.pose_fit import CircleEdgePoints, circle_bias_gain_reference, fit_pose
from livetrack.estimator.shared_edge_bias import circle_bias_covariance, with_circle_bias
from livetrack.geometry import Pose, look_rotation
from tests.circle_edges import circle_edge_points

CAMERA = CameraModel(1920, 1200, 1800.0, 1800.0, 959.5, 599.5, (-0.1, 0.0, 0.0, 0.0, 0.0), 12)
RADII_M = (0.125, 0.0688, 0.025, 0.0138)  # two fractal levels: each a ring's outer and inner circle
WHITE_OUTSIDE = (True, False, True, False)


def edges(pose: Pose, per_circle: int = 240) -> tuple[CircleEdgePoints, np.ndarray]:
    """Exact edge points of the four circles seen at ``pose`` (std 0.05 px) and their black-to-white normals."""
    return circle_edge_points(CAMERA, pose, RADII_M, WHITE_OUTSIDE, per_circle, 0.05)


def shifted(obs: CircleEdgePoints, n_bw: np.ndarray, by_circle_px: dict[float, float]) -> CircleEdgePoints:
    """``obs`` with the points of each circle (by radius) moved by its bias along their black-to-white normals (which
    adds the bias to their residuals)."""
    shift = np.array([by_circle_px.get(float(r), 0.0) for r in obs.radius_m])
    return dataclasses.replace(obs, points_px=obs.points_px + shift[:, None] * n_bw)


def params(fit) -> np.ndarray:
    return np.array([*fit.pose.t, fit.delta_px])


POSE = Pose(look_rotation(35.0, 60.0, 0.0), np.array([0.2, -0.1, 3.0]))


@pytest.mark.parametrize("circle", range(4))
def test_the_gain_is_how_a_re_solved_fit_moves(circle):
    obs, n_bw = edges(POSE)
    fit = fit_pose(CAMERA, obs, POSE)
    assert fit.ok and fit.circle_bias_gain.shape == (6, 4)
    b = 0.05
    moved = fit_pose(CAMERA, shifted(obs, n_bw, {RADII_M[circle]: b}), fit.pose, delta_px=fit.delta_px)
    assert moved.ok
    got = params(moved) - params(fit)
    order = np.argsort(RADII_M)  # the gain's columns are by ascending radius
    want = b * fit.circle_bias_gain[[0, 1, 2, 5], list(order).index(circle)]
    np.testing.assert_allclose(got, want, rtol=0.02, atol=1e-9)
    assert np.linalg.norm(got[:3]) > 1e-6  # one circle alone moves the position, not just delta


@pytest.mark.parametrize("seed", range(4))
def test_compiled_gain_is_the_reference(seed):
    rng = np.random.default_rng(seed)
    n, p = int(rng.integers(12, 800)), int(rng.choice([5, 6]))
    J, w = rng.normal(size=(n, 6)), rng.uniform(0.1, 400.0, n)
    radius = rng.choice([0.125, 0.0688, 0.025, 0.0138, 0.006][: int(rng.integers(1, 6))], n)  # in any order
    got, status = pose_kernels.circle_bias_gain(np.ascontiguousarray(J[:, :p]), w, radius, p)
    want = circle_bias_gain_reference(J[:, :p], w, radius)
    assert status == 0 and got.shape == want.shape == (p, len(np.unique(radius)))
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())
    J[:, 2] = 0.0  # a parameter no residual moves: singular, NaN and status 1 (the reference: None)
    got, status = pose_kernels.circle_bias_gain(np.ascontiguousarray(J[:, :p]), w, radius, p)
    assert status == 1 and np.all(np.isnan(got)) and circle_bias_gain_reference(J[:, :p], w, radius) is None


def test_a_bias_common_to_every_circle_moves_delta_alone():
    obs, n_bw = edges(POSE)
    fit = fit_pose(CAMERA, obs, POSE)
    np.testing.assert_allclose(fit.circle_bias_gain.sum(axis=1), [0, 0, 0, 0, 0, -1], atol=1e-9)
    moved = fit_pose(CAMERA, shifted(obs, n_bw, {r: 0.1 for r in RADII_M}), fit.pose, delta_px=fit.delta_px)
    np.testing.assert_allclose(moved.pose.t, fit.pose.t, atol=1e-7)
    assert moved.delta_px - fit.delta_px == pytest.approx(-0.1, abs=1e-5)
    # without delta estimated, the same bias moves the pose, and the gain says so
    fixed = fit_pose(CAMERA, obs, POSE, estimate_delta=False)
    assert fixed.circle_bias_gain.shape == (5, 4)
    assert np.linalg.norm(fixed.circle_bias_gain.sum(axis=1)[:3]) > 1e-4


def distance_z(fit, truth: Pose) -> float:
    t = fit.pose.t
    sd_m = np.sqrt(t @ fit.covariance[:3, :3] @ t) / np.linalg.norm(t)
    return abs(np.linalg.norm(t) - truth.distance_m) / sd_m


def z_plain_and_widened(rng: np.random.Generator, offsets, widen, n: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """Distance errors over sd of ``n`` random poses whose circles are offset as a whole (``offsets(rng)``: radius ->
    px) plus independent noise of 0.05 px per point: of the plain fit and of ``widen(fit)``, whose pose must be the
    fit's."""
    plain, wide = [], []
    for _ in range(n):
        pose = Pose(look_rotation(float(rng.uniform(0, 60)), float(rng.uniform(0, 360)), 0.0),
                    np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.uniform(2.0, 6.0)]))
        obs, n_bw = edges(pose)
        biased = shifted(obs, n_bw, offsets(rng))
        noisy = dataclasses.replace(biased, points_px=biased.points_px + rng.normal(0.0, 0.05, len(obs))[:, None]
                                    * n_bw)
        fit = fit_pose(CAMERA, noisy, pose)
        assert fit.ok
        widened = widen(fit)
        np.testing.assert_array_equal(widened.pose.t, fit.pose.t)  # the pose itself is untouched
        plain.append(distance_z(fit, pose))
        wide.append(distance_z(widened, pose))
    return np.array(plain), np.array(wide)


def test_the_distance_sd_is_honest_for_circles_offset_as_a_whole():
    """Each circle's edges offset by N(0, 0.03 px) as a whole, plus independent noise of 0.05 px per point: the
    edges' covariance claims far too little; with the floor at the bias's sd, about what a Gaussian gives."""
    plain, floored = z_plain_and_widened(np.random.default_rng(11),
                                         lambda rng: {r: float(rng.normal(0.0, 0.03)) for r in RADII_M},
                                         lambda fit: with_circle_bias(fit, 0.03))
    assert np.mean(plain <= 3.0) < 0.6
    assert np.mean(floored <= 3.0) >= 0.98
    assert 0.5 < np.median(floored) < 0.85


def test_no_gain_no_floor_and_failed_fits_alone():
    obs, _ = edges(POSE)
    fit = fit_pose(CAMERA, obs, POSE)
    assert with_circle_bias(fit, 0.0) is fit
    failed = dataclasses.replace(fit, ok=False, reason="test")
    assert with_circle_bias(failed, 0.03) is failed
    bare = dataclasses.replace(fit, circle_bias_gain=None)
    assert circle_bias_covariance(bare, 0.03) is None and with_circle_bias(bare, 0.03) is bare
    added = circle_bias_covariance(fit, 0.03)
    np.testing.assert_allclose(added, added.T, atol=1e-18)
    assert np.all(np.linalg.eigvalsh(added) >= -1e-15)
    np.testing.assert_allclose(circle_bias_covariance(fit, 0.06), 4.0 * added, rtol=1e-12)


def test_the_tracker_reports_the_floor_and_finds_the_same_poses():
    """paper-lab at x1 and x16, searched then tracked: the floor changes only the covariance, by its own share."""
    from livetrack.estimator.tracker import Tracker, TrackerOptions
    from tests.sweep_frames import paper_lab_frames

    scenario, frames = paper_lab_frames(0, [1.0, 16.0, 1.0, 16.0])

    def run(floor_px: float) -> list:
        tracker = Tracker(scenario.camera, scenario.targets, TrackerOptions(tracking=True,
                                                                            edge_bias_floor_px=floor_px))
        return [r for f in frames for r in tracker.process(f.image, f.exposure_us).targets]

    plain, floored = run(0.0), run(0.01)
    assert len(plain) == len(floored) >= 4
    for p, f in zip(plain, floored, strict=True):
        assert p.fit.ok and f.fit.ok
        np.testing.assert_array_equal(p.pose.t, f.pose.t)
        assert p.delta_px == f.delta_px
        if f.target_model is None:
            added = circle_bias_covariance(p.fit, 0.01)
            np.testing.assert_allclose(f.fit.covariance - p.fit.covariance, added, rtol=1e-6,
                                       atol=1e-9 * np.abs(added).max())
            assert f.fit.covariance[2, 2] > p.fit.covariance[2, 2]
