"""Detection in any scene (issue 10): every visible target found with its id, nothing found where there is no
target. Seeded sweeps of ``livetrack.evaluation.detection``; the default run holds a small hand-picked set of
hard scenes, the slow one the evaluation's quick sweep. The figures are printed (``-s``) for the README."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from livetrack.commands.evaluate import format_detection, format_explain, plot_detection
from livetrack.estimator.detect import TraceEvent
from livetrack.estimator.tracker import Tracker, TrackerOptions
from livetrack.evaluation.detection import (
    QUICK_EXPOSURES,
    TABLE_KEYS,
    DetectionResult,
    EmptyOutcome,
    TargetOutcome,
    build_cases,
    explain_counts,
    explain_miss,
    make_case,
    measure_visibility,
    run_case,
    run_detection_sweep,
    run_no_target,
    run_photos,
    target_masks,
)
from livetrack.sim.scenario import Scenario
from livetrack.targets.spec import TargetSpec
from tests.realdata import REPO, realdata_dir

REQUIRED_FOUND_RATE = 0.995


def photos() -> list[tuple[str, np.ndarray]]:
    root = realdata_dir()
    if root is None:
        return []
    files = sorted((root / "other-markers").glob("*.png")) + sorted((root / "chessboard").glob("*.jpg"))[:3]
    return [(f.name, cv2.imread(str(f), cv2.IMREAD_UNCHANGED)) for f in files]


def report(result: DetectionResult) -> str:
    s = result.summary()
    misses = [(m.case, m.background, m.exposure_factor, round(100 * m.area_fraction, 3), round(m.tilt_deg),
               m.failure) for m in result.misses()]
    return (f"found {s['found']}/{s['visible']} visible, false positives {s['false_positives_no_target']} on "
            f"{s['no_target_frames']} empty frames, {s['false_positives_with_targets']} beside targets; "
            f"misses {misses}")


def test_visibility_follows_the_ring_contrast():
    case = make_case("v", "single", "grey", "1280x800-8bit", [(0.01, 0.0)], (1.0, 32.0, 256.0), seed=4)
    scenario = Scenario.from_dict(case.scenario)
    (tid, pose), = scenario.truth_for(0).items()
    spec = next(t for t in scenario.targets if t.id == tid)
    masks = target_masks(scenario.formation.render_camera, spec, pose)
    assert masks is not None and masks.ring.sum() > 50 and masks.white.sum() > 50
    vis = [measure_visibility(f.image, masks, 0.0) for f in scenario.frames()]
    assert vis[0].visible and vis[0].contrast > 0.8
    # Far over-exposed, the ring fills with light and saturates with the white: not visible.
    assert vis[2].contrast < vis[1].contrast < vis[0].contrast and not vis[2].visible
    # A target too small for a pixel clear of the edges on its ring cannot be measured.
    tiny = TargetSpec.default(3, 0.125)
    far = pose.__class__(pose.R, pose.t * 60.0)
    assert not measure_visibility(scenario.render_frame(0).image,
                                  target_masks(scenario.formation.render_camera, tiny, far), 0.0).visible


@pytest.fixture(scope="module")
def hard_scenes() -> DetectionResult:
    """Small far targets in saturated bright scenes, textured and lit unevenly, edge-to-edge, several at once,
    in the corner of a distorted lens, 8/12/16 bit, x0.25 to x32."""
    exposures = (0.25, 4.0, 32.0)
    cases = [
        make_case("bright-far", "single", "bright-noise", "1920x1200-12bit", [(0.0006, 10.0)], exposures, 1),
        make_case("white-far-tilted", "single", "white", "1280x800-8bit", [(0.002, 50.0)], exposures, 2),
        make_case("text-no-sheet", "single", "text", "1280x800-8bit", [(0.004, 30.0)], exposures, 3, sheet="none"),
        make_case("several", "multi", "gradient", "1280x800-8bit", [(0.001, 0.0), (0.005, 40.0), (0.02, 20.0)],
                  exposures, 4),
        make_case("corner", "border", "foliage", "1280x960-16bit-wide", [(0.003, 30.0)], exposures, 5,
                  where="corner"),
    ]
    result = DetectionResult()
    for case in cases:
        run_case(case, result, explain=True)
    run_no_target(cases[:3], result, (1.0, 32.0), np.random.default_rng(9))
    run_photos(photos()[:2], result, [TargetSpec.default(i, 0.125) for i in (1, 3, 5, 8, 12)])
    print(report(result))
    return result


MEASURED_FOUND_RATE_HARD = 18 / 18
"""Found rate of the hard scenes on 2026-12-03, session 15 (17 / 18 from session 5 on, the miss at x32, a 0.06 %
target on bright noise; session 4 also missed one of three on a gradient). A regression floor: lower means the
detector got worse."""
MEASURED_FOUND_RATE_QUICK = 0.96
"""Found rate of the quick sweep (`evaluate detection --quick`) on 2026-12-02, session 5: 94 / 102 (92.2 %); a
regression floor with room for this test's other backgrounds. Session 7, with the no-sheet family: 107 / 116
(92.2 %); session 8: 108 / 116 (93.1 %), the same one false positive beside a target; session 10: 111 / 116
(95.7 %), 0 false positives on 154 frames without targets, the one beside a target; session 11: 113 / 116
(97.4 %), the same. Session 13, with the optics family (4 scenes here): 122 / 128 (95.3 %; the other scenes 113 /
116 as before, the optics ones 9 / 12: an 11.6 px target defocused by 2.2 px, its code dots blurred away), 0 false
positives on 162 frames without targets, the same one beside a target. Session 15: 125 / 128 (97.7 %; the three
misses that defocused target's), 0 false positives on 135 frames without targets, the one beside a target; the
floor raised to 0.96."""


def test_hard_scenes_no_false_positive_and_no_regression(hard_scenes):
    s = hard_scenes.summary()
    assert s["visible"] >= 12 and s["no_target_frames"] >= 8
    assert s["found_rate"] >= MEASURED_FOUND_RATE_HARD, report(hard_scenes)
    assert s["false_positives_no_target"] == 0 and s["false_positives_with_targets"] == 0, report(hard_scenes)
    assert s["max_abs_distance_error_pct"] < 1.0


def test_each_miss_is_explained(hard_scenes):
    """``run_case(explain=True)``: every visible target missed carries the stage that lost it, no found one does."""
    misses = hard_scenes.misses()
    assert all(t.explain and t.explain.split(":")[0] in EXPLAIN_STAGES + ("pose_fit", "level", "estimate")
               for t in misses), [t.explain for t in misses]
    assert all(t.explain is None for t in hard_scenes.targets if t.found)
    assert sum(explain_counts(hard_scenes.targets).values()) == len(misses)


EXPLAIN_STAGES = ("no blob", "blob", "pair", "border", "code", "identified", "wrong id")


def test_explain_miss_names_the_furthest_stage():
    centre = np.array([100.0, 50.0])

    def event(stage, level=0, at=(100.0, 50.0), size=20.0, detail=""):
        return TraceEvent(stage, level, at, size, detail)

    assert explain_miss([], centre, 18.0, 20.0).startswith("no blob")
    far = [event("pair", at=(150.0, 50.0)), event("candidate", at=(100.0, 50.0), size=90.0, detail="id 3 level 0")]
    assert explain_miss(far, centre, 18.0, 20.0).startswith("no blob")  # elsewhere, or of another size
    blobs = [event("blob", 0, detail="no hole"), event("blob", 1, detail="hole area/centre"),
             event("blob", 1, detail="no hole")]
    assert explain_miss(blobs, centre, 18.0, 20.0) == "blob: L0 no hole; L1 hole area/centre, no hole"
    coded = blobs + [event("pair", 1, detail="plain"), event("code", -1, detail="no code match")]
    assert explain_miss(coded, centre, 18.0, 20.0) == "code: no code match"
    assert explain_miss(coded + [event("border", -1)], centre, 18.0, 20.0).startswith("border")
    assert explain_miss(blobs + [event("pair", 2)], centre, 18.0, 20.0) == "pair: ratio matches no geometry (L2)"
    found = coded + [event("candidate", -1, detail="id 3 level 1")]
    assert explain_miss(found, centre, 18.0, 20.0) == "identified: id 3 level 1 (lost after)"
    assert explain_miss(found, centre, 18.0, 20.0, failure="pose_fit: cap") == "pose_fit: cap"
    assert explain_miss(found, centre, 18.0, 20.0, wrong_id=True) == "wrong id"


def test_hard_scenes_every_visible_target_found(hard_scenes):
    """Every visible target of the hard scenes, since session 15 (17 / 18 before: at x32, a 0.06 % target on
    bright noise, its ring cut open by its grown dots: ``detect/arcs.py``)."""
    assert hard_scenes.summary()["found_rate"] >= REQUIRED_FOUND_RATE, report(hard_scenes)


@pytest.mark.slow
def test_quick_sweep_no_false_positive_and_no_regression():
    root = realdata_dir()
    backgrounds = [str(f) for f in sorted((root / "other-markers").glob("*.png"))] if root else []
    result = run_detection_sweep(seed=0, quick=True, photos=photos(), background_files=backgrounds)
    s = result.summary()
    print(report(result))
    assert s["visible"] >= 100 and s["no_target_frames"] >= 40
    assert {t.exposure_factor for t in result.targets} == set(QUICK_EXPOSURES)
    # The aim is REQUIRED_FOUND_RATE (99.5 %); measured 95.3 % on 2026-12-03 (`evaluate detection --quick`).
    assert s["found_rate"] >= MEASURED_FOUND_RATE_QUICK, report(result)
    assert s["false_positives_no_target"] == 0, report(result)
    # Beside targets: one known since session 7's no-sheet scenes (no-sheet-000 at x32: on a large target whose
    # ring is clipped to light grey, one grown code dot taken for an inner disk and two others for id 1's two-dot
    # code). A regression floor, not the aim (0).
    assert s["false_positives_with_targets"] <= KNOWN_FALSE_POSITIVES_BESIDE_TARGETS_QUICK, report(result)


KNOWN_FALSE_POSITIVES_BESIDE_TARGETS_QUICK = 1


def outcome(**changes) -> TargetOutcome:
    base = dict(case="c", family="single", background="grey", camera="cam", bit_depth=12, sheet="2.8",
                exposure_factor=1.0, target_id=3, distance_m=2.0, tilt_deg=30.0, area_fraction=0.01,
                semi_minor_px=50.0, contrast=0.9, snr=50.0, ring_visible=True, visible=True, found=True, detected=True,
                wrong_id=False, distance_error_pct=0.01, centre_error_px=0.3, failure=None)
    return TargetOutcome(**{**base, **changes})


def test_tables_report_and_plot(tmp_path):
    result = DetectionResult(targets=[
        outcome(), outcome(exposure_factor=32.0, found=False, distance_error_pct=None, failure="pose_fit: x",
                           explain="pose_fit: x"),
        outcome(exposure_factor=32.0, ring_visible=False, visible=False, found=False, contrast=0.05,
                distance_error_pct=None),
        outcome(semi_minor_px=6.0, visible=False, found=False, distance_error_pct=None),
        outcome(background="text", area_fraction=0.0006, semi_minor_px=15.0, distance_error_pct=-8.0),
    ], empty=[EmptyOutcome("photo.png x1", "photo", 1, (5,)), EmptyOutcome("grey x1", "background", 0, ())])
    s = result.summary()
    assert (s["visible"], s["found"], s["invisible"], s["gross_pose_errors"]) == (3, 2, 2, 1)
    assert s["ring_visible_too_small"] == 1 and s["found_too_small"] == 0
    assert s["false_positives_no_target"] == 1 and s["found_rate"] == pytest.approx(2 / 3)
    by_exposure = {r["exposure_factor"]: r for r in result.table("exposure_factor")}
    assert by_exposure[32.0]["visible"] == 1 and by_exposure[32.0]["found_rate"] == 0.0
    assert [r["area"] for r in result.table("area")] == ["<0.1%", "0.5-2%"]
    assert [r["size"] for r in result.table("size")] == ["b<12px", "b12-20px", "b40-100px"]
    text = format_detection(s, {k: result.table(k) for k in ("exposure_factor", "background")})
    assert "visible targets found: 2/3 (66.67%)" in text and "1 on 2 frames without targets" in text
    report = {"summary": s, "tables": {k: result.table(k) for k in TABLE_KEYS},
              "targets": result.to_dict()["targets"]}
    plot_detection(report, tmp_path / "d.png")
    assert (tmp_path / "d.png").stat().st_size > 10000
    explained = format_explain(result.misses())
    assert "1 visible targets missed" in explained and "pose_fit        1" in explained
    assert explained.splitlines()[-1].endswith("pose_fit: x")


@pytest.mark.parametrize("seed, camera", [(2, "1280x960-16bit-wide"), (3, "1920x1200-12bit"),
                                          (6, "1920x1200-12bit")])
def test_target_printed_without_a_sheet_on_grey_ground(seed, camera):
    """A target printed edge to edge on grey ground (1 % of the frame, 20 deg): the detector's threshold between
    its black and white puts the outer edge (black against grey) pixels off, beyond the edge profiles; the outer
    circle's profiles are fitted again longer (``Tracker._wide_circles``). Without that, these frames failed
    ("edges": too few outer points) in 21 of 32 such scenes x exposures."""
    case = make_case("no-sheet", "single", "grey", camera, [(0.01, 20.0)], (1.0, 2.0), seed, sheet="none")
    result = DetectionResult()
    run_case(case, result)
    assert [t.found for t in result.targets] == [True, True], [(t.failure, t.explain) for t in result.targets]
    assert max(abs(t.distance_error_pct) for t in result.targets) < 0.05


def test_the_specified_range_of_sizes_is_reported_apart():
    """Issue 10 specifies detection for targets covering 0.05 % to 60 % of the frame; the sweep also draws smaller
    ones (tilted), which count in the found rate and are left out of the rate within that range."""
    gone = dict(found=False, distance_error_pct=None)
    result = DetectionResult(targets=[outcome(), outcome(area_fraction=0.0003, **gone),
                                      outcome(area_fraction=0.0004), outcome(area_fraction=0.7, **gone),
                                      outcome(area_fraction=0.0005, **gone)])
    s = result.summary()
    assert (s["visible"], s["found"]) == (5, 2)
    assert (s["visible_in_specified_range"], s["found_in_specified_range"]) == (2, 1)
    assert s["found_rate_in_specified_range"] == 0.5
    text = format_detection(s, {})
    assert "of those covering 0.05-60 % of the frame (the specified range): 1/2 (50.00%)" in text
    assert DetectionResult().summary()["found_rate_in_specified_range"] is None


def test_found_targets_carry_their_fit_quality_and_dots_scale():
    """Each found target's outcome says how well its pose fits (edge RMS), how precise it claims to be (the
    distance's sd from the covariance) and where its code dots lie (``dots_scale``, ~1 for a good pose); a missed
    one carries none. A 1 % target at 20 deg on grey ground: within 0.1 px RMS, 0.05 % sd and 1 % of its dots."""
    case = make_case("quality", "single", "grey", "1920x1200-12bit", [(0.01, 20.0)], (1.0, 8.0), 3)
    result = DetectionResult()
    run_case(case, result)
    assert [t.found for t in result.targets] == [True, True]
    for t in result.targets:
        assert 0.0 < t.residual_rms_px < 0.1 and 0.0 < t.distance_sd_pct < 0.05
        assert abs(t.dots_scale - 1.0) < 0.01
        assert abs(t.distance_error_pct) < 3.0 * t.distance_sd_pct + 0.01
    assert {"residual_rms_px", "distance_sd_pct", "dots_scale"} <= set(result.to_dict()["targets"][0])
    within = sum(abs(t.distance_error_pct) <= 3.0 * t.distance_sd_pct for t in result.targets) / 2
    assert result.summary()["distance_within_3sd"] == within


def test_srgb_encoded_frames_keep_the_distance():
    """Another renderer's convention: 8-bit frames sRGB-encoded (a phone, most image tools) instead of linear.
    The encoding moves every black/white edge toward the black by ~0.4 px at the usual blur, as an exposure bias
    does; the joint exposure-bias estimate (delta) absorbs it and the distance stays within 0.02 %."""
    case = make_case("srgb", "single", "grey", "1280x800-8bit", [(0.02, 30.0)], (0.5, 2.0), 2)
    scenario = Scenario.from_dict(case.scenario)
    tracker_linear = Tracker(scenario.camera, scenario.targets, TrackerOptions(compensate_exposure=True))
    tracker_srgb = Tracker(scenario.camera, scenario.targets, TrackerOptions(compensate_exposure=True))
    for k in range(len(scenario)):
        frame = scenario.render_frame(k)
        linear = frame.image.astype(np.float64) / 255.0
        encoded = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1 / 2.4) - 0.055)
        image = np.clip(np.round(encoded * 255.0), 0, 255).astype(np.uint8)
        deltas = []
        for tracker, im in ((tracker_linear, frame.image), (tracker_srgb, image)):
            found = [t for t in tracker.process(im, frame.exposure_us).targets if t.fit.ok]
            assert len(found) == 1
            truth = frame.truth[found[0].target_id]
            assert abs(found[0].pose.distance_m / truth.distance_m - 1.0) < 2e-4
            deltas.append(found[0].fit.delta_px)
        assert deltas[1] - deltas[0] > 0.2  # the encoding's shift, absorbed by delta


def _single_target(case) -> TargetOutcome:
    """The outcome of the one target of a one-frame ``case``, which must have been found (else its failure and the
    stage that lost it)."""
    result = DetectionResult()
    run_case(case, result, explain=True)
    (target,) = result.targets
    assert target.found, (target.failure, target.explain)
    return target


@pytest.mark.parametrize("background, area, tilt_deg, exposure, seed", [
    ("grey", 0.002, 0.0, 16.0, 2399), ("grey", 0.01, 50.0, 16.0, 3953), ("carpet", 0.002, 0.0, 16.0, 6454),
    ("carpet", 0.01, 0.0, 4.0, 6521)])
def test_over_exposed_target_printed_without_a_sheet_keeps_its_distance(background, area, tilt_deg, exposure,
                                                                        seed):
    """Over-exposed, a target printed edge to edge shows grey or textured ground, not its own white, outside its
    outer circle: the clipped edge profiles there have 2-5x less contrast than the rest. One shared contrast
    for all put the outer circle's edges off (distance -1.6 %, -0.8 %, -0.5 %, -0.3 % in these four scenes); the
    ground's profiles now keep their own (``fit_edges_two_pass(contrast_groups=...)``)."""
    target = _single_target(make_case("no-sheet", "single", background, "1920x1200-12bit", [(area, tilt_deg)],
                                      (exposure,), seed, sheet="none"))
    assert abs(target.distance_error_pct) < 0.15


def test_child_alone_on_dark_ground_is_not_taken_for_its_parent():
    """A target printed without a sheet on dark foliage: its outer circle merges with the ground and only the
    nested level (8 px) is found. Its parent's dots, sampled through the child's own map extrapolated 3-5 of its
    radii out, read dark, so the parent was refuted and the child came out as the outer level: +400 % distance.
    Read through a map anchored on the parent's white disk edge, the parent's code confirms the nested level."""
    target = _single_target(make_case("no-sheet", "single", "foliage", "1920x1200-12bit", [(0.002, 0.0)], (1.0,),
                                      8704, sheet="none"))
    assert abs(target.distance_error_pct) < 0.5


@pytest.mark.parametrize("exposure", [0.25, 1.0])
def test_small_target_inner_profiles_stop_short_of_the_nested_level(exposure):
    """A 20 px target (semi-minor axis; its nested level 4 px, too small to fit): the inner circle's profiles
    reached the nested level's black ring, whose blur darkened their white side and moved that edge ~0.2 px into
    the black; the exposure bias took it for over-exposure and the distance came out 0.6 % short. The profiles
    now stop short of the next edge of the design on their white side (``Tracker._reach_px``)."""
    target = _single_target(make_case("small", "single", "grey", "1920x1200-12bit", [(0.0005, 0.0)], (exposure,),
                                      2399, sheet=2.8))
    assert abs(target.distance_error_pct) < 0.25


def test_deeply_over_exposed_target_on_its_sheet_shares_one_contrast():
    """Paper-lab on bright ground, a target 5.6 m away at 16x: its outer circle's clipped profiles read 0.65 of
    the contrast of its inner circle's, though both see the same white paper. Taken for a darker ground, each got
    its own contrast and the distance was 0.39 % off; so deep a clip needs a far darker ground to split
    (``CONTRAST_SPLIT_RATIO_DEEP``)."""
    scenario = Scenario.from_file(REPO / "config/scenarios/paper-lab-bright.yaml")
    tracker = Tracker(scenario.camera, scenario.targets, TrackerOptions(compensate_exposure=True))
    n = len(scenario.exposure_factors)
    for k in range(6 * n, 7 * n):  # the step's exposures in order, as the sweep tracks them
        frame = scenario.render_frame(k)
        out = tracker.process(frame.image, frame.exposure_us)
    assert frame.exposure_factor == 16.0
    (found,) = [t for t in out.targets if t.fit.ok]
    truth = frame.truth[found.target_id]
    assert abs(found.pose.distance_m / truth.distance_m - 1.0) < 5e-4


def test_target_without_sheet_on_carpet_keeps_its_ground_contrast_apart_when_clipped_deep():
    """Seed 1's no-sheet-000: a 39 px target printed without a sheet on carpet (0.45) at x8. Its ground read 0.55
    of its white's contrast, 13 standard errors below it, but the deep-clip rule asked for under 0.5: both shared
    one contrast, too low for the inner circle and too high for the outer one, and the distance came out 0.82 %
    short. Split now (``two_pass.CONTRAST_SPLIT_Z_DEEP``): -0.25 %."""
    case = next(c for c in build_cases(1) if c.name == "no-sheet-000")
    result = DetectionResult()
    run_case(case, result)
    (target,) = [t for t in result.targets if t.target_id == 8 and t.exposure_factor == 8.0]
    assert target.found and abs(target.distance_error_pct) < 0.4, target


@pytest.mark.slow  # its one frame takes ~40 s (the search's 2-D target-model fit of a 380 px target)
def test_huge_target_deep_in_an_8_bit_clip_keeps_a_contrast_that_reaches_the_clip():
    """Seed 1's single-001 at x32: a 380 px target printed without a sheet on grey, 8-bit, its ring at 0.83 of
    full scale (1 % of its contrast below the clip). Detected, but the inner circles' fits shared a contrast of 28
    levels (their white at the clip level), under which no profile of the outer circle could reach the clip: 0 of
    360 fitted, no pose. Found now (``two_pass._reaching_the_clip``), within 1 %."""
    case = next(c for c in build_cases(1) if c.name == "single-001")
    result = DetectionResult()
    run_case(case, result, exposures={32.0})
    (target,) = result.targets
    assert target.found and abs(target.distance_error_pct) < 1.0, target


def test_ring_merged_with_dark_squares_is_paired_from_its_hole():
    """A 34 px target printed without a sheet on a chessboard: its black ring merges with the dark squares it
    touches, so its blob's outline is no ellipse (or the blob is too big for a pair) and no pair came from it at
    any exposure. Its white inner disk is still a clean round hole: the outer ellipse it implies, dark around
    the hole and bright in part beyond, is read like any pair, more strictly (``_hole_pairs``). Under- and
    over-exposed, the hole scaled by the design's ratio missed the outer edge by ~1 px (exposure moves the hole
    and the edge opposite ways) and the dark-ring check failed at x0.25, x8 and x16: the edge is now read off
    the merged blob's outline where it borders bright squares (``_outer_on_outline``)."""
    case = next(c for c in build_cases(0) if c.name == "no-sheet-004")
    case.scenario["exposure"]["factors"] = [0.25, 1.0, 8.0, 16.0]
    result = DetectionResult()
    run_case(case, result, explain=True)
    assert all(t.visible and t.found for t in result.targets), [(t.exposure_factor, t.explain) for t in result.targets]
    assert max(abs(t.distance_error_pct) for t in result.targets) < 0.15


def test_two_dot_code_of_a_ring_merged_with_squares():
    """Seed 1's no-sheet-004: id 1 (a two-dot code), 36 px, printed without a sheet on a chessboard; its ring merges
    with the squares and is found from its hole alone, where codes of under three dots are refused (two bright
    flecks around a round hole in foliage read as id 1). Its outer edge runs along the merged blob's outline in
    21 of 32 directions: a pair so seen ("outline") may carry a sparse code. Missed at every exposure before."""
    case = next(c for c in build_cases(1) if c.name == "no-sheet-004")
    result = DetectionResult()
    run_case(case, result, explain=True)  # the sweep's 8 exposures (each frame's noise is the sweep's)
    visible = [t for t in result.targets if t.visible]
    assert len(visible) == 8 and {t.target_id for t in visible} == {1}
    # x2 (the ring merged with the squares all around on level 1) since the closed retry pairs holes too; x32
    # (contrast 0.11, the white squares clipped across its outer edge) since its code is read against the gaps
    # beside its slots (``code._against_the_gaps``), its pose poor: -2.3 %, the edges fitted to 2.8 px RMS
    assert all(t.found for t in visible), [(t.exposure_factor, t.explain) for t in visible]
    assert max(abs(t.distance_error_pct) for t in visible if t.exposure_factor <= 16.0) < 0.25  # x2: -0.15 %
    (x32,) = [t for t in visible if t.exposure_factor == 32.0]
    assert abs(x32.distance_error_pct) < 3.0 and x32.residual_rms_px > 1.0


def test_ring_merged_with_foliage_and_its_dot_is_found_from_the_closed_hole():
    """Seed 4's multi-001: id 8 (19 x 32 px, 60 deg, no sheet) on foliage. Its inner disk touches a code dot (no
    clean hole) and its outline is merged with texture (no ellipse, trimmed or not). Closing the crop parts the
    dot from the disk, and the pair is then found from that hole, its outer edge read off the outline
    (``_pairs_closed(from_holes=...)``): found at x0.25 and x4, missed at every exposure before."""
    case = next(c for c in build_cases(4) if c.name == "multi-001")
    result = DetectionResult()
    run_case(case, result)  # the sweep's exposures (each frame's noise is the sweep's)
    found = {t.exposure_factor for t in result.targets if t.target_id == 8 and t.found}
    assert {0.25, 4.0} <= found, found
    assert all(abs(t.distance_error_pct) < 1.0 for t in result.targets if t.target_id == 8 and t.found)


def test_text_around_a_target_is_not_taken_for_its_parent():
    """Seed 4's single-023: an 18 px target without a sheet on printed text (reflectance 0.85), x0.5. The text
    around it read as its parent's code on 4 of 8 slots, at 0.43-0.57 of the pair's contrast, and the target came
    out as its own nested level: -80 % distance, reported as a pose. A parent is now confirmed only where its
    readable slots keep most of the pair's contrast (``levels.PARENT_MIN_CONTRAST``)."""
    case = next(c for c in build_cases(4) if c.name == "single-023")
    result = DetectionResult()
    run_case(case, result)
    found = [t for t in result.targets if t.found]
    assert len(found) >= 7
    assert max(abs(t.distance_error_pct) for t in found) < 0.5, [(t.exposure_factor, t.distance_error_pct)
                                                                   for t in found]


def test_two_dot_code_of_a_ring_seen_on_part_of_its_outline():
    """Seed 3's multi-004: id 1 (two dots), 21 px, no sheet, merged with chessboard squares on three sides: its
    outer edge runs along the merged outline in 15 of 32 directions around a 9 px hole, under the 60 % asked of a
    4 px one. Around a hole of 6 px or more 40 % suffices (``hole_pairs.HOLE_PAIR_OUTLINE_SEEN``): missed at x0.25-x8
    before, found now; its distance is 0.22-0.41 % short (the outer circle's profiles run into the dark squares
    where the ring merges with them: open)."""
    case = next(c for c in build_cases(3) if c.name == "multi-004")
    result = DetectionResult()
    run_case(case, result)
    found = {t.exposure_factor for t in result.targets if t.target_id == 1 and t.found}
    assert {0.25, 0.5, 1.0, 2.0, 4.0, 8.0} <= found, found
    assert all(abs(t.distance_error_pct) < 0.5 for t in result.targets if t.target_id == 1 and t.found)


def test_grey_rings_of_a_frame_saturated_around_them_at_x32():
    """Seed 4's multi-004 at x32: three targets printed without a sheet on a chessboard, whose white and white
    squares saturate; the black rings and the dark squares are a light grey at 0.83 of full scale (~1 level of
    noise). The noise figure counted the clipped pairs and read 21 levels: the offset below saturation (24
    levels) left half of each ring's pixels above it, and nothing was found. The offset below saturated pixels
    now comes from the unclipped pairs' noise (``threshold._noise``): all three found, within 0.15 %."""
    case = next(c for c in build_cases(4) if c.name == "multi-004")
    result = DetectionResult()
    run_case(case, result)
    at_x32 = {t.target_id: t for t in result.targets if t.exposure_factor == 32.0}
    assert {5, 8, 12} <= {tid for tid, t in at_x32.items() if t.found}, at_x32
    assert all(abs(at_x32[tid].distance_error_pct) < 0.5 for tid in (5, 8, 12))


def test_small_target_without_sheet_on_grey_in_a_wide_lens_corner():
    """A 13.5 px target printed without a sheet on grey ground (0.2) in the corner of a wide lens, at x2: halfway
    between its black and its inner white, the grey ground reads dark, so the refinement found no pair and the
    local threshold's outer ellipse (2-3 px too wide) started the edge fits: two thirds of the outer profiles
    missed the edge and the pose fit failed (10.8 px RMS). The refinement now thresholds halfway to the ground
    when the ground is darker than the middle. (The distance is then 0.35-0.45 % short at x1-x8 here, more than
    such a target's usual 0.1 %: both circles' edges read 0.02-0.06 px wide; open.)"""
    case = next(c for c in build_cases(0) if c.name == "border-003")
    result = DetectionResult()
    run_case(case, result)  # all 8 exposures: the x2 frame's noise is that of the sweep's
    (target,) = [t for t in result.targets if t.exposure_factor == 2.0]
    assert target.visible and target.found, target.failure
    assert abs(target.distance_error_pct) < 1.0


def test_two_dot_code_of_a_ring_on_carpet_seen_in_the_image():
    """Seed 2's multi-000: id 1 (two dots), 25 x 39 px, printed without a sheet on carpet. The threshold joined
    its ring to dark patches of the carpet, so it was paired from its hole alone with its outer edge on the
    outline in under 40 % of the directions ("hole"), where codes of under three dots are refused: missed at
    every exposure. The image itself shows the step from its ring to the carpet in 0.75-0.81 of the directions
    at x0.25-x4 (``refine.outer_edge_seen``); from 0.7 the sparse code is read (``HOLE_PAIR_EDGE_SEEN``). Its
    distance is off by up to 1.1-1.3 % (x0.5-x1): the outer circle's profiles run into the carpet's dark patches
    where the ring merges with them (as on the chessboard: open)."""
    case = next(c for c in build_cases(2) if c.name == "multi-000")
    case.scenario["exposure"]["factors"] = [0.25, 1.0, 4.0]
    result = DetectionResult()
    run_case(case, result)
    ones = [t for t in result.targets if t.target_id == 1]
    assert len(ones) == 3 and all(t.visible and t.found for t in ones), [(t.exposure_factor, t.failure)
                                                                         for t in ones]
    assert all(abs(t.distance_error_pct) < 1.5 for t in ones), [(t.exposure_factor, t.distance_error_pct) for t in ones]


def test_ring_in_foliage_paired_on_a_coarse_level_is_placed_on_its_edge():
    """Seed 2's border-001: id 3, 26 x 29 px, in dark foliage at the border of a wide 16-bit frame. Found only
    from its hole on level 1, whose outer ellipse (the hole scaled) came out 16 % too large: its code was read
    at the wrong radii ("no code match") at x0.5-x2. The outer ellipse is now rescaled to where the image shows
    the ring's outer edge (12 of 32 directions, at 0.87 of it; ``HOLE_PAIR_EDGE_PLACED``): found at x0.5-x8, its
    distance within 0.35 % at x0.5-x2 and 1.1-1.3 % short at x4-x8 (its outer profiles run into the foliage)."""
    case = next(c for c in build_cases(2) if c.name == "border-001")
    result = DetectionResult()
    run_case(case, result)  # the sweep's 8 exposures (each frame's noise is the sweep's)
    found = {t.exposure_factor for t in result.targets if t.target_id == 3 and t.found}
    assert {0.5, 1.0, 2.0} <= found, found
    assert all(abs(t.distance_error_pct) < 1.5 for t in result.targets if t.target_id == 3 and t.found), \
        [(t.exposure_factor, t.distance_error_pct) for t in result.targets if t.target_id == 3 and t.found]


def test_ring_cut_by_a_grown_dot_on_a_small_sheet_is_closed_alone():
    """Seed 2's single-018: id 1, 12 x 19 px, on a small sheet on black ground. Over-exposed (x4), a grown code dot
    cuts its ring open; the closed-crop retry then also closed the sheet's 1-3 px margin and joined the ring to the
    ground: no ellipse. The blob's own pixels are now closed first (with a 5 px disk, then a 7 px one: the dot's
    gap was 5-6 px), the whole crop only when that gives nothing (``pairs._pairs_closed``). Missed at x0.25 and
    x4 before."""
    case = next(c for c in build_cases(2) if c.name == "single-018")
    case.scenario["exposure"]["factors"] = [0.25, 4.0]
    result = DetectionResult()
    run_case(case, result)
    assert all(t.visible and t.found for t in result.targets), [(t.exposure_factor, t.failure)
                                                                for t in result.targets]
    assert all(abs(t.distance_error_pct) < 0.5 for t in result.targets), [
        (t.exposure_factor, t.distance_error_pct) for t in result.targets]


def test_dark_fleck_in_ground_clipped_all_round_is_no_target():
    """Seed 9's 1920x1200 12-bit foliage without targets, at x16: a dark fleck around a lighter spot, the ground
    clipped all round, read as id 1's two dots (its "white" 2151 of 4095, its ring thicker than the design's, as
    no target in ground that clips looks: ``code._darker_than_its_clipped_surroundings``). Reported as id 1 on
    the background alone and with the decoys before. The frame's real targets at x16 (single-004: id 3 at two
    levels) are still found."""
    case = next(c for c in build_cases(9) if c.background == "foliage" and c.camera == "1920x1200-12bit")
    result = DetectionResult()
    run_no_target([case], result, (16.0,), np.random.default_rng(9))
    assert [e.reported for e in result.empty] == [0, 0], result.empty
    found = DetectionResult()
    case = next(c for c in build_cases(9) if c.name == "single-004")
    case.scenario["exposure"]["factors"] = [16.0]
    run_case(case, found)
    assert all(t.found for t in found.targets if t.visible) and not found.spurious, (found.targets, found.spurious)


def test_code_of_a_clipped_ring_lifted_unevenly_is_read_against_its_gaps():
    """Seed 7's single-008: id 5 ("00011011"), 124 px at 70 deg on a 2.8 R sheet, x32 with a 3 % halo, vignetting
    and a 0.6 light gradient. Its ring, lifted by the halo more on one side, read 1, 1, 0.56, 1, 1, -0.14, 0.03,
    0.35 against one black level: no code. Read against the gaps beside each slot (``code._against_the_gaps``) it
    is 1, 1, 0.04, 1, 1, 0, 0, 0.05: found (the sweep: +0.78 %). Missed before."""
    from livetrack.estimator.detect import Detector

    case = next(c for c in build_cases(7) if c.name == "single-008")
    scenario = Scenario.from_dict(case.scenario)
    optical = scenario.formation.optical_image(scenario.placements_for(0))
    frame = scenario.render_frame(case.scenario["exposure"]["factors"].index(32.0), optical=optical)
    (target_id, pose), = scenario.truth_for(0).items()
    centre = scenario.camera.project(pose.t[None, :])[0]
    found = Detector(scenario.targets).detect(frame.image, saturation=float(scenario.camera.saturation_level))
    assert [c.target_id for c in found] == [target_id]
    assert found[0].inner.sampson_distance(centre[None, :])[0] <= 0  # its inner disk around the true centre
    assert found[0].code_margin >= 0.5


def test_hole_pair_read_where_the_usual_pair_of_a_merged_ring_reads_nothing():
    """Seed 2's no-sheet-004 at x32: id 3, 93 px, printed without a sheet on a chessboard whose white squares
    clip (contrast 0.16). Its ring merges with the dark squares: the only usual pair there (pyramid level 4) has
    the merged blob's outline, 14 px off-centre and 30 % too big, and reads no code. Its white inner disk is a
    clean hole on levels 1-3, whose pair was dropped for lying where a usual pair lies. A pair from a hole is now
    read where the usual pairs gave no candidate: found, -0.6 %. Missed before."""
    case = next(c for c in build_cases(2) if c.name == "no-sheet-004")
    case.scenario["exposure"]["factors"] = [32.0]
    result = DetectionResult()
    run_case(case, result, explain=True)
    (target,) = result.targets
    assert target.visible and target.found and not target.wrong_id, target
    assert abs(target.distance_error_pct) < 1.0 and not result.spurious


def test_target_whose_surroundings_mimic_a_parent_shows_its_own_nested_ring():
    """Held-out seed 8's multi-004: id 12, 26 x 41 px at 50 deg on a 2.8 R sheet on a chessboard. Where its parent's
    ring would be (were it its own nested level), the squares beyond the sheet read as a parent's code but one
    square lies in the parent's white disk: its level was reported unknown (x0.25-x8). Its inner disk holds its
    own nested ring (5 x 8 px), which the design's deepest level has not (``levels._child_seen``): level 0, found
    at x0.25-x4 (x8: the nested ring lifted past seeing, still reported unknown)."""
    case = next(c for c in build_cases(8) if c.name == "multi-004")
    case.scenario["exposure"]["factors"] = [1.0, 4.0]
    result = DetectionResult()
    run_case(case, result)
    target = [t for t in result.targets if t.target_id == 12]
    assert len(target) == 2 and all(t.visible and t.found for t in target), target
    assert max(abs(t.distance_error_pct) for t in target) < 0.1


def test_coarse_pair_not_refined_is_placed_on_the_image_edges():
    """Held-out seed 8's single-019 at x16: id 8, 19 px at 70 deg (8-bit, a 3 % halo), paired on pyramid level 3 as
    60.7 x 23.8 px where over-exposure left its ring's outer edge at 55.2 x 17.8; its ring is cut by a grown dot, so
    no refinement, and every edge profile (4 px each way, the design's clearance) lay in the clipped white: no
    pose. Re-placed on the grey image's edges (``detector.COARSE_PAIR_EDGE_SEEN``): found."""
    case = next(c for c in build_cases(8) if c.name == "single-019")
    case.scenario["exposure"]["factors"] = [8.0, 16.0]  # (each frame's noise is that of this sweep)
    result = DetectionResult()
    run_case(case, result)
    assert all(t.visible and t.found and abs(t.distance_error_pct) < 0.2 for t in result.targets), result.targets


def test_frames_delivered_as_other_renderers_deliver_them_are_read():
    """The encoded family (``_draw_encoding``; none before session 25): seed 2's encoded-004, id 3 at 0.043 % of
    the frame on white, an 8-bit camera delivering sRGB then JPEG at quality 90, and seed 0's encoded-001, text
    ground, 12-bit through a display gamma of 2.12: every visible frame found, nothing else reported, and the
    12-bit frames' distances as good as on linear frames (the small JPEG'd target's were 0.5-1.8 % off with
    standard deviations of 0.2-1.1 %: its 8-bit sRGB edges are a few codes deep and blocky; not asserted)."""
    cases = {(c.name, seed): c for seed in (0, 2) for c in build_cases(seed) if c.family == "encoded"}
    jpeg, gamma = cases[("encoded-004", 2)], cases[("encoded-001", 0)]
    assert set(jpeg.scenario["effects"]) >= {"srgb_encoding", "jpeg"}
    assert "gamma_encoding" in gamma.scenario["effects"] and gamma.camera.endswith("12bit")
    for case in (jpeg, gamma):
        result = DetectionResult()
        run_case(case, result)
        visible = [t for t in result.targets if t.visible]
        assert len(visible) >= 5, report(result)
        assert all(t.found for t in visible), report(result)
        assert result.summary()["false_positives_with_targets"] == 0, report(result)
    assert max(abs(t.distance_error_pct) for t in visible) < 0.1, report(result)


def test_encoding_known_gives_the_tracker_the_scenes_encoding():
    """``--encoding-known``: seed 4's encoded-001 (id 1 without a sheet on grey, 12-bit sRGB) read through the
    inverse curve: every visible exposure within 0.1 % (0.44-0.53 % short at x0.25-x4 read as linear)."""
    [case] = [c for c in build_cases(4) if c.name == "encoded-001"]
    told, untold = DetectionResult(), DetectionResult()
    run_case(case, told, encoding_known=True)
    run_case(dataclasses.replace(case, scenario={**case.scenario, "exposure": {
        **case.scenario["exposure"], "factors": [1.0]}}), untold)
    visible = [t for t in told.targets if t.visible]
    assert len(visible) >= 6 and all(t.found for t in visible), report(told)
    assert max(abs(t.distance_error_pct) for t in visible) < 0.1, report(told)
    assert abs(untold.targets[0].distance_error_pct) > 0.3, report(untold)
