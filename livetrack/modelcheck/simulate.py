"""Simulated exposure series of a disk grid with (at most) one hidden catalogue effect, written as a recording.

Used by the hidden-effect tests and as a demo INPUT for ``livetrack model``. The recording's ``meta`` holds
only what a user would know of a printed pattern (``pattern: disk_grid``, the pitch, the paper and ink
reflectances); the effect and its size are returned to the caller, never written.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from livetrack.camera import CameraModel
from livetrack.geometry import Pose, look_rotation
from livetrack.modelcheck.texture import DiskGridTexture
from livetrack.recording import RecordingWriter
from livetrack.sim.coverage import Placement
from livetrack.sim.effects import EFFECTS, Effects
from livetrack.sim.formation import ImageFormation, Radiometry
from livetrack.sim.optics import OpticsModel
from livetrack.sim.sensor import SensorModel

HIDDEN_EFFECTS = ("halo", "blooming", "nonlinear", "veiling_glare", "vignetting", "defocus", "lens_distortion")
"""Effects the hidden-effect tests draw from by default (plus ``None``; kept so that a seed draws what it drew)."""
NEW_HIDDEN_EFFECTS = ("anisotropic_core", "exponential_tail", "lorentzian_tail", "ink_floor")
"""The effects added for the real disks' findings (``draw_hidden_effect(seed, NEW_HIDDEN_EFFECTS)``)."""
CATALOGUE_EFFECTS = HIDDEN_EFFECTS + NEW_HIDDEN_EFFECTS
"""Every effect ``draw_hidden_effect`` can size (the full catalogue, e.g. for ring recordings)."""

WHITE_FRACTIONS_OF_FULL_WELL = (0.3, 0.6, 1.2, 2.4, 4.8, 9.6)
"""Default exposure series: white paper at these multiples of full well (under- to 10x over-exposed)."""


@dataclass(frozen=True)
class HiddenEffect:
    """The effect switched on in a simulated series (``name`` None: none) and its main parameter."""

    name: str | None
    parameter: str | None
    value: float | None
    params: dict[str, Any]


_ONE_PARAMETER_RANGES = {
    "blooming": ("spill_fraction", 0.3, 1.0),
    "nonlinear": ("knee_fraction_of_full_well", 0.5, 0.8),
    "veiling_glare": ("fraction", 0.02, 0.08),
    "vignetting": ("strength", 0.15, 0.45),
    "defocus": ("radius_px", 1.5, 3.0),
}
"""Effect -> (its one parameter, the range its size is drawn from) for the hidden-effect tests."""


def draw_hidden_effect(seed: int, names: tuple[str | None, ...] = (None, *HIDDEN_EFFECTS)) -> HiddenEffect:
    """Choose an effect (or none) and its size from ``seed``; sizes are in the range the analysis should see."""
    rng = np.random.default_rng(seed)
    name = names[int(rng.integers(len(names)))]
    if name is None:
        return HiddenEffect(None, None, None, {})
    if name == "halo":
        p = {"fraction": float(rng.uniform(0.03, 0.10)), "sigma_px": float(rng.uniform(4.0, 8.0))}
        return HiddenEffect(name, "fraction", p["fraction"], p)
    if name == "lens_distortion":
        k1 = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.15, 0.4))
        return HiddenEffect(name, "k1", k1, {"dist": [k1, 0.0, 0.0, 0.0, 0.0]})
    if name == "anisotropic_core":  # the main parameter: the axis ratio sigma_x / sigma_y
        p = {"sigma_x_px": float(rng.uniform(1.0, 1.3)), "sigma_y_px": float(rng.uniform(0.6, 0.8)),
             "angle_deg": float(rng.uniform(-90.0, 90.0))}
        return HiddenEffect(name, "axis_ratio", p["sigma_x_px"] / p["sigma_y_px"], p)
    if name == "exponential_tail":
        p = {"fraction": float(rng.uniform(0.1, 0.3)), "scale_px": float(rng.uniform(0.7, 1.5))}
        return HiddenEffect(name, "fraction", p["fraction"], p)
    if name == "lorentzian_tail":
        p = {"fraction": float(rng.uniform(0.05, 0.15)), "scale_px": float(rng.uniform(0.4, 0.8))}
        return HiddenEffect(name, "fraction", p["fraction"], p)
    if name == "ink_floor":
        value = float(rng.uniform(0.07, 0.15))
        return HiddenEffect(name, "black_to_white", value, {"black_to_white": value})
    if name in _ONE_PARAMETER_RANGES:
        key, low, high = _ONE_PARAMETER_RANGES[name]
        value = float(rng.uniform(low, high))
        return HiddenEffect(name, key, value, {key: value})
    raise ValueError(f"unknown effect {name!r}")


def disk_grid_formation(hidden: HiddenEffect, width: int = 320, height: int = 240, focal_px: float = 800.0,
                        psf_sigma_px: float = 0.9, optics: OpticsModel | None = None,
                        sensor: SensorModel | None = None) -> ImageFormation:
    """The simulated camera with the hidden effect on: by default 12 bit, 10000 e full well, 5 e read noise and
    a Gaussian PSF of ``psf_sigma_px``; ``optics``/``sensor`` replace those models (e.g. a scenario's, see
    :func:`scenario_optics_and_sensor`; ``psf_sigma_px`` is then ignored). The camera's bit depth follows the
    sensor."""
    sensor = SensorModel(bit_depth=12) if sensor is None else sensor
    optics = OpticsModel(psf_sigma_px=psf_sigma_px) if optics is None else optics
    camera = CameraModel(width=width, height=height, fx=focal_px, fy=focal_px, cx=(width - 1) / 2,
                         cy=(height - 1) / 2, bit_depth=sensor.bit_depth)
    effects = Effects()
    if hidden.name is not None:
        effects = Effects.from_dict({hidden.name: hidden.params})
        assert hidden.name in EFFECTS
    return ImageFormation(camera=camera, radiometry=Radiometry(), optics=optics, sensor=sensor, effects=effects,
                          background_reflectance=0.2)


def scenario_optics_and_sensor(formation: ImageFormation) -> tuple[OpticsModel, SensorModel]:
    """The PSF and sensor a scenario renders with (its ``effects`` folded in: halo, defocus, blooming, knee), to
    simulate a disk-grid series of the same camera: ``write_disk_grid_series(..., optics=o, sensor=s)``."""
    return formation.optics_in_use, formation.sensor_in_use


def write_disk_grid_series(path: str | os.PathLike, hidden: HiddenEffect, seed: int, *, pitch_m: float = 0.008,
                           radius_m: float = 0.002, distance_m: float = 0.2, tilt_deg: float = 3.0,
                           white_fractions: tuple[float, ...] = WHITE_FRACTIONS_OF_FULL_WELL,
                           width: int = 320, height: int = 240, overwrite: bool = True,
                           optics: OpticsModel | None = None, sensor: SensorModel | None = None) -> None:
    """Render the exposure series of a disk grid (shot and read noise from ``seed``) into a recording;
    ``optics``/``sensor``: the camera's PSF and sensor (default: see :func:`disk_grid_formation`)."""
    rng = np.random.default_rng(seed + 1_000_003)
    formation = disk_grid_formation(hidden, width, height, optics=optics, sensor=sensor)
    texture = DiskGridTexture(pitch_m=pitch_m, radius_m=radius_m, half_size_m=0.1)
    shift = rng.uniform(-0.5, 0.5, 2) * pitch_m
    pose = Pose(look_rotation(tilt_deg, float(rng.uniform(0, 360))), np.array([shift[0], shift[1], distance_m]))
    optical = formation.optical_image([Placement(pose, texture)])
    meta = {"pattern": "disk_grid", "pitch_m": pitch_m, "white_reflectance": texture.white,
            "black_reflectance": texture.black, "source": "livetrack.modelcheck.simulate"}
    with RecordingWriter(path, formation.camera, [], meta=meta, overwrite=overwrite) as writer:
        for i, frac in enumerate(white_fractions):
            exposure_us = formation.nominal_exposure_us(texture.white, frac)
            image = formation.render_from_optical(optical, exposure_us, rng=rng)
            writer.write_frame(image, timestamp_ns=i * 100_000_000, exposure_us=math.floor(exposure_us * 10) / 10,
                               gain_db=0.0)


def main(argv: list[str] | None = None) -> int:
    """``python -m livetrack.modelcheck.simulate OUT [--scenario FILE] [--seed N]``: a disk-grid exposure series
    (recording) through a scenario's optics and sensor (default: the package's built-in ones, no effect), an
    INPUT for ``livetrack model``."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m livetrack.modelcheck.simulate", description=main.__doc__)
    parser.add_argument("out", help="recording folder to write (overwritten)")
    parser.add_argument("--scenario", default=None, help="scenario YAML whose optics, effects and sensor to use")
    parser.add_argument("--seed", type=int, default=0, help="noise and grid placement seed (default 0)")
    args = parser.parse_args(argv)
    optics = sensor = None
    if args.scenario is not None:
        from livetrack.sim.scenario import Scenario

        optics, sensor = scenario_optics_and_sensor(Scenario.from_file(args.scenario).formation)
    write_disk_grid_series(args.out, HiddenEffect(None, None, None, {}), args.seed, optics=optics, sensor=sensor)
    print(f"disk-grid series -> {args.out} (optics {optics or 'default'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
