"""Target-aware auto-exposure (issue 14 item 3): a pure controller, one call per frame, no I/O.

``ExposureController.update(image, result, exposure_us) -> float | None`` returns the exposure to set (us) or None
(keep). It meters the tracked targets' own black and white from the image, on rings where the printed target is
plain black or plain white (inside the white inner disk, between its nested level and its edge; in the black
annulus inside and outside the code dots), and sets the exposure so that:

- the target's white sits at ``white_goal`` of full scale (below saturation: a clipped white cannot be measured,
  so a clipped target is stepped down by ``max_step``), and
- its black stays above ``black_min`` of full scale (above the noise) when the target's contrast allows both;
  when it does not, the white wins (no saturation).

Without a target it falls back to scene metering: the median of the image at ``scene_goal`` of full scale, and at
most ``scene_clipped_max`` of the pixels clipped.

Step law (no hunting): the wanted factor is computed in log space, nothing is done inside a dead band of
``deadband`` (ratio), a step is at most ``max_step`` (ratio) and only a fraction ``gain`` of the log error is
applied; after a step the controller waits until a frame shows the requested exposure in force (sources report the
exposure per frame) or ``settle_frames`` frames have passed, so that it never acts twice on the same evidence.
Limits: ``min_exposure_us`` .. ``max_exposure_us``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

# Radii (fractions of the inner ellipse, of the outer ellipse) where the default target design is plain white or
# plain black: the nested level fills 0.5 of the inner disk, the code dots sit between 0.6 and 0.8 of the outer.
WHITE_RINGS = (0.65, 0.8)  # of the inner ellipse
BLACK_RINGS = (0.5, 0.9)  # of the outer ellipse (the inner disk ends at 0.4)
SAMPLES_PER_RING = 90


@dataclass(frozen=True)
class ExposureControlOptions:
    """Tunables (see the module docstring). Fractions are of the sensor's full scale."""

    white_goal: float = 0.7  # target white at this fraction of full scale
    black_min: float = 0.03  # target black above this fraction (noise)
    clipped_fraction: float = 0.98  # a white sample at or above this is clipped
    scene_goal: float = 0.35  # no target: the image median here
    scene_clipped_max: float = 0.02  # no target: at most this fraction of the pixels clipped
    deadband: float = 1.15  # no change while the wanted ratio is within [1/deadband, deadband]
    max_step: float = 4.0  # at most this ratio per step
    gain: float = 0.8  # fraction of the log error corrected per step (< 1: no overshoot)
    settle_frames: int = 3  # after a step, wait for the exposure to be in force, at most this many frames
    min_exposure_us: float = 10.0
    max_exposure_us: float = 30_000.0


@dataclass(frozen=True)
class Metering:
    """What a frame showed: the target's white (90th percentile) and black (10th percentile) in DN, or the scene's
    median and clipped fraction when no target was tracked."""

    white_dn: float | None = None
    black_dn: float | None = None
    clipped: bool = False
    scene_median_dn: float | None = None
    scene_clipped: float | None = None


def _ring_values(image: npt.NDArray, ellipse, scale: float) -> npt.NDArray[np.float64]:
    angles = np.linspace(0.0, 2.0 * np.pi, SAMPLES_PER_RING, endpoint=False)
    centre = np.asarray(ellipse.centre_px, dtype=np.float64)
    points = centre + scale * (np.asarray(ellipse.points(angles), dtype=np.float64) - centre)
    x = np.rint(points[:, 0]).astype(int)
    y = np.rint(points[:, 1]).astype(int)
    inside = (x >= 0) & (y >= 0) & (x < image.shape[1]) & (y < image.shape[0])
    return image[y[inside], x[inside]].astype(np.float64)


def meter(image: npt.NDArray, targets, full_scale_dn: float, clipped_fraction: float = 0.98,
          decode: Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]] | None = None) -> Metering:
    """Meter the converged targets (their candidate ellipses) or, without any, the scene. ``decode``: the metered
    values of a camera whose values are encoded (sRGB, a gamma) to linear ones (``camera.encoding.linear_dn``):
    exposure scales linear light."""
    if decode is not None:
        return meter(_Decoded(image, decode), targets, full_scale_dn, clipped_fraction)
    whites, blacks = [], []
    for target in targets:
        if not target.fit.ok:
            continue
        cand = target.candidate
        whites += [_ring_values(image, cand.inner, s) for s in WHITE_RINGS]
        blacks += [_ring_values(image, cand.outer, s) for s in BLACK_RINGS]
    white = np.concatenate(whites) if whites else np.zeros(0)
    black = np.concatenate(blacks) if blacks else np.zeros(0)
    if white.size and black.size:
        white_dn = float(np.percentile(white, 90))
        return Metering(white_dn=white_dn, black_dn=float(np.percentile(black, 10)),
                        clipped=white_dn >= clipped_fraction * full_scale_dn)
    sub = np.asarray(image[::4, ::4], dtype=np.float64)
    return Metering(scene_median_dn=float(np.median(sub)),
                    scene_clipped=float(np.mean(sub >= clipped_fraction * full_scale_dn)))


class _Decoded:
    """An image whose indexed values come out decoded (``meter``'s only reads: ``[y, x]`` and ``[::4, ::4]``)."""

    def __init__(self, image: npt.NDArray, decode: Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]]):
        self.image, self.decode, self.shape = image, decode, image.shape

    def __getitem__(self, index):
        return self.decode(np.asarray(self.image[index], dtype=np.float64))


class ExposureController:
    """Per-frame exposure decisions (module docstring). Keeps only the pending request between frames."""

    def __init__(self, full_scale_dn: float, options: ExposureControlOptions | None = None,
                 decode: Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]] | None = None):
        self.options = options or ExposureControlOptions()
        self.full_scale_dn = float(full_scale_dn)
        self.decode = decode  # an encoded camera's codes to linear values (``meter``)
        self._requested_us: float | None = None
        self._waited = 0
        self.last_metering: Metering | None = None
        self.steps = 0

    def wanted_ratio(self, m: Metering) -> float:
        """The exposure ratio the metering asks for (1: as is)."""
        o, fs = self.options, self.full_scale_dn
        if m.white_dn is not None and m.black_dn is not None:
            if m.clipped:
                return 1.0 / o.max_step
            ratio = o.white_goal * fs / max(m.white_dn, 1.0)
            if m.black_dn * ratio < o.black_min * fs:  # the black would sink into the noise
                ratio = min(o.black_min * fs / max(m.black_dn, 1.0), 0.98 * fs / max(m.white_dn, 1.0))
            return ratio
        assert m.scene_median_dn is not None and m.scene_clipped is not None
        if m.scene_clipped > o.scene_clipped_max:
            return 1.0 / math.sqrt(o.max_step)
        return o.scene_goal * fs / max(m.scene_median_dn, 1.0)

    def applied(self, exposure_us: float) -> None:
        """The exposure the source actually set for the pending request (a camera rounds it)."""
        if self._requested_us is not None:
            self._requested_us = float(exposure_us)

    def update(self, image: npt.NDArray, result, exposure_us: float | None) -> float | None:
        """The exposure to set now (us), or None to keep the current one. ``exposure_us``: the one in force for
        this frame (None: unknown, no decision)."""
        if exposure_us is None or not exposure_us > 0:
            return None
        o = self.options
        if self._requested_us is not None:  # a step is pending: act on a frame taken with it
            self._waited += 1
            in_force = abs(exposure_us - self._requested_us) <= 0.01 * self._requested_us
            if not in_force and self._waited < o.settle_frames:
                return None
            self._requested_us = None
        m = meter(image, result.targets, self.full_scale_dn, o.clipped_fraction, self.decode)
        self.last_metering = m
        ratio = self.wanted_ratio(m)
        if 1.0 / o.deadband <= ratio <= o.deadband:
            return None
        log_step = max(-math.log(o.max_step), min(math.log(o.max_step), o.gain * math.log(ratio)))
        new = min(o.max_exposure_us, max(o.min_exposure_us, exposure_us * math.exp(log_step)))
        if abs(new - exposure_us) <= 0.01 * exposure_us:  # at a limit
            return None
        self._requested_us = new
        self._waited = 0
        self.steps += 1
        return new
