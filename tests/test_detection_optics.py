"""The detection sweep's optics family (``evaluation.detection._draw_optics``: blur, defocus, motion, glare, PSF
tails, a soft or blooming pixel, grey ink) and what it showed: a ring cut open by blur, a parent confirmed from one
dot, a target inside another's white disk, an outer level whose edges the model does not fit."""

from __future__ import annotations

import dataclasses

import numpy as np

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect.detector import _without_foreign_inside
from livetrack.estimator.detect.results import Candidate
from livetrack.estimator.tracker import Tracker, TrackerOptions
from livetrack.evaluation import detection
from livetrack.evaluation.detection import (
    OUTER_RADIUS_M,
    DetectionResult,
    build_cases,
    disk_outline_px,
    make_case,
    run_case,
)
from livetrack.sim.scenario import Scenario
from livetrack.targets.spec import TargetSpec
from tests.sweep_frames import family_apart


def test_optics_family_leaves_the_other_scenes_as_they_were(monkeypatch):
    """Drawn from its own random stream: the sweep's other scenes (and so their figures) do not move with it."""
    scenes = detection.OPTICS_SCENES
    optics = family_apart(monkeypatch, "optics", "OPTICS_SCENES", "_draw_optics")
    assert len(optics) == scenes
    effects = {name for c in optics for name in c.scenario["effects"]}
    assert len(effects) >= 6, effects  # varied, not the sweep's defaults
    sigmas = [c.scenario["optics"]["psf_sigma_px"] for c in optics]
    assert min(sigmas) >= 0.5 and max(sigmas) <= 2.2 and max(sigmas) - min(sigmas) > 0.5
    assert not any(c.background == "black" and c.scenario["scene"]["sheet_side_factor"] == "none" for c in optics)


def test_encoded_family_leaves_the_other_scenes_as_they_were(monkeypatch):
    """The encoded family (session 25) has its own random stream too: every scene of the families before it is the
    one they had without it; its scenes are sRGB or gamma-encoded, JPEG-compressed only on 8-bit cameras."""
    scenes = detection.ENCODED_SCENES
    encoded = family_apart(monkeypatch, "encoded", "ENCODED_SCENES", "_draw_encoding")
    assert len(encoded) == scenes
    for c in encoded:
        effects = c.scenario["effects"]
        assert ("srgb_encoding" in effects) != ("gamma_encoding" in effects)
        assert "jpeg" not in effects or c.scenario["camera"]["bit_depth"] == 8
    assert len({c.background for c in encoded}) >= 4


def _candidate(target_id: int, level: int, centre: tuple[float, float], outer_px: float) -> Candidate:
    spec = dict(TargetSpec.default(target_id, 0.125).levels())[level]
    c = np.array(centre, dtype=np.float64)
    return Candidate(target_id=target_id, level=level, spec=spec,
                     outer=Ellipse(c, np.array([outer_px, outer_px]), 0.0),
                     inner=Ellipse(c, np.array([0.4 * outer_px, 0.4 * outer_px]), 0.0),
                     rotation_slots=0, heading_rad=None, code_margin=1.0, code_values=np.zeros(8),
                     black_level=10.0, white_level=200.0)


def test_a_target_inside_another_targets_white_disk_is_dropped():
    """Seed 7's optics-000 at x32: a piece of a 200 px target's nested ring with one of its grown dots read as id 1
    inside that target's white disk (a false target at 20 m). A target is not seen through another's white disk;
    its own nested level is (and targets beside each other are kept)."""
    big = _candidate(3, 0, (600.0, 560.0), 100.0)
    foreign = _candidate(1, 0, (585.0, 565.0), 9.0)
    nested = _candidate(3, 1, (600.0, 560.0), 20.0)
    beside = _candidate(5, 0, (760.0, 560.0), 40.0)
    kept = _without_foreign_inside([big, foreign, nested, beside])
    assert kept == [big, nested, beside]
    on_its_ring = dataclasses.replace(foreign, outer=Ellipse(np.array([530.0, 560.0]), np.array([9.0, 9.0]), 0.0))
    assert _without_foreign_inside([big, on_its_ring]) == [big, on_its_ring]  # (outside the white disk)


def test_small_ring_cut_open_by_blur_is_read_with_its_own_threshold():
    """Seed 0's optics-006: id 8, 19.5 px, on a small sheet (2.2 R) in foliage, PSF 1.6 px with 3.5 px of motion
    blur, a 6 % halo, glare and grey ink. At x0.5 the bands beside two dots gave way to the local threshold: the
    ring was a C, its inner disk joined to the ground (no hole). A C whose convex hull is an ellipse around a
    brighter middle is now tried with its own threshold (``SmallBlobs.add_open_ring``, up to
    ``SMALL_BLOB_MAX_RADIUS_PX`` = 24 px): found, within 1 %."""
    case = next(c for c in build_cases(0) if c.name == "optics-006")
    result = DetectionResult()
    run_case(case, result)  # the sweep's 8 exposures (each frame's noise is the sweep's)
    found = {t.exposure_factor: t for t in result.targets if t.found}
    assert {0.25, 0.5, 1.0, 2.0, 4.0} <= set(found), sorted(found)
    assert all(abs(t.distance_error_pct) < 1.0 for t in found.values()), [
        (x, t.distance_error_pct) for x, t in found.items()]


def test_streaks_across_the_outer_ring_do_not_make_the_nested_level_the_outer_one():
    """Bright streaks from outside across the top of a target's ring (as blooming from a saturated sheet draws
    them down a column, or a bright object in front): the outer level gives no pair, and its nested level's
    parent was refuted, two streaked blank slots reading as dots, so the nested level came out as the outer one
    and the pose 5x too far (+400 %, reported ok). Such a slot is not read when its outer band is bright and its
    inner one dark (``levels_kernel.verdict``): the parent is confirmed by its four dots and two dark blanks."""
    case = make_case("streaked", "single", "grey", "1920x1200-12bit", [(0.05, 20.0)], [1.0], 3, sheet=2.8)
    scenario = Scenario.from_dict(case.scenario)
    frame = scenario.render_frame(0)
    ((target_id, pose),) = scenario.truth_for(0).items()
    centre = scenario.camera.project(pose.t[None, :])[0]
    outline = disk_outline_px(scenario.formation.render_camera, pose, OUTER_RADIUS_M)
    radius = float(np.linalg.norm(outline - outline.mean(axis=0), axis=1).max())
    image = frame.image.copy()
    top = int(image.max())
    for x in range(int(centre[0] - 0.8 * radius), int(centre[0] + 0.8 * radius), 5):
        image[int(centre[1] - 1.3 * radius) : int(centre[1] - 0.6 * radius) + x * 13 % 9, x : x + 3] = top
    result = Tracker(scenario.camera, scenario.targets, TrackerOptions(compensate_exposure=True)).process(
        image, frame.exposure_us)
    (found,) = [t for t in result.targets if t.fit.ok]
    assert found.target_id == target_id
    assert abs(found.pose.distance_m / pose.distance_m - 1.0) < 0.01, found.levels_used


def test_a_pose_bent_by_blooming_is_refused():
    """Seed 7's optics-003 (a 117 px target under strong blooming: 21 % charge spill, 2.5 px defocus, 3.5 px
    motion blur, a halo) at x4 after its x0.25 frame: fitted jointly, its two levels gave +5.9 % (2.96 px RMS,
    under the 3 px limit) and were reported ok; fitted alone, its outer level's edges are 3.4 px RMS off the model
    and the levels disagree by 4.4 %. Refused (``tracker.checks.MAX_LEVEL_DISAGREEMENT``), and the nested level alone
    (+8.3 %, its residuals mostly a directional bias: ``tracker.checks.ANISOTROPY_MAX_SHIFT``) too."""
    (case,) = [c for c in build_cases(7) if c.name == "optics-003"]
    scenario = Scenario.from_dict(case.scenario)
    optical = scenario.formation.optical_image(scenario.placements_for(0))
    tracker = Tracker(scenario.camera, scenario.targets, TrackerOptions(compensate_exposure=True))
    truth = scenario.truth_for(0)[12].distance_m
    for k, factor in ((0, 0.25), (4, 4.0)):
        frame = scenario.render_frame(k, optical=optical)
        assert frame.exposure_factor == factor
        result = tracker.process(frame.image, frame.exposure_us)
        ok = [t for t in result.targets if t.fit.ok]
        if factor < 1.0:
            assert [t.target_id for t in ok] == [12] and abs(ok[0].pose.distance_m / truth - 1.0) < 0.001
    assert not any(abs(t.pose.distance_m / truth - 1.0) > 0.01 for t in ok), [t.pose.distance_m / truth for t in ok]
    assert any("alone" in f.reason for f in result.failures), result.failures
    # both refusals are reported: the outer level's and its nested level's alone (a directional bias)
    assert any("its nested levels alone: " in f.reason and "direction" in f.reason for f in result.failures), \
        result.failures
