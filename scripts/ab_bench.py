"""Compare the speed of two source trees of livetrack on a noisy machine: alternating passes in two persistent
processes.

    .venv/bin/python scripts/ab_bench.py {nominal,x4,full} ROUNDS TREE_A TREE_B

Each tree (a checkout, e.g. ``git worktree add /tmp/base <rev>``) runs in a process of its own (``PYTHONPATH`` set
to it, pinned to core 0, OpenCV on one thread), which renders paper-lab's frames once, warms its tracker up, and then
waits; the parent asks the two for one pass over the frames at a time, alternating (A B, B A, A B, ...), and compares
each round's medians. ``nominal`` and ``x4``: a moving target tracked (``livetrack bench``'s sequences; tracked frames
only); ``full``: every frame a search (bench's full frame). Printed: each tree's median CPU ms per frame, the median
and quartiles of the per-round ratio B / A, and each tree's ``timings_ms`` medians.

Why: on a shared 2-core machine the same code timed 1.3-1.5x apart from one run to the next (and a second process
run right after a first came out slower more often than not), so a 5-10 % change cannot be told from sequential
runs of ``livetrack bench``; alternating passes share the machine's slow and fast minutes. Developer tooling: not
installed with the package, not run by the tests.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

MODES = ("nominal", "x4", "full")


def child(mode: str) -> None:
    """One tree's side: frames and a warm tracker, then one pass per line read on stdin, its timings on stdout."""
    import time

    import cv2
    import numpy as np

    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {0})
    cv2.setNumThreads(1)
    from livetrack.commands.bench import _moving_sequences
    from livetrack.estimator import warm
    from livetrack.estimator.tracker import Tracker, TrackerOptions
    from livetrack.sim.scenario import Scenario

    warm.warm_up()
    scenario = Scenario.from_file(Path("config/scenarios/paper-lab.yaml"))
    steps = np.linspace(0, len(scenario.steps) - 1, 10).round().astype(int)
    if mode == "full":
        n_exp, nominal = len(scenario.exposure_factors), scenario.exposure_factors.index(1.0)
        frames = [(scenario.render_frame(int(s) * n_exp + nominal).image, None) for s in steps]
        tracker = Tracker(scenario.camera, list(scenario.targets))
    else:
        frames = _moving_sequences(scenario, steps[::3][:3], 8)[mode]
        tracker = Tracker(scenario.camera, list(scenario.targets), TrackerOptions(tracking=True))
    for image, exposure in frames:
        tracker.process(image, exposure)
    print("ready", flush=True)
    for _ in sys.stdin:
        out: dict[str, list[float]] = {"cpu_ms": []}
        for image, exposure in frames:
            t0 = time.thread_time_ns()
            result = tracker.process(image, exposure)
            cpu_ms = (time.thread_time_ns() - t0) / 1e6
            if mode == "full" or result.timings_ms.get("detect_ms", 0.0) == 0.0:
                out["cpu_ms"].append(cpu_ms)
                for key, value in result.timings_ms.items():
                    out.setdefault(key, []).append(value)
        print(json.dumps(out), flush=True)


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == "--child":
        child(argv[1])
        return 0
    if len(argv) != 4 or argv[0] not in MODES or not argv[1].isdigit():
        print(__doc__, file=sys.stderr)
        return 2
    mode, rounds, trees = argv[0], int(argv[1]), [str(Path(t).resolve()) for t in argv[2:]]
    procs = [subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--child", mode], cwd=tree,
                              env=dict(os.environ, PYTHONPATH=tree), stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True) for tree in trees]
    for p in procs:
        while (line := p.stdout.readline()) and line.strip() != "ready":
            pass
        if not line:
            print("a tree's process ended before it was ready", file=sys.stderr)
            return 1
    medians: list[dict[str, list[float]]] = [{}, {}]
    for r in range(rounds):
        for i in ((0, 1) if r % 2 == 0 else (1, 0)):
            procs[i].stdin.write("go\n")
            procs[i].stdin.flush()
            for key, values in json.loads(procs[i].stdout.readline()).items():
                medians[i].setdefault(key, []).append(statistics.median(values))
    for p in procs:
        p.stdin.close()
        p.wait()
    for tree, m in zip(trees, medians, strict=True):
        print(f"{tree}: {statistics.median(m['cpu_ms']):.3f} ms per frame (median of {rounds} passes' medians)")
    ratios = [b / a for a, b in zip(medians[0]["cpu_ms"], medians[1]["cpu_ms"], strict=True)]
    q1, q2, q3 = statistics.quantiles(ratios, n=4) if len(ratios) >= 2 else (ratios[0],) * 3
    print(f"B / A per round: median {statistics.median(ratios):.3f} (quartiles {q1:.3f}, {q3:.3f})")
    for key in sorted(set(medians[0]) & set(medians[1]) - {"cpu_ms"}):
        print(f"  {key}: {statistics.median(medians[0][key]):.3f} / {statistics.median(medians[1][key]):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
