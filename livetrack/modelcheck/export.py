"""What a model check hands on to the estimator: the fitted PSF and the noise of saturated pixels, written as a
camera file (``livetrack model --camera-out FILE``, read by ``livetrack.camera.io.load_camera_with_optics``).

Exported: the Gaussian core ``psf_sigma_px`` of the chosen model, its ``halo`` (fraction, sigma) when the chosen
model has one, and ``response.read_noise_dn``, the spread of saturated pixels below the top code, measured on
the paper of deeply over-exposed frames (:func:`saturated_read_noise_dn`). Other chosen effects (blooming,
glare, vignetting, ...) are named in the file's header but not stored: the estimator does not model them.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from livetrack.camera import CameraModel
from livetrack.camera.io import write_camera_file
from livetrack.camera.optics import CameraOptics
from livetrack.modelcheck.analysis import ModelReport

DEEP_SATURATION = 2.0
"""A frame's paper counts as deeply saturated when the fitted (unclipped) paper level is at least this many
times the saturation code: its pixels then read the top code minus read noise only."""
MIN_SATURATED_PIXELS = 200
"""Fewer deeply saturated paper pixels than this: no noise measurement (the response section is left out)."""


def saturated_read_noise_dn(report: ModelReport) -> float | None:
    """sd (DN) of the reading of saturated pixels, or None without enough deeply saturated paper.

    A saturated pixel holds full well and reads ``min(top, round(top + N))`` with N the read noise: the deficit
    ``D = top - reading`` is the negative half of N, so ``E[D^2] = sd^2 / 2`` and ``sd = sqrt(2 mean(D^2))``
    (rounding adds ~1/24 DN^2). 0 when saturated pixels read exactly the top code (an ADC that clips below
    full well). Paper pixels: the outer ring of each disk's cell, as ``measure.levels`` takes them."""
    series, params = report.series, report.final.params
    dp = report.disk_pixels["extended"]
    pitch = report.check.layout.pitch_px
    top = series.saturation_dn
    radius = float(np.median(dp.radii_px))
    deficits = []
    for i in range(series.n_frames):
        if params["white_dn_per_ms"] * series.exposure_ms[i] < DEEP_SATURATION * top:
            continue
        for image, valid, d, o in zip(series.images[i], series.valid[i], dp.disk, dp.offset_px, strict=True):
            paper = valid & (d >= 0) & (o > 0.6 * (0.45 * pitch - radius))
            deficits.append(top - image[paper])
    if not deficits:
        return None
    deficit = np.concatenate(deficits)
    if deficit.size < MIN_SATURATED_PIXELS:
        return None
    return float(math.sqrt(2.0 * np.mean(np.maximum(deficit, 0.0) ** 2)))


def fitted_optics(report: ModelReport) -> CameraOptics:
    """The chosen model's PSF core and halo, and the saturated-pixel noise."""
    params = report.final.params
    halo = "halo" in report.final.effects
    return CameraOptics(psf_sigma_px=float(params["sigma_px"]),
                        halo_fraction=float(params["halo_fraction"]) if halo else 0.0,
                        halo_sigma_px=float(params["halo_sigma_px"]) if halo else None,
                        read_noise_dn=saturated_read_noise_dn(report))


def recording_camera(path: str | os.PathLike) -> CameraModel | None:
    """The camera (intrinsics) of a recording input; None for other inputs (the real folder has none)."""
    from livetrack.recording import Recording

    if not (Path(path) / "recording.yaml").is_file():
        return None
    return Recording.open(path).camera


def write_fitted_camera(report: ModelReport, file: str | os.PathLike, camera: CameraModel | None) -> dict[str, Any]:
    """Write the camera file (intrinsics of ``camera`` when given, the fitted optics) and return what was written
    (for the JSON report): ``{"file", "optics", "not_exported"}``."""
    optics = fitted_optics(report)
    left_out = [e for e in report.final.effects if e != "halo"]
    lines = [f"livetrack model --camera-out: fitted on {report.series.name} "
             f"({len(report.series.exposure_ms)} exposures)",
             f"chosen model: {' + '.join(report.final.effects) or 'baseline (Gaussian PSF)'}"]
    if left_out:
        lines.append(f"not stored (the estimator does not model them): {', '.join(left_out)}")
    if camera is None:
        lines.append("no intrinsics in the input: add the camera section (width, height, fx, fy, cx, cy, ...)")
    if optics.read_noise_dn is None:
        lines.append("no deeply saturated frame: response.read_noise_dn not measured")
    write_camera_file(file, camera, optics, "\n".join(lines))
    return {"file": str(file), "optics": optics.to_sections(), "intrinsics": camera is not None,
            "not_exported": left_out}
