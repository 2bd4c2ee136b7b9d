"""``livetrack bench``: speed of detection + pose on 1920x1200 frames, against ArUco and AprilTag, and memory.

Pinned to one CPU core (``sched_setaffinity``) with OpenCV single-threaded, so the figures are per core.
Prints a table and writes JSON; medians over frames (these machines are noisy: compare ratios within one run),
wall-clock and CPU (thread) time: on a shared, loaded machine the CPU figures are the steadier ones.

Tracking mode is timed three ways: on a moving target (each frame a new render, the target 0.5 px further
across the image, new noise: what a live camera gives), at the nominal exposure and at 4x over-exposure (every
edge profile clipped), and on a static target (the same frame again right after an untimed call on it, the
best case). With ``--moving-frames`` and ``--repeat`` below ``TrackerOptions.tracking_verify_every`` (10) the
timed calls follow the last edges without detection; live, one frame in 10 also runs the window search.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import time
from pathlib import Path

import cv2
import numpy as np

NAME = "bench"
HELP = "speed (ms per 1920x1200 frame, one core) of livetrack vs ArUco/AprilTag, and memory of a long replay"

REPO = Path(__file__).resolve().parents[2]
TRACKING_NOTE = "timed calls follow the last edges; live, 1 frame in 10 also searches the window"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", type=Path, default=REPO / "config" / "scenarios" / "paper-lab.yaml",
                        help="scenario giving the frames (default paper-lab, 1920x1200)")
    parser.add_argument("--frames", type=int, default=20, help="distinct frames (poses) to time")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per frame")
    parser.add_argument("--moving-frames", type=int, default=8,
                        help="frames per moving-target sequence (3 sequences, each at two exposures)")
    parser.add_argument("--replay-frames", type=int, default=1000, help="frames of the memory replay")
    parser.add_argument("--replay", type=Path, default=REPO / "recordings" / "sample",
                        help="recording looped for the memory figure")
    parser.add_argument("--json", type=Path, required=True, help="report file")


def _median_ms(fn, inputs, repeat: int, cpu: list[float] | None = None) -> float:
    """Median wall-clock ms of ``fn`` over inputs x repeat; appends the median CPU (thread) ms to ``cpu``, which
    a loaded shared machine inflates far less (time spent waiting for the core is not counted)."""
    times, cpu_times = [], []
    for x in inputs:
        fn(x)  # warm (and, for tracking, sets the window and the edges to follow)
        for _ in range(repeat):
            t0, c0 = time.perf_counter_ns(), time.thread_time_ns()
            fn(x)
            times.append((time.perf_counter_ns() - t0) / 1e6)
            cpu_times.append((time.thread_time_ns() - c0) / 1e6)
    if cpu is not None:
        cpu.append(statistics.median(cpu_times))
    return statistics.median(times)


def _moving_sequences(scenario, steps, n_frames: int) -> dict[str, list[tuple[np.ndarray, float]]]:
    """For each of ``steps``, ``n_frames`` renders of its target moved 0.5 px further across the image each frame
    (each with its own noise), at the nominal exposure and at 4x: {"nominal": [...], "x4": [...]} of (image,
    exposure_us); a sequence starts where the previous one ends (the tracker searches again there)."""
    import dataclasses

    from livetrack.geometry import Pose

    camera, formation = scenario.camera, scenario.formation
    out: dict[str, list[tuple[np.ndarray, float]]] = {"nominal": [], "x4": []}
    for step in steps:
        index = int(step) * len(scenario.exposure_factors)
        placement = scenario.placements_for(index)[0]
        per_px_m = placement.pose.t[2] / camera.fx
        for k in range(n_frames):
            pose = Pose(placement.pose.R, placement.pose.t + np.array([0.5 * k * per_px_m, 0.0, 0.0]))
            optical = formation.optical_image([dataclasses.replace(placement, pose=pose)])
            for name, factor in (("nominal", 1.0), ("x4", 4.0)):
                exposure_us = scenario.nominal_exposure_us * factor
                rng = np.random.default_rng([int(step), k, int(factor)])
                image = formation.render_from_optical(optical, exposure_us, scenario.gain_db, rng, True)
                out[name].append((image, exposure_us))
    return out


def _tracking_ms(camera, targets, frames, cpu: list[float], options=None) -> float:
    """Median wall-clock ms of a tracking-mode tracker (``options``, default ``TrackerOptions(tracking=True)``) over
    ``frames`` (image, exposure_us) in order, frames that ran a search (the first of each sequence, one in
    ``tracking_verify_every``) left out; appends the CPU median to ``cpu``."""
    from livetrack.estimator.tracker import Tracker, TrackerOptions

    tracker = Tracker(camera, targets, options or TrackerOptions(tracking=True))
    times, cpu_times = [], []
    for image, exposure_us in frames:
        t0, c0 = time.perf_counter_ns(), time.thread_time_ns()
        result = tracker.process(image, exposure_us)
        wall, used = (time.perf_counter_ns() - t0) / 1e6, (time.thread_time_ns() - c0) / 1e6
        if result.timings_ms.get("detect_ms", 0.0) == 0.0:
            times.append(wall)
            cpu_times.append(used)
    cpu.append(statistics.median(cpu_times) if cpu_times else float("nan"))
    return statistics.median(times) if times else float("nan")


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def run(args: argparse.Namespace) -> int:
    from livetrack.app_config import load_config
    from livetrack.baselines.square_markers import AprilTagMethod, ArucoMethod
    from livetrack.estimator.tracker import Tracker, TrackerOptions
    from livetrack.evaluation.exposure_sweep import marker_placement
    from livetrack.recording import Recording
    from livetrack.sim.scenario import Scenario

    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    cv2.setNumThreads(1)
    scenario = Scenario.from_file(args.scenario)
    n_exp = len(scenario.exposure_factors)
    nominal = scenario.exposure_factors.index(1.0) if 1.0 in scenario.exposure_factors else 0
    steps = np.linspace(0, len(scenario.steps) - 1, min(args.frames, len(scenario.steps))).round().astype(int)
    spec = scenario.targets[0]
    ring, aruco, april = [], [], []
    print(f"rendering {len(steps)} frames of {args.scenario.name} "
          f"({scenario.camera.width}x{scenario.camera.height}) ...", flush=True)
    for step in steps:
        index = int(step) * n_exp + nominal
        placement = scenario.placements_for(index)[0]
        ring.append(scenario.render_frame(index).image)
        side = placement.texture.bounds_m[1] - placement.texture.bounds_m[0]
        for kind, out in (("aruco", aruco), ("apriltag", april)):
            mk = marker_placement(kind, placement.pose, spec.outer_radius_m, side, spec.id,
                                  scenario.scene.white_reflectance, scenario.scene.black_reflectance)
            optical = scenario.formation.optical_image([mk])
            out.append(scenario.render_frame(index, optical=optical).image)
    camera, targets = scenario.camera, list(scenario.targets)
    full = Tracker(camera, targets)
    tracking = Tracker(camera, targets, TrackerOptions(tracking=True))
    aruco_m = ArucoMethod(camera, 2 * spec.outer_radius_m)
    april_m = AprilTagMethod(camera, 2 * spec.outer_radius_m)
    found = sum(bool(full.process(im).targets) for im in ring)
    live_options = load_config(None).tracker  # what `livetrack run` uses: fewer edge points per target
    moving = _moving_sequences(scenario, steps[:: max(1, len(steps) // 3)][:3], args.moving_frames)

    def track(im):
        return tracking.process(im)

    cpu: list[float] = []
    figures = {
        "frames": len(ring), "livetrack_found": found,
        "full_frame_ms": _median_ms(full.process, ring, args.repeat, cpu),
        "tracking_ms": _tracking_ms(camera, targets, moving["nominal"], cpu),
        "tracking_overexposed_ms": _tracking_ms(camera, targets, moving["x4"], cpu),
        "tracking_static_ms": _median_ms(track, ring, args.repeat, cpu),
        "tracking_live_config_ms": _tracking_ms(camera, targets, moving["nominal"], cpu, live_options),
        "aruco_detect_and_pose_ms": _median_ms(aruco_m.estimate, aruco, args.repeat, cpu),
        "apriltag_detect_and_pose_ms": _median_ms(april_m.estimate, april, args.repeat, cpu),
    }
    figures.update(zip(("full_frame_cpu_ms", "tracking_cpu_ms", "tracking_overexposed_cpu_ms",
                        "tracking_static_cpu_ms", "tracking_live_config_cpu_ms", "aruco_cpu_ms", "apriltag_cpu_ms"),
                       cpu, strict=True))
    stage = [full.process(im).timings_ms for im in ring]
    figures["full_frame_detect_ms"] = statistics.median(t["detect_ms"] for t in stage)
    figures["full_frame_edges_and_pose_ms"] = statistics.median(t["pose_ms"] for t in stage)

    rec = Recording.open(args.replay)
    replay_tracker = Tracker(rec.camera, rec.targets)
    rss_start = _rss_mb()
    rss_samples = []
    n = 0
    t0 = time.perf_counter()
    while n < args.replay_frames:
        for frame, image in rec.iter_images():
            replay_tracker.process(image, frame.exposure_us)
            n += 1
            if n % 100 == 0:
                rss_samples.append(round(_rss_mb(), 1))
            if n >= args.replay_frames:
                break
    figures.update({
        "replay_frames": n, "replay_seconds": time.perf_counter() - t0,
        "replay_rss_start_mb": rss_start, "replay_rss_every_100_frames_mb": rss_samples,
        "replay_rss_end_mb": _rss_mb(),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    })
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(figures, indent=1))
    print(f"one core, median ms per {camera.width}x{camera.height} frame over {len(ring)} frames x {args.repeat}:")
    print(f"  livetrack full frame (detect + edges + pose): {figures['full_frame_ms']:7.1f} ms "
          f"(detect {figures['full_frame_detect_ms']:.1f}, edges + pose {figures['full_frame_edges_and_pose_ms']:.1f})"
          f"  found {found}/{len(ring)}")
    print(f"  livetrack tracking mode, moving target:       {figures['tracking_ms']:7.1f} ms "
          f"(nominal exposure; {TRACKING_NOTE})")
    print(f"  livetrack tracking mode, moving, 4x over-exp.: {figures['tracking_overexposed_ms']:6.1f} ms "
          f"(every edge profile clipped)")
    print(f"  livetrack tracking mode, static target:       {figures['tracking_static_ms']:7.1f} ms "
          f"(the same frame again: the best case)")
    print(f"  livetrack tracking, moving, live config:      {figures['tracking_live_config_ms']:7.1f} ms "
          f"(`livetrack run`'s tracker: edge every {live_options.edge_spacing_px:g} px, at most "
          f"{live_options.max_points_per_circle} per circle)")
    print(f"  ArUco (detect + IPPE pose):                   {figures['aruco_detect_and_pose_ms']:7.1f} ms")
    print(f"  AprilTag 36h11 (detect + IPPE pose):          {figures['apriltag_detect_and_pose_ms']:7.1f} ms")
    print(f"  CPU time (less inflated by a loaded machine): full {figures['full_frame_cpu_ms']:.1f}, tracking "
          f"{figures['tracking_cpu_ms']:.1f} / {figures['tracking_overexposed_cpu_ms']:.1f} (4x) / "
          f"{figures['tracking_static_cpu_ms']:.1f} (static) / {figures['tracking_live_config_cpu_ms']:.1f} (live "
          f"config), ArUco {figures['aruco_cpu_ms']:.1f}, "
          f"AprilTag {figures['apriltag_cpu_ms']:.1f} ms")
    print(f"memory: {n}-frame replay of {args.replay.name}: RSS {rss_start:.0f} MB at start, "
          f"{figures['replay_rss_end_mb']:.0f} MB at the end, peak {figures['peak_rss_mb']:.0f} MB")
    print(f"report: {args.json}")
    return 0
