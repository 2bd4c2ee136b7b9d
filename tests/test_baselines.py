"""Baselines on rendered truth: ArUco, AprilTag and the naive ellipse reader, same simulator, same outer size.

Images come from the project's simulator (``ImageTexture`` / ``TargetTexture`` + ``ImageFormation``: exact pixel
coverage, 0.8 px Gaussian PSF, shot and read noise, 12-bit ADC), seeded.
"""

from __future__ import annotations

import numpy as np
import pytest

from livetrack.baselines import PoseEstimate
from livetrack.baselines.naive import NaiveEllipseMethod
from livetrack.baselines.square_markers import (
    AprilTagMethod,
    ArucoMethod,
    apriltag_marker_image,
    aruco_marker_image,
    texture_side_m,
)
from livetrack.camera import CameraModel
from livetrack.geometry import Pose, look_rotation, rotation_angle_deg
from livetrack.sim import ImageTexture, Placement, TargetTexture
from livetrack.sim.formation import ImageFormation
from livetrack.sim.sensor import SensorModel
from livetrack.targets.spec import TargetSpec

OUTER_RADIUS_M = 0.125
BLACK_SIDE_M = 2 * OUTER_RADIUS_M  # the square markers' black side = the ring target's outer diameter
WHITE = 0.85

CAMERA = CameraModel(width=1920, height=1200, fx=1800.0, fy=1800.0, cx=959.5, cy=599.5,
                     dist=(-0.1, 0.0, 0.0, 0.0, 0.0), bit_depth=12)

POSES = {
    "frontal-1.5m": Pose(look_rotation(5.0, 60.0, 10.0), np.array([0.06, -0.04, 1.5])),
    "tilt30-3m": Pose(look_rotation(30.0, 200.0, -25.0), np.array([0.35, 0.25, 3.0])),
}


@pytest.fixture(scope="module")
def formation() -> ImageFormation:
    return ImageFormation(CAMERA, sensor=SensorModel(bit_depth=12))


def _render(formation: ImageFormation, placement: Placement, white_fraction_of_full_well: float,
            seed: int) -> np.ndarray:
    exposure_us = formation.nominal_exposure_us(WHITE, white_fraction_of_full_well)
    return formation.render([placement], exposure_us, rng=np.random.default_rng(seed))


def _square_corners_px(pose: Pose, side_m: float) -> np.ndarray:
    """True (4, 2) pixel corners of the black square: TL, TR, BR, BL seen from the front (target y down)."""
    h = side_m / 2
    return CAMERA.project(pose.apply(np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])))


MARKER_IDS = {"aruco": 7, "apriltag": 23}


def _square_method(kind: str) -> tuple[ArucoMethod | AprilTagMethod, np.ndarray]:
    if kind == "aruco":
        return ArucoMethod(CAMERA, BLACK_SIDE_M), aruco_marker_image(MARKER_IDS[kind])
    return AprilTagMethod(CAMERA, BLACK_SIDE_M), apriltag_marker_image(MARKER_IDS[kind])


def _errors(est: PoseEstimate, truth: Pose) -> tuple[float, float, float]:
    """(relative translation error, normal error in degrees, full rotation error in degrees)."""
    t_rel = float(np.linalg.norm(est.pose.t - truth.t) / np.linalg.norm(truth.t))
    normal_deg = float(np.degrees(np.arccos(np.clip(est.pose.normal_cam @ truth.normal_cam, -1.0, 1.0))))
    return t_rel, normal_deg, rotation_angle_deg(est.pose.R.T @ truth.R)


# ---------------------------------------------------------------------------------------------- marker images
def test_marker_images_have_one_texel_per_cell_and_the_documented_borders():
    aruco = aruco_marker_image(7)
    tag = apriltag_marker_image(3)
    assert aruco.shape == (8, 8) and tag.shape == (10, 10)
    for image, black_cells in ((aruco, 6), (tag, 8)):
        assert set(np.unique(image)) <= {0.0, 1.0}
        ring = np.ones_like(image, dtype=bool)
        ring[1:-1, 1:-1] = False
        assert np.all(image[ring] == 1.0)  # white quiet zone of one cell
        inner = image[1:-1, 1:-1]
        assert inner.shape == (black_cells, black_cells)
        border = np.ones_like(inner, dtype=bool)
        border[1:-1, 1:-1] = False
        assert np.all(inner[border] == 0.0)  # black border of one cell
        assert 0.0 < inner[1:-1, 1:-1].mean() < 1.0  # some code
    assert texture_side_m(tag, 0.25) == pytest.approx(0.25 * 10 / 8)
    assert texture_side_m(aruco, 0.25) == pytest.approx(0.25 * 8 / 6)
    assert not np.array_equal(apriltag_marker_image(3), apriltag_marker_image(4))


# ---------------------------------------------------------------------------------------------- square markers
@pytest.mark.parametrize("pose_name", sorted(POSES))
@pytest.mark.parametrize("kind", ["aruco", "apriltag"])
def test_square_marker_pose_on_rendered_truth(formation, kind, pose_name):
    truth = POSES[pose_name]
    method, image = _square_method(kind)
    marker_id = MARKER_IDS[kind]
    texture = ImageTexture(image, size_m=texture_side_m(image, BLACK_SIDE_M), margin_m=0.03)
    frame = _render(formation, Placement(truth, texture), 0.5, seed=11)
    found = method.estimate(frame)
    assert [e.target_id for e in found] == [marker_id]
    est = found[0]
    t_rel, normal_deg, rot_deg = _errors(est, truth)
    assert t_rel < 0.01
    assert normal_deg < 3.0
    assert rot_deg < 3.0  # the in-plane rotation too: livetrack's target frame, not OpenCV's marker frame
    # Corners in livetrack's pixel convention (AprilTag's half-pixel offset removed), in TL, TR, BR, BL order.
    corner_err = est.extra["corners_px"] - _square_corners_px(truth, BLACK_SIDE_M)
    assert np.abs(corner_err.mean(axis=0)).max() < 0.15
    assert np.abs(corner_err).max() < 0.5
    errs = est.extra["reprojection_errors_px"]
    assert errs.shape == (2,) and errs[0] <= errs[1]
    assert est.delta_px is None and np.isfinite(est.quality)


@pytest.mark.parametrize("kind", ["aruco", "apriltag"])
def test_square_marker_distance_grows_with_overexposure(formation, kind):
    """No exposure model either: the white grows over the black square, the corners move inward."""
    truth = POSES["frontal-1.5m"]
    method, image = _square_method(kind)
    texture = ImageTexture(image, size_m=texture_side_m(image, BLACK_SIDE_M), margin_m=0.03)
    distance = {}
    for fraction in (0.5, 4.0):
        found = method.estimate(_render(formation, Placement(truth, texture), fraction, seed=3))
        assert len(found) == 1
        distance[fraction] = found[0].pose.distance_m
    assert abs(distance[0.5] / truth.distance_m - 1) < 0.01
    assert distance[4.0] / distance[0.5] - 1 > 0.003


def test_float_images_with_their_own_full_scale():
    """A noise-free reflectance image (float, white = 0.85) read with saturation=1.0."""
    from livetrack.sim import render_reflectance

    truth = POSES["tilt30-3m"]
    image = aruco_marker_image(7)
    texture = ImageTexture(image, size_m=texture_side_m(image, BLACK_SIDE_M), margin_m=0.03)
    reflectance = render_reflectance(CAMERA, [Placement(truth, texture)])
    found = ArucoMethod(CAMERA, BLACK_SIDE_M, saturation=1.0).estimate(reflectance)
    assert [e.target_id for e in found] == [7]
    assert _errors(found[0], truth)[0] < 0.01
    assert found[0].extra["flip_ratio"] >= 1.0
    assert found[0].extra["other_pose"].t[2] > 0


def test_apriltag_decodes_several_ids_of_the_opencv_made_images(formation):
    method = AprilTagMethod(CAMERA, BLACK_SIDE_M)
    truth = POSES["frontal-1.5m"]
    for tag_id in (0, 5, 586):
        image = apriltag_marker_image(tag_id)
        texture = ImageTexture(image, size_m=texture_side_m(image, BLACK_SIDE_M), margin_m=0.03)
        frame = _render(formation, Placement(truth, texture), 0.5, seed=tag_id)
        assert [e.target_id for e in method.estimate(frame)] == [tag_id]


# ---------------------------------------------------------------------------------------------- naive
@pytest.fixture(scope="module")
def ring_spec() -> TargetSpec:
    return TargetSpec.default(3, OUTER_RADIUS_M)


@pytest.mark.parametrize("pose_name", sorted(POSES))
def test_naive_pose_at_moderate_exposure(formation, ring_spec, pose_name):
    truth = POSES[pose_name]
    frame = _render(formation, Placement(truth, TargetTexture(ring_spec)), 0.5, seed=5)
    found = NaiveEllipseMethod(CAMERA, [ring_spec]).estimate(frame)
    assert [e.target_id for e in found] == [3]
    t_rel, normal_deg, rot_deg = _errors(found[0], truth)
    assert t_rel < 0.01
    assert normal_deg < 3.0
    assert rot_deg < 10.0  # heading from the 8-slot code: a few degrees
    assert found[0].delta_px is None and 0.0 < found[0].quality < 0.6  # Canny pixels: ~0.35 px RMS


def test_naive_distance_grows_with_overexposure(formation, ring_spec):
    truth = POSES["frontal-1.5m"]
    placement = Placement(truth, TargetTexture(ring_spec))
    method = NaiveEllipseMethod(CAMERA, [ring_spec])
    distance = {}
    for fraction in (0.5, 4.0):
        found = method.estimate(_render(formation, placement, fraction, seed=2))
        assert len(found) == 1
        distance[fraction] = found[0].pose.distance_m
        outer = found[0].extra["outer_ellipse"]
        radius_px = OUTER_RADIUS_M * CAMERA.fx / truth.distance_m
        if fraction > 1:  # the white grows: the outer ellipse shrinks by about 1.4 sigma of the PSF
            assert outer.a < radius_px - 0.5
    assert abs(distance[0.5] / truth.distance_m - 1) < 0.01
    assert distance[4.0] / distance[0.5] - 1 > 0.003


# ---------------------------------------------------------------------------------------------- bad input
BAD_IMAGES = {
    "blank": np.full((1200, 1920), 2000, dtype=np.uint16),
    "black": np.zeros((1200, 1920), dtype=np.uint16),
    "saturated": np.full((600, 800), 255, dtype=np.uint8),
    "tiny": np.array([[0, 4095], [4095, 0]], dtype=np.uint16),
    "empty": np.zeros((0, 0), dtype=np.uint8),
    "nan": np.full((64, 64), np.nan),
    "noise": np.random.default_rng(0).integers(0, 4096, (300, 400)).astype(np.uint16),
    "colour": np.zeros((100, 100, 3), dtype=np.uint8),
}


@pytest.mark.parametrize("image_name", sorted(BAD_IMAGES))
def test_bad_input_gives_an_empty_list(ring_spec, image_name):
    methods = [ArucoMethod(CAMERA, BLACK_SIDE_M), AprilTagMethod(CAMERA, BLACK_SIDE_M),
               NaiveEllipseMethod(CAMERA, [ring_spec])]
    for method in methods:
        assert method.estimate(BAD_IMAGES[image_name]) == [], method.name
