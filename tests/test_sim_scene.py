"""Scene generalisation of the simulator: background reflectance and texture, illumination gradient, the white
sheet's size (or none), each validated with its key path."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from livetrack.camera import CameraModel
from livetrack.config.checks import ConfigError
from livetrack.geometry import Pose
from livetrack.sim.coverage import Placement, render_reflectance
from livetrack.sim.scenario import Scenario
from livetrack.sim.texture import (
    CheckerBackground,
    NoiseBackground,
    TargetTexture,
    TextBackground,
    background_image,
)
from livetrack.targets.spec import TargetSpec

BASE = {
    "seed": 5,
    "camera": {"width": 200, "height": 120, "fx": 200, "fy": 200, "cx": 99.5, "cy": 59.5, "bit_depth": 12},
    "optics": {"psf_sigma_px": 0.8, "oversampling": 2},
    "targets": [{"id": 3, "outer_radius_m": 0.125}],
    "poses": [{"t_m": [0.0, 0.0, 1.0]}],
    "exposure": {"factors": [1]},
}


def scenario(**scene) -> Scenario:
    data = copy.deepcopy(BASE)
    data["scene"] = scene
    return Scenario.from_dict(data)


@pytest.mark.parametrize("scene, message", [
    ({"background_texture": {"kind": "noise", "colour": 1}}, r"^scene\.background_texture\.colour: unknown key"),
    ({"background_texture": {"kind": "text", "square_px": 3}},
     r"^scene\.background_texture\.square_px: not a parameter of kind 'text'"),
    ({"background_texture": {"kind": "plasma"}}, r"^scene\.background_texture\.kind: "),
    ({"background_texture": {"kind": "noise", "scales_px": [4, -1]}}, r"^scene\.background_texture\.scales_px: "),
    ({"background_texture": {"kind": "noise", "contrast": -0.1}}, r"^scene\.background_texture\.contrast: "),
    ({"background_texture": {"kind": "image", "file": "nope.png"}}, r"^scene\.background_texture\.file: cannot"),
    ({"illumination": {"gradient": 1.2}}, r"^scene\.illumination\.gradient: must be < 1"),
    ({"illumination": {"slope": 0.2}}, r"^scene\.illumination\.slope: unknown key"),
    ({"sheet_side_factor": 1.5}, r"^scene\.sheet_side_factor: must be >= 2"),
    ({"sheet_side_factor": "off"}, r"^scene\.sheet_side_factor: must be a number >= 2 or 'none'"),
    ({"background_reflectance": 1.3}, r"^scene\.background_reflectance: must be <= 1"),
])
def test_scene_errors_name_the_key_path(scene, message):
    with pytest.raises(ConfigError, match=message):
        scenario(**scene)


@pytest.mark.parametrize("texture", [
    {"kind": "noise", "scales_px": [2, 8, 32], "contrast": 0.3},
    {"kind": "text", "line_height_px": 9},
    {"kind": "checker", "square_px": 17, "angle_deg": 25},
])
def test_textured_bright_background_is_seeded_and_reloads(texture):
    s = scenario(background_reflectance=0.9, background_texture=texture)
    optical = s.formation.optical_image(s.placements_for(0))
    again = Scenario.from_dict(s.to_dict()).formation.optical_image(s.placements_for(0))
    np.testing.assert_array_equal(optical, again)
    corner = optical[:20, :40]  # background only (the sheet is in the middle)
    assert corner.std() > 0.03 and 0.3 < corner.mean() < 1.0
    other = Scenario.from_dict({**copy.deepcopy(BASE), "seed": 6,
                                "scene": {"background_reflectance": 0.9, "background_texture": texture}})
    differs = not np.array_equal(other.formation.optical_image(other.placements_for(0)), optical)
    assert differs == (texture["kind"] != "checker")  # the checker has no randomness


def test_noise_background_has_the_asked_mean_and_contrast():
    pattern = NoiseBackground(0.5, (3.0, 12.0, 48.0), 0.2, 400, 300, seed=1)
    img = background_image(pattern, 400, 300)
    assert img.mean() == pytest.approx(0.5, abs=0.03)
    assert img.std() / img.mean() == pytest.approx(0.2, rel=0.25)  # averaged over 2 x 2 points per pixel


def test_text_and_checker_are_high_contrast():
    text = background_image(TextBackground(0.8, 10.0, 300, 200, seed=2), 300, 200)
    assert text.max() == pytest.approx(0.8) and text.min() < 0.1
    ink = np.mean(text < 0.4)
    assert 0.05 < ink < 0.4
    checker = background_image(CheckerBackground(0.9, 20.0), 100, 100, samples=1)
    assert checker[5, 5] == pytest.approx(0.9) and checker[5, 25] == pytest.approx(0.04)


def test_illumination_gradient_scales_the_scene_across_the_image():
    s = scenario(background_reflectance=0.5, illumination={"gradient": 0.4, "angle_deg": 0})
    optical = s.formation.optical_image(s.placements_for(0))
    assert optical[60, 0] == pytest.approx(0.5 * 0.6, rel=1e-4)
    assert optical[60, 199] == pytest.approx(0.5 * 1.4, rel=1e-4)
    # The target is lit too: its white centre follows the light at its place.
    flat = scenario(background_reflectance=0.5)
    ratio = optical / flat.formation.optical_image(flat.placements_for(0))
    assert ratio[60, 100] == pytest.approx(1.0, abs=0.01)


def test_sheet_size_and_no_sheet():
    camera = CameraModel(width=160, height=160, fx=300, fy=300, cx=79.5, cy=79.5)
    spec = TargetSpec.from_dict({"id": 3, "outer_radius_m": 0.125}, "t")
    pose = Pose(np.eye(3), np.array([0.01, -0.004, 1.0]))  # R = 37.5 px, off the pixel grid
    sheet = render_reflectance(camera, [Placement(pose, TargetTexture(spec))], background=0.3)
    bare = render_reflectance(camera, [Placement(pose, TargetTexture(spec, edge_to_edge=True))], background=0.3)
    # Beyond the black disk: white paper with the sheet, the background without it.
    assert sheet[80, 80 + 45] == pytest.approx(0.85) and bare[80, 80 + 45] == pytest.approx(0.3)
    inside = np.hypot(*np.meshgrid(np.arange(160) - 81.5, np.arange(160) - 78.3)) < 30
    np.testing.assert_allclose(bare[inside], sheet[inside])
    # Exact coverage of the round border: over a background as white as the paper, no sheet renders the same.
    white = render_reflectance(camera, [Placement(pose, TargetTexture(spec, edge_to_edge=True))], background=0.85)
    paper = render_reflectance(camera, [Placement(pose, TargetTexture(spec))], background=0.85)
    np.testing.assert_allclose(white, paper, atol=2e-3)
    assert abs(white.sum() - paper.sum()) < 0.05  # of ~3000 px of dark area x 0.81
    # A sheet of 2.2 R ends between the disk and the default 2.8 R sheet.
    small = scenario(background_reflectance=0.3, sheet_side_factor=2.2)
    ref = small.formation.reflectance(small.placements_for(0))
    r_px = 0.125 * 200 / 1.0
    assert ref[60, round(99.5 + 1.05 * r_px)] == pytest.approx(0.85)
    assert ref[60, round(99.5 + 1.2 * r_px)] == pytest.approx(0.3)
    assert small.to_dict()["scene"]["sheet_side_factor"] == 2.2
    assert scenario(sheet_side_factor="none").to_dict()["scene"]["sheet_side_factor"] == "none"


def test_image_background_from_file(tmp_path):
    import cv2

    picture = (np.arange(64 * 48, dtype=np.uint8).reshape(48, 64) % 200) + 20
    cv2.imwrite(str(tmp_path / "wall.png"), picture)
    data = copy.deepcopy(BASE)
    data["scene"] = {"background_reflectance": 0.6, "background_texture": {"kind": "image", "file": "wall.png"}}
    (tmp_path / "s.yaml").write_text(__import__("yaml").safe_dump(data))
    s = Scenario.from_file(tmp_path / "s.yaml")
    ref = s.formation.reflectance([])
    assert ref.mean() == pytest.approx(0.6, rel=0.05) and ref.std() > 0.1
    # The resolved content names the file absolutely: it reloads from anywhere (a recording's scenario).
    assert s.to_dict()["scene"]["background_texture"]["file"] == str(tmp_path / "wall.png")
    np.testing.assert_array_equal(Scenario.from_dict(s.to_dict()).formation.reflectance([]), ref)
