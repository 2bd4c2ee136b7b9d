"""File adapter of the ring check: a v1 recording of livetrack targets -> ``RingSeries`` (``livetrack.modelcheck
.rings``). The recording's ``meta`` may give the print (``white_reflectance``, ``black_reflectance``); nothing
else in it is read (a simulated recording's scenario stays unseen)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from livetrack.camera.encoding import as_linear
from livetrack.modelcheck.rings import RingSeries
from livetrack.recording import Recording


def is_ring_recording(path: str | os.PathLike) -> bool:
    """A recording (``recording.yaml``) that is not a disk-grid series (``meta.pattern: disk_grid``)."""
    if not (Path(path) / "recording.yaml").is_file():
        return False
    return Recording.open(path).meta.get("pattern") != "disk_grid"


def ring_series_from_recording(path: str | os.PathLike) -> RingSeries:
    """Read every frame of the recording. ValueError when it names no target or has fewer than three exposures."""
    rec = Recording.open(path)
    if not rec.targets:
        raise ValueError(f"{path}: the recording names no target (its recording.yaml needs the targets' specs)")
    exposures, images = [], []
    for frame, image in rec.iter_images():
        exposures.append(frame.exposure_us)
        images.append(image)
    if len(set(exposures)) < 3:
        raise ValueError(f"{path}: {len(set(exposures))} distinct exposure(s): the model check needs three or more "
                         f"(record one with livetrack record-sweep)")
    meta = rec.meta or {}

    def reflectance(key: str) -> float | None:
        value = meta.get(key)
        return float(value) if isinstance(value, int | float) and 0 < value <= 1 else None

    camera, images = as_linear(rec.camera, images)  # the model's pixel values are linear in the light
    return RingSeries(name=Path(path).name, camera=camera, targets=tuple(rec.targets),
                      exposure_us=np.asarray(exposures, dtype=np.float64), images=images,
                      white_reflectance=reflectance("white_reflectance"),
                      black_reflectance=reflectance("black_reflectance"))
