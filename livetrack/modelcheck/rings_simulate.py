"""Simulated ring-target exposure series with (at most) one hidden catalogue effect, written as a recording: the
hidden-effect tests of the ring check and a demo INPUT for ``livetrack model``.

Rendered by the simulator from a scenario (``livetrack.sim.scenario``): one livetrack target at a few poses, each
at every exposure. The recording's ``meta`` holds only what a user knows of a printed target (paper and ink
reflectances); the effect and its size are returned to the caller, never written.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from livetrack.modelcheck.simulate import HiddenEffect
from livetrack.recording import RecordingWriter
from livetrack.sim.scenario import Scenario

RING_HIDDEN_EFFECTS = ("halo", "exponential_tail", "lorentzian_tail", "defocus", "anisotropic_core", "blooming",
                       "nonlinear", "ink_floor", "vignetting")
"""Effects the ring hidden-effect tests draw (plus None); lens distortion, motion blur and veiling glare are not
identified on ring recordings (``rings.NOT_IN_RING_CATALOGUE``, ``RingCheck.candidates``)."""

RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "halo": {"fraction": (0.03, 0.10), "sigma_px": (3.0, 7.0)},
    "blooming": {"spill_fraction": (1e-3, 3e-2)},  # drawn log-uniform: the real CCD's were 1e-4 to 8e-4
    "nonlinear": {"knee_fraction_of_full_well": (0.5, 0.8)},
    "exponential_tail": {"fraction": (0.1, 0.3), "scale_px": (0.7, 1.5)},
    "lorentzian_tail": {"fraction": (0.05, 0.15), "scale_px": (0.3, 0.8)},
    "ink_floor": {"black_to_white": (0.07, 0.15)},
    "vignetting": {"strength": (0.15, 0.45)},
    "defocus": {"radius_px": (1.5, 3.0)},
    "anisotropic_core": {"sigma_x_px": (0.95, 1.3), "sigma_y_px": (0.6, 0.8), "angle_deg": (-90.0, 90.0)},
}
"""Effect -> parameter -> range drawn from; the first parameter is the one checked."""

WHITE_FRACTIONS = (0.35, 0.85, 2.5, 8.0)
"""White paper at these multiples of full well (under-exposed to 8x over-exposed)."""


def draw_ring_effect(seed: int, names: tuple[str | None, ...] = (None, *RING_HIDDEN_EFFECTS)) -> HiddenEffect:
    """An effect (or none) and its size drawn from ``seed``."""
    rng = np.random.default_rng([seed, 77])
    name = names[int(rng.integers(len(names)))]
    if name is None:
        return HiddenEffect(None, None, None, {})
    params = {k: float(np.exp(rng.uniform(np.log(lo), np.log(hi))) if name == "blooming" else rng.uniform(lo, hi))
              for k, (lo, hi) in RANGES[name].items()}
    key = next(iter(RANGES[name]))
    return HiddenEffect(name, key, params[key], params)


def ring_scenario(hidden: HiddenEffect, seed: int, width: int = 640, height: int = 480, focal_px: float = 800.0,
                  poses: int = 2, white_fractions: tuple[float, ...] = WHITE_FRACTIONS,
                  psf_sigma_px: float = 0.8) -> Scenario:
    """The scenario: a 12-bit camera (10000 e, 5 e read noise), a Gaussian core of ``psf_sigma_px``, target 3
    (R = 0.1 m) at ``poses`` poses (1.6-2.2 m, tilted 10-35 deg; the first near the image centre, the others
    toward the corners), the hidden effect on."""
    rng = np.random.default_rng([seed, 78])
    steps = []
    corners = [(1, 1), (-1, -1), (1, -1), (-1, 1)]
    for k in range(poses):
        d = float(rng.uniform(1.6, 2.2))
        if k == 0:
            px = rng.uniform(-30, 30, 2)
        else:
            sx, sy = corners[(k - 1 + int(rng.integers(4))) % 4]
            px = np.array([sx * rng.uniform(0.22, 0.3) * width, sy * rng.uniform(0.2, 0.26) * height])
        t = [float(px[0] * d / focal_px), float(px[1] * d / focal_px), d]
        steps.append({"target_id": 3, "t_m": t, "tilt_deg": float(rng.uniform(10, 35)),
                      "tilt_axis_deg": float(rng.uniform(0, 360)), "roll_deg": float(rng.uniform(0, 360))})
    data: dict[str, Any] = {
        "name": f"ring-hidden-{seed}", "seed": seed,
        "camera": {"width": width, "height": height, "fx": focal_px, "fy": focal_px, "cx": (width - 1) / 2,
                   "cy": (height - 1) / 2, "bit_depth": 12},
        "sensor": {"full_well_e": 10000, "read_noise_e": 5},
        "optics": {"psf_sigma_px": psf_sigma_px},
        "effects": {hidden.name: hidden.params} if hidden.name else {},
        "targets": [{"id": 3, "outer_radius_m": 0.1}],
        "poses": steps,
        "exposure": {"nominal_us": "auto", "white_fraction_of_full_well": 1.0, "factors": list(white_fractions)},
        "timing": {"fps": 5},
    }
    return Scenario.from_dict(data)


def write_ring_series(path: str | os.PathLike, scenario: Scenario, overwrite: bool = True,
                      truth: bool = False) -> None:
    """Render every frame of ``scenario`` into a recording (``truth``: with truth.csv, for closed-loop checks)."""
    meta = {"white_reflectance": scenario.scene.white_reflectance,
            "black_reflectance": scenario.scene.black_reflectance, "source": "livetrack.modelcheck.rings_simulate"}
    with RecordingWriter(path, scenario.camera, scenario.targets, meta=meta, overwrite=overwrite) as writer:
        for frame in scenario.frames():
            writer.write_frame(frame.image, timestamp_ns=frame.timestamp_ns, exposure_us=frame.exposure_us,
                               gain_db=frame.gain_db, truth=frame.truth if truth else None)


def main(argv: list[str] | None = None) -> int:
    """``python -m livetrack.modelcheck.rings_simulate OUT [--seed N] [--poses N] [--truth]``: the seed's hidden
    effect (printed) rendered into a ring recording, an INPUT for ``livetrack model``."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m livetrack.modelcheck.rings_simulate", description=main.__doc__)
    parser.add_argument("out", help="recording folder to write (overwritten)")
    parser.add_argument("--seed", type=int, default=0, help="effect, size, poses and noise (default 0)")
    parser.add_argument("--poses", type=int, default=2, help="poses of the target (default 2)")
    parser.add_argument("--truth", action="store_true", help="write truth.csv too")
    args = parser.parse_args(argv)
    hidden = draw_ring_effect(args.seed)
    write_ring_series(args.out, ring_scenario(hidden, args.seed, poses=args.poses), truth=args.truth)
    print(f"ring series -> {args.out}; hidden effect: {hidden.name or 'none'} {hidden.params}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
