"""The exposure comparison of docs/calibration.md: a simulated camera with known intrinsics and distortion
calibrated at each exposure (x0.25 ... x16) from views of two ring targets (the default: edges measured again
clear of the design's other edges, one exposure bias per exposure; the tracker's edges with one bias per target
per view; each with the bias held at 0) and, as OpenCV's baseline, from views of a rendered circle grid
(``findCirclesGrid`` + ``calibrateCamera``). Prints one JSON line per calibration and writes them all to ``--json``.

    python -m livetrack.calibration.experiment --views 16 --json out/calibration-exposures.json

Cost on 2 busy cores: ~14 min for 16 views (each ring calibration 7-93 s of CPU, 13-190 s wall; the grid's rays
~10 s, its optical images ~2 s per view).
"""

from __future__ import annotations

import argparse
import json
import time
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
INITIAL = CameraModel(480, 360, 440.0, 440.0, 239.5, 179.5, bit_depth=12)  # f 5 % off, centred, no distortion
METHODS = {"rings (default: edges measured again, delta per exposure)": TargetCalibrationOptions(),
           "rings, the tracker's edges, delta per target": TargetCalibrationOptions(refine_edges=False),
           "rings, delta = 0 (edges measured again)": TargetCalibrationOptions(compensate=False),
           "rings, delta = 0, the tracker's edges": TargetCalibrationOptions(compensate=False, refine_edges=False)}


def errors(camera: CameraModel, truth: CameraModel) -> dict[str, float]:
    """fx, fy, k1 in % of the truth; cx, cy in px; k2 absolute."""
    return {"fx_pct": 100 * (camera.fx / truth.fx - 1), "fy_pct": 100 * (camera.fy / truth.fy - 1),
            "cx_px": camera.cx - truth.cx, "cy_px": camera.cy - truth.cy,
            "k1_pct": 100 * (camera.dist[0] / truth.dist[0] - 1), "k2": camera.dist[1] - truth.dist[1]}


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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=16)
    parser.add_argument("--json", type=Path, required=True)
    parser.add_argument("--no-grid", action="store_true", help="leave out the circle-grid baseline")
    args = parser.parse_args(argv)
    data = dict(SCENARIO, trajectory=dict(SCENARIO["trajectory"], count=args.views))
    scenario = Scenario.from_dict(data)
    truth = scenario.camera
    frames = list(scenario.frames())
    rows = []
    for factor in scenario.exposure_factors:
        chosen = [f for f in frames if f.exposure_factor == factor]
        for name, options in METHODS.items():
            t0, c0 = time.perf_counter(), time.process_time()
            result = calibrate_targets([f.image for f in chosen], list(scenario.targets), INITIAL,
                                       [f.exposure_us for f in chosen], options=options)
            u = result.uncertainty
            rows.append({"exposure_factor": factor, "method": name, "views": len(result.view_names),
                         "rms_px": result.rms_px, **errors(result.camera, truth), "sd_fx_pct": 100 * u.fx / truth.fx,
                         "sd_cx_px": u.cx, "sd_k1_pct": 100 * u.dist[0] / abs(truth.dist[0]),
                         "blur_px": result.extra.get("blur_px"),
                         "delta_px_median": float(np.median(list(result.extra["delta_px"].values()))),
                         "seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0})
            print(json.dumps(rows[-1]), flush=True)
    if not args.no_grid:
        grid, rng = CircleGrid(), np.random.default_rng(1)
        rays = pixel_rays(truth, 4)
        optical = [optical_image(truth, grid, p, rays) for p in grid_poses(truth, grid, args.views, rng)]
        for factor in scenario.exposure_factors:
            fit = calibrate_grid([expose(o, factor, rng) for o in optical], grid, (truth.width, truth.height),
                                 truth.bit_depth)
            row = {"exposure_factor": factor, "method": "OpenCV circle grid 7x5", "views": 0 if fit is None else fit[1]}
            if fit is not None:
                row.update({"rms_px": fit[2], **errors(fit[0], truth)})
            rows.append(row)
            print(json.dumps(row), flush=True)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
