"""livetrack calibrate --source: the stop rule (coverage, corner cells, parameter uncertainties) and the live
collection on a sim: source, shown in a Rerun recording."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from livetrack.calibration.experiment import SCENARIO
from livetrack.calibration.live import StopRule, check
from livetrack.calibration.live_view import coverage_image
from livetrack.calibration.report import CameraUncertainty
from livetrack.camera import CameraModel
from livetrack.cli import main

CAMERA = CameraModel(480, 360, 420.0, 420.0, 240.0, 180.0, (-0.2, 0.08, 0.0, 0.0, 0.0))


def _grid_points(x0, x1, y0, y1, n=10):
    xs, ys = np.meshgrid(np.linspace(x0, x1, n), np.linspace(y0, y1, n))
    return np.column_stack([xs.ravel(), ys.ravel()])


def test_stop_rule_needs_coverage_corners_and_uncertainties():
    rule = StopRule(coverage=0.5, corners=4, min_views=3)
    centre = [_grid_points(150, 330, 100, 260)] * 3
    progress = check(rule, centre, 480, 360)
    assert not progress.done and progress.corners == 0 and progress.coverage < 0.5
    assert any(u.startswith("coverage") for u in progress.unmet) and any("corner" in u for u in progress.unmet)
    whole = [_grid_points(0, 479, 0, 359)] * 3
    progress = check(rule, whole, 480, 360)
    assert progress.coverage == 1.0 and progress.corners == 4 and progress.coverage_reached
    assert progress.unmet == ["parameter uncertainties not evaluated yet"]
    good = CameraUncertainty(fx=0.4, fy=0.4, cx=0.5, cy=0.5, dist=(0.002, 0.01, 0, 0, 0))
    assert check(rule, whole, 480, 360, CAMERA, good).done
    bad = CameraUncertainty(fx=2.0, fy=0.4, cx=0.5, cy=0.5, dist=(0.02, 0.01, 0, 0, 0))
    progress = check(rule, whole, 480, 360, CAMERA, bad)
    assert [u.split(" ")[2] for u in progress.unmet] == ["fx", "k1"]
    assert progress.relative_std["fx"] == pytest.approx(2.0 / 420)
    # a lens without distortion: k1's 1-sigma is taken relative to the floor (0.05), not to |k1| = 0
    flat = CameraModel(480, 360, 420.0, 420.0, 240.0, 180.0)
    assert check(rule, whole, 480, 360, flat, good).relative_std["k1"] == pytest.approx(0.002 / 0.05)
    with pytest.raises(ValueError, match="coverage"):
        StopRule(coverage=60)


def test_coverage_image_marks_empty_corners():
    counts = np.zeros((6, 8), dtype=np.int64)
    counts[0, 0] = 5
    counts[2, 3] = 1
    image = coverage_image(counts, 480, 360)
    assert image.shape == (360, 480, 3) and image.dtype == np.uint8
    assert tuple(image[30, 30]) != (70, 70, 70) and image[30, 30, 1] > 200  # a hit cell, the fullest: bright
    assert tuple(image[359, 479]) == (230, 40, 40)  # an empty corner cell: red outline
    assert tuple(image[180, 240]) == (70, 70, 70) or image[180, 240].sum() == 0  # empty cell (or a border)


@pytest.fixture()
def sim_files(tmp_path):
    scenario = dict(SCENARIO, trajectory=dict(SCENARIO["trajectory"], count=12), exposure={"factors": [1]})
    (tmp_path / "scenario.yaml").write_text(yaml.safe_dump(scenario))
    (tmp_path / "initial.yaml").write_text("camera: {width: 480, height: 360, fx: 440, fy: 440, cx: 239.5, "
                                           "cy: 179.5, bit_depth: 12}\n")
    return tmp_path


def _calibrate(files, *extra):
    return main(["calibrate", "targets", "--source", f"sim:{files / 'scenario.yaml'}", "--source-option",
                 "realtime=false", "--initial", str(files / "initial.yaml"), "--out", str(files / "camera.yaml"),
                 *extra])


def test_live_collection_stops_once_the_thresholds_are_reached(sim_files, capsys):
    from tests.test_sinks import _rrd_columns

    rrd = sim_files / "calibration.rrd"
    code = _calibrate(sim_files, "--views", "12", "--stop-min-views", "4", "--stop-coverage", "0.4",
                      "--stop-corners", "0", "--stop-std-fx", "0.01", "--stop-std-c", "0.02", "--stop-std-k1",
                      "0.1", "--rerun", f"save:{rrd}")
    out = capsys.readouterr().out
    assert code == 0
    assert "collection done after 4 views" in out and "every threshold reached" in out
    assert "view 5/" not in out
    data = _rrd_columns(rrd)
    for entity in ("/calibration/image", "/calibration/image/features", "/calibration/image/all",
                   "/calibration/coverage", "/series/coverage", "/series/std_over_limit/fx", "/status"):
        assert entity in data, f"{entity} missing from {sorted(data)}"
    assert data["/series/coverage"]["view"] == [1, 2, 3, 4]
    assert 0 < np.ravel(data["/series/std_over_limit/fx"]["Scalars:scalars"])[0] <= 1


def test_live_collection_stops_at_the_view_limit_and_says_what_was_not_reached(sim_files, capsys):
    code = _calibrate(sim_files, "--views", "4", "--stop-min-views", "3", "--stop-coverage", "0.3",
                      "--stop-corners", "0", "--stop-std-fx", "1e-5", "--stop-std-c", "0.05")
    out = capsys.readouterr().out
    assert code == 0
    assert "collection stopped at 4 views (--views), thresholds not reached" in out
    assert "final calibration: thresholds not reached: 1-sigma of fx" in out
    assert "1-sigma of cx" not in out.split("final calibration")[-1]
