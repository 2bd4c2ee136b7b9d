"""livetrack calibrate targets: bundle adjustment over ring-target edges with exposure-bias compensation, on
simulated views of a camera with known intrinsics and distortion."""

from __future__ import annotations

import json

import numpy as np
import pytest

from livetrack.calibration.experiment import INITIAL
from livetrack.calibration.experiment import SCENARIO as EXPERIMENT
from livetrack.calibration.targets import TargetCalibrationOptions, assign_circles, calibrate_targets
from livetrack.camera import CameraModel
from livetrack.camera.io import load_camera, load_camera_uncertainty
from livetrack.cli import main
from livetrack.geometry import Pose, look_rotation
from livetrack.sim.scenario import Scenario
from livetrack.targets.spec import TargetSpec

SCENARIO = dict(EXPERIMENT, trajectory=dict(EXPERIMENT["trajectory"], count=12))  # 480x360, k1 -0.2, k2 0.08


@pytest.fixture(scope="module")
def rendered():
    scenario = Scenario.from_dict(SCENARIO)
    return scenario, list(scenario.frames())


def _views(rendered, factor):
    scenario, frames = rendered
    chosen = [f for f in frames if f.exposure_factor == factor]
    return [f.image for f in chosen], [f.exposure_us for f in chosen]


def test_assign_circles_puts_edge_points_on_their_circles():
    spec = TargetSpec.default(3, 0.1)
    camera = CameraModel(400, 300, 400.0, 400.0, 199.5, 149.5)
    pose = Pose(look_rotation(30, 20, 0), np.array([0.02, -0.01, 1.2]))
    angles = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    points, radii = [], []
    for radius in (0.1, 0.04, 0.02, 0.008):
        circle = np.column_stack([radius * np.cos(angles), radius * np.sin(angles), np.zeros_like(angles)])
        points.append(camera.project(circle @ pose.R.T + pose.t))
        radii.append(np.full(len(angles), radius))
    edges = assign_circles(camera, np.concatenate(points), pose, spec)
    assert len(edges) == 160
    np.testing.assert_allclose(edges.radius_m, np.concatenate(radii))
    assert edges.white_outside.tolist() == ([True] * 40 + [False] * 40) * 2


@pytest.mark.slow  # ~67 s: the default set's slowest (moved in session 13, when the set ran over 10 min)
def test_over_exposed_views_give_the_camera_with_compensation(rendered):
    scenario, _ = rendered
    truth = scenario.camera
    images, exposures = _views(rendered, 4.0)
    # one pass of the edge measurement (the default two cost ~20 s more; at x4 the first finds the blur already)
    result = calibrate_targets(images, list(scenario.targets), INITIAL, exposures,
                               options=TargetCalibrationOptions(refine_passes=1, blur_passes=1))
    cam, u = result.camera, result.uncertainty
    assert len(result.view_names) == 12 and result.rms_px < 0.05
    # measured with the edges measured again: fx -0.07 %, cx -0.05 px, k1 +0.4 %, delta -0.03 px (one run with
    # the default two passes; the tracker's edges alone gave fx -0.04 %, cx -0.6 px, k1 -0.4 %, delta -0.59 px)
    assert abs(cam.fx / truth.fx - 1) < 0.003 and abs(cam.fy / truth.fy - 1) < 0.003
    assert abs(cam.cx - truth.cx) < 2.0 and abs(cam.cy - truth.cy) < 2.0
    assert abs(cam.dist[0] / truth.dist[0] - 1) < 0.03
    assert 0 < u.fx < 2 and 0 < u.dist[0] < 0.01
    # the tracker's edges of these x4 views are 0.6 px off (its blur for clipped profiles, 1.0 px, is not the
    # scene's 0.8 px); measured again with the blur found from their residuals, the one bias of the exposure
    # is close to 0
    assert abs(result.extra["blur_px"] - 0.8) < 0.05
    deltas = np.array(list(result.extra["delta_px"].values()))
    assert np.all(np.abs(deltas) < 0.15)
    # the blur's uncertainty (jackknife over the views) is in the reported 1-sigma: each parameter's 1-sigma is
    # at least the adjustment's own and grows by its change with the blur times the blur's 1-sigma
    blur_std, slope = result.extra["blur_std_px"], result.extra["d_camera_d_blur"]
    assert 0 < blur_std < 0.05
    alone = result.extra["uncertainty_without_blur"]
    for name, value, before in (("fx", u.fx, alone["fx"]), ("k1", u.dist[0], alone["dist"][0])):
        assert np.isfinite(slope[name])
        assert value == pytest.approx(np.hypot(before, slope[name] * blur_std), rel=1e-9)
    assert slope["p1"] == 0 and u.dist[2] == 0  # held fixed


@pytest.mark.slow
def test_delta_fixed_at_zero_is_biased_where_compensation_is_not(rendered):
    scenario, _ = rendered
    truth = scenario.camera
    images, exposures = _views(rendered, 16.0)
    # the tracker's edges (their blur for clipped profiles is 1.0 px, the scene's 0.8 px): measured again with
    # the blur found from the residuals, delta = 0 is nearly right too (+0.11 % in the 16-view experiment)
    fits = {comp: calibrate_targets(images, list(scenario.targets), INITIAL, exposures,
                                    options=TargetCalibrationOptions(compensate=comp, refine_edges=False)).camera
            for comp in (True, False)}
    error = {comp: abs(cam.fx / truth.fx - 1) for comp, cam in fits.items()}
    assert error[True] < 0.003
    assert error[False] > 3 * error[True]


def test_cli_calibrates_from_images_and_writes_a_camera_file(rendered, tmp_path):
    import cv2

    scenario, frames = rendered
    files = []
    for k, frame in enumerate(f for f in frames if f.exposure_factor == 1.0):
        if k >= 8:
            break
        files.append(str(tmp_path / f"view{k:02d}.png"))
        cv2.imwrite(files[-1], frame.image)
    (tmp_path / "targets.yaml").write_text("targets:\n  - {id: 3, outer_radius_m: 0.08}\n"
                                           "  - {id: 5, outer_radius_m: 0.08}\n")
    (tmp_path / "initial.yaml").write_text("camera: {width: 480, height: 360, fx: 440, fy: 440, cx: 239.5, "
                                           "cy: 179.5, bit_depth: 12}\n")
    out = tmp_path / "camera.yaml"
    code = main(["calibrate", "targets", *files, "--targets", str(tmp_path / "targets.yaml"), "--initial",
                 str(tmp_path / "initial.yaml"), "--out", str(out), "--json", str(tmp_path / "cal.json"),
                 "--plots", str(tmp_path / "plots")])
    assert code == 0
    camera, truth = load_camera(out), scenario.camera
    assert abs(camera.fx / truth.fx - 1) < 0.005 and abs(camera.dist[0] / truth.dist[0] - 1) < 0.05
    assert camera.bit_depth == 12 and load_camera_uncertainty(out).fx > 0
    figures = json.loads((tmp_path / "cal.json").read_text())
    assert len(figures["views"]) == 8 and figures["compensated"] is True
    assert (tmp_path / "plots" / "residuals.png").is_file()


def test_rendered_circle_grid_is_found_where_its_centres_project():
    from livetrack.calibration.circle_grid import CircleGrid, expose, find_grid, optical_image, pixel_rays

    camera = CameraModel(240, 180, 220.0, 220.0, 121.3, 88.6, (-0.1, 0.0, 0.0, 0.0, 0.0), 12)
    grid = CircleGrid()
    pose = Pose(look_rotation(20, 30, 5), np.array([0.01, -0.01, 0.55]))
    optical = optical_image(camera, grid, pose, pixel_rays(camera, 3))
    image = expose(optical, 1.0, np.random.default_rng(2))
    centres = find_grid(image, grid, 12)
    assert centres is not None
    truth = camera.project(grid.centres_m() @ pose.R.T + pose.t)
    # the order of findCirclesGrid may start from either end of the grid
    error = min(np.abs(centres - truth).max(), np.abs(centres[::-1] - truth).max())
    assert error < 0.3  # the centre of a disk's image is not the image of its centre: ~0.1 px here


def test_cli_collects_views_from_a_live_source(tmp_path):
    import yaml

    scenario = dict(SCENARIO, trajectory=dict(SCENARIO["trajectory"], count=6), exposure={"factors": [4]})
    (tmp_path / "scenario.yaml").write_text(yaml.safe_dump(scenario))
    (tmp_path / "initial.yaml").write_text("camera: {width: 480, height: 360, fx: 440, fy: 440, cx: 239.5, "
                                           "cy: 179.5, bit_depth: 12}\n")
    out = tmp_path / "camera.yaml"
    code = main(["calibrate", "targets", "--source", f"sim:{tmp_path / 'scenario.yaml'}", "--source-option",
                 "realtime=false", "--views", "5", "--max-frames", "12", "--initial", str(tmp_path / "initial.yaml"),
                 "--out", str(out), "--json", str(tmp_path / "cal.json")])
    assert code == 0
    assert len(json.loads((tmp_path / "cal.json").read_text())["views"]) == 5
    camera = load_camera(out)
    assert abs(camera.fx / 420 - 1) < 0.01 and abs(camera.dist[0] / -0.2 - 1) < 0.05


def test_neighbour_correlation_of_edge_residuals():
    from livetrack.calibration.targets import neighbour_correlation

    rng = np.random.default_rng(0)
    independent = [rng.normal(0, 0.03, 500) for _ in range(20)]
    assert abs(neighbour_correlation(independent)) < 0.03
    # neighbouring profiles sharing pixels: a moving average e_k + 0.6 e_(k-1), lag-1 correlation 0.6 / 1.36
    shared = []
    for _ in range(20):
        e = rng.normal(0, 0.03, 501)
        shared.append(e[1:] + 0.6 * e[:-1])
    assert abs(neighbour_correlation(shared) - 0.6 / 1.36) < 0.03
    alternating = [np.tile([0.01, -0.01], 200)]  # negative correlation: no scaling below independent points
    assert neighbour_correlation(alternating) == 0.0
    assert neighbour_correlation([np.ones(2)]) == 0.0
