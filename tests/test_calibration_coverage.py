"""One coverage grid everywhere: the printed summary, the JSON, the live stop rule, the live console line and the
coverage plot (``coverage.png``) count the same cells (``livetrack.calibration.report.COVERAGE_CELLS``)."""

from __future__ import annotations

import cv2
import numpy as np

from livetrack.calibration.chessboard import board_points_m, calibrate_points
from livetrack.calibration.live import StopRule, check
from livetrack.calibration.live_view import ConsoleView
from livetrack.calibration.plots import coverage_figure, plt
from livetrack.calibration.report import COVERAGE_CELLS, summary_text
from livetrack.camera import CameraModel


def _result():
    """A chessboard calibration of 8 synthetic views, the boards kept in the left two thirds of the image and
    near its top (so that the coverage is neither empty nor full, and not symmetric)."""
    rng = np.random.default_rng(4)
    camera = CameraModel(width=800, height=600, fx=700.0, fy=700.0, cx=399.5, cy=299.5, dist=(-0.1, 0, 0, 0, 0))
    board = board_points_m((9, 6), 0.02)
    centred = board - board.mean(axis=0)
    views = []
    for _ in range(8):
        R, _ = cv2.Rodrigues(rng.uniform(-0.4, 0.4, 3))
        t = np.array([rng.uniform(-0.25, 0.02), rng.uniform(-0.18, -0.05), rng.uniform(0.5, 0.7)])
        views.append(camera.project(centred @ R.T + t) + rng.normal(0, 0.05, (54, 2)))
    return calibrate_points([board] * len(views), views, camera.width, camera.height)


def test_plot_report_json_and_stop_rule_share_one_grid(capsys):
    result = _result()
    cov = result.coverage()
    cols, rows = COVERAGE_CELLS
    assert cov.counts.shape == (rows, cols) and 0.1 < cov.covered_fraction < 0.9
    # The printed summary and the JSON.
    assert cov.text() in summary_text(result)
    assert f"{cols}x{rows} = {cols * rows} image cells" in cov.text()
    assert result.to_dict()["coverage"]["counts"] == cov.counts.tolist()
    # The plot: its heat map is the same counts, its title the same line.
    fig = coverage_figure(result)
    try:
        [image] = fig.axes[0].get_images()
        assert np.array_equal(np.asarray(image.get_array()), cov.counts)
        assert cov.text() in fig.axes[0].get_title()
        written = sorted(int(t.get_text()) for t in fig.axes[0].texts)
        assert written == sorted(cov.counts.ravel().tolist())
    finally:
        plt.close(fig)
    # The live stop rule and the live console line.
    progress = check(StopRule(), result.points_px, result.camera.width, result.camera.height)
    assert progress.coverage == cov.covered_fraction
    corners = sum(cov.counts[i, j] > 0 for i in (0, -1) for j in (0, -1))
    assert progress.corners == corners
    ConsoleView().view_added(np.zeros((600, 800), np.uint8), 0, result.points_px, 8, 8)
    assert cov.text() in capsys.readouterr().out
