"""Concentric-circle closed form and the rigorous pose + exposure-bias fit, on exact synthetic edge points."""

import numpy as np
import pytest

from livetrack.camera import CameraModel
from livetrack.estimator.circle_pose import concentric_pose, fit_conic
from livetrack.estimator.pose_fit import CircleEdgePoints, _model, bias_weights, fit_pose
from livetrack.geometry import Pose, look_rotation, rotation_from_rotvec

CAMERA = CameraModel(1920, 1200, 1800.0, 1800.0, 959.5, 599.5, (-0.1, 0.0, 0.0, 0.0, 0.0), 12)
RADII_M = (0.125, 0.05, 0.025, 0.01)  # outer / inner of level 0, outer / inner of level 1
WHITE_OUTSIDE = (True, False, True, False)


def normal_angle_deg(R_a, R_b):
    return float(np.degrees(np.arccos(np.clip(R_a[:, 2] @ R_b[:, 2], -1.0, 1.0))))


def circle_points_norm(pose, radius_m, n=180):
    ang = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    X = pose.apply(np.column_stack([radius_m * np.cos(ang), radius_m * np.sin(ang), np.zeros(n)]))
    return X[:, :2] / X[:, 2:]


def edge_observations(pose, delta_px, noise_px, rng, per_circle=300):
    pts, rad, wo = [], [], []
    for r, o in zip(RADII_M, WHITE_OUTSIDE, strict=True):
        ang = rng.uniform(0.0, 2.0 * np.pi, per_circle)
        X = pose.apply(np.column_stack([r * np.cos(ang), r * np.sin(ang), np.zeros(per_circle)]))
        pts.append(CAMERA.project(X))
        rad += [r] * per_circle
        wo += [o] * per_circle
    obs = CircleEdgePoints(np.vstack(pts), np.array(rad), np.array(wo), np.full(len(rad), max(noise_px, 0.01)))
    _, n_bw, _ = _model(CAMERA, CAMERA.unproject(obs.points_px), obs, pose.R, pose.t)
    shift = -delta_px + rng.normal(0.0, noise_px, len(rad)) if noise_px else -delta_px
    moved = obs.points_px + np.asarray(shift).reshape(-1, 1) * n_bw
    return CircleEdgePoints(moved, obs.radius_m, obs.white_outside, obs.std_px)


@pytest.mark.parametrize("tilt_deg", [0.0, 0.5, 5.0, 30.0, 60.0])
def test_closed_form_recovers_centre_normal_and_distance(tilt_deg):
    pose = Pose(look_rotation(tilt_deg, 40.0, 10.0), np.array([0.3, -0.2, 3.0]))
    q_outer = fit_conic(circle_points_norm(pose, 0.125))
    q_inner = fit_conic(circle_points_norm(pose, 0.05))
    sol = concentric_pose(q_outer, q_inner, 0.125, 0.05)
    assert np.linalg.norm(sol.t_m - pose.t) < 1e-9
    assert normal_angle_deg(pose.R, np.column_stack([np.eye(3)[:, :2], sol.normal_cam])) < 1e-5
    assert sol.radius_ratio == pytest.approx(0.4, abs=1e-9)
    true_centre = pose.t[:2] / pose.t[2]
    assert np.linalg.norm(sol.centre_norm - true_centre) < 1e-12 + 1e-9


@pytest.mark.parametrize("tilt_deg", [3.0, 8.0])
def test_two_circles_do_not_flip_near_frontal_where_one_circle_is_ambiguous(tilt_deg):
    """Near-frontal, one circle has two poses that explain its image equally well (the "flip" of single-circle
    and square-marker methods): the rigorous fit on the outer circle alone, started from the mirrored normal,
    settles there with a residual as small as the true pose's. The concentric pair's closed form always picks
    the true normal."""
    rng = np.random.default_rng(7)
    flips_two, flipped_single = 0, 0
    for _ in range(10):
        pose = Pose(look_rotation(tilt_deg, rng.uniform(0, 360), 0.0),
                    np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), 2.5]))
        ray = pose.t / np.linalg.norm(pose.t)
        true_n = pose.R[:, 2]
        mirrored_n = 2.0 * (true_n @ ray) * ray - true_n  # the other single-circle solution

        noise = 0.1 / 1800  # 0.1 px at f = 1800, in normalized units
        pts_o = circle_points_norm(pose, 0.125) + rng.normal(0.0, noise, (180, 2))
        pts_i = circle_points_norm(pose, 0.05) + rng.normal(0.0, noise, (180, 2))
        sol = concentric_pose(fit_conic(pts_o), fit_conic(pts_i), 0.125, 0.05)
        if sol.normal_cam @ mirrored_n > sol.normal_cam @ true_n:
            flips_two += 1

        obs = edge_observations(pose, 0.0, 0.1, rng)
        outer = obs.subset(obs.radius_m == 0.125)
        axis = np.cross(true_n, mirrored_n)
        angle = np.arcsin(np.clip(np.linalg.norm(axis), 0, 1))
        R_m = rotation_from_rotvec(axis / np.linalg.norm(axis) * angle) @ pose.R
        fit_true = fit_pose(CAMERA, outer, pose, estimate_delta=False)
        fit_mirror = fit_pose(CAMERA, outer, Pose(R_m, pose.t), estimate_delta=False)
        if (fit_mirror.pose.R[:, 2] @ mirrored_n > fit_mirror.pose.R[:, 2] @ true_n
                and fit_mirror.residual_rms_px < 1.2 * fit_true.residual_rms_px):
            flipped_single += 1
    assert flips_two == 0
    assert flipped_single >= 8  # one circle cannot tell the two poses apart


@pytest.mark.parametrize("delta_px", [-1.0, 0.0, 0.7, 1.5])
def test_joint_fit_recovers_pose_and_exposure_bias(delta_px):
    rng = np.random.default_rng(3)
    pose = Pose(look_rotation(35.0, 20.0, 15.0), np.array([0.4, -0.2, 3.0]))
    obs = edge_observations(pose, delta_px, 0.05, rng)
    start = Pose(look_rotation(38.0, 25.0, 15.0), pose.t * 1.05)
    fit = fit_pose(CAMERA, obs, start)
    assert fit.ok
    sd = np.sqrt(np.diag(fit.covariance))
    assert abs(fit.delta_px - delta_px) < 4 * sd[6] + 1e-3
    assert np.all(np.abs(fit.pose.t - pose.t) < 4 * sd[:3] + 1e-6)
    assert normal_angle_deg(fit.pose.R, pose.R) < 0.02
    assert fit.residual_rms_px == pytest.approx(0.05, rel=0.15)


@pytest.mark.parametrize("delta_px", [0.0, 0.8])
def test_a_ring_on_darker_ground_takes_no_bias_on_its_outer_edge(delta_px):
    """Level 0's outer edge seen with its white inside (ink against darker ground: ``white_outside`` False there)
    and unmoved by the exposure, every other edge moved by ``delta_px`` into its black: the joint fit gives each
    edge its share (``bias_weights``: 0 on that edge) and recovers pose and delta; taking delta on it too would
    read the ring's thickness wrong."""
    rng = np.random.default_rng(5)
    pose = Pose(look_rotation(35.0, 20.0, 15.0), np.array([0.4, -0.2, 3.0]))
    obs = edge_observations(pose, delta_px, 0.05, rng)
    outer = obs.radius_m == RADII_M[0]
    clean = edge_observations(pose, 0.0, 0.0, np.random.default_rng(5))  # the same angles, unmoved
    points = np.where(outer[:, None], clean.points_px, obs.points_px)
    reversed_obs = CircleEdgePoints(points, obs.radius_m, obs.white_outside & ~outer, obs.std_px)
    assert np.array_equal(bias_weights(reversed_obs), np.where(outer, 0.0, 1.0))
    assert np.array_equal(bias_weights(obs), np.ones(len(obs)))
    fit = fit_pose(CAMERA, reversed_obs, Pose(look_rotation(38.0, 25.0, 15.0), pose.t * 1.05))
    assert fit.ok
    sd = np.sqrt(np.diag(fit.covariance))
    assert abs(fit.delta_px - delta_px) < 4 * sd[6] + 1e-3
    assert abs(fit.pose.distance_m / pose.distance_m - 1.0) < 4 * sd[2] / pose.distance_m + 1e-6


@pytest.mark.parametrize("share", [0.0, 0.3, 0.6])
def test_an_outer_edge_with_its_own_share_of_the_bias_is_fitted_with_it(share):
    """Level 0's outer edge (grey ground on its bright side: a target printed without a sheet) moved by ``share``
    of the white's bias, every other edge by all of it: with that share in ``CircleEdgePoints.bias_share``, the
    joint fit recovers pose and delta; with the white's bias on every edge (the share not given), the distance is
    off by many standard deviations."""
    delta_px = 1.2
    pose = Pose(look_rotation(35.0, 20.0, 15.0), np.array([0.4, -0.2, 3.0]))
    obs = edge_observations(pose, delta_px, 0.05, np.random.default_rng(9))
    outer = obs.radius_m == RADII_M[0]
    part = edge_observations(pose, share * delta_px, 0.05, np.random.default_rng(9))  # the same angles and noise
    points = np.where(outer[:, None], part.points_px, obs.points_px)
    weights = np.where(outer, share, 1.0)
    shared = CircleEdgePoints(points, obs.radius_m, obs.white_outside, obs.std_px, weights)
    assert np.array_equal(bias_weights(shared), weights)
    start = Pose(look_rotation(38.0, 25.0, 15.0), pose.t * 1.05)
    fit = fit_pose(CAMERA, shared, start)
    assert fit.ok
    sd = np.sqrt(np.diag(fit.covariance))
    assert abs(fit.delta_px - delta_px) < 4 * sd[6] + 1e-3
    assert abs(fit.pose.distance_m / pose.distance_m - 1.0) < 4 * sd[2] / pose.distance_m + 1e-6
    assert np.array_equal(shared.subset(outer).bias_share, np.full(outer.sum(), share))
    whole = fit_pose(CAMERA, CircleEdgePoints(points, obs.radius_m, obs.white_outside, obs.std_px), start)
    assert abs(whole.pose.distance_m - pose.distance_m) > 10 * sd[2]


def test_without_compensation_the_distance_is_biased_by_exposure():
    rng = np.random.default_rng(4)
    pose = Pose(look_rotation(20.0, 0.0, 0.0), np.array([0.0, 0.1, 3.0]))
    obs = edge_observations(pose, 1.0, 0.0, rng)
    naive = fit_pose(CAMERA, obs, pose, estimate_delta=False)
    joint = fit_pose(CAMERA, obs, pose)
    err_naive = naive.pose.distance_m / pose.distance_m - 1.0
    err_joint = joint.pose.distance_m / pose.distance_m - 1.0
    assert abs(err_naive) > 3e-3  # white grows: the ring thins; the distance is off by a few per mille
    assert abs(err_joint) < 1e-5  # numeric-Jacobian Gauss-Newton converges to ~1e-6 relative


def test_fit_with_too_few_points_is_a_value_not_an_exception():
    rng = np.random.default_rng(5)
    pose = Pose(np.eye(3), np.array([0.0, 0.0, 2.0]))
    obs = edge_observations(pose, 0.0, 0.0, rng, per_circle=1)
    fit = fit_pose(CAMERA, obs, pose)
    assert not fit
    assert "too few" in fit.reason


def test_a_fit_stopped_at_the_iteration_cap_is_not_ok_and_says_why():
    """From a start 5 % and 3 degrees off, one iteration cannot converge: the fit is falsy with the reason, and
    still carries the pose it reached (closer than the start); the default cap converges (a few iterations)."""
    rng = np.random.default_rng(6)
    pose = Pose(look_rotation(35.0, 20.0, 15.0), np.array([0.4, -0.2, 3.0]))
    obs = edge_observations(pose, 0.5, 0.05, rng)
    start = Pose(look_rotation(38.0, 25.0, 15.0), pose.t * 1.05)
    capped = fit_pose(CAMERA, obs, start, max_iterations=1)
    assert not capped.ok and not capped
    assert capped.iterations == 1 and "iteration cap" in capped.reason
    assert abs(capped.pose.distance_m - pose.distance_m) < abs(start.distance_m - pose.distance_m)
    full = fit_pose(CAMERA, obs, start)
    assert full.ok and full.reason == "" and 1 < full.iterations < 15


def test_a_fit_still_moving_by_under_a_standard_deviation_at_the_cap_gets_as_many_iterations_again(monkeypatch):
    """At the cap, a next step between ``STEP_SIGMA_TOL`` and ``EXTEND_STEP_SIGMA`` standard deviations (a slow,
    reweighted convergence) runs the iterations once more before the fit is judged; beyond it, it is judged."""
    from livetrack.estimator import pose_fit

    rng = np.random.default_rng(6)
    pose = Pose(look_rotation(35.0, 20.0, 15.0), np.array([0.4, -0.2, 3.0]))
    obs = edge_observations(pose, 0.5, 0.05, rng)
    start = Pose(look_rotation(38.0, 25.0, 15.0), pose.t * 1.05)
    monkeypatch.setattr(pose_fit, "EXTEND_STEP_SIGMA", np.inf)
    extended = fit_pose(CAMERA, obs, start, max_iterations=2)
    assert extended.ok and 2 < extended.iterations <= 4, extended.reason
    monkeypatch.setattr(pose_fit, "EXTEND_STEP_SIGMA", 0.0)
    judged = fit_pose(CAMERA, obs, start, max_iterations=2)
    assert not judged.ok and judged.iterations == 2 and "2 iterations" in judged.reason


@pytest.mark.parametrize("seed", [8, 9])
def test_edges_noisier_than_their_stated_uncertainty_still_converge(seed, monkeypatch):
    """Edge points scattered by 0.8 px whose stated uncertainty is 0.05 px (a phone photo: JPEG, sharpening, an
    uncalibrated lens): Huber at 3 stated sd would down-weight most points and crawl (an L1 fit) into the
    iteration cap; with the threshold rescaled by the residuals' robust sd the fit converges near the truth."""
    from livetrack.estimator import pose_fit

    rng = np.random.default_rng(seed)
    pose = Pose(look_rotation(30.0, 60.0, 0.0), np.array([0.2, 0.1, 2.5]))
    noisy = edge_observations(pose, 1.2, 0.8, rng, per_circle=150)
    obs = CircleEdgePoints(noisy.points_px, noisy.radius_m, noisy.white_outside, np.full(len(noisy), 0.05))
    start = Pose(look_rotation(33.0, 60.0, 0.0), pose.t * 1.03)
    fit = fit_pose(CAMERA, obs, start)
    assert fit.ok, fit.reason
    sd = np.sqrt(np.diag(fit.covariance))
    assert abs(fit.pose.t[2] - pose.t[2]) < 4 * sd[2] and abs(fit.delta_px - 1.2) < 4 * sd[6]
    monkeypatch.setattr(pose_fit, "HUBER_SCALE_MIN", np.inf)  # the threshold in stated sd, as before
    crawl = fit_pose(CAMERA, obs, start)
    # It crawls into the iteration cap (there its next step may be small enough, STEP_SIGMA_TOL, to count as
    # converged, or not); the rescaled threshold converges on the step size, in about half the iterations.
    assert crawl.iterations >= 15 and fit.iterations < 12  # (15 more when its next step is under 1 sd)


@pytest.mark.parametrize("dist", [(-0.1, 0.0, 0.0, 0.0, 0.0), (0.12, -0.25, 0.001, -0.002, 0.05),
                                  (0.0, 0.0, 0.0, 0.0, 0.0)], ids=["radial", "full", "none"])
def test_compiled_camera_kernels_give_the_camera_models_numbers(dist, monkeypatch):
    """The tracking path's compiled undistortion, projection and lens Jacobian (``pose_kernels.camera_kernels``)
    repeat ``CameraModel``'s arithmetic: the same numbers (NaN points included), not only close ones."""
    from livetrack.estimator import pose_fit, pose_kernels

    monkeypatch.setenv("LIVETRACK_KERNELS", "numba")
    camera = CameraModel(1920, 1200, 1800.0, 1790.0, 959.5, 599.5, dist, 12)
    rng = np.random.default_rng(3)
    pixels = rng.uniform([-50.0, -50.0], [1970.0, 1250.0], (700, 2))
    pixels[5] = np.nan
    norm = pose_fit.pixels_to_normalized(camera, pixels)
    np.testing.assert_array_equal(norm, camera.pixels_to_normalized(pixels))
    np.testing.assert_array_equal(pose_fit.unproject(camera, pixels), camera.unproject(pixels))
    points = np.column_stack([rng.normal(0.0, 1.0, 700), rng.normal(0.0, 0.6, 700), rng.uniform(1.0, 6.0, 700)])
    np.testing.assert_array_equal(pose_fit.project(camera, points), camera.project(points))
    good = norm[np.isfinite(norm).all(axis=1)]
    jac = camera._distort_jacobian(good) * np.array([camera.fx, camera.fy])[None, :, None]
    np.testing.assert_array_equal(pose_kernels.lens_jacobian(good, camera.fx, camera.fy, *camera.dist),
                                  jac.reshape(-1, 4).T)
    assert (pose_fit.UNDISTORT_ITERATIONS, pose_fit.UNDISTORT_TOL) == camera.undistort.__defaults__
    assert pose_fit.pixels_to_normalized(camera, pixels[:0]).shape == (0, 2)
    monkeypatch.setenv("LIVETRACK_KERNELS", "numpy")
    np.testing.assert_array_equal(pose_fit.pixels_to_normalized(camera, pixels), norm)


def test_the_closed_forms_cross_product_is_numpys():
    """``circle_pose._cross`` (3-vectors, without np.cross's argument handling) gives np.cross's numbers, signed
    zeros included."""
    from livetrack.estimator.circle_pose import _cross

    rng = np.random.default_rng(5)
    for k in range(2000):
        a = rng.normal(size=3) * 10.0 ** rng.uniform(-8, 3)
        b = np.array([1.0, 0.0, 0.0]) if k % 5 == 0 else rng.normal(size=3)
        np.testing.assert_array_equal(_cross(a, b), np.cross(a, b))
        np.testing.assert_array_equal(np.signbit(_cross(a, b)), np.signbit(np.cross(a, b)))


@pytest.mark.parametrize("n_points, noise_px, arc_deg", [(24, 0.0, 360.0), (300, 0.3, 360.0), (600, 0.5, 360.0),
                                                         (40, 0.2, 120.0)])
def test_the_conic_from_the_scatter_matrix_is_the_svds(n_points, noise_px, arc_deg):
    """``fit_conic`` takes the least eigenvector of the 6 x 6 scatter matrix (faster than the SVD of the N x 6 design
    it replaced): on edge points of a tilted ellipse in normalised coordinates, whole or an arc, clean or noisy, its
    conic is the SVD's least right singular vector (up to sign) to 1e-9."""
    rng = np.random.default_rng(n_points)
    t = np.radians(np.linspace(0.0, arc_deg, n_points, endpoint=False))
    f_px = 1400.0
    x = (310.0 + 160.0 * np.cos(t) * np.cos(0.4) - 70.0 * np.sin(t) * np.sin(0.4)) / f_px
    y = (-120.0 + 160.0 * np.cos(t) * np.sin(0.4) + 70.0 * np.sin(t) * np.cos(0.4)) / f_px
    pts = np.column_stack([x, y]) + rng.normal(0.0, noise_px / f_px, (n_points, 2))

    def by_svd(points):
        mean = points.mean(axis=0)
        scale = np.sqrt(2.0) / np.sqrt(((points - mean) ** 2).sum(axis=1)).mean()
        u, v = (points[:, 0] - mean[0]) * scale, (points[:, 1] - mean[1]) * scale
        design = np.column_stack([u * u, u * v, v * v, u, v, np.ones_like(u)])
        a, b, c, d, e, f = np.linalg.svd(design, full_matrices=False)[2][-1]
        T = np.array([[scale, 0, -scale * mean[0]], [0, scale, -scale * mean[1]], [0, 0, 1.0]])
        Q = T.T @ np.array([[a, b / 2, d / 2], [b / 2, c, e / 2], [d / 2, e / 2, f]]) @ T
        return Q / np.linalg.norm(Q)

    Q, reference = fit_conic(pts), by_svd(pts)
    sign = np.sign(np.sum(Q * reference))
    assert np.max(np.abs(Q - sign * reference)) < 1e-9
