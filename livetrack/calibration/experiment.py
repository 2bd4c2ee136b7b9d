"""The exposure comparison of docs/calibration.md: a simulated camera with known intrinsics and distortion
calibrated at each exposure (x0.25 ... x16) from views of ring targets (the default: edges measured again clear of
the design's other edges, one exposure bias per exposure; the tracker's edges with one bias per target per view;
each with the bias held at 0) and, as OpenCV's baseline, from views of a rendered circle grid (``findCirclesGrid``
+ ``calibrateCamera``, views with outlying residuals left out). Each noise seed draws the noise again on the same
views; the summary gives per exposure and method the mean error over the draws, its standard error, one run's
scatter, the calibration's own 1-sigma and the RMS z-score. Prints one JSON line per calibration, then the
summary table; writes both to ``--json``.

    python -m livetrack.calibration.experiment --views 16 --noise-seeds 5 11 12 13 14 15 16 17 18 19 \\
        --noise-free --methods rings rings-delta0 grid --json out/calibration-exposures.json

Cost (near scene, 16 views): 6 / 7 / 19 / 34 s of CPU per default ring calibration at x0.25 / x1 / x4 / x16
(medians of 10 draws, 2026-12-02: clipped views take 2-4 passes and the blur's uncertainty); ~13 min for the 88
of the command above before those; the
grid's rays ~10 s, its optical images ~2 s per view, once. The far scene costs 12-50 s per ring calibration.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from livetrack.calibration.circle_grid import CircleGrid, calibrate_grid, expose, optical_image, pixel_rays
from livetrack.calibration.targets import TargetCalibrationOptions, calibrate_targets
from livetrack.camera import CameraModel
from livetrack.geometry import Pose, look_rotation
from livetrack.sim.scenario import Scenario

SCENARIO = {
    "name": "calibration", "seed": 5,
    "camera": {"width": 480, "height": 360, "fx": 420, "fy": 420, "cx": 243.2, "cy": 178.7,
               "dist": [-0.2, 0.08, 0, 0, 0], "bit_depth": 12},
    "sensor": {"full_well_e": 10000, "read_noise_e": 5, "black_level_dn": 0},
    "optics": {"psf_sigma_px": 0.8},
    "targets": [{"id": 3, "outer_radius_m": 0.08}, {"id": 5, "outer_radius_m": 0.08}],
    "trajectory": {"kind": "spread", "count": 16, "distance_m": [0.8, 1.5], "tilt_deg": [10, 50], "margin_px": 5},
    "exposure": {"factors": [0.25, 1, 4, 16]},
}
NEAR_SCENARIO = dict(SCENARIO, trajectory=dict(SCENARIO["trajectory"], distance_m=[0.45, 0.8], target_ids=[3]))
"""The experiment's default scene: one target per view, at 0.45-0.8 m (its radius 42-75 px): a 16-view
calibration's fx scatters by 0.07 / 0.035 / 0.016 / 0.05 % at x0.25 / x1 / x4 / x16 (sd over 10 noise draws),
against ~0.2-0.25 / 0.08 / 0.05 / 0.10 % with two targets at 0.8-1.5 m (``SCENARIO``, the tests' scene), for fewer
CPU seconds (a closer tilted circle shows more perspective: its near side larger than its far side, what tells the
focal length from the distance)."""
SCENES = {"near": NEAR_SCENARIO, "far": SCENARIO}
INITIAL = CameraModel(480, 360, 440.0, 440.0, 239.5, 179.5, bit_depth=12)  # f 5 % off, centred, no distortion
METHODS = {"rings (default: edges measured again, delta per exposure)": TargetCalibrationOptions(),
           "rings, the tracker's edges, delta per target": TargetCalibrationOptions(refine_edges=False),
           "rings, delta = 0 (edges measured again)": TargetCalibrationOptions(compensate=False),
           "rings, delta = 0, the tracker's edges": TargetCalibrationOptions(compensate=False, refine_edges=False)}
GRID = "OpenCV circle grid 7x5"
METHODS_ALL = [*METHODS, GRID]


def errors(camera: CameraModel, truth: CameraModel) -> dict[str, float]:
    """fx, fy, k1 in % of the truth; cx, cy in px; k2 absolute."""
    return {"fx_pct": 100 * (camera.fx / truth.fx - 1), "fy_pct": 100 * (camera.fy / truth.fy - 1),
            "cx_px": camera.cx - truth.cx, "cy_px": camera.cy - truth.cy,
            "k1_pct": 100 * (camera.dist[0] / truth.dist[0] - 1), "k2": camera.dist[1] - truth.dist[1]}


def _without_blur(extra: dict, truth: CameraModel) -> dict[str, float]:
    """The 1-sigma of fx and k1 (% of the truth) before the blur's uncertainty was added (none when no blur was
    estimated: the same as the reported one)."""
    u = extra.get("uncertainty_without_blur")
    if u is None:
        return {}
    return {"sd_fx_pct_no_blur": 100 * u["fx"] / truth.fx, "sd_k1_pct_no_blur": 100 * u["dist"][0] / abs(truth.dist[0])}


def grid_poses(camera: CameraModel, grid: CircleGrid, count: int, rng: np.random.Generator) -> list[Pose]:
    """Grid poses at 0.45-0.8 m, tilted 10-45 degrees, spread over the image with the whole sheet inside."""
    poses: list[Pose] = []
    half = np.array([(grid.cols - 1) / 2 * grid.spacing_m + grid.margin_m,
                     (grid.rows - 1) / 2 * grid.spacing_m + grid.margin_m])
    corners = np.array([[sx * half[0], sy * half[1], 0.0] for sx in (-1, 1) for sy in (-1, 1)])
    while len(poses) < count:
        ray = camera.unproject(np.array([rng.uniform(40, camera.width - 40), rng.uniform(40, camera.height - 40)]))
        pose = Pose(look_rotation(rng.uniform(10, 45), rng.uniform(0, 360), rng.uniform(-20, 20)),
                    ray / ray[2] * rng.uniform(0.45, 0.8))
        if np.all(camera.contains(camera.project(corners @ pose.R.T + pose.t), 5)):
            poses.append(pose)
    return poses


METHOD_KEYS = {"rings": "rings (default: edges measured again, delta per exposure)",
               "tracker": "rings, the tracker's edges, delta per target",
               "rings-delta0": "rings, delta = 0 (edges measured again)",
               "tracker-delta0": "rings, delta = 0, the tracker's edges",
               "grid": GRID}


def ring_images(scenario: Scenario, noise_seed: int | None) -> list:
    """The scenario's frames with the noise of ``noise_seed`` (None: noise-free), the poses of the scenario's own
    seed: the same views, another draw of the noise."""
    noisy = replace(scenario, seed=scenario.seed if noise_seed is None else noise_seed)
    out, cached = [], None
    for k in range(len(scenario)):
        step = scenario.pose_index(k)
        if cached is None or cached[0] != step:
            cached = (step, scenario.formation.optical_image(scenario.placements_for(k)))
        out.append(noisy.render_frame(k, noise=noise_seed is not None, optical=cached[1]))
    return out


def summarise(rows: list[dict]) -> list[dict]:
    """Per exposure and method, over the noisy runs (noise seed not None): the mean error of fx and k1, its
    standard error over the runs (sd / sqrt(n)), the mean of the adjustment's own 1-sigma and the RMS of the
    z-scores (error / that run's 1-sigma: about 1 when the 1-sigma is honest and the bias small); and the
    noise-free run's errors where there is one."""
    out = []
    keys = sorted({(r["exposure_factor"], r["method"]) for r in rows}, key=lambda k: (k[0], METHODS_ALL.index(k[1])))
    for factor, method in keys:
        mine = [r for r in rows if r["exposure_factor"] == factor and r["method"] == method and "fx_pct" in r]
        noisy = [r for r in mine if r["noise_seed"] is not None]
        clean = [r for r in mine if r["noise_seed"] is None]
        summary: dict = {"exposure_factor": factor, "method": method, "runs": len(noisy),
                         "failed": sum(1 for r in rows if r["exposure_factor"] == factor and r["method"] == method
                                       and "fx_pct" not in r and r["noise_seed"] is not None)}
        for name in ("fx_pct", "k1_pct", "cx_px", "cy_px"):
            v = np.array([r[name] for r in noisy])
            if len(v):
                summary[f"{name}_mean"] = float(v.mean())
                summary[f"{name}_se"] = float(v.std(ddof=1) / np.sqrt(len(v))) if len(v) > 1 else float("nan")
                summary[f"{name}_sd"] = float(v.std(ddof=1)) if len(v) > 1 else float("nan")
            sd_key = "sd_" + name
            if len(v) and all(sd_key in r for r in noisy):
                sd = np.array([r[sd_key] for r in noisy])
                summary[f"{sd_key}_mean"] = float(sd.mean())
                summary[f"{name}_z_rms"] = float(np.sqrt(np.mean((v / sd) ** 2)))
            if clean:
                summary[f"{name}_noise_free"] = clean[0][name]
        out.append(summary)
    return out


def format_summary(summary: list[dict]) -> str:
    """A markdown table of :func:`summarise`."""
    def cell(s: dict, name: str) -> str:
        if f"{name}_mean" not in s:
            return "-"
        text = f"{s[name + '_mean']:+.3f} +- {s[name + '_se']:.3f}"
        if f"sd_{name}_mean" in s:
            text += (f" (sd {s[name + '_sd']:.3f}, own 1-sigma {s['sd_' + name + '_mean']:.3f}, "
                     f"z RMS {s[name + '_z_rms']:.2f})")
        if f"{name}_noise_free" in s:
            text += f"; noise-free {s[name + '_noise_free']:+.3f}"
        return text
    lines = ["| exposure | method | runs | fx error % | k1 error % |", "| --- | --- | --- | --- | --- |"]
    for s in summary:
        runs = f"{s['runs']}" + (f" ({s['failed']} failed)" if s["failed"] else "")
        lines.append(f"| x{s['exposure_factor']:g} | {s['method']} | {runs} | {cell(s, 'fx_pct')} | "
                     f"{cell(s, 'k1_pct')} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=16)
    parser.add_argument("--json", type=Path, required=True)
    parser.add_argument("--noise-seeds", type=int, nargs="*", default=[SCENARIO["seed"]],
                        help="one run per noise seed, the same views (default: the scenario's seed, 5)")
    parser.add_argument("--noise-free", action="store_true", help="also a run without noise")
    parser.add_argument("--methods", nargs="+", choices=list(METHOD_KEYS), default=list(METHOD_KEYS))
    parser.add_argument("--exposures", type=float, nargs="+", default=None,
                        help="exposure factors to run (default: all of the scenario's)")
    parser.add_argument("--scene", choices=list(SCENES), default="near",
                        help="near (default): one target per view at 0.45-0.8 m; far: two at 0.8-1.5 m (the tests')")
    parser.add_argument("--no-grid", action="store_true", help="leave out the circle-grid baseline")
    args = parser.parse_args(argv)
    base = SCENES[args.scene]
    data = dict(base, trajectory=dict(base["trajectory"], count=args.views))
    scenario = Scenario.from_dict(data)
    truth = scenario.camera
    factors = [f for f in scenario.exposure_factors if args.exposures is None or f in args.exposures]
    methods = [METHOD_KEYS[k] for k in args.methods if not (k == "grid" and args.no_grid)]
    seeds: list[int | None] = list(args.noise_seeds) + ([None] if args.noise_free else [])
    rows: list[dict] = []
    grid_optical = None
    for seed in seeds:
        frames = ring_images(scenario, seed) if any(m != GRID for m in methods) else []
        for factor in factors:
            chosen = [f for f in frames if f.exposure_factor == factor]
            for name in methods:
                if name == GRID:
                    continue
                t0, c0 = time.perf_counter(), time.process_time()
                result = calibrate_targets([f.image for f in chosen], list(scenario.targets), INITIAL,
                                           [f.exposure_us for f in chosen], options=METHODS[name])
                u = result.uncertainty
                rows.append({"noise_seed": seed, "exposure_factor": factor, "method": name,
                             "views": len(result.view_names), "rms_px": result.rms_px, **errors(result.camera, truth),
                             "sd_fx_pct": 100 * u.fx / truth.fx, "sd_cx_px": u.cx, "sd_cy_px": u.cy,
                             "sd_k1_pct": 100 * u.dist[0] / abs(truth.dist[0]),
                             "blur_px": result.extra.get("blur_px"), "blur_std_px": result.extra.get("blur_std_px"),
                             **_without_blur(result.extra, truth),
                             "delta_px_median": float(np.median(list(result.extra["delta_px"].values()))),
                             "edge_points": result.extra.get("edge_points"),
                             "seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0})
                print(json.dumps(rows[-1]), flush=True)
        if GRID in methods:
            grid = CircleGrid()
            if grid_optical is None:  # the grid's poses: one draw for every seed
                rays = pixel_rays(truth, 4)
                grid_optical = [optical_image(truth, grid, p, rays)
                                for p in grid_poses(truth, grid, args.views, np.random.default_rng(1))]
            rng = np.random.default_rng(np.random.SeedSequence([0 if seed is None else seed, 3]))
            for factor in factors:
                images = [expose(o, factor, rng, noise=seed is not None)
                          for o in grid_optical]
                fit = calibrate_grid(images, grid, (truth.width, truth.height), truth.bit_depth)
                row = {"noise_seed": seed, "exposure_factor": factor, "method": GRID,
                       "views": 0 if fit is None else len(fit.view_names),
                       "rejected": 0 if fit is None else len(fit.rejected)}
                if fit is not None:
                    u = fit.uncertainty
                    row.update({"rms_px": fit.rms_px, **errors(fit.camera, truth), "sd_fx_pct": 100 * u.fx / truth.fx,
                                "sd_cx_px": u.cx, "sd_cy_px": u.cy, "sd_k1_pct": 100 * u.dist[0] / abs(truth.dist[0])})
                rows.append(row)
                print(json.dumps(row), flush=True)
    summary = summarise(rows)
    print(format_summary(summary), flush=True)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"runs": rows, "summary": summary}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
