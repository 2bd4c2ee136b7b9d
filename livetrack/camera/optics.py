"""Fitted image formation of one camera: the PSF (Gaussian core, optional wide halo) and the sensor's read noise
at the clip level, as stored in a camera file and used by the estimator.

A camera file (``livetrack.camera.io``) may carry, next to the intrinsics::

    optics: {psf_sigma_px: 0.80, halo_fraction: 0.03, halo_sigma_px: 6.0}   # halo_* optional, both or neither
    response: {read_noise_dn: 2.05}                                          # optional

``livetrack model --camera-out`` writes them from a fitted exposure series; ``tracker_options_with_optics``
turns them into ``TrackerOptions`` settings. No I/O here.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from livetrack.config import checks as cc

if TYPE_CHECKING:
    from livetrack.estimator.tracker import TrackerOptions

CLIP_MARGIN_READ_NOISE_SD = 3.0
"""A pixel at full well reads the top code plus read noise, rounded and clipped: about half of the saturated pixels
read a little below the top code. The estimator counts samples within this many read-noise sd of the top code as
clipped (0.13 % of the saturated pixels stay below)."""


@dataclass(frozen=True)
class CameraOptics:
    """PSF and clip-level noise of a camera (pixels of that camera, DN of its ADC).

    psf_sigma_px: standard deviation of the Gaussian core of the PSF (px, > 0), before pixel integration.
    halo_fraction: share of the PSF's energy in a wide Gaussian halo, in [0, 1); 0: no halo.
    halo_sigma_px: standard deviation of the halo (px, > 0); None when there is no halo.
    read_noise_dn: read-noise sd (DN) of a saturated pixel; None when unknown (then no clip margin).
    """

    psf_sigma_px: float
    halo_fraction: float = 0.0
    halo_sigma_px: float | None = None
    read_noise_dn: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.psf_sigma_px) and self.psf_sigma_px > 0):
            raise ValueError(f"psf_sigma_px must be > 0, got {self.psf_sigma_px}")
        if not 0.0 <= self.halo_fraction < 1.0:
            raise ValueError(f"halo_fraction must be in [0, 1), got {self.halo_fraction}")
        if self.halo_fraction > 0 and not (self.halo_sigma_px is not None and math.isfinite(self.halo_sigma_px)
                                           and self.halo_sigma_px > 0):
            raise ValueError(f"halo_sigma_px must be > 0 with a halo, got {self.halo_sigma_px}")
        if self.read_noise_dn is not None and not (math.isfinite(self.read_noise_dn) and self.read_noise_dn >= 0):
            raise ValueError(f"read_noise_dn must be >= 0, got {self.read_noise_dn}")

    @property
    def halo(self) -> tuple[float, float] | None:
        """(fraction, sigma_px) of the halo, None without one."""
        if self.halo_fraction == 0 or self.halo_sigma_px is None:
            return None
        return (self.halo_fraction, self.halo_sigma_px)

    @property
    def clip_margin_dn(self) -> float | None:
        """DN below the top code from which a sample counts as clipped (None without a read noise: the tracker's
        default)."""
        return None if self.read_noise_dn is None else CLIP_MARGIN_READ_NOISE_SD * self.read_noise_dn

    # ------------------------------------------------------------------ camera-file sections
    @classmethod
    def from_sections(cls, optics: Any, response: Any, path: str) -> CameraOptics:
        """From the ``optics`` mapping (required) and the ``response`` mapping (None: absent) of a camera file;
        ``path`` prefixes the key paths of ConfigError messages (e.g. ``cam.yaml``)."""
        o_path = cc.join(path, "optics")
        cc.mapping(optics, o_path, required=["psf_sigma_px"], optional=["halo_fraction", "halo_sigma_px"])
        sigma = cc.number(optics, "psf_sigma_px", o_path, gt=0)
        fraction, halo_sigma = 0.0, None
        has = [k in optics and optics[k] is not None for k in ("halo_fraction", "halo_sigma_px")]
        if any(has):
            if not all(has):
                missing = "halo_sigma_px" if has[0] else "halo_fraction"
                raise cc.ConfigError(cc.join(o_path, missing), "missing (halo_fraction and halo_sigma_px go together)")
            fraction = cc.number(optics, "halo_fraction", o_path, ge=0, lt=1)
            halo_sigma = cc.number(optics, "halo_sigma_px", o_path, gt=0)
        read_noise = None
        if response is not None:
            r_path = cc.join(path, "response")
            cc.mapping(response, r_path, optional=["read_noise_dn"])
            if response.get("read_noise_dn") is not None:
                read_noise = cc.number(response, "read_noise_dn", r_path, ge=0)
        return cls(sigma, fraction, halo_sigma, read_noise)

    def to_sections(self) -> dict[str, dict[str, float]]:
        """``{"optics": {...}[, "response": {...}]}``, the inverse of :meth:`from_sections`."""
        optics: dict[str, float] = {"psf_sigma_px": float(self.psf_sigma_px)}
        if self.halo is not None:
            optics["halo_fraction"], optics["halo_sigma_px"] = (float(v) for v in self.halo)
        out: dict[str, dict[str, float]] = {"optics": optics}
        if self.read_noise_dn is not None:
            out["response"] = {"read_noise_dn": float(self.read_noise_dn)}
        return out


def tracker_options_with_optics(options: TrackerOptions, optics: CameraOptics | None) -> TrackerOptions:
    """``options`` with the camera's known PSF core (``psf_sigma_px``), halo (``psf_halo``) and clip margin
    (``clip_margin_dn``); unchanged for ``optics`` None."""
    if optics is None:
        return options
    return dataclasses.replace(options, psf_sigma_px=optics.psf_sigma_px, psf_halo=optics.halo,
                               clip_margin_dn=optics.clip_margin_dn)

