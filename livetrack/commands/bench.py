"""``livetrack bench``: speed of detection + pose on 1920x1200 frames, against ArUco and AprilTag, and memory.

Pinned to one CPU core (``sched_setaffinity``) with OpenCV single-threaded, so the figures are per core.
Prints a table and writes JSON; medians over frames (these machines are noisy: compare ratios within one run),
wall-clock and CPU (thread) time: on a shared, loaded machine the CPU figures are the steadier ones.

Tracking mode is timed three ways: on a moving target (each frame a new render, the target 0.5 px further
across the image, new noise: what a live camera gives), at the nominal exposure and at 4x over-exposure (every
edge profile clipped), and on a static target (the same frame again right after an untimed call on it, the
best case). With ``--moving-frames`` and ``--repeat`` below ``TrackerOptions.tracking_verify_every`` (10) the
timed calls follow the last edges without detection; live, one frame in 10 also runs the window search.

First frame: the first ``Tracker.process`` of the process, timed before anything else runs an edge fit, includes
loading the compiled edge kernels from numba's cache (or compiling them, a few seconds, on a fresh install or
after a change of ``livetrack/estimator/edge_kernels.py``); the report says which happened. ``--compare-kernels``
also times every livetrack row with the numpy reference kernels (``LIVETRACK_KERNELS=numpy``), interleaved frame
by frame with the compiled ones, so that both see the same load.

Baselines, single-threaded on the same frames (one marker each, rendered at the ring target's pose): ArUco
(``DICT_4X4_50``) at OpenCV's defaults (no corner refinement) and with sub-pixel corners (as the exposure sweep
runs it), AprilTag 36h11 (pupil-apriltags, ``nthreads=1``) at its default ``quad_decimate=2`` and at 1 (full
resolution, as the exposure sweep runs it); each with IPPE pose from its corners. Ratios are against AprilTag at
its default decimation.
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
    parser.add_argument("--compare-kernels", action="store_true",
                        help="also time livetrack with the numpy reference edge kernels, interleaved with the "
                             "compiled ones (about doubles the livetrack part of the run)")
    parser.add_argument("--scaling", action="store_true",
                        help="also time the full frame and tracking against the number of targets (1, 4, 14 at "
                             "1080p) and the resolution (VGA, 1080p, 5 MP with one target): simulated frames")
    parser.add_argument("--scaling-frames", type=int, default=3, help="frames (noise draws) per scaling point")
    parser.add_argument("--profile", action="store_true",
                        help="also profile (cProfile) the full frame and tracking a moving target: the stages' "
                             "ms per frame and share, and the functions with the most own time (the profiler "
                             "adds a cost per Python call: read the shares)")
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


def _median_ms_each(fns: dict, inputs, repeat: int) -> tuple[dict[str, float], dict[str, float]]:
    """:func:`_median_ms` of several functions, interleaved (per input: each warmed, then ``repeat`` rounds of one
    call of each), so that they see the same machine load: ({name: wall ms}, {name: CPU ms}) medians."""
    times = {name: [] for name in fns}
    cpu_times = {name: [] for name in fns}
    for x in inputs:
        for fn in fns.values():
            fn(x)
        for _ in range(repeat):
            for name, fn in fns.items():
                t0, c0 = time.perf_counter_ns(), time.thread_time_ns()
                fn(x)
                times[name].append((time.perf_counter_ns() - t0) / 1e6)
                cpu_times[name].append((time.thread_time_ns() - c0) / 1e6)
    return ({k: statistics.median(v) for k, v in times.items()},
            {k: statistics.median(v) for k, v in cpu_times.items()})


def _with_kernels(kernels: str, fn):
    """``fn`` run with the edge kernels ``kernels`` ("numba" or "numpy", ``LIVETRACK_KERNELS``)."""
    from livetrack.estimator import edge_kernels

    def run(*args):
        if edge_kernels.kernels() != kernels:  # the choice is cached: set and read again only when it changes
            os.environ[edge_kernels.KERNELS_ENV] = kernels
            edge_kernels.reset_kernels()
        return fn(*args)

    return run


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


def _tracking_ms(camera, targets, frames, kernels: list[str], options=None
                 ) -> tuple[dict[str, float], dict[str, float]]:
    """Median wall-clock and CPU ms of a tracking-mode tracker (``options``, default
    ``TrackerOptions(tracking=True)``) over ``frames`` (image, exposure_us) in order, frames that ran a search (the
    first of each sequence, one in ``tracking_verify_every``) left out: ({kernels: wall}, {kernels: CPU}), one
    tracker per edge-kernel choice, fed the frames alternately."""
    from livetrack.estimator.tracker import Tracker, TrackerOptions

    trackers = {k: _with_kernels(k, Tracker(camera, targets, options or TrackerOptions(tracking=True)).process)
                for k in kernels}
    times = {k: [] for k in kernels}
    cpu_times = {k: [] for k in kernels}
    for image, exposure_us in frames:
        for k, process in trackers.items():
            t0, c0 = time.perf_counter_ns(), time.thread_time_ns()
            result = process(image, exposure_us)
            wall, used = (time.perf_counter_ns() - t0) / 1e6, (time.thread_time_ns() - c0) / 1e6
            if result.timings_ms.get("detect_ms", 0.0) == 0.0:
                times[k].append(wall)
                cpu_times[k].append(used)

    def med(v):
        return statistics.median(v) if v else float("nan")

    return {k: med(v) for k, v in times.items()}, {k: med(v) for k, v in cpu_times.items()}


SCALING_RESOLUTIONS = {"VGA": (640, 480), "1080p": (1920, 1080), "5MP": (2592, 1944)}
"""Image sizes of the scaling rows (width, height px)."""
SCALING_TARGETS = (1, 4, 14)
"""Numbers of targets of the scaling rows (at 1080p); 14 rather than 16: the 8-slot code book has 14 ids."""


def _scaling_scenario(width: int, height: int, n_targets: int, seed: int) -> dict:
    """A scenario mapping: ``n_targets`` targets in a square grid over the middle of a ``width`` x ``height``
    12-bit image (focal length = width, so the same field of view at every resolution), 2.5 m away, tilted
    10-30 degrees, each about 0.3 of its grid cell in outer radius; the paper-lab sensor, optics and scene, one
    nominal exposure."""
    side = int(np.ceil(np.sqrt(n_targets)))
    f, z = float(width), 2.5
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    cell_px = 0.9 * min(width, height) / side
    radius_m = 0.3 * cell_px * z / f
    poses = []
    for k in range(n_targets):
        u = cx + (k % side - (side - 1) / 2.0) * cell_px
        v = cy + (k // side - (side - 1) / 2.0) * cell_px
        poses.append({"target_id": k, "t_m": [(u - cx) * z / f, (v - cy) * z / f, z],
                      "tilt_deg": 10.0 + 20.0 * (k % 3) / 2.0, "tilt_axis_deg": 40.0 * k, "roll_deg": 15.0 * k})
    return {
        "name": f"scaling-{width}x{height}-{n_targets}", "seed": seed,
        "camera": {"width": width, "height": height, "fx": f, "fy": f, "cx": cx, "cy": cy,
                   "dist": [-0.05, 0, 0, 0, 0], "bit_depth": 12},
        "sensor": {"full_well_e": 10000, "read_noise_e": 5, "black_level_dn": 0},
        "optics": {"psf_sigma_px": 0.8},
        "scene": {"white_reflectance": 0.85, "black_reflectance": 0.04, "background_reflectance": 0.2},
        "targets": [{"id": k, "outer_radius_m": radius_m} for k in range(n_targets)],
        "poses": [poses],
        "exposure": {"nominal_us": "auto", "white_fraction_of_full_well": 0.55, "factors": [1.0]},
    }


def _scaling_rows(n_frames: int, repeat: int) -> list[dict]:
    """Full-frame and tracking (static target, the same frame again) medians (wall and CPU ms) and the targets
    found, for each number of targets at 1080p and each resolution with one target."""
    from livetrack.estimator.tracker import Tracker, TrackerOptions
    from livetrack.sim.scenario import Scenario

    points = [("1080p", n) for n in SCALING_TARGETS] + [(r, 1) for r in SCALING_RESOLUTIONS if r != "1080p"]
    rows = []
    for resolution, n_targets in points:
        width, height = SCALING_RESOLUTIONS[resolution]
        scenario = Scenario.from_dict(_scaling_scenario(width, height, n_targets, 11))
        images = [scenario.render_frame(0).image]
        optical = scenario.formation.optical_image(scenario.placements_for(0))
        for k in range(1, n_frames):  # the same scene, new noise
            rng = np.random.default_rng([11, k])
            images.append(scenario.formation.render_from_optical(optical, scenario.nominal_exposure_us,
                                                                 scenario.gain_db, rng, True))
        targets = list(scenario.targets)
        full = Tracker(scenario.camera, targets)
        tracking = Tracker(scenario.camera, targets, TrackerOptions(tracking=True))
        found = statistics.median(len(full.process(im).targets) for im in images)
        cpu: list[float] = []
        row = {"resolution": resolution, "width": width, "height": height, "targets": n_targets,
               "targets_found_median": found,
               "full_frame_ms": _median_ms(full.process, images, repeat, cpu),
               "tracking_static_ms": _median_ms(tracking.process, images, repeat, cpu)}
        row["full_frame_cpu_ms"], row["tracking_static_cpu_ms"] = cpu
        rows.append(row)
    return rows


PROFILE_STAGES = {
    "detector.Detector.detect": "detection (Detector.detect)",
    "threshold._normalise_halved": "  16-to-8-bit map (16-bit frames: with pyramid level 1)",
    "~.<pyrDown>": "  pyramid (cv2.pyrDown, the other levels)",
    "~.<GaussianBlur>": "  full-resolution blur (OpenCV's, where not fused)",
    "threshold._blurred_for_noise": "  full-resolution blur of the noise's rows",
    "threshold._noise": "  noise estimate",
    "threshold._dark_box": "  local threshold (_dark_box: the blur fused in)",
    "pairs._pairs": "  contours and ellipse pairs (_pairs, plain + closed)",
    "~.<morphologyEx>": "  closing (cv2.morphologyEx)",
    "refine._refine": "  refine pairs",
    "code._identify": "  verify and read the code (_identify)",
    "tracker.Tracker._samples": "edge samples from the ellipses",
    "tracker.Tracker._predicted": "motion prediction",
    "two_pass.fit_edges_two_pass": "edge fits (fit_edges_two_pass)",
    "edge_kernels.levenberg_marquardt": "  of which the compiled LM kernel",
    "tracker.Tracker._closed_form": "closed-form pose",
    "pose_fit.fit_pose": "pose fit (fit_pose)",
}
"""Functions whose cumulative time ``bench --profile`` reports, keyed ``module.name`` as cProfile names them (``~``
for C functions such as OpenCV's), with their label; indented labels are parts of the row above."""


def _profile_calls(process, frames, tracked_only: bool = False) -> dict:
    """cProfile ``process(image, exposure_us)`` over ``frames`` (``tracked_only``: only the calls that ran no
    detection count): {"calls", "total_ms_per_call", "stages": {label: [ms per call, share]}, "top_own":
    [[function, own ms per call, share], ...]} (the 15 with the most own time)."""
    import cProfile
    import pstats

    stats: pstats.Stats | None = None
    calls = 0
    for image, exposure_us in frames:
        profiler = cProfile.Profile()
        profiler.enable()
        result = process(image, exposure_us)
        profiler.disable()
        if tracked_only and result.timings_ms.get("detect_ms", 0.0) != 0.0:
            continue
        calls += 1
        if stats is None:
            stats = pstats.Stats(profiler)
        else:
            stats.add(profiler)
    if stats is None:
        return {"calls": 0, "total_ms_per_call": float("nan"), "stages": {}, "top_own": []}
    total_s = max(stats.total_tt, 1e-12)  # type: ignore[attr-defined]
    per = 1e3 / max(calls, 1)
    cumulative: dict[str, float] = {}
    own: list[tuple[str, float]] = []
    for (file, _line, func), (_cc, _nc, tt, ct, _callers) in stats.stats.items():  # type: ignore[attr-defined]
        module = "~" if file == "~" else Path(file).stem
        name = f"{module}.{func}"
        cumulative[name] = max(cumulative.get(name, 0.0), ct)  # detector.detect wraps Detector.detect: the outer
        own.append((name if module != "~" else func, tt))
    # the qualified names of methods: pstats keys hold the bare function name
    qualified = {"detector.detect": "detector.Detector.detect", "tracker._samples": "tracker.Tracker._samples",
                 "tracker._predicted": "tracker.Tracker._predicted",
                 "tracker._closed_form": "tracker.Tracker._closed_form"}
    for bare, full in qualified.items():
        if bare in cumulative:
            cumulative[full] = cumulative.pop(bare)
    stages = {label: [cumulative.get(key, 0.0) * per, cumulative.get(key, 0.0) / total_s]
              for key, label in PROFILE_STAGES.items() if cumulative.get(key, 0.0) > 0}
    top = sorted(own, key=lambda kv: -kv[1])[:15]
    return {"calls": calls, "total_ms_per_call": total_s * per, "stages": stages,
            "top_own": [[name, tt * per, tt / total_s] for name, tt in top]}


def _print_profile(title: str, prof: dict) -> None:
    print(f"  profile, {title}: {prof['total_ms_per_call']:.1f} ms per frame under the profiler "
          f"({prof['calls']} calls)")
    for label, (ms, share) in prof["stages"].items():
        print(f"    {label:54s} {ms:7.2f} ms  {100 * share:5.1f} %")
    print("    most own time: " + "; ".join(f"{name} {ms:.2f} ms ({100 * share:.0f} %)"
                                            for name, ms, share in prof["top_own"][:10]))


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def run(args: argparse.Namespace) -> int:
    from livetrack.baselines.square_markers import AprilTagMethod, ArucoMethod
    from livetrack.config.app import load_config
    from livetrack.estimator import edge_kernels
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
    # the start-up, as `livetrack run` does it: every compiled kernel loaded from numba's cache (or compiled), then
    # the first frame of the process
    from livetrack.estimator import warm

    default_kernels = edge_kernels.kernels()
    warm_up_s = warm.warm_up()
    first = Tracker(camera, targets)
    t0 = time.perf_counter_ns()
    first.process(ring[0])
    first_frame_ms = (time.perf_counter_ns() - t0) / 1e6
    t0 = time.perf_counter_ns()
    first.process(ring[0])
    second_frame_ms = (time.perf_counter_ns() - t0) / 1e6
    cache = warm.cache_stats()
    kernel_load = ("numpy reference (no compilation)" if default_kernels != "numba" else
                   "kernels compiled" if cache["misses"] else "kernels loaded from numba's cache")
    kernels = [default_kernels] + (["numpy"] if args.compare_kernels and default_kernels != "numpy" else [])
    kernels_env = os.environ.get(edge_kernels.KERNELS_ENV)  # the timed calls set it; restored after them
    full = {k: Tracker(camera, targets) for k in kernels}
    static = {k: Tracker(camera, targets, TrackerOptions(tracking=True)) for k in kernels}
    aruco_m = ArucoMethod(camera, 2 * spec.outer_radius_m)
    aruco_default = ArucoMethod(camera, 2 * spec.outer_radius_m, corner_refinement=cv2.aruco.CORNER_REFINE_NONE)
    april_m = AprilTagMethod(camera, 2 * spec.outer_radius_m, quad_decimate=1.0)
    april_d2 = AprilTagMethod(camera, 2 * spec.outer_radius_m, quad_decimate=2.0)
    found = sum(bool(full[default_kernels].process(im).targets) for im in ring)
    live_options = load_config(None).tracker  # what `livetrack run` uses: fewer edge points per target
    moving = _moving_sequences(scenario, steps[:: max(1, len(steps) // 3)][:3], args.moving_frames)

    full_ms, full_cpu = _median_ms_each({k: _with_kernels(k, full[k].process) for k in kernels}, ring, args.repeat)
    static_ms, static_cpu = _median_ms_each({k: _with_kernels(k, static[k].process) for k in kernels}, ring,
                                            args.repeat)
    track_ms, track_cpu = _tracking_ms(camera, targets, moving["nominal"], kernels)
    over_ms, over_cpu = _tracking_ms(camera, targets, moving["x4"], kernels)
    live_ms, live_cpu = _tracking_ms(camera, targets, moving["nominal"], kernels, live_options)
    if kernels_env is None:
        os.environ.pop(edge_kernels.KERNELS_ENV, None)
    else:
        os.environ[edge_kernels.KERNELS_ENV] = kernels_env
    edge_kernels.reset_kernels()
    cpu: list[float] = []
    figures = {
        "frames": len(ring), "livetrack_found": found, "kernels": default_kernels,
        "warm_up_s": warm_up_s, "first_frame_ms": first_frame_ms, "first_frame_again_ms": second_frame_ms,
        "first_frame_kernels": kernel_load,
        "kernel_cache_hits": cache["hits"], "kernel_compilations": cache["misses"],
        "full_frame_ms": full_ms[default_kernels],
        "tracking_ms": track_ms[default_kernels],
        "tracking_overexposed_ms": over_ms[default_kernels],
        "tracking_static_ms": static_ms[default_kernels],
        "tracking_live_config_ms": live_ms[default_kernels],
        "aruco_default_detect_and_pose_ms": _median_ms(aruco_default.estimate, aruco, args.repeat, cpu),
        "aruco_detect_and_pose_ms": _median_ms(aruco_m.estimate, aruco, args.repeat, cpu),
        "apriltag_decimate2_detect_and_pose_ms": _median_ms(april_d2.estimate, april, args.repeat, cpu),
        "apriltag_detect_and_pose_ms": _median_ms(april_m.estimate, april, args.repeat, cpu),
        "aruco_default_found": sum(bool(aruco_default.estimate(im)) for im in aruco),
        "aruco_found": sum(bool(aruco_m.estimate(im)) for im in aruco),
        "apriltag_decimate2_found": sum(bool(april_d2.estimate(im)) for im in april),
        "apriltag_found": sum(bool(april_m.estimate(im)) for im in april),
        "full_frame_cpu_ms": full_cpu[default_kernels], "tracking_cpu_ms": track_cpu[default_kernels],
        "tracking_overexposed_cpu_ms": over_cpu[default_kernels], "tracking_static_cpu_ms": static_cpu[default_kernels],
        "tracking_live_config_cpu_ms": live_cpu[default_kernels],
    }
    figures.update(zip(("aruco_default_cpu_ms", "aruco_cpu_ms", "apriltag_decimate2_cpu_ms", "apriltag_cpu_ms"), cpu,
                       strict=True))
    if len(kernels) > 1:
        figures["numpy_kernels"] = {
            "full_frame_ms": full_ms["numpy"], "tracking_ms": track_ms["numpy"],
            "tracking_overexposed_ms": over_ms["numpy"], "tracking_static_ms": static_ms["numpy"],
            "tracking_live_config_ms": live_ms["numpy"], "full_frame_cpu_ms": full_cpu["numpy"],
            "tracking_cpu_ms": track_cpu["numpy"], "tracking_overexposed_cpu_ms": over_cpu["numpy"],
            "tracking_static_cpu_ms": static_cpu["numpy"], "tracking_live_config_cpu_ms": live_cpu["numpy"],
        }
    april_ref = figures["apriltag_decimate2_detect_and_pose_ms"]
    figures["ratios_apriltag_decimate2_over"] = {
        key: april_ref / figures[key] for key in ("full_frame_ms", "tracking_ms", "tracking_overexposed_ms",
                                                  "tracking_live_config_ms")}
    april_cpu = figures["apriltag_decimate2_cpu_ms"]  # CPU time: steadier than wall-clock on a loaded machine
    figures["ratios_apriltag_decimate2_over_cpu"] = {
        key: april_cpu / figures[key] for key in ("full_frame_cpu_ms", "tracking_cpu_ms",
                                                  "tracking_overexposed_cpu_ms", "tracking_live_config_cpu_ms")}
    stage = [full[default_kernels].process(im).timings_ms for im in ring]
    figures["full_frame_detect_ms"] = statistics.median(t["detect_ms"] for t in stage)
    figures["full_frame_edges_and_pose_ms"] = statistics.median(t["pose_ms"] for t in stage)

    if args.scaling:
        figures["scaling"] = _scaling_rows(args.scaling_frames, args.repeat)
    if args.profile:
        full_tracker = Tracker(camera, targets)
        track_tracker = Tracker(camera, targets, TrackerOptions(tracking=True))
        figures["profile"] = {
            "full_frame": _profile_calls(full_tracker.process, [(im, None) for im in ring] * args.repeat),
            # the tracked frames only (the searches -- first of each sequence, 1 in 10 -- left out)
            "tracking": _profile_calls(track_tracker.process, moving["nominal"] * args.repeat, tracked_only=True),
        }

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
    rss_end = _rss_mb()
    # the kernel's high-water mark lags the resident size it samples (per-thread counters synced now and then: a test
    # saw it 0.2 MB below the start's VmRSS), so the peak is at least every size read here
    high_water_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    figures.update({
        "replay_frames": n, "replay_seconds": time.perf_counter() - t0,
        "replay_rss_start_mb": rss_start, "replay_rss_every_100_frames_mb": rss_samples,
        "replay_rss_end_mb": rss_end,
        "peak_rss_mb": max([high_water_mb, rss_start, rss_end, *rss_samples]),
    })
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(figures, indent=1))
    ratio = figures["ratios_apriltag_decimate2_over"]
    ref = figures.get("numpy_kernels", {})

    def with_ref(key):
        return f" (numpy kernels {ref[key]:.1f})" if key in ref else ""

    print(f"one core, median ms per {camera.width}x{camera.height} frame over {len(ring)} frames x {args.repeat} "
          f"(edge kernels: {default_kernels}):")
    print(f"  livetrack start-up (compiled kernels ready):  {warm_up_s * 1e3:7.1f} ms ({kernel_load})")
    print(f"  livetrack first frame of the process:         {first_frame_ms:7.1f} ms (after the start-up; the same "
          f"frame again: {second_frame_ms:.1f} ms)")
    print(f"  livetrack full frame (detect + edges + pose): {figures['full_frame_ms']:7.1f} ms "
          f"(detect {figures['full_frame_detect_ms']:.1f}, edges + pose {figures['full_frame_edges_and_pose_ms']:.1f})"
          f"  found {found}/{len(ring)}; AprilTag d2 / this: {ratio['full_frame_ms']:.2f}x" + with_ref("full_frame_ms"))
    print(f"  livetrack tracking mode, moving target:       {figures['tracking_ms']:7.1f} ms "
          f"(nominal exposure; {TRACKING_NOTE}); AprilTag d2 / this: {ratio['tracking_ms']:.2f}x"
          + with_ref("tracking_ms"))
    print(f"  livetrack tracking mode, moving, 4x over-exp.: {figures['tracking_overexposed_ms']:6.1f} ms "
          f"(every edge profile clipped)" + with_ref("tracking_overexposed_ms"))
    print(f"  livetrack tracking mode, static target:       {figures['tracking_static_ms']:7.1f} ms "
          f"(the same frame again: the best case)" + with_ref("tracking_static_ms"))
    print(f"  livetrack tracking, moving, live config:      {figures['tracking_live_config_ms']:7.1f} ms "
          f"(`livetrack run`'s tracker: edge every {live_options.edge_spacing_px:g} px, at most "
          f"{live_options.max_points_per_circle} per circle)" + with_ref("tracking_live_config_ms"))
    n_fr = len(ring)
    print(f"  ArUco at defaults (no corner refinement) + IPPE: {figures['aruco_default_detect_and_pose_ms']:4.1f} ms"
          f"  found {figures['aruco_default_found']}/{n_fr}")
    print(f"  ArUco, sub-pixel corners + IPPE (the sweep's): {figures['aruco_detect_and_pose_ms']:6.1f} ms"
          f"  found {figures['aruco_found']}/{n_fr}")
    print(f"  AprilTag 36h11, quad_decimate 2 (default) + IPPE: {figures['apriltag_decimate2_detect_and_pose_ms']:3.1f}"
          f" ms  found {figures['apriltag_decimate2_found']}/{n_fr}")
    print(f"  AprilTag 36h11, quad_decimate 1 + IPPE (the sweep's): {figures['apriltag_detect_and_pose_ms']:.1f} ms"
          f"  found {figures['apriltag_found']}/{n_fr}")
    print(f"  CPU time (less inflated by a loaded machine): full {figures['full_frame_cpu_ms']:.1f}, tracking "
          f"{figures['tracking_cpu_ms']:.1f} / {figures['tracking_overexposed_cpu_ms']:.1f} (4x) / "
          f"{figures['tracking_static_cpu_ms']:.1f} (static) / {figures['tracking_live_config_cpu_ms']:.1f} (live "
          f"config), ArUco {figures['aruco_default_cpu_ms']:.1f} / {figures['aruco_cpu_ms']:.1f} (sub-pixel), "
          f"AprilTag {figures['apriltag_decimate2_cpu_ms']:.1f} (decimate 2) / {figures['apriltag_cpu_ms']:.1f} ms "
          f"(decimate 1)")
    ratio_cpu = figures["ratios_apriltag_decimate2_over_cpu"]
    print(f"  AprilTag (decimate 2) / livetrack, CPU time: full frame {ratio_cpu['full_frame_cpu_ms']:.2f}x, tracking "
          f"{ratio_cpu['tracking_cpu_ms']:.2f}x (4x over-exposed {ratio_cpu['tracking_overexposed_cpu_ms']:.2f}x, live "
          f"config {ratio_cpu['tracking_live_config_cpu_ms']:.2f}x)")
    for row in figures.get("scaling", []):
        print(f"  scaling: {row['resolution']:>5s} ({row['width']}x{row['height']}), {row['targets']:2d} target(s), "
              f"found {row['targets_found_median']:g}: full frame {row['full_frame_ms']:6.1f} ms (CPU "
              f"{row['full_frame_cpu_ms']:.1f}), tracking (static) {row['tracking_static_ms']:5.1f} ms (CPU "
              f"{row['tracking_static_cpu_ms']:.1f})")
    if "profile" in figures:
        _print_profile("full frame", figures["profile"]["full_frame"])
        _print_profile("tracking a moving target (tracked frames only)", figures["profile"]["tracking"])
    print(f"memory: {n}-frame replay of {args.replay.name}: RSS {rss_start:.0f} MB at start, "
          f"{figures['replay_rss_end_mb']:.0f} MB at the end, peak {figures['peak_rss_mb']:.0f} MB")
    print(f"report: {args.json}")
    return 0
