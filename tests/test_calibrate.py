"""livetrack calibrate chessboard: real OpenCV chessboard images, synthetic views with known truth, the camera
file's uncertainty section and the CLI round trip into ``detect --camera``."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from livetrack.calibration.chessboard import (
    ChessboardOptions,
    board_points_m,
    calibrate_images,
    calibrate_points,
    find_corners,
)
from livetrack.calibration.report import coverage_map
from livetrack.camera import CameraModel
from livetrack.camera.io import load_camera, load_camera_uncertainty
from livetrack.cli import main
from livetrack.config.checks import ConfigError
from tests.realdata import realdata_dir

REAL = realdata_dir()
CHESSBOARD = REAL / "chessboard" if REAL is not None else None
needs_chessboard = pytest.mark.skipif(CHESSBOARD is None or not CHESSBOARD.is_dir(),
                                      reason="no ../shared/realdata/chessboard")


def _real_images():
    files = sorted(CHESSBOARD.glob("left*.jpg"))
    return [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files], [f.name for f in files]


@needs_chessboard
def test_real_chessboard_matches_opencv_on_the_same_corners():
    images, names = _real_images()
    # OpenCV's tutorial settings: a fixed 11 px window, every view kept.
    options = ChessboardOptions(adaptive_window=False, reject_factor=1e9)
    result = calibrate_images(images, names, options)
    assert len(result.view_names) == len(images) == 12
    corners = [find_corners(im, (9, 6), 11, adaptive_window=False) for im in images]
    board = board_points_m((9, 6), 0.025).astype(np.float32)
    rms_cv, K_cv, _, _, _ = cv2.calibrateCamera([board] * len(corners), [c.astype(np.float32) for c in corners],
                                                (640, 480), None, None)
    assert abs(rms_cv - 0.42) < 0.05
    assert abs(result.rms_px - rms_cv) < 0.05
    assert abs(result.camera.fx / K_cv[0, 0] - 1) < 0.01
    assert abs(result.camera.fx / 536.0 - 1) < 0.01
    assert abs(result.camera.cx - 342) < 3 and abs(result.camera.cy - 236) < 3
    # the per-view errors give back the overall RMS
    n = np.array([len(p) for p in result.points_px])
    assert np.sqrt(np.sum(n * result.per_view_rms_px**2) / n.sum()) == pytest.approx(result.rms_px, rel=1e-3)
    # left02.jpg (small squares) is the view the 11 px window spoils
    assert result.view_names[int(np.argmax(result.per_view_rms_px))] == "left02.jpg"


@needs_chessboard
def test_real_chessboard_default_adaptive_window():
    images, names = _real_images()
    result = calibrate_images(images, names)
    assert not result.rejected and len(result.view_names) == 12
    assert result.rms_px < 0.25  # 0.18 px measured, against 0.42 px with the fixed 11 px window
    assert abs(result.camera.fx / 536.0 - 1) < 0.01
    u = result.uncertainty
    assert 0 < u.fx < 2 and 0 < u.cx < 2 and 0 < u.dist[0] < 0.05
    cov = result.coverage()
    assert 0.5 < cov.covered_fraction <= 1 and cov.counts.sum() == 12 * 54


def _synthetic_views(seed: int, noise_px: float, n_views: int = 10):
    rng = np.random.default_rng(seed)
    camera = CameraModel(width=800, height=600, fx=700.0, fy=702.0, cx=405.0, cy=296.0,
                         dist=(-0.12, 0.05, 0.0005, -0.0003, 0.0))
    board = board_points_m((9, 6), 0.03)
    board_c = board - board.mean(axis=0)
    views = []
    for _ in range(n_views):
        rvec = rng.uniform(-0.5, 0.5, 3)
        R, _ = cv2.Rodrigues(rvec)
        t = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.05, 0.05), rng.uniform(0.45, 0.7)])
        pts = camera.project(board_c @ R.T + t)
        views.append(pts + rng.normal(0, noise_px, pts.shape))
    return camera, board, views


@pytest.mark.parametrize("seed", [1, 2])
def test_synthetic_views_recover_the_camera_and_reject_a_bad_view(seed):
    truth, board, views = _synthetic_views(seed, 0.1)
    views[3] = views[3] + np.random.default_rng(seed + 100).normal(0, 2.0, views[3].shape)
    result = calibrate_points([board] * len(views), views, truth.width, truth.height)
    assert [r.name for r in result.rejected] == ["view3"]
    assert "view3" not in result.view_names and len(result.view_names) == 9
    cam, u = result.camera, result.uncertainty
    assert result.rms_px == pytest.approx(0.1 * np.sqrt(2), abs=0.02)  # per point: 2-D error norm
    for name in ("fx", "fy", "cx", "cy"):
        error = getattr(cam, name) - getattr(truth, name)
        assert abs(error) < 5 * getattr(u, name) + 1e-9, name
    assert abs(cam.dist[0] - truth.dist[0]) < 5 * u.dist[0]


def test_too_few_views_is_an_error():
    _, board, views = _synthetic_views(3, 0.1, n_views=2)
    with pytest.raises(ValueError, match="at least 3"):
        calibrate_points([board] * 2, views, 800, 600)


def test_coverage_map_counts_cells_with_pixel_centres():
    cov = coverage_map([np.array([[-0.5, -0.5], [99.4, 49.4], [99.6, 49.6], [199.49, 99.49]])], 200, 100, (2, 2))
    assert cov.counts.tolist() == [[1, 0], [0, 1]] or cov.counts.tolist() == [[2, 0], [0, 2]]
    assert cov.counts.sum() == 4 and cov.covered_fraction == 0.5


@needs_chessboard
def test_cli_writes_a_camera_file_that_detect_reads(tmp_path):
    files = sorted(str(f) for f in CHESSBOARD.glob("left*.jpg"))
    out = tmp_path / "camera.yaml"
    code = main(["calibrate", "chessboard", *files, "--inner", "9x6", "--square-mm", "25", "--out", str(out),
                 "--plots", str(tmp_path / "plots"), "--json", str(tmp_path / "cal.json")])
    assert code == 0
    camera = load_camera(out)
    assert (camera.width, camera.height) == (640, 480) and abs(camera.fx / 536 - 1) < 0.01
    u = load_camera_uncertainty(out)
    assert u is not None and u.fx > 0 and len(u.dist) == 5
    figures = json.loads((tmp_path / "cal.json").read_text())
    assert len(figures["views"]) == 12 and figures["rms_px"] < 0.25
    assert (tmp_path / "plots" / "residuals.png").stat().st_size > 1000
    assert (tmp_path / "plots" / "coverage.png").stat().st_size > 1000
    targets = tmp_path / "targets.yaml"
    targets.write_text("targets:\n  - id: 3\n    outer_radius_m: 0.125\n")
    code = main(["detect", files[0], "--camera", str(out), "--targets", str(targets), "--json",
                 str(tmp_path / "detect.json")])
    assert code == 0
    [frame] = json.loads((tmp_path / "detect.json").read_text())["frames"]
    assert frame["camera"] == "file" and "error" not in frame


def test_cli_bad_inner_is_refused(tmp_path, capsys):
    image = tmp_path / "a.png"
    cv2.imwrite(str(image), np.zeros((20, 20), np.uint8))
    code = main(["calibrate", "chessboard", str(image), "--inner", "9-6", "--square-mm", "25",
                 "--out", str(tmp_path / "c.yaml")])
    assert code == 2 and "--inner" in capsys.readouterr().err


@pytest.mark.parametrize("section, problem", [
    ("{fx: -1, fy: 1, cx: 1, cy: 1}", "fx"),
    ("{fx: 1, fy: 1, cx: 1, cy: 1, dist: [0, 0, 0]}", "dist"),
    ("{fx: 1, fy: 1, cx: 1, cy: 1, dist: [0, -1, 0, 0, 0]}", "dist"),
    ("{fx: 1, fy: 1, cx: 1, cy: 1, skew: 0}", "skew"),
])
def test_camera_file_uncertainty_is_validated(tmp_path, section, problem):
    file = tmp_path / "camera.yaml"
    file.write_text("camera: {width: 10, height: 10, fx: 10, fy: 10, cx: 4.5, cy: 4.5}\n"
                    f"uncertainty: {section}\n")
    with pytest.raises(ConfigError, match=problem):
        load_camera(file)


def test_camera_file_without_uncertainty_still_loads(tmp_path):
    file = tmp_path / "camera.yaml"
    file.write_text("camera: {width: 10, height: 10, fx: 10, fy: 10, cx: 4.5, cy: 4.5}\n")
    assert load_camera(file).fx == 10 and load_camera_uncertainty(file) is None
