"""The camera file's calibration uncertainty propagated into the pose covariance (first order): Monte-Carlo check
against poses re-solved with cameras drawn from that uncertainty; the Tracker option, the config key and the
``detect --propagate-camera-uncertainty`` flag."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from livetrack.camera import CameraModel
from livetrack.cli import main
from livetrack.config.app import default_config_data, merge, parse_config
from livetrack.config.checks import ConfigError
from livetrack.estimator.intrinsics_uncertainty import camera_covariance, with_camera_uncertainty
from livetrack.estimator.pose_fit import CircleEdgePoints, fit_pose
from livetrack.estimator.tracker import Tracker, TrackerOptions
from livetrack.geometry import Pose, look_rotation
from livetrack.sim.scenario import Scenario

CAMERA = CameraModel(480, 360, 420.0, 421.0, 243.2, 178.7, (-0.2, 0.08, 0.0, 0.0, 0.0), 12)
# the 1-sigma of a 9-view targets calibration of this camera (livetrack calibrate targets --source, one run)
STD = np.array([0.57, 0.59, 0.61, 0.69, 0.0012, 0.0025, 0.0, 0.0, 0.0])
UNCERTAINTY_YAML = "uncertainty: {fx: 0.57, fy: 0.59, cx: 0.61, cy: 0.69, dist: [0.0012, 0.0025, 0, 0, 0]}\n"


def _edge_points(pose: Pose, seed: int, noise_px: float = 0.02) -> CircleEdgePoints:
    """Edge points of a two-level ring target (R 80 mm) under ``pose``, with Gaussian noise along x and y."""
    angles = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    points, radii, outside = [], [], []
    for radius, white_outside in ((0.08, True), (0.032, False), (0.016, True), (0.0064, False)):
        circle = np.column_stack([radius * np.cos(angles), radius * np.sin(angles), np.zeros_like(angles)])
        points.append(CAMERA.project(circle @ pose.R.T + pose.t))
        radii.append(np.full(len(angles), radius))
        outside.append(np.full(len(angles), white_outside))
    p = np.concatenate(points)
    p = p + np.random.default_rng(seed).normal(0, noise_px, p.shape)
    return CircleEdgePoints(p, np.concatenate(radii), np.concatenate(outside), np.full(len(p), noise_px))


@pytest.mark.parametrize("pose", [
    Pose(look_rotation(35, 20, 0), np.array([0.15, -0.08, 1.1])),  # off-centre, tilted
    Pose(look_rotation(10, 200, 0), np.array([-0.02, 0.01, 0.7])),  # near the axis, near
])
def test_predicted_spread_matches_poses_re_solved_with_drawn_cameras(pose):
    obs = _edge_points(pose, 1)
    fit = fit_pose(CAMERA, obs, pose)
    assert fit
    added = camera_covariance(CAMERA, obs, fit, STD)
    rng = np.random.default_rng(7)
    nominal = np.array([CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy, *CAMERA.dist])
    solved = []
    for _ in range(200):  # the same edge points, cameras drawn from the stated uncertainty
        p = nominal + rng.normal(size=9) * STD
        camera = CameraModel(480, 360, *p[:4], tuple(p[4:]), 12)
        f = fit_pose(camera, obs, fit.pose)
        assert f
        solved.append([*f.pose.t, f.pose.distance_m])
    solved = np.array(solved)
    direction = fit.pose.t / np.linalg.norm(fit.pose.t)
    predicted = np.append(np.sqrt(np.diag(added[:3, :3])), np.sqrt(direction @ added[:3, :3] @ direction))
    empirical = solved.std(axis=0, ddof=1)
    # measured (one run): within 5 % for every component; the test allows 30 % (200 draws: ~5 % sampling error)
    np.testing.assert_allclose(predicted, empirical, rtol=0.3)
    # the camera's share dominates these precise edges: the covariance grows
    grown = with_camera_uncertainty(fit, CAMERA, obs, STD)
    assert np.all(np.diag(grown.covariance)[:3] > 10 * np.diag(fit.covariance)[:3])
    assert grown.pose is fit.pose and grown.delta_px == fit.delta_px
    # a camera without uncertainty adds nothing
    np.testing.assert_allclose(with_camera_uncertainty(fit, CAMERA, obs, np.zeros(9)).covariance, fit.covariance)


@pytest.fixture(scope="module")
def frame():
    scenario = Scenario.from_dict({
        "name": "propagate", "seed": 3,
        "camera": {"width": 480, "height": 360, "fx": 420, "fy": 421, "cx": 243.2, "cy": 178.7,
                   "dist": [-0.2, 0.08, 0, 0, 0], "bit_depth": 12},
        "targets": [{"id": 3, "outer_radius_m": 0.08}],
        "poses": [{"target_id": 3, "t_m": [0.1, -0.05, 1.0], "tilt_deg": 30, "tilt_axis_deg": 40}],
        "exposure": {"nominal_us": "auto", "factors": [1]},
    })
    return scenario, scenario.render_frame(0)


def test_tracker_option_grows_the_covariance_and_keeps_the_pose(frame):
    scenario, rendered = frame
    plain = Tracker(scenario.camera, scenario.targets).process(rendered.image)
    propagated = Tracker(scenario.camera, scenario.targets,
                         TrackerOptions(camera_std=tuple(STD))).process(rendered.image)
    [a], [b] = plain.targets, propagated.targets
    assert a.fit and b.fit
    np.testing.assert_allclose(b.pose.t, a.pose.t, rtol=1e-12)
    var_a, var_b = np.diag(a.fit.pose_covariance), np.diag(b.fit.pose_covariance)
    assert np.all(var_b[:3] > 4 * var_a[:3])  # the camera dominates the translation's uncertainty here
    assert np.all(var_b >= var_a - 1e-18)


def _config(camera):
    return merge(default_config_data(), {"source": {"uri": "sim:", "options": {}}, "camera": camera,
                                         "tracker": {"propagate_camera_uncertainty": True}})


def test_config_key_reads_the_camera_files_uncertainty(tmp_path):
    base = "camera: {width: 480, height: 360, fx: 420, fy: 421, cx: 243.2, cy: 178.7}\n"
    with_u, without = tmp_path / "with.yaml", tmp_path / "without.yaml"
    with_u.write_text(base + UNCERTAINTY_YAML)
    without.write_text(base)
    config = parse_config(_config({"file": str(with_u)}), tmp_path)
    assert config.tracker.camera_std == pytest.approx(tuple(STD))
    assert parse_config(merge(default_config_data(), {"camera": {"file": str(with_u)}}), tmp_path).tracker \
        .camera_std is None  # off by default
    with pytest.raises(ConfigError, match="tracker.propagate_camera_uncertainty.*no uncertainty section"):
        parse_config(_config({"file": str(without)}), tmp_path)
    with pytest.raises(ConfigError, match="tracker.propagate_camera_uncertainty.*needs camera: {file"):
        parse_config(_config({"width": 480, "height": 360, "fx": 420, "fy": 421, "cx": 243.2, "cy": 178.7}),
                     tmp_path)
    data = _config({"file": str(with_u)})
    data["tracker"]["propagate_camera_uncertainty"] = "yes"
    with pytest.raises(ConfigError, match="propagate_camera_uncertainty"):
        parse_config(data, tmp_path)
    data["tracker"] = {"camera_std": [1] * 9}  # not a config key: the camera file is the one source
    with pytest.raises(ConfigError, match="camera_std"):
        parse_config(data, tmp_path)


def test_detect_flag_puts_the_grown_covariance_in_the_json(frame, tmp_path):
    scenario, rendered = frame
    png = tmp_path / "frame.png"
    assert cv2.imwrite(str(png), rendered.image)
    (tmp_path / "targets.yaml").write_text("targets:\n  - {id: 3, outer_radius_m: 0.08}\n")
    camera = tmp_path / "camera.yaml"
    camera.write_text("camera: {width: 480, height: 360, fx: 420, fy: 421, cx: 243.2, cy: 178.7, "
                      "dist: [-0.2, 0.08, 0, 0, 0], bit_depth: 12}\n" + UNCERTAINTY_YAML)
    out = {}
    for flag in ([], ["--propagate-camera-uncertainty"]):
        file = tmp_path / f"out{len(flag)}.json"
        assert main(["detect", str(png), "--camera", str(camera), "--targets", str(tmp_path / "targets.yaml"),
                     *flag, "--json", str(file)]) == 0
        [target] = json.loads(file.read_text())["frames"][0]["targets"]
        out[bool(flag)] = np.array(target["covariance_t_m_rotvec_rad"])
    assert np.all(np.diag(out[True])[:3] > 4 * np.diag(out[False])[:3])
    code = main(["detect", str(png), "--focal-px", "420", "--targets", str(tmp_path / "targets.yaml"),
                 "--propagate-camera-uncertainty", "--json", str(tmp_path / "x.json")])
    assert code == 2
