"""``livetrack bench`` runs end to end on a small scenario and reports every figure (the figures themselves are
measured by running it; see the README)."""

import json
import math
import os
from pathlib import Path

import cv2

from livetrack.cli import main

REPO = Path(__file__).resolve().parents[1]


def test_bench_reports_every_figure_on_a_small_scenario(tmp_path):
    out = tmp_path / "bench.json"
    cores, threads = os.sched_getaffinity(0), cv2.getNumThreads()
    try:  # the bench pins the process to one core and OpenCV to one thread: undone for the tests after it
        code = main(["bench", "--scenario", str(REPO / "config" / "scenarios" / "demo.yaml"), "--frames", "2",
                     "--repeat", "1", "--moving-frames", "3", "--replay-frames", "12", "--compare-kernels",
                     "--profile", "--json", str(out)])
    finally:
        os.sched_setaffinity(0, cores)
        cv2.setNumThreads(threads)
    assert code == 0
    figures = json.loads(out.read_text())
    assert figures["livetrack_found"] == figures["frames"] == 2
    for key in ("full_frame_ms", "tracking_ms", "tracking_overexposed_ms", "tracking_static_ms",
                "tracking_live_config_ms", "aruco_detect_and_pose_ms", "apriltag_detect_and_pose_ms",
                "full_frame_cpu_ms", "tracking_cpu_ms", "first_frame_ms", "aruco_default_detect_and_pose_ms",
                "apriltag_decimate2_detect_and_pose_ms"):
        assert math.isfinite(figures[key]) and figures[key] > 0, key
    for key in ("full_frame_ms", "tracking_ms", "tracking_overexposed_ms", "tracking_static_ms",
                "tracking_live_config_ms"):  # the numpy reference kernels, timed alongside
        assert math.isfinite(figures["numpy_kernels"][key]) and figures["numpy_kernels"][key] > 0, key
    assert figures["kernels"] == "numba" and "LIVETRACK_KERNELS" not in os.environ
    assert figures["apriltag_found"] == figures["aruco_found"] == 2
    assert set(figures["ratios_apriltag_decimate2_over"]) >= {"full_frame_ms", "tracking_ms"}
    profile = figures["profile"]  # --profile: the stages of a full frame and of tracked frames
    assert profile["full_frame"]["calls"] == 2 and "detection (Detector.detect)" in profile["full_frame"]["stages"]
    assert profile["tracking"]["calls"] >= 1 and "detection (Detector.detect)" not in profile["tracking"]["stages"]
    assert all(0 < share <= 1 for _, share in profile["full_frame"]["stages"].values())
    assert figures["replay_frames"] == 12 and figures["peak_rss_mb"] >= figures["replay_rss_start_mb"] > 0


def test_scaling_rows_time_every_point_and_find_every_target(monkeypatch):
    """The scaling rows (``bench --scaling``) on small images: each point is timed and all its targets found."""
    from livetrack.commands import bench

    monkeypatch.setattr(bench, "SCALING_RESOLUTIONS", {"VGA": (480, 360), "1080p": (640, 480), "5MP": (800, 600)})
    monkeypatch.setattr(bench, "SCALING_TARGETS", (1, 4))
    rows = bench._scaling_rows(1, 1)
    assert [(r["resolution"], r["targets"]) for r in rows] == [("1080p", 1), ("1080p", 4), ("VGA", 1), ("5MP", 1)]
    for row in rows:
        assert row["targets_found_median"] == row["targets"], row
        for key in ("full_frame_ms", "tracking_static_ms", "full_frame_cpu_ms", "tracking_static_cpu_ms"):
            assert math.isfinite(row[key]) and row[key] > 0, (row, key)
