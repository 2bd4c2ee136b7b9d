"""``livetrack sim``: render a simulation scenario into a recording (PNG frames + truth poses)."""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from livetrack.config.checks import ConfigError
from livetrack.recording import RecordingWriter
from livetrack.sim.scenario import Scenario, load_scenario

NAME = "sim"
HELP = "render a simulation scenario (default: the built-in demo) into a recording with truth poses"

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", type=Path, default=None, metavar="FILE",
                        help="scenario YAML (e.g. config/scenarios/paper-lab.yaml); default: the built-in "
                             "small demo")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="recording directory to write")
    parser.add_argument("--max-frames", type=int, default=None, metavar="N",
                        help="write at most the first N frames (default: all)")
    parser.add_argument("--seed", type=int, default=None, metavar="N",
                        help="override the scenario's seed (generated trajectory and noise)")
    parser.add_argument("--no-noise", action="store_true",
                        help="noise-free images (expected DN, rounded) instead of shot + read noise")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing recording at --out (only a directory holding "
                             "recording.yaml)")


def run(args: argparse.Namespace) -> int:
    if args.max_frames is not None and args.max_frames < 1:
        raise ConfigError("--max-frames", f"must be >= 1, got {args.max_frames}")
    if args.seed is not None and args.seed < 0:
        raise ConfigError("--seed", f"must be >= 0, got {args.seed}")
    scenario = load_scenario(args.scenario, seed=args.seed)
    count = len(scenario) if args.max_frames is None else min(len(scenario), args.max_frames)
    meta = {
        "source": "livetrack sim",
        "scenario": scenario.name,
        "scenario_file": str(args.scenario) if args.scenario is not None else "built-in default",
        "noise": not args.no_noise,
        "scenario_resolved": scenario.to_dict(),
    }
    try:
        writer = RecordingWriter(args.out, scenario.camera, scenario.targets, meta=meta,
                                 overwrite=args.overwrite)
    except FileExistsError as exc:
        raise ConfigError("--out", f"{exc}; --overwrite replaces a recording") from None
    start = time.perf_counter()
    exposures = []
    with writer:
        for frame in scenario.frames(max_frames=count, noise=not args.no_noise):
            writer.write_frame(frame.image, timestamp_ns=frame.timestamp_ns, exposure_us=frame.exposure_us,
                               gain_db=frame.gain_db, truth=frame.truth,
                               extra={"pose_index": frame.pose_index,
                                      "exposure_factor": frame.exposure_factor})
            exposures.append(frame.exposure_us)
            log.debug("frame %d: exposure %.1f us", frame.frame_index, frame.exposure_us)
    seconds = time.perf_counter() - start
    _report(scenario, args.out, writer.frame_count, exposures, seconds)
    return 0


def _report(scenario: Scenario, out: Path, frames: int, exposures: list[float], seconds: float) -> None:
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    cam = scenario.camera
    print(f"wrote {out}: {frames} frames of scenario '{scenario.name}' ({cam.width}x{cam.height}, "
          f"{cam.bit_depth} bit, {len(scenario.targets)} target(s)), {size / 1e6:.2f} MB on disk")
    if exposures:
        factors = ", ".join(f"{f:g}" for f in scenario.exposure_factors)
        print(f"exposure {min(exposures):.1f} .. {max(exposures):.1f} us (nominal "
              f"{scenario.nominal_exposure_us:.1f} us x {factors}), gain {scenario.gain_db:g} dB; "
              f"{seconds / max(frames, 1):.2f} s per frame")
