"""``livetrack bench-sim``: time the simulator on the paper-lab set-up (budget: 0.5 s per frame in all)."""

from __future__ import annotations

import argparse
import logging
import time

import numpy as np

from livetrack.camera import CameraModel
from livetrack.geometry import Pose, look_rotation
from livetrack.sim.coverage import DEFAULT_SUPERSAMPLING, Placement, corner_map, render_reflectance
from livetrack.sim.texture import TargetTexture
from livetrack.targets.spec import TargetSpec

NAME = "bench-sim"
HELP = "time the simulator's rendering on the paper-lab set-up (1920x1200, 2-level target, 1.5..6 m)"

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=10, help="frames to time (default 10)")
    parser.add_argument("--supersampling", type=int, default=DEFAULT_SUPERSAMPLING,
                        help=f"sub-cells per mixed pixel, a perfect square (default {DEFAULT_SUPERSAMPLING})")
    parser.add_argument("--no-full", action="store_true", help="time only the coverage step")


def paper_lab_camera() -> CameraModel:
    """The paper-lab camera: 1920x1200, f = 1800 px, k1 = -0.1, 12 bits."""
    return CameraModel(1920, 1200, 1800.0, 1800.0, 959.5, 599.5, dist=(-0.1, 0.0, 0.0, 0.0, 0.0),
                       bit_depth=12)


def paper_lab_placements(frames: int) -> list[Placement]:
    """One placement per frame: the 0.125 m two-level target from 1.5 m (the slowest case) to 6 m, tilted up
    to 40 degrees about varying axes, off-centre."""
    texture = TargetTexture(TargetSpec.default(1, 0.125, levels=2))
    rng = np.random.default_rng(0)
    out = []
    for k, z in enumerate(np.linspace(1.5, 6.0, max(frames, 1))[:frames]):
        tilt = 40.0 * (k % 3) / 2.0
        xy = rng.uniform(-0.15, 0.15, 2) * z / 1.5
        pose = Pose(look_rotation(tilt, 37.0 * k, 11.0 * k), np.array([xy[0], xy[1], z]))
        out.append(Placement(pose, texture))
    return out


def _stats(seconds: list[float]) -> str:
    return (f"median {np.median(seconds):.3f} s, max {np.max(seconds):.3f} s per frame "
            f"over {len(seconds)} frames")


def run(args: argparse.Namespace) -> int:
    if args.frames < 1:
        print("bench-sim: --frames must be >= 1")
        return 2
    camera = paper_lab_camera()
    placements = paper_lab_placements(args.frames)
    t0 = time.perf_counter()
    corner_map(camera)
    print(f"corner map (once per camera): {time.perf_counter() - t0:.3f} s")
    seconds = []
    for placement in placements:
        t0 = time.perf_counter()
        render_reflectance(camera, [placement], supersampling=args.supersampling)
        seconds.append(time.perf_counter() - t0)
        log.debug("z = %.2f m: %.4f s", placement.pose.t[2], seconds[-1])
    print(f"render_reflectance (supersampling {args.supersampling}): {_stats(seconds)}")
    if args.no_full:
        return 0
    try:
        from livetrack.sim.formation import ImageFormation

        formation = ImageFormation(camera=camera, supersampling=args.supersampling)
        white = placements[0].texture.white  # type: ignore[attr-defined]
        exposure_us = formation.nominal_exposure_us(white, 0.7)
    except Exception as exc:  # the image-formation stage is optional for this benchmark
        print(f"full render: not timed, livetrack.sim.formation.ImageFormation is not usable here ({exc})")
        return 0
    rng = np.random.default_rng(0)
    seconds = []
    for placement in placements:
        t0 = time.perf_counter()
        formation.render([placement], exposure_us, rng=rng)
        seconds.append(time.perf_counter() - t0)
    print(f"full render (coverage + optics + sensor): {_stats(seconds)}")
    return 0
