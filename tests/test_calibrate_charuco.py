"""livetrack calibrate charuco: views of a ChArUco board rendered with cv2 (its own generateImage), seen through a
camera with known intrinsics and distortion, partly outside the image; calibrated through OpenCV's aruco module."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from livetrack.calibration.charuco import CharucoFinder, calibrate_charuco_images
from livetrack.calibration.charuco_experiment import OPTIONS, TRUTH, corner_errors, views
from livetrack.camera.io import load_camera, load_camera_uncertainty
from livetrack.cli import main


@pytest.fixture(scope="module")
def rendered_with_poses():
    return views(10)


@pytest.fixture(scope="module")
def rendered(rendered_with_poses):
    return rendered_with_poses[0]


def test_board_corners_are_found_where_they_project(rendered):
    finder = CharucoFinder(OPTIONS)
    found = [finder.find(image) for image in rendered]
    assert sum(f is not None for f in found) >= 9
    assert any(f is not None and len(f[0]) < 24 for f in found)  # a partial view still identifies its corners


def test_rendered_views_give_the_camera(rendered):
    result = calibrate_charuco_images(rendered, [f"view{k}" for k in range(len(rendered))], OPTIONS)
    cam, u = result.camera, result.uncertainty
    assert len(result.view_names) >= 9 and result.rms_px < 0.2
    # measured (one run): see docs/calibration.md
    assert abs(cam.fx / TRUTH.fx - 1) < 0.005 and abs(cam.fy / TRUTH.fy - 1) < 0.005
    assert abs(cam.cx - TRUTH.cx) < 2 and abs(cam.cy - TRUTH.cy) < 2
    assert abs(cam.dist[0] / TRUTH.dist[0] - 1) < 0.05
    for name in ("fx", "cx", "cy"):
        assert abs(getattr(cam, name) - getattr(TRUTH, name)) < 5 * getattr(u, name) + 0.05, name


def test_cli_charuco_writes_a_camera_file(rendered, tmp_path, capsys):
    files = []
    for k, image in enumerate(rendered[:8]):
        files.append(str(tmp_path / f"view{k}.png"))
        cv2.imwrite(files[-1], image)
    out = tmp_path / "camera.yaml"
    code = main(["calibrate", "charuco", *files, "--squares", "7x5", "--square-mm", "40", "--marker-mm", "30",
                 "--dictionary", "DICT_5X5_100", "--out", str(out)])
    assert code == 0
    camera = load_camera(out)
    assert abs(camera.fx / TRUTH.fx - 1) < 0.01 and load_camera_uncertainty(out).fx > 0
    code = main(["calibrate", "charuco", *files, "--squares", "7x5", "--square-mm", "40", "--marker-mm", "50",
                 "--out", str(out)])
    assert code == 2 and "--marker-mm" in capsys.readouterr().err
    code = main(["calibrate", "charuco", *files, "--squares", "7x5", "--square-mm", "40", "--marker-mm", "30",
                 "--dictionary", "DICT_NOPE", "--out", str(out)])
    assert code == 2 and "DICT_NOPE" in capsys.readouterr().err


def test_corners_refined_clear_of_the_markers_are_closer_to_their_true_projections(rendered_with_poses):
    # against the corners' true projections (one run, these 10 views): OpenCV's CharucoDetector corners 0.047 px
    # RMS (its windows reach the markers' borders), refined with a window clear of them 0.024 px, on the image
    # enlarged twice 0.019 px (cornerSubPix's bilinear sampling pulls corners toward pixel boundaries: a sine of
    # the sub-pixel position, 0.033 px amplitude without the enlargement over 30 draws of views, 0.005-0.009 px
    # with it)
    images, poses = rendered_with_poses
    rms, locking = {}, {}
    for name, options in (("default", OPTIONS), ("not enlarged", dataclasses.replace(OPTIONS, refine_upsample=1)),
                          ("opencv", dataclasses.replace(OPTIONS, refine_window=False))):
        errors, true_px = corner_errors(images, poses, options)
        rms[name] = float(np.sqrt(np.mean(errors ** 2)))
        phase = true_px - np.round(true_px)
        locking[name] = float(np.mean([np.linalg.lstsq(
            np.column_stack([np.sin(2 * np.pi * phase[:, i]), np.ones(len(phase))]), errors[:, i], rcond=None)[0][0]
            for i in (0, 1)]))
    assert rms["default"] < 0.022 and rms["default"] < 0.5 * rms["opencv"]
    assert rms["default"] < rms["not enlarged"]
    assert abs(locking["default"]) < 0.5 * abs(locking["not enlarged"])
