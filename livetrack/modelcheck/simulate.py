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
"""Effects the hidden-effect tests draw from (plus ``None``)."""

WHITE_FRACTIONS_OF_FULL_WELL = (0.3, 0.6, 1.2, 2.4, 4.8, 9.6)
"""Default exposure series: white paper at these multiples of full well (under- to 10x over-exposed)."""


@dataclass(frozen=True)
class HiddenEffect:
    """The effect switched on in a simulated series (``name`` None: none) and its main parameter."""

    name: str | None
    parameter: str | None
    value: float | None
    params: dict[str, Any]


def draw_hidden_effect(seed: int, names: tuple[str | None, ...] = (None, *HIDDEN_EFFECTS)) -> HiddenEffect:
    """Choose an effect (or none) and its size from ``seed``; sizes are in the range the analysis should see."""
    rng = np.random.default_rng(seed)
    name = names[int(rng.integers(len(names)))]
    if name is None:
        return HiddenEffect(None, None, None, {})
    if name == "halo":
        p = {"fraction": float(rng.uniform(0.03, 0.10)), "sigma_px": float(rng.uniform(4.0, 8.0))}
        return HiddenEffect(name, "fraction", p["fraction"], p)
    if name == "blooming":
        p = {"spill_fraction": float(rng.uniform(0.3, 1.0))}
        return HiddenEffect(name, "spill_fraction", p["spill_fraction"], p)
    if name == "nonlinear":
        p = {"knee_fraction_of_full_well": float(rng.uniform(0.5, 0.8))}
        return HiddenEffect(name, "knee_fraction_of_full_well", p["knee_fraction_of_full_well"], p)
    if name == "veiling_glare":
        p = {"fraction": float(rng.uniform(0.02, 0.08))}
        return HiddenEffect(name, "fraction", p["fraction"], p)
    if name == "vignetting":
        p = {"strength": float(rng.uniform(0.15, 0.45))}
        return HiddenEffect(name, "strength", p["strength"], p)
    if name == "defocus":
        p = {"radius_px": float(rng.uniform(1.5, 3.0))}
        return HiddenEffect(name, "radius_px", p["radius_px"], p)
    if name == "lens_distortion":
        k1 = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.15, 0.4))
        return HiddenEffect(name, "k1", k1, {"dist": [k1, 0.0, 0.0, 0.0, 0.0]})
    raise ValueError(f"unknown effect {name!r}")


def disk_grid_formation(hidden: HiddenEffect, width: int = 320, height: int = 240, focal_px: float = 800.0,
                        psf_sigma_px: float = 0.9) -> ImageFormation:
    """The simulated camera (12 bit, 10000 e full well, 5 e read noise) with the hidden effect on."""
    camera = CameraModel(width=width, height=height, fx=focal_px, fy=focal_px, cx=(width - 1) / 2,
                         cy=(height - 1) / 2, bit_depth=12)
    effects = Effects()
    if hidden.name is not None:
        effects = Effects.from_dict({hidden.name: hidden.params})
        assert hidden.name in EFFECTS
    return ImageFormation(camera=camera, radiometry=Radiometry(), optics=OpticsModel(psf_sigma_px=psf_sigma_px),
                          sensor=SensorModel(bit_depth=12), effects=effects, background_reflectance=0.2)


def write_disk_grid_series(path: str | os.PathLike, hidden: HiddenEffect, seed: int, *, pitch_m: float = 0.008,
                           radius_m: float = 0.002, distance_m: float = 0.2, tilt_deg: float = 3.0,
                           white_fractions: tuple[float, ...] = WHITE_FRACTIONS_OF_FULL_WELL,
                           width: int = 320, height: int = 240, overwrite: bool = True) -> None:
    """Render the exposure series of a disk grid (shot and read noise from ``seed``) into a recording."""
    rng = np.random.default_rng(seed + 1_000_003)
    formation = disk_grid_formation(hidden, width, height)
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
