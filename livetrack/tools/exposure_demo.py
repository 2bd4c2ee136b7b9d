"""Auto-exposure on the simulated camera with a light level that changes 100x over 10 s (issue 14 item 3).

``python -m livetrack.tools.exposure_demo --out docs/figures/exposure-control.png [--fps 30] [--json OUT]``

The built-in scenario's moving target, rendered at the exposure the controller asks for times the light level
(0.1 -> 10, log-linear), each request taking effect ``--latency-frames`` frames later (a camera applies a new
exposure a frame or two after it is written); the live tracker settings; prints and plots the exposure, the
target's white and black (fractions of full scale), the pose's validity and its distance error against the truth.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np


def run(fps: float, seconds: float, latency_frames: int, seed: int = 0) -> dict:
    from livetrack.config.app import load_config
    from livetrack.estimator.tracker import Tracker
    from livetrack.exposure_control import ExposureController
    from livetrack.sim.scenario import Scenario

    s = Scenario.default()
    optical = [s.formation.optical_image(s.placements_for(k)) for k in range(len(s))]
    tracker = Tracker(s.camera, s.targets, load_config().tracker)
    full_scale = 2**s.camera.bit_depth - 1
    controller = ExposureController(full_scale)
    n = int(round(fps * seconds))
    exposure_us = s.nominal_exposure_us
    pending: list[tuple[int, float]] = []  # (frame from which it applies, exposure)
    rows = []
    t0 = time.perf_counter()
    for i in range(n):
        while pending and pending[0][0] <= i:
            exposure_us = pending.pop(0)[1]
        light = 10 ** (-1 + 2 * i / max(n - 1, 1))
        k = i % len(s)
        image = s.formation.render_from_optical(optical[k], exposure_us * light, s.gain_db,
                                                np.random.default_rng([seed, i]), True)
        result = tracker.process(image, exposure_us)
        target = result.targets[0] if result.targets else None
        ok = target is not None and bool(target.fit.ok)
        truth = s.truth_for(k)[s.targets[0].id]
        error_m = abs(target.fit.pose.distance_m - float(np.linalg.norm(truth.t))) if ok else math.nan
        new = controller.update(image, result, exposure_us)
        m = controller.last_metering
        rows.append({"t_s": i / fps, "light": light, "exposure_us": exposure_us, "ok": ok, "distance_error_m": error_m,
                     "white": None if m is None or m.white_dn is None else m.white_dn / full_scale,
                     "black": None if m is None or m.black_dn is None else m.black_dn / full_scale,
                     "delta_px": float(target.fit.delta_px) if ok else None})
        if new is not None:
            pending.append((i + latency_frames, new))
    errors = np.array([r["distance_error_m"] for r in rows])
    whites = np.array([r["white"] if r["white"] is not None else math.nan for r in rows])
    return {"fps": fps, "seconds": seconds, "latency_frames": latency_frames, "frames": n,
            "ok_frames": sum(r["ok"] for r in rows), "steps": controller.steps,
            "distance_error_m_max": float(np.nanmax(errors)), "distance_error_m_median": float(np.nanmedian(errors)),
            "white_min_after_1s": float(np.nanmin(whites[int(fps):])),
            "white_max_after_1s": float(np.nanmax(whites[int(fps):])),
            "cpu_s": time.perf_counter() - t0, "rows": rows}


def plot(report: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = report["rows"]
    t = [r["t_s"] for r in rows]
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    axes[0].semilogy(t, [r["light"] for r in rows], label="light level (x)")
    axes[0].semilogy(t, [r["exposure_us"] / rows[0]["exposure_us"] for r in rows], label="exposure (x initial)")
    axes[0].legend()
    axes[1].plot(t, [r["white"] for r in rows], label="target white")
    axes[1].plot(t, [r["black"] for r in rows], label="target black")
    axes[1].axhline(1.0, color="k", lw=0.5)
    axes[1].set_ylabel("fraction of full scale")
    axes[1].legend()
    axes[2].plot(t, [r["distance_error_m"] * 1000 for r in rows], ".", label="|distance error| (mm)")
    axes[2].set_ylabel("mm")
    axes[2].set_xlabel("time (s)")
    axes[2].legend()
    fig.suptitle(f"auto-exposure, light 100x over {report['seconds']:g} s at {report['fps']:g} fps: "
                 f"{report['ok_frames']}/{report['frames']} poses valid")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="the plot (PNG)")
    parser.add_argument("--json", type=Path, help="the per-frame figures")
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--latency-frames", type=int, default=2)
    args = parser.parse_args(argv)
    report = run(args.fps, args.seconds, args.latency_frames)
    plot(report, args.out)
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    print(json.dumps({k: v for k, v in report.items() if k != "rows"}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
