"""Camera model against OpenCV over the whole image, and its validation."""

import cv2
import numpy as np
import pytest

from livetrack.camera import CameraModel
from livetrack.config.checks import ConfigError

LENSES = {
    "none": (0.0, 0.0, 0.0, 0.0, 0.0),
    "paper-lab": (-0.1, 0.0, 0.0, 0.0, 0.0),
    "full": (-0.28, 0.09, 0.0012, -0.0008, -0.015),
}


def image_grid(camera, step=7.0):
    xs = np.arange(-0.5, camera.width - 0.5 + 1e-9, step)
    ys = np.arange(-0.5, camera.height - 0.5 + 1e-9, step)
    gx, gy = np.meshgrid(np.append(xs, camera.width - 0.5), np.append(ys, camera.height - 0.5))
    return np.column_stack([gx.ravel(), gy.ravel()])


@pytest.mark.parametrize("lens", LENSES)
def test_project_equals_opencv_over_the_whole_image(lens):
    cam = CameraModel(1920, 1200, 1800.0, 1790.0, 955.3, 601.8, LENSES[lens], 12)
    pixels = image_grid(cam)
    depth = np.random.default_rng(0).uniform(0.5, 20.0, len(pixels))
    points = np.column_stack([cam.pixels_to_normalized(pixels), np.ones(len(pixels))]) * depth[:, None]
    ours = cam.project(points)
    ref, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), cam.K, cam.dist_array)
    assert np.abs(ours - ref.reshape(-1, 2)).max() < 1e-6
    assert np.abs(ours - pixels).max() < 1e-6  # and unproject inverts project


@pytest.mark.parametrize("lens", LENSES)
def test_unproject_equals_converged_opencv_undistort(lens):
    cam = CameraModel(1920, 1200, 1800.0, 1790.0, 955.3, 601.8, LENSES[lens], 12)
    pixels = image_grid(cam)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-15)
    ref = cv2.undistortPoints(pixels.reshape(-1, 1, 2), cam.K, cam.dist_array, None, None, None, criteria)
    # compare in pixels of the ideal (undistorted) camera
    ours = cam.pixels_to_normalized(pixels)
    assert np.abs(ours - ref.reshape(-1, 2)).max() * cam.fx < 1e-6
    rays = cam.unproject(pixels)
    assert np.allclose(np.linalg.norm(rays, axis=1), 1.0)


def test_round_trip_dict_and_errors_name_the_key():
    cam = CameraModel(640, 480, 500.0, 500.0, 319.5, 239.5, (0.01, 0, 0, 0, 0), 12)
    assert CameraModel.from_dict(cam.to_dict()) == cam
    bad = cam.to_dict()
    del bad["fx"]
    with pytest.raises(ConfigError, match=r"camera\.fx: missing"):
        CameraModel.from_dict(bad)
    bad = cam.to_dict() | {"fy": -3}
    with pytest.raises(ConfigError, match=r"camera\.fy: must be > 0"):
        CameraModel.from_dict(bad)
    bad = cam.to_dict() | {"dist": [0, 0, 0]}
    with pytest.raises(ConfigError, match=r"camera\.dist: must have 5 numbers"):
        CameraModel.from_dict(bad)
    with pytest.raises(ConfigError, match=r"camera\.focal: unknown key"):
        CameraModel.from_dict(cam.to_dict() | {"focal": 3})


def test_pixel_centre_convention_and_scaling():
    cam = CameraModel(100, 80, 100.0, 100.0, 49.5, 39.5)
    # the optical axis hits the centre of the image: between pixels 49 and 50 on x
    assert np.allclose(cam.project(np.array([[0.0, 0.0, 1.0]])), [[49.5, 39.5]])
    half = cam.scaled(0.5)
    assert (half.width, half.height) == (50, 40)
    assert np.allclose([half.cx, half.cy], [24.5, 19.5])  # still the image centre, pixel centres on integers
    assert cam.contains(np.array([[-0.5, -0.5], [99.5, 79.5], [99.6, 0.0]])).tolist() == [True, True, False]


def test_image_formation_must_be_a_mapping():
    """Found by the recording fuzz test: a list there gave a TypeError, not the documented ConfigError."""
    data = {"width": 10, "height": 10, "fx": 1.0, "fy": 1.0, "cx": 4.5, "cy": 4.5, "image_formation": [None]}
    with pytest.raises(ConfigError, match="image_formation: must be a mapping"):
        CameraModel.from_dict(data)
