"""Scenarios: validation with key paths, generated trajectories, frames and the ``livetrack sim`` command."""

from __future__ import annotations

import argparse
import copy
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from livetrack.commands import sim as sim_command
from livetrack.config.checks import ConfigError
from livetrack.recording import Recording
from livetrack.sim.scenario import Scenario, sheet_inside

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "config" / "scenarios"

SMALL = {
    "name": "small",
    "seed": 3,
    "camera": {"width": 160, "height": 100, "fx": 150, "fy": 150, "cx": 79.5, "cy": 49.5, "bit_depth": 12},
    "targets": [{"id": 3, "outer_radius_m": 0.125}],
    "poses": [{"t_m": [0.0, 0.0, 1.5]}, {"t_m": [0.1, 0.05, 1.8], "tilt_deg": 30, "tilt_axis_deg": 45}],
    "exposure": {"factors": [1, 4]},
}


def small(**changes) -> dict:
    data = copy.deepcopy(SMALL)
    data.update(changes)
    return data


def line_of_sight_tilt_deg(pose) -> float:
    """Angle between the target normal and the viewing ray to its centre."""
    ray = pose.t / np.linalg.norm(pose.t)
    return math.degrees(math.acos(np.clip(pose.normal_cam @ ray, -1.0, 1.0)))


def test_paper_lab_has_140_frames_with_every_target_fully_in_the_image():
    s = Scenario.from_file(SCENARIOS / "paper-lab.yaml")
    assert s.name == "paper-lab" and len(s) == 140 and len(s.steps) == 20
    assert s.exposure_factors == (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0)
    assert s.camera.width == 1920 and s.camera.height == 1200 and s.camera.dist[0] == -0.1
    assert s.formation.effects.halo.fraction == 0.03 and s.formation.optics.psf_sigma_px == 0.8
    # Nominal: white paper (0.85) at 55 % of full well.
    white_e = 0.85 * s.formation.radiometry.white_rate_e_per_us * s.nominal_exposure_us
    assert white_e == pytest.approx(5500.0)
    distances, tilts = [], []
    for k in range(0, len(s), 7):
        (placement,) = s.placements_for(k)
        assert sheet_inside(s.formation.render_camera, placement, margin_px=20.0)
        distances.append(placement.pose.distance_m)
        tilts.append(line_of_sight_tilt_deg(placement.pose))
    assert 1.5 <= min(distances) < 1.8 and 5.7 < max(distances) <= 6.0  # spread over the range
    assert 0.0 <= min(tilts) < 5.0 and 45.0 < max(tilts) <= 50.0 + 1e-9
    # Frames are pose-major and timed by fps.
    assert [s.pose_index(k) for k in (0, 6, 7, 139)] == [0, 0, 1, 19]
    assert s.timestamp_ns(30) == 1_000_000_000


def test_builtin_default_is_the_demo_scenario():
    default = Scenario.default()
    demo = Scenario.from_file(SCENARIOS / "demo.yaml")
    assert default.to_dict() == demo.to_dict()
    assert len(default) == 12


def test_sample_scenario_shows_two_distinct_targets_clear_of_each_other():
    s = Scenario.from_file(SCENARIOS / "sample.yaml")
    assert len(s) == 8 and (s.camera.width, s.camera.height) == (640, 400)
    assert sorted(t.id for t in s.targets) == [3, 5]
    for step in s.steps:
        assert sorted(step) == [3, 5]
    for k in range(0, len(s), 2):
        for placement in s.placements_for(k):
            assert sheet_inside(s.formation.render_camera, placement, margin_px=8.0)


def test_resolved_content_reloads_to_the_same_frames():
    s = Scenario.from_dict(small())
    text = yaml.safe_dump(s.to_dict())
    again = Scenario.from_dict(yaml.safe_load(text))
    assert len(again) == len(s) == 4
    assert again.exposures_us == pytest.approx(s.exposures_us)
    for a, b in zip(s.steps, again.steps, strict=True):
        np.testing.assert_allclose(a[3].R, b[3].R, atol=1e-12)
        np.testing.assert_allclose(a[3].t, b[3].t, atol=1e-12)
    np.testing.assert_array_equal(s.render_frame(3).image, again.render_frame(3).image)


def test_frames_are_deterministic_and_match_single_renders():
    s = Scenario.from_dict(small())
    frames = list(s.frames())
    assert [f.frame_index for f in frames] == [0, 1, 2, 3]
    assert [f.exposure_factor for f in frames] == [1.0, 4.0, 1.0, 4.0]
    assert frames[1].exposure_us == pytest.approx(4 * frames[0].exposure_us)
    assert frames[1].timestamp_ns == round(1e9 / 30)
    np.testing.assert_array_equal(frames[2].image, s.render_frame(2).image)
    np.testing.assert_array_equal(frames[2].image, Scenario.from_dict(small()).render_frame(2).image)
    assert not np.array_equal(frames[2].image, Scenario.from_dict(small(), seed=4).render_frame(2).image)
    assert frames[0].image.dtype == np.uint16 and frames[0].image.shape == (100, 160)
    assert set(frames[0].truth) == {3}
    # Over-exposed frame: white saturates, the black ring does not.
    assert frames[1].image.max() >= 4090 and frames[1].image.min() < 1000
    assert len(list(s.frames(max_frames=3))) == 3


def test_spread_trajectory_is_seeded_and_keeps_targets_apart():
    data = small(targets=[{"id": 3, "outer_radius_m": 0.1}, {"id": 5, "outer_radius_m": 0.1}],
                 poses=None,
                 trajectory={"kind": "spread", "count": 5, "distance_m": [2.0, 3.0], "tilt_deg": [0, 30],
                             "margin_px": 4})
    data.pop("poses")
    a, b = Scenario.from_dict(data), Scenario.from_dict(data)
    c = Scenario.from_dict(data, seed=99)
    for sa, sb in zip(a.steps, b.steps, strict=True):
        np.testing.assert_array_equal(sa[5].t, sb[5].t)
    assert not np.allclose(a.steps[0][3].t, c.steps[0][3].t)
    for step in a.steps:
        assert 2.0 <= step[3].distance_m <= 3.0
        assert line_of_sight_tilt_deg(step[5]) <= 30.0 + 1e-9
    with pytest.raises(ConfigError, match=r"^trajectory: step 0: cannot place target"):
        Scenario.from_dict({**data, "trajectory": {**data["trajectory"], "distance_m": [0.2, 0.3]}})


@pytest.mark.parametrize(("change", "message"), [
    ({"sensor": {"full_well_e": 0}}, r"^sensor\.full_well_e: must be > 0"),
    ({"sensor": {"full_well": 10}}, r"^sensor\.full_well: unknown key"),
    ({"optics": {"psf_sigma_px": -1}}, r"^optics\.psf_sigma_px: must be >= 0"),
    ({"effects": {"halo": {"sigma": 3}}}, r"^effects\.halo\.sigma: unknown key"),
    ({"effects": {"sparkle": {}}}, r"^effects\.sparkle: unknown key"),
    ({"camera": {"width": 10}}, r"^camera\.height: missing"),
    ({"scene": {"supersampling": 10}}, r"^scene\.supersampling: must be a perfect square"),
    ({"targets": [{"id": 3, "outer_radius_m": 0.1}, {"id": 3, "outer_radius_m": 0.2}]},
     r"^targets\[1\]\.id: duplicate target id 3"),
    ({"poses": [{"t_m": [0, 0, 1], "target_id": 9}]}, r"^poses\[0\]\.target_id: no target with id 9"),
    ({"poses": [{"t_m": [0, 0, -1]}]}, r"^poses\[0\]\.t_m: the target must be in front"),
    ({"poses": [{"t_m": [0, 0, 1], "q_xyzw": [0, 0, 0, 1], "tilt_deg": 3}]}, r"^poses\[0\]\.tilt_deg: give"),
    ({"trajectory": {"kind": "spread", "count": 2}}, r"^trajectory: give either"),
    ({"exposure": {"factors": [1, -2]}}, r"^exposure\.factors\[1\]: must be > 0"),
    ({"exposure": {"nominal_us": "long"}}, r"^exposure\.nominal_us: must be a number"),
    ({"exposure": {"factors": [1, 40]}}, r"^exposure\.factors: longest exposure .* exceeds the frame period"),
    ({"timing": {"fps": 0}}, r"^timing\.fps: must be > 0"),
    ({"colour": True}, r"^colour: unknown key"),
])
def test_scenario_errors_name_the_key_path(change, message):
    with pytest.raises(ConfigError, match=message):
        Scenario.from_dict(small(**change))


def test_trajectory_errors_name_the_key_path():
    data = small()
    data.pop("poses")
    for traj, message in [
        ({"kind": "spiral", "count": 2}, r"^trajectory\.kind: must be one of"),
        ({"kind": "spread", "count": 0}, r"^trajectory\.count: must be >= 1"),
        ({"kind": "spread", "count": 2, "distance_m": [3, 2]},
         r"^trajectory\.distance_m: must be \[low, high\]"),
        ({"kind": "spread", "count": 2, "target_ids": [4]},
         r"^trajectory\.target_ids\[0\]: no target with id 4"),
    ]:
        with pytest.raises(ConfigError, match=message):
            Scenario.from_dict({**data, "trajectory": traj})
    with pytest.raises(ConfigError, match=r"^poses: missing"):
        Scenario.from_dict(data)


def run_sim(tmp_path: Path, *argv: str) -> int:
    parser = argparse.ArgumentParser()
    sim_command.add_arguments(parser)
    return sim_command.run(parser.parse_args(list(argv)))


def test_sim_command_writes_a_recording_with_truth(tmp_path, capsys):
    scenario = tmp_path / "s.yaml"
    scenario.write_text(yaml.safe_dump(small()), encoding="utf-8")
    out = tmp_path / "rec"
    assert run_sim(tmp_path, "--scenario", str(scenario), "--out", str(out), "--max-frames", "3") == 0
    printed = capsys.readouterr().out
    assert "3 frames" in printed and "MB on disk" in printed and "s per frame" in printed
    rec = Recording.open(out)
    assert len(rec) == 3
    assert rec.meta["scenario"] == "small" and rec.meta["scenario_resolved"]["seed"] == 3
    expected = Scenario.from_dict(small())
    np.testing.assert_allclose(rec.truth(2)[3].t, expected.steps[1][3].t)
    np.testing.assert_array_equal(rec.read_image(1), expected.render_frame(1).image)
    with pytest.raises(ConfigError, match=r"^--out: .*not empty"):
        run_sim(tmp_path, "--scenario", str(scenario), "--out", str(out))
    argv = ["--scenario", str(scenario), "--out", str(out), "--overwrite", "--seed", "5"]
    assert run_sim(tmp_path, *argv) == 0
    assert Recording.open(out).meta["scenario_resolved"]["seed"] == 5
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(small(sensor={"full_well_e": -1})), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"^sensor\.full_well_e: must be > 0"):
        run_sim(tmp_path, "--scenario", str(bad), "--out", str(tmp_path / "other"))


def test_paper_lab_bright_is_paper_lab_on_a_bright_textured_ground():
    lab = Scenario.from_file(SCENARIOS / "paper-lab.yaml")
    bright = Scenario.from_file(SCENARIOS / "paper-lab-bright.yaml")
    assert len(bright) == len(lab) and bright.exposure_factors == lab.exposure_factors
    assert [s[3].t.tolist() for s in bright.steps] == [s[3].t.tolist() for s in lab.steps]  # the same poses
    assert bright.scene.background_reflectance == 0.9 > bright.scene.white_reflectance
    assert bright.scene.background_texture["kind"] == "noise"
    # At x4 the paper and the ground saturate around a far target (about half of them at x2 already); the
    # ring stays below the clip.
    k = max(range(0, len(bright), 7), key=lambda i: bright.truth_for(i)[3].distance_m) + 4
    frame = bright.render_frame(k)
    assert frame.exposure_factor == 4.0
    top = bright.camera.saturation_level
    assert np.mean(frame.image >= 0.99 * top) > 0.95  # read noise after the well: clipped pixels read 4080+
    centre = np.rint(bright.camera.project(frame.truth[3].t[None, :])[0]).astype(int)
    ring_px = int(round(0.5 * 0.125 * bright.camera.fx / frame.truth[3].distance_m))  # at 0.5 R
    assert frame.image[centre[1], centre[0] - ring_px - 2: centre[0] + ring_px + 3].min() < 0.2 * top
