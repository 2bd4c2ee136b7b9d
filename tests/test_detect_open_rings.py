"""Rings the threshold image cannot close: a ring cut open by its grown dots (``arcs``), and a large ring merged
with dark ground all round, paired from its hole and re-placed on the grey image's edges."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from livetrack.estimator.detect import Detector, arcs
from livetrack.estimator.detect.arcs import arc_outline, arc_outlines
from livetrack.estimator.detect.options import DetectOptions
from livetrack.estimator.detect.pairs import _pairs
from livetrack.evaluation.detection import disk_outline_px
from livetrack.sim.scenario import Scenario
from livetrack.targets.spec import TargetSpec
from tests.sweep_frames import sweep_frame

_frame = sweep_frame


def _truth_centre(scenario: Scenario, target_id: int) -> np.ndarray:
    pose = scenario.truth_for(0)[target_id]
    spec = next(t for t in scenario.targets if t.id == target_id)
    return disk_outline_px(scenario.formation.render_camera, pose, spec.outer_radius_m).mean(axis=0)


def _found_near(seed: int, name: str, exposure: float, target_id: int, tolerance_px: float) -> list:
    """The candidates the detector reports within ``tolerance_px`` of the truth centre of ``target_id`` in the sweep
    frame of (seed, case name, exposure)."""
    scenario, image = _frame(seed, name, exposure)
    centre = _truth_centre(scenario, target_id)
    found = Detector(scenario.targets).detect(image, saturation=float(scenario.camera.saturation_level))
    return [c for c in found if np.hypot(*(c.outer.centre_px - centre)) < tolerance_px]


def _ring(cut_deg: float) -> np.ndarray:
    """A binary image (255 = dark) of a ring 40 x 26 px (semi-axes), inner 0.4 of it, tilted 30 deg, with a
    wedge of ``cut_deg`` degrees cut out of it."""
    binary = np.zeros((120, 140), np.uint8)
    cv2.ellipse(binary, (70, 60), (40, 26), 30.0, 0, 360, 255, -1)
    cv2.ellipse(binary, (70, 60), (16, 10), 30.0, 0, 360, 0, -1)
    if cut_deg:
        cv2.ellipse(binary, (70, 60), (60, 60), 30.0, -cut_deg / 2, cut_deg / 2, 0, -1)
    return binary


def _blobs(binary: np.ndarray):
    contours, hierarchy = cv2.findContours(binary, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    lengths = np.array([len(c) for c in contours])
    return contours, hierarchy.reshape(-1, 4), lengths


def test_the_arc_of_a_ring_cut_open_gives_its_outer_ellipse():
    """A ring with a 60 deg wedge cut out (no hole left): the ellipse through its outer boundary without the cut is
    the ring's, within half a pixel; the ring closed (it has a hole: the usual pairs' business) or cut down to a
    third of it gives none."""
    binary = _ring(60.0)
    contours, hier, lengths = _blobs(binary)
    found = arc_outlines(binary, contours, hier, lengths, 12, 8.0, 48.0, 0.1)
    assert len(found) == 1
    e = found[0]
    assert np.hypot(*(e.centre_px - (70, 60))) < 0.5
    assert np.allclose(e.semi_axes_px, (40.5, 26.5), atol=0.6), e
    closed = _ring(0.0)
    assert arc_outlines(closed, *_blobs(closed), 12, 8.0, 48.0, 0.1) == []
    third = _ring(240.0)
    contours, hier, lengths = _blobs(third)
    assert arc_outline(contours[0], cv2.boundingRect(contours[0]), third, 0.1) is None


def test_a_ring_cut_open_with_dots_left_in_it_is_an_arc_when_asked():
    """The same C with two white dots inside its band (holes of the blob): not among the holeless blobs, but given
    as a blob whose holes made no pair (``pairs._pairs`` does so), its outer ellipse is the ring's."""
    binary = _ring(60.0)
    for angle in (120.0, 200.0):
        t = np.radians(angle)
        x, y = 28.0 * np.cos(t), 18.0 * np.sin(t)
        c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
        cv2.circle(binary, (int(round(70 + x * c - y * s)), int(round(60 + x * s + y * c))), 3, 0, -1)
    contours, hier, lengths = _blobs(binary)
    assert arc_outlines(binary, contours, hier, lengths, 12, 8.0, 48.0, 0.1) == []
    top = int(np.flatnonzero(hier[:, 3] < 0)[0])
    assert hier[top, 2] >= 0  # it has holes
    found = arc_outlines(binary, contours, hier, lengths, 12, 8.0, 48.0, 0.1, blobs=[top])
    assert len(found) == 1 and np.hypot(*(found[0].centre_px - (70, 60))) < 0.5


def test_a_solid_or_ragged_blob_is_no_arc():
    """A solid dark ellipse (dark in its middle) and a ragged texture blob give no arc."""
    solid = np.zeros((120, 140), np.uint8)
    cv2.ellipse(solid, (70, 60), (40, 26), 30.0, 0, 360, 255, -1)
    assert arc_outlines(solid, *_blobs(solid), 12, 8.0, 48.0, 0.1) == []
    rng = np.random.default_rng(3)
    ragged = (cv2.GaussianBlur(rng.random((120, 140)), (0, 0), 4.0) > 0.5).astype(np.uint8) * 255
    assert arc_outlines(ragged, *_blobs(ragged), 12, 8.0, 48.0, 0.1) == []


def test_an_over_exposed_ring_cut_open_by_its_dots_is_found():
    """Seed 3's border-003 at x32: id 3, 18 x 29 px at 50 deg on grey ground without a sheet; its grown dots cut
    the ring through, and every level's threshold image holds a C and fragments, no hole (missed before). Its
    arc gives the pair and its code reads."""
    scenario, image = _frame(3, "border-003", 32.0)
    centre = _truth_centre(scenario, 3)
    found = Detector(scenario.targets).detect(image, saturation=float(scenario.camera.saturation_level))
    near = [c for c in found if np.hypot(*(c.outer.centre_px - centre)) < 3.0]
    assert [c.target_id for c in near] == [3], found


def test_a_large_ring_merged_with_a_chessboard_is_paired_from_its_hole():
    """Seed 2's multi-004 at x32: id 12, 192 px across on a chessboard without a sheet; 16 dark squares joined to
    its outline (no ellipse there on any level), its hole clean. Its pair from the hole, 190 px, was dropped (over
    128 px: the hole scaled misses a large tilted ring's edge); re-placed on the grey image's edges it is kept, and
    the code reads."""
    near = _found_near(2, "multi-004", 32.0, 12, 3.0)
    assert [c.target_id for c in near] == [12], near
    assert abs(near[0].outer.b / 192.3 - 1.0) < 0.03


def test_an_over_exposed_steep_ring_is_paired_from_its_hole():
    """Two rings at 70 deg whose outlines the threshold cannot fit. Seed 1's single-000 at x16: 31 x 99 px, the
    sheet's margin thin at its ends on black ground; its hole, 24.6 px in mean radius, was not tried on the
    full-resolution level (its a_hi 32 px; 1.25 a_hi before, ``hole_pairs.HOLE_PAIR_MEAN_RADIUS`` now) and the ring came
    apart on the coarser ones. Seed 4's no-sheet-004 at x16: 70 x 217 px on a chessboard, squares joined all along
    its outline; its pair from the hole, 212 x 81 px, is re-placed on the grey image's edges with its outer edge
    looked for from 0.75 of it (over-exposure grew the hole)."""
    for seed, name, target_id, exposure in ((1, "single-000", 12, 16.0), (4, "no-sheet-004", 8, 16.0)):
        scenario, image = _frame(seed, name, exposure)
        centre = _truth_centre(scenario, target_id)
        found = Detector(scenario.targets).detect(image, saturation=float(scenario.camera.saturation_level))
        near = [c.target_id for c in found if np.hypot(*(c.outer.centre_px - centre)) < 8.0]
        assert near == [target_id], (name, found)


def test_a_hole_pair_whose_white_disk_reads_grey_is_placed_on_its_edges():
    """Held-out seed 6's single-013 at x1: id 1, 20 px, in dark foliage without a sheet, merged with the ground;
    paired from its hole on level 1, the hole 9.9 x 9.2 px for the truth's 8.2-8.6 put the white disk's samples on
    its blurred edge ("inner disk not white", missed before). Re-placed on the grey image's edges, its code reads."""
    near = _found_near(6, "single-013", 1.0, 1, 2.0)
    assert [c.target_id for c in near] == [1], near
    assert abs(near[0].inner.b / 8.3 - 1.0) < 0.05


def _checker_scene(offset_px: tuple[float, float], factor: float) -> Scenario:
    """A 480 x 360 px 12-bit frame: id 3 printed without a sheet on a chessboard (squares of 37 px at 17 deg), about
    55 x 35 px, its centre ``offset_px`` from the image centre, at ``factor`` x the nominal exposure (3 % halo)."""
    z_m, f_px = 2.585, 1800.0
    return Scenario.from_dict({
        "name": "checker-ring", "seed": 1,
        "camera": {"width": 480, "height": 360, "fx": f_px, "fy": f_px, "cx": 239.5, "cy": 179.5,
                   "dist": [0, 0, 0, 0, 0], "bit_depth": 12},
        "sensor": {"full_well_e": 10000, "read_noise_e": 5, "black_level_dn": 0},
        "optics": {"psf_sigma_px": 0.84, "oversampling": 2}, "effects": {"halo": {"fraction": 0.03, "sigma_px": 6.0}},
        "scene": {"background_reflectance": 0.8, "sheet_side_factor": "none", "supersampling": 4,
                  "background_texture": {"kind": "checker", "square_px": 37, "angle_deg": 17}},
        "targets": [{"id": 3, "outer_radius_m": 0.125}],
        "poses": [[{"target_id": 3, "t_m": [offset_px[0] * z_m / f_px, offset_px[1] * z_m / f_px, z_m],
                    "q_xyzw": [-0.2684, 0.2769, -0.8516, 0.3551]}]],
        "exposure": {"nominal_us": "auto", "white_fraction_of_full_well": 0.55, "factors": [factor]},
        "timing": {"fps": 1.0}})


def test_a_ring_cut_open_and_merged_with_a_chessboard_is_paired_from_its_closed_hole():
    """Like seed 2's multi-004 at x32 (id 3, 55 px without a sheet on a chessboard): the grown dots cut the ring
    open on the plain threshold image (no hole), and closed over 6 level pixels (``wide``) it is whole but joined
    to the squares (no ellipse: "hole area/centre"). Its hole there gives the pair (``hole_pairs._hole_pairs``). At 9
    places 5-10 px apart the detector before found it at 5."""
    for dx in (-5.0, 0.0, 5.0):
        for dy in (-10.0, 0.0, 10.0):
            scenario = _checker_scene((dx, dy), 32.0)
            image = scenario.render_frame(0).image
            found = Detector(scenario.targets).detect(image, saturation=float(scenario.camera.saturation_level))
            assert [c.target_id for c in found] == [3], (dx, dy, found)


def test_an_over_exposed_hole_is_tried_at_its_seen_ratio():
    """A ring closed over its grown dots and joined to dark ground: its hole, grown by over-exposure to 0.53 of the
    ring, scaled by the design's R / r puts the outer ellipse beyond the ring (its black bands fail); the seen
    ratios of an edge shift of 0.05-0.1 R (``Detector._seen_ratios``, given to the closed binary's holes) put it on
    the ring (seed 4's multi-001 at x16: id 8, 18 px without a sheet in foliage, missed before)."""
    binary = np.zeros((120, 160), np.uint8)
    cv2.ellipse(binary, (80, 60), (30, 24), 20.0, 0, 360, 255, -1)
    cv2.ellipse(binary, (80, 60), (16, 13), 20.0, 0, 360, 0, -1)
    cv2.rectangle(binary, (100, 10), (150, 50), 255, -1)
    detector = Detector([TargetSpec.default(3, 0.1)])
    for hole_ratios, expected in ((None, 0), (detector._seen_ratios, 1)):
        holes: list = []
        assert _pairs(binary, 12.0, 48.0, detector._ratios, 3.0, DetectOptions(), from_holes=holes,
                      hole_ratios=hole_ratios) == []
        assert len(holes) == expected
    outer = holes[0][0]
    assert np.hypot(*(outer.centre_px - (80, 60))) < 0.5 and np.allclose(outer.semi_axes_px, (30.5, 24.5), atol=0.6)


def test_a_large_steep_ring_on_a_chessboard_is_placed_on_its_edges_from_sampled_points():
    """Like seed 7's single-016 at x32 (8 bits): a ring of ~415 x 150 px at 70 deg on a chessboard without a sheet,
    paired from its hole (squares joined to its outline). Re-placed on the grey image's edges, its outer edge points
    lie at radii spread over a third of the window (the outer ellipse's centre ~45 px from the hole's) and in half
    the directions a code dot's near edge is the steeper rise: a fit through all of them, or through the densest
    radii, kept too few and the pair was dropped at every one of these places. An ellipse through 5 sampled
    points with the most points near it (``refine._sampled_start``) starts the fit, and the edge is looked for
    again near it."""
    for target_id in (8, 3):
        for dx_px, dy_px in ((10.0, 5.0), (-10.0, -5.0)):
            z_m, f_px = 0.3666, 1150.0
            scenario = Scenario.from_dict({
                "name": "steep-ring", "seed": 7,
                "camera": {"width": 1280, "height": 800, "fx": f_px, "fy": f_px, "cx": 641.0, "cy": 398.0,
                           "dist": [-0.05, 0.01, 0, 0, 0], "bit_depth": 8},
                "sensor": {"full_well_e": 10000, "read_noise_e": 5, "black_level_dn": 0},
                "optics": {"psf_sigma_px": 1.02, "oversampling": 1},
                "effects": {"halo": {"fraction": 0.03, "sigma_px": 6.0}},
                "scene": {"background_reflectance": 0.8, "sheet_side_factor": "none", "supersampling": 4,
                          "background_texture": {"kind": "checker", "square_px": 37, "angle_deg": 17}},
                "targets": [{"id": target_id, "outer_radius_m": 0.125}],
                "poses": [[{"target_id": target_id,
                            "t_m": [-0.054795 + dx_px * z_m / f_px, -0.058985 + dy_px * z_m / f_px, z_m],
                            "q_xyzw": [0.094686, 0.630129, -0.765144, 0.092338]}]],
                "exposure": {"nominal_us": "auto", "white_fraction_of_full_well": 0.55, "factors": [32.0]},
                "timing": {"fps": 1.0}})
            image = scenario.render_frame(0).image
            found = Detector(scenario.targets).detect(image, saturation=float(scenario.camera.saturation_level))
            # level 0; its nested level too where its clipped, grown dots still read (``code._gaps_to_test``)
            assert [c.target_id for c in found if c.level == 0] == [target_id], (target_id, dx_px, dy_px, found)
            assert {c.target_id for c in found} == {target_id}
            truth = disk_outline_px(scenario.formation.render_camera, scenario.truth_for(0)[target_id], 0.125)
            (cx, cy), _, _ = cv2.fitEllipse(truth.astype(np.float32))
            level0 = next(c for c in found if c.level == 0)
            assert np.hypot(*(level0.outer.centre_px - (cx, cy))) < 8.0  # coarse: ~5 % of its 150 px minor axis


@pytest.mark.parametrize("at_once", [1, arcs.BOXES_AT_ONCE])
def test_the_arcs_of_all_blobs_are_those_of_each_blob_alone(at_once, monkeypatch):
    """``arc_outlines`` of every holeless blob (its size and middle tests run on all their boxes at once first,
    from ``at_once`` boxes on) is its result with the blobs given one by one (each tested in the loop alone):
    C-shaped rings of many sizes and cuts on textured ground, searched sizes whose bounds fall on box sizes."""
    monkeypatch.setattr(arcs, "BOXES_AT_ONCE", at_once)
    rng = np.random.default_rng(21)
    found_any = 0
    for k in range(40):
        binary = (cv2.GaussianBlur(rng.random((160, 200)), (0, 0), float(rng.uniform(1.0, 4.0)))
                  > rng.uniform(0.45, 0.6)).astype(np.uint8) * 255
        for _ in range(int(rng.integers(1, 5))):
            centre = (int(rng.integers(20, 180)), int(rng.integers(20, 140)))
            axes = (int(rng.integers(5, 40)), int(rng.integers(4, 30)))
            angle = float(rng.uniform(0, 180))
            cv2.ellipse(binary, centre, axes, angle, 0, 360, 255, -1)
            cv2.ellipse(binary, centre, (int(axes[0] * 0.4), int(axes[1] * 0.4)), angle, 0, 360, 0, -1)
            cut = float(rng.uniform(20, 90))
            start = float(rng.uniform(0, 360))
            cv2.ellipse(binary, centre, (2 * axes[0], 2 * axes[0]), angle, start, start + cut, 0, -1)
        contours, hier, lengths = _blobs(binary)
        a_lo, a_hi = (4.0, 10.0, 5.0, 7.5)[k % 4], (12.0, 32.0, 20.0)[k % 3]
        blobs = np.flatnonzero((hier[:, 3] < 0) & (hier[:, 2] < 0) & (lengths >= 12)).tolist()
        together = arc_outlines(binary, contours, hier, lengths, 12, a_lo, a_hi, 0.1)
        alone = arc_outlines(binary, contours, hier, lengths, 12, a_lo, a_hi, 0.1, blobs=blobs)
        assert ([(e.centre_px.tolist(), e.semi_axes_px.tolist(), e.angle_rad) for e in together]
                == [(e.centre_px.tolist(), e.semi_axes_px.tolist(), e.angle_rad) for e in alone])
        found_any += len(together)
    assert found_any >= 10


def test_a_ring_cut_in_two_by_grown_dots_is_paired_from_its_pieces_outline():
    """Seed 2's single-017 at x16: id 8, 14 x 40 px at 70 deg on a gradient, 12-bit. Over-exposure grew its white
    disk into the dots on either side of it: the ring is two arcs of under half of it each (no C, no hole), and
    closing them with a 7 px disk left a hole that is no ellipse. The outline of the two pieces together
    (``arcs.arcs_outline``) is its outer edge: re-placed on the grey image's edges, the code reads."""
    near = _found_near(2, "single-017", 16.0, 8, 3.0)
    assert [c.target_id for c in near] == [8], near


def test_depth_in_hull_is_opencvs_distance_inside():
    """``arcs._depth_in_hull``: each point's distance to its convex hull's boundary, as ``cv2.pointPolygonTest``
    gives it for points inside (at once instead of a call per point)."""
    rng = np.random.default_rng(7)
    for _ in range(100):
        points = rng.integers(0, 60, (int(rng.integers(3, 80)), 2)).astype(np.int32)
        hull = cv2.convexHull(points)
        if len(hull) < 3:
            continue
        expected = [cv2.pointPolygonTest(hull, (float(x), float(y)), True) for x, y in points.tolist()]
        assert np.allclose(arcs._depth_in_hull(points), expected, atol=1e-9)


def test_an_over_exposed_ring_cut_open_is_placed_with_the_ratio_its_grown_white_shows():
    """Seed 3's multi-002 at x32: id 1, 20 px on a sheet over printed text, its ring at 0.83 of white and cut open by
    its two grown dots (one C). Its arc's outer ellipse is right, but the white disk grew to 0.58 of it: at the
    design's ratio (0.4) the ring's middle (0.52) read white, no contrast, no pair, and it was missed. The ratios
    an over-exposed ring shows (``detector.WIDE_HOLE_SHIFTS``) are tried after the design's in frames with clipped
    pixels; the code reads, and the tracker's distance is within 1 %."""
    from livetrack.estimator.tracker import Tracker, TrackerOptions

    near = _found_near(3, "multi-002", 32.0, 1, 3.0)
    assert [c.target_id for c in near] == [1], near
    scenario, image = _frame(3, "multi-002", 32.0)
    found = Tracker(scenario.camera, scenario.targets, TrackerOptions(compensate_exposure=True)).process(image)
    pose = next(t.pose for t in found.targets if t.target_id == 1 and t.fit.ok)
    assert abs(pose.distance_m / scenario.truth_for(0)[1].distance_m - 1.0) < 0.01
