"""``livetrack bench-live``: throughput, overhead and latency of the live pipeline. Prints figures; not a test.

(a) replay of a 1920x1200 recording as fast as possible with every output on (Rerun to a file, UDP to loopback,
    ZeroMQ PUB, record): frames per second, and the time per frame spent outside detection and pose -- on the
    processing thread (the latency path; aim < 2 ms) and in CPU time over all threads (decoding, encoding, sinks);
(b) the simulated camera paced at 60 fps (frames pre-rendered: the renderer itself cannot feed 60 fps): latency
    p50/p99 and drops at each stage, for two scenes: a target moving smoothly (~1.5 px per frame) at constant
    exposure, what a camera on a vehicle sees; and the demo, whose target jumps to a new pose every 3 frames
    while the exposure cycles x0.25, x1, x4 every frame (a stress case: most frames search the image again);
(c) ``--soak-minutes N``: (b)'s demo with UDP and ZeroMQ on for N minutes, printing the resident memory every 10 s.
"""

from __future__ import annotations

import argparse
import logging
import socket
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from livetrack.config.app import load_config
from livetrack.config.checks import ConfigError
from livetrack.pipeline import RunSummary, build_pipeline
from livetrack.recording import RecordingWriter
from livetrack.sim.scenario import Scenario
from livetrack.sinks.runner import STATS_WINDOW

NAME = "bench-live"
HELP = "benchmark the live pipeline: 1920x1200 replay with every output, 60 fps simulated latency, soak"

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--recording", type=Path, metavar="DIR",
                        help="1920x1200 recording for (a) (default: render --frames frames of the demo at "
                             "1920x1200 into a temporary directory)")
    parser.add_argument("--frames", type=int, default=24, metavar="N", help="frames to render for (a) (default 24)")
    parser.add_argument("--repeat", type=int, default=1, metavar="N", help="replay (a) N times (default 1)")
    parser.add_argument("--seconds", type=float, default=10.0, metavar="S", help="duration of (b) (default 10)")
    parser.add_argument("--soak-minutes", type=float, default=0.0, metavar="N", help="run (c) for N minutes")
    parser.add_argument("--skip", choices=["replay", "live"], action="append", default=[],
                        help="skip part (a) replay or (b) live")
    parser.add_argument("--search-worker", choices=["auto", "on", "off"], default="auto",
                        help="(b), (c): searches on a second thread (auto: on, the live pipeline's default) or "
                             "every frame through Tracker.process on one thread (off: the pipeline before issue 13)")
    parser.add_argument("--scene", choices=["smooth", "stress", "both"], default="both",
                        help="(b): which 60 fps scene(s) to run (default both)")


def run(args: argparse.Namespace) -> int:
    if args.frames < 1 or args.repeat < 1 or args.seconds <= 0 or args.soak_minutes < 0:
        raise ConfigError("bench-live", "--frames and --repeat must be >= 1, --seconds > 0, --soak-minutes >= 0")
    with tempfile.TemporaryDirectory(prefix="livetrack-bench-") as tmp_text:
        tmp = Path(tmp_text)
        if "replay" not in args.skip:
            recording = args.recording or _render_recording(tmp / "input", args.frames)
            for i in range(args.repeat):
                _bench_replay(recording, tmp / f"out{i}")
        worker = {"auto": None, "on": True, "off": False}[args.search_worker]
        if "live" not in args.skip:
            if args.scene in ("smooth", "both"):
                _bench_live(tmp, args.seconds, soak=False, smooth=True, search_worker=worker)
            if args.scene in ("stress", "both"):
                _bench_live(tmp, args.seconds, soak=False, search_worker=worker)
        if args.soak_minutes > 0:
            _bench_live(tmp, args.soak_minutes * 60.0, soak=True, search_worker=worker)
    return 0


# ---------------------------------------------------------------------------------------------- (a)
def _scenario_data(width: int, height: int, fps: float) -> dict[str, Any]:
    data = Scenario.default().to_dict()
    scale = width / data["camera"]["width"]
    cam = data["camera"]
    cam.update(width=width, height=height, fx=cam["fx"] * scale, fy=cam["fy"] * scale,
               cx=(width - 1) / 2.0, cy=(height - 1) / 2.0)
    data["timing"]["fps"] = fps
    return data


def _smooth_scenario_data(width: int, height: int, fps: float, frames: int = 120) -> dict[str, Any]:
    """The demo's target moving smoothly from its first pose to its last over ``frames`` frames (~1.5 px per frame
    at 960x600), one pose per frame, at the nominal exposure."""
    data = _scenario_data(width, height, fps)
    first, last = data["poses"][0][0], data["poses"][-1][0]
    poses = []
    for k in range(frames):
        w = k / max(frames - 1, 1)
        t_m = [a + w * (b - a) for a, b in zip(first["t_m"], last["t_m"], strict=True)]
        q = np.array(first["q_xyzw"]) * (1.0 - w) + np.array(last["q_xyzw"]) * w  # normalised lerp
        poses.append([{"target_id": first["target_id"], "t_m": t_m, "q_xyzw": (q / np.linalg.norm(q)).tolist()}])
    data.update(name="smooth", poses=poses)
    data["exposure"]["factors"] = [1.0]
    return data


def _render_recording(path: Path, frames: int) -> Path:
    scenario = Scenario.from_dict(_scenario_data(1920, 1200, 30.0))
    t0 = time.perf_counter()
    with RecordingWriter(path, scenario.camera, scenario.targets, meta={"source": "bench-live"}) as writer:
        n = 0
        while n < frames:
            for sim in scenario.frames(max_frames=min(len(scenario), frames - n)):
                writer.write_frame(sim.image, timestamp_ns=sim.timestamp_ns + n * 10**9, exposure_us=sim.exposure_us,
                                   gain_db=sim.gain_db, truth=sim.truth)
            n = writer.frame_count
    print(f"rendered {frames} frames of 1920x1200 into {path} in {time.perf_counter() - t0:.1f} s")
    return path


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _bench_replay(recording: Path, out: Path) -> None:
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.setblocking(False)
    overrides = {
        "source": {"uri": f"replay:{recording}", "options": {"pace": "fast"}},
        "logging": {"print_every_s": 0},
        "outputs": {"rerun": {"mode": f"save:{out / 'bench.rrd'}", "queue_size": 4},
                    "udp": {"destination": f"127.0.0.1:{receiver.getsockname()[1]}"},
                    "zmq": {"endpoint": f"tcp://127.0.0.1:{_free_port()}"},
                    "record": {"dir": str(out / "record"), "queue_size": 64}},
    }
    pipeline = build_pipeline(load_config(overrides=overrides))
    cpu0, wall0 = time.process_time(), time.perf_counter()
    summary = pipeline.run()
    cpu_s, wall_s = time.process_time() - cpu0, time.perf_counter() - wall0
    received = 0
    while True:
        try:
            receiver.recv(65536)
            received += 1
        except BlockingIOError:
            break
    receiver.close()
    n = max(summary.frames_processed, 1)
    stage = summary.stage_ms
    track_cpu = stage["track_cpu_ms"]["mean"] or 0.0  # the processing thread's own CPU
    print("\n(a) replay 1920x1200, as fast as possible, every output on (rerun save, UDP, ZeroMQ, record)")
    print(f"  {summary.frames_processed} frames in {wall_s:.2f} s: {summary.processing_fps:.2f} fps; "
          f"detect p50 {_f(stage['detect_ms']['p50'])} ms, pose p50 {_f(stage['pose_ms']['p50'])} ms")
    print(f"  outside detection+pose on the processing thread: p50 {_f(stage['outside_track_ms']['p50'])} ms, "
          f"p99 {_f(stage['outside_track_ms']['p99'])} ms per frame (aim < 2 ms); hand-off to sinks p50 "
          f"{_f(stage['handoff_ms']['p50'])} ms")
    sinks_cpu = sum(s["cpu_ms_per_item"] * (s["handled"] + s["errors"]) for s in summary.sinks.values()) / n
    outside_cpu = summary.read_cpu_ms_per_frame + sinks_cpu + (stage["outside_track_ms"]["mean"] or 0.0)
    print(f"  CPU time outside detection+pose, all threads: {outside_cpu:.1f} ms per frame = source read (PNG "
          f"decode) {summary.read_cpu_ms_per_frame:.1f} + sinks {sinks_cpu:.1f} (" + ", ".join(
              f"{k} {v['cpu_ms_per_item']:.1f}" for k, v in summary.sinks.items()) + ") + processing thread "
          f"{stage['outside_track_ms']['mean'] or 0.0:.2f}; Tracker.process: {track_cpu:.1f} ms CPU on its thread "
          f"(+ OpenCV's worker threads), process total {cpu_s / n * 1e3:.1f} ms per frame")
    _print_first(summary)
    _print_sinks(summary)
    print(f"  UDP datagrams received on loopback: {received}")


# ---------------------------------------------------------------------------------------------- (b), (c)
def _bench_live(tmp: Path, seconds: float, soak: bool, smooth: bool = False,
                search_worker: bool | None = None) -> None:
    scenario_file = tmp / ("smooth60.yaml" if smooth else "sim60.yaml")
    scenario_file.write_text(yaml.safe_dump((_smooth_scenario_data if smooth else _scenario_data)(960, 600, 60.0)))
    outputs: dict[str, Any] = {}
    if soak:
        outputs = {"udp": {"destination": "127.0.0.1:9"}, "zmq": {"endpoint": f"tcp://127.0.0.1:{_free_port()}"}}
    # Pre-rendered: the renderer (~30 ms per frame) cannot feed 60 fps; a camera costs the pipeline a copy.
    overrides = {"source": {"uri": f"sim:{scenario_file}", "options": {"prerender": True}},
                 "logging": {"print_every_s": 0},
                 "outputs": outputs}
    pipeline = build_pipeline(load_config(overrides=overrides), search_worker=search_worker)
    scene = ("smooth motion (~1.5 px per frame), constant exposure" if smooth
             else "demo: pose jumps every 3 frames, exposure x0.25/x1/x4 cycling")
    title = f"(c) soak {seconds / 60:.1f} min" if soak else f"(b) simulated camera at 60 fps for {seconds:.0f} s"
    print(f"\n{title}: 960x600 12-bit, one target, {scene}" + (", UDP + ZeroMQ on" if soak else ", outputs off")
          + ("; searches on a second thread" if pipeline.search_worker else "; one processing thread"))
    cpu0 = time.process_time()
    pipeline.start()
    deadline = time.monotonic() + seconds
    next_report = time.monotonic()
    rss_mb: list[tuple[float, float]] = []  # (t s, RSS MB) every 10 s of a soak
    while time.monotonic() < deadline and not pipeline.wait(0.5):
        if soak and time.monotonic() >= next_report:
            rss_mb.append((seconds - (deadline - time.monotonic()), _rss_mb()))
            print(f"  t {rss_mb[-1][0]:7.1f} s  RSS {rss_mb[-1][1]:7.1f} MB", flush=True)
            next_report += 10.0
    pipeline.stop("benchmark duration")
    summary = pipeline.close()
    cpu_s = time.process_time() - cpu0
    print(f"  {summary.frames_acquired} frames acquired ({summary.acquisition_fps:.1f} fps), "
          f"{summary.frames_processed} processed ({summary.processing_fps:.1f} fps)")
    print(f"  latency host arrival -> sinks: p50 {_f(summary.latency_ms['p50'])} ms, p99 "
          f"{_f(summary.latency_ms['p99'])} ms, max {_f(summary.latency_ms['max'])} ms")
    _print_first(summary)
    print(f"  drops: in the source (render thread, not read in time) {summary.source_stats.get('dropped', 0)}, "
          f"before processing {summary.dropped_before_processing}; the source was late "
          f"{summary.source_stats.get('late', 0)} times (rendering slower than 60 fps)")
    print(f"  latency of frames with a pose: p50 {_f(summary.pose_latency_ms['p50'])} ms, p99 "
          f"{_f(summary.pose_latency_ms['p99'])} ms; {summary.targets_found} poses ({summary.fits_ok} ok)")
    stage = summary.stage_ms
    print(f"  stages p50: queue {_f(stage['queue_ms']['p50'])} ms, track {_f(stage['track_ms']['p50'])} ms "
          f"(p99 {_f(stage['track_ms']['p99'])}), outside track {_f(stage['outside_track_ms']['p50'])} ms"
          + (f", search {_f(stage['search_ms']['p50'])} ms (p99 {_f(stage['search_ms']['p99'])})"
             if "search_ms" in stage else ""))
    if summary.searches:
        print("  searches: " + ", ".join(f"{k} {v}" for k, v in summary.searches.items()))
    print(f"  CPU time of the process during the run: {cpu_s:.1f} s ({100.0 * cpu_s / seconds:.0f} % of one core; "
          f"pre-rendered frames, so mostly the pipeline)")
    if soak:
        print(f"  final RSS {_rss_mb():.1f} MB")
        if len(rss_mb) >= 4:
            half = rss_mb[len(rss_mb) // 2]
            rate = (rss_mb[-1][1] - half[1]) / max(rss_mb[-1][0] - half[0], 1e-9) * 60.0
            print(f"  RSS growth over the second half ({half[0]:.0f}-{rss_mb[-1][0]:.0f} s): {rate:+.2f} MB/min "
                  f"(the run statistics fill their {STATS_WINDOW}-value windows during the first "
                  f"{STATS_WINDOW} processed frames, ~1.4 MB)")
        _print_sinks(summary)


def _print_first(summary: RunSummary) -> None:
    """The start-up: the kernels' warm-up before acquisition and the first frames (which the percentiles include;
    in a process that ran a pipeline before, the kernels were loaded already)."""
    first = summary.first_frames_ms
    print(f"  start-up: compiled kernels ready in {_f(summary.warm_up_s)} s before acquisition; first frame "
          f"latency {_f(first.get('latency'))} ms, first search {_f(first.get('search'))} ms, first tracked frame "
          f"{_f(first.get('tracked'))} ms")


def _print_sinks(summary: RunSummary) -> None:
    for name, s in summary.sinks.items():
        print(f"  sink {name}: handled {s['handled']}, dropped {s['dropped']}, errors {s['errors']}, handle p50 "
              f"{_f(s['handle_ms_p50'])} ms p99 {_f(s['handle_ms_p99'])} ms")


def _rss_mb() -> float:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _f(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"
