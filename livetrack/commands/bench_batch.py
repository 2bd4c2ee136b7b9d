"""``livetrack bench-batch``: detection frames per second against the number of Dask workers, and the overhead of
one task, on this machine (or on a cluster with ``--scheduler``).

A small simulated archive is written (``livetrack.batch.synthetic``; or ``--archive DIR/*`` gives recordings), run
once in this process (the serial reference, its CPU time per frame) and then on a local cluster of each size in
``--workers``: the cluster's start-up, a first run (the workers import livetrack and load the compiled kernels),
a warm run (frames per second), the CPU time the workers spent per frame and whether the JSON equals the serial
one. Then ``--empty-tasks`` tasks that do nothing give the scheduling overhead per task. Wall-clock figures depend
on what else the machine runs: the CPU times are the steadier figures.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from livetrack.config.checks import ConfigError

NAME = "bench-batch"
HELP = "batch detection: frames per second vs Dask workers (1, 2, 4), overhead per task"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--workers", default="1,2,4", metavar="N,N,...",
                        help="local cluster sizes to time (default 1,2,4)")
    parser.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786",
                        help="time an existing cluster instead (its workers must see the archive's paths)")
    parser.add_argument("--archive", nargs="*", type=Path, default=None, metavar="RECORDING",
                        help="recordings to run (default: a simulated archive written to a temporary folder)")
    parser.add_argument("--recordings", type=int, default=4, help="simulated recordings (default 4)")
    parser.add_argument("--frames", type=int, default=60, help="frames per simulated recording (default 60)")
    parser.add_argument("--size", default="960x600", metavar="WxH", help="simulated image size (default 960x600)")
    parser.add_argument("--range-frames", type=int, default=20, help="frames per task (default 20)")
    parser.add_argument("--empty-tasks", type=int, default=200, help="tasks for the overhead figure (default 200)")
    parser.add_argument("--json", type=Path, default=None, help="write the figures here")


def run(args: argparse.Namespace) -> int:
    try:
        sizes = [int(v) for v in args.workers.split(",") if v.strip()]
        width, height = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        raise ConfigError("--workers/--size", "expected N,N,... and WxH") from None
    if any(n < 1 for n in sizes) or width < 64 or height < 64:
        raise ConfigError("--workers/--size", "workers >= 1, image at least 64x64")
    with tempfile.TemporaryDirectory(prefix="livetrack-bench-batch-") as tmp:
        if args.archive:
            paths = list(args.archive)
        else:
            t0 = time.perf_counter()
            from livetrack.batch.synthetic import write_archive

            paths = write_archive(tmp, args.recordings, args.frames, width_px=width, height_px=height)
            print(f"archive: {len(paths)} simulated recordings x {args.frames} frames, {width}x{height}, written in "
                  f"{time.perf_counter() - t0:.1f} s")
        figures = bench(paths, sizes, args.scheduler, args.range_frames, args.empty_tasks)
    print(format_figures(figures))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=1))
        print(f"figures: {args.json}")
    return 0 if all(r["same_as_serial"] for r in figures["runs"]) else 1


def cpu_seconds() -> float:
    """Task: this process's CPU time (user + system) so far."""
    return time.process_time()


def empty_task() -> None:
    """Task: nothing (the overhead figure)."""
    return None


def bench(paths: list[Path], sizes: list[int], scheduler: str | None, range_frames: int, empty_tasks: int) -> dict:
    from livetrack.batch.detect import DetectSettings, detect_recordings
    from livetrack.batch.executor import DaskExecutor, SerialExecutor, Task, code_fingerprint

    settings = DetectSettings(timings=False)
    code = code_fingerprint()
    serial = SerialExecutor()
    detect_recordings(paths[:1], DetectSettings(timings=False, max_frames=2), serial, range_frames)  # warm-up
    cpu0, t0 = time.process_time(), time.perf_counter()
    reference = [o.to_dict() for o in detect_recordings(paths, settings, serial, range_frames)]
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    frames = sum(len(o["frames"]) for o in reference)
    ok = all(o["complete"] for o in reference)
    figures: dict = {"frames": frames, "recordings": len(paths), "range_frames": range_frames,
                     "tasks": sum(-(-o["frame_count"] // range_frames) for o in reference),
                     "serial": {"wall_s": wall, "cpu_s": cpu, "frames_per_s": frames / wall,
                                "cpu_ms_per_frame": 1e3 * cpu / max(frames, 1), "complete": ok},
                     "runs": []}
    print(f"serial (this process): {frames} frames in {wall:.1f} s, CPU {1e3 * cpu / max(frames, 1):.1f} ms/frame")
    t_empty = time.perf_counter()
    serial.run([Task(empty_task, (), "empty")] * empty_tasks)
    figures["serial"]["empty_task_ms"] = 1e3 * (time.perf_counter() - t_empty) / max(empty_tasks, 1)
    for n in ([None] if scheduler else sizes):
        t0 = time.perf_counter()
        executor = DaskExecutor(workers=n, scheduler=scheduler)
        try:
            startup = time.perf_counter() - t0
            t1 = time.perf_counter()
            first = [o.to_dict() for o in detect_recordings(paths, settings, executor, range_frames)]
            first_wall = time.perf_counter() - t1
            cpu_before = executor.client.run(cpu_seconds)
            t2 = time.perf_counter()
            warm = [o.to_dict() for o in detect_recordings(paths, settings, executor, range_frames)]
            warm_wall = time.perf_counter() - t2
            cpu_after = executor.client.run(cpu_seconds)
            worker_cpu = sum(cpu_after[w] - cpu_before.get(w, cpu_after[w]) for w in cpu_after)
            t3 = time.perf_counter()
            executor.run([Task(empty_task, (), f"empty {k}") for k in range(empty_tasks)])
            empty_ms = 1e3 * (time.perf_counter() - t3) / max(empty_tasks, 1)
            row = {"workers": executor.workers, "startup_s": startup, "first_run_s": first_wall,
                   "warm_run_s": warm_wall, "frames_per_s": frames / warm_wall,
                   "worker_cpu_ms_per_frame": 1e3 * worker_cpu / max(frames, 1), "empty_task_ms": empty_ms,
                   "same_as_serial": first == reference and warm == reference,
                   "same_code": executor.check_code() and code_fingerprint() == code}
        finally:
            executor.close()
        figures["runs"].append(row)
        print(f"{row['workers']} workers: {row['frames_per_s']:.1f} frames/s (warm), start-up {startup:.1f} s, "
              f"first run {first_wall:.1f} s, empty task {empty_ms:.2f} ms", flush=True)
    one = next((r for r in figures["runs"] if r["workers"] == 1), None)
    for r in figures["runs"]:
        r["speed_up_vs_1"] = r["frames_per_s"] / one["frames_per_s"] if one else None
    return figures


def format_figures(figures: dict) -> str:
    s = figures["serial"]
    head = (f"{'workers':>8s} {'start-up s':>10s} {'1st run s':>9s} {'warm run s':>10s} {'frames/s':>9s} "
            f"{'speed-up':>8s} {'CPU ms/frame':>12s} {'empty task ms':>13s} {'= serial':>8s}")
    lines = [f"{figures['frames']} frames in {figures['recordings']} recordings, {figures['tasks']} tasks of "
             f"{figures['range_frames']} frames", head, "-" * len(head),
             f"{'serial':>8s} {'-':>10s} {'-':>9s} {s['wall_s']:10.2f} {s['frames_per_s']:9.1f} {'-':>8s} "
             f"{s['cpu_ms_per_frame']:12.1f} {s['empty_task_ms']:13.3f} {'ref':>8s}"]
    for r in figures["runs"]:
        up = "-" if r["speed_up_vs_1"] is None else f"x{r['speed_up_vs_1']:.2f}"
        lines.append(f"{r['workers']:8d} {r['startup_s']:10.1f} {r['first_run_s']:9.1f} {r['warm_run_s']:10.2f} "
                     f"{r['frames_per_s']:9.1f} {up:>8s} {r['worker_cpu_ms_per_frame']:12.1f} "
                     f"{r['empty_task_ms']:13.2f} {'yes' if r['same_as_serial'] else 'NO':>8s}"
                     + ("" if r["same_code"] else "  (livetrack's sources changed during the run)"))
    return "\n".join(lines)
