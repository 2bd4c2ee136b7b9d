"""Sensor of the simulator: from the mean photo-electrons of each pixel to digital numbers (DN).

Order (``SensorModel.digitise``), per pixel:

1. shot noise: the charge is Poisson distributed about the mean (exact Poisson draws below
   ``exact_poisson_below_e``, a Gaussian with the same mean and variance above);
2. the well: a pixel holds at most ``full_well_e``. With the ``nonlinear`` effect
   (``knee_fraction_of_full_well = k < 1``) it holds ``q`` up to the knee ``k F`` and less and less of
   the charge above it::

       held(q) = q                                       for q <= k F
       held(q) = F - (1 - k) F exp(-(q - k F) / ((1 - k) F))   above

   (continuous with slope 1 at the knee, tending to F: at q = F it holds F (1 - (1 - k)/e), 0.926 F for
   k = 0.8). With k = 1 (the default) ``held(q) = min(q, F)``, the hard clip;
3. blooming (``bloom_spill_fraction = s > 0``): of the charge a pixel could not hold, the fraction s spills
   along its column, half up and half down, filling the neighbours up to full well (up to the knee k F with
   the nonlinear response) and running on past full ones; the rest (and charge running off the top or
   bottom) goes to the drain. Charge is conserved up to that. Exact for the one-directional flows,
   computed with a cumulative sum per column (the Lindley recursion ``W_i = max(0, W_(i-1) + x_i)``): the
   downward flow is resolved first, the upward flow then fills what room is left;
4. read noise: Gaussian, ``read_noise_e`` electrons RMS;
5. gain: ``dn_per_e * 10^(gain_db / 20)`` DN per electron, plus ``black_level_dn``;
6. ADC: round to the nearest integer and clip to [0, 2^bit_depth - 1].

By default full well reads exactly the top code at 0 dB. Noise-free output: ``expected_dn``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.floating]


@dataclass(frozen=True)
class SensorModel:
    """Pixel well, noise and ADC of a camera.

    full_well_e : charge a pixel holds, electrons (default 10000). Sets the saturation level.
    read_noise_e : RMS read noise, electrons (default 5). With a black level of 0 dark pixels clip at 0 DN.
    black_level_dn : DN offset added before the ADC (default 0).
    bit_depth : ADC bits, 8..16 (default 12); output dtype uint8 for 8 bits, else uint16.
    dn_per_e : conversion gain at 0 dB, DN per electron (default None: full well reads the top code,
        ``(2^bit_depth - 1 - black_level_dn) / full_well_e``).
    shot_noise : draw Poisson shot noise when a random generator is given (default True).
    bloom_spill_fraction : share of the charge a pixel cannot hold that spills along its column, 0..1
        (default 0: no blooming, the excess drains). Cost: two cumulative sums over the columns holding
        saturated pixels, about 0.1 s for 1920x1200 when every column saturates.
    knee_fraction_of_full_well : charge, as a fraction of full well, above which the pixel response bends
        smoothly towards full well (formula in the module docstring), in (0, 1] (default 1: linear up to a
        hard clip at full well).
    exact_poisson_below_e : shot noise is drawn exactly (``Generator.poisson``) for means below this, and as a
        Gaussian of equal mean and variance above, where the Poisson skewness 1/sqrt(mean) is below 0.1 for
        the default 100 e. Cost: exact draws are ~5x slower (0.1-0.2 s for a full 1920x1200 frame); 0 makes
        all draws Gaussian, ``inf`` all exact.
    """

    full_well_e: float = 10000.0
    read_noise_e: float = 5.0
    black_level_dn: float = 0.0
    bit_depth: int = 12
    dn_per_e: float | None = None
    shot_noise: bool = True
    bloom_spill_fraction: float = 0.0
    knee_fraction_of_full_well: float = 1.0
    exact_poisson_below_e: float = 100.0

    def __post_init__(self) -> None:
        def check(name: str, ok: bool) -> None:
            if not ok:
                raise ValueError(f"SensorModel.{name}: invalid value {getattr(self, name)!r}")

        check("full_well_e", math.isfinite(self.full_well_e) and self.full_well_e > 0)
        check("read_noise_e", math.isfinite(self.read_noise_e) and self.read_noise_e >= 0)
        check("bit_depth", isinstance(self.bit_depth, int) and 8 <= self.bit_depth <= 16)
        check("black_level_dn", 0 <= self.black_level_dn < self.top_code)
        check("dn_per_e", self.dn_per_e is None or (math.isfinite(self.dn_per_e) and self.dn_per_e > 0))
        check("bloom_spill_fraction", 0.0 <= self.bloom_spill_fraction <= 1.0)
        check("knee_fraction_of_full_well", 0.0 < self.knee_fraction_of_full_well <= 1.0)
        check("exact_poisson_below_e", self.exact_poisson_below_e >= 0)

    # ------------------------------------------------------------------ derived
    @property
    def top_code(self) -> int:
        """Largest DN the ADC delivers, 2^bit_depth - 1."""
        return (1 << self.bit_depth) - 1

    @property
    def dn_per_e_at_0db(self) -> float:
        """Conversion gain in use at 0 dB (``dn_per_e`` or its default)."""
        if self.dn_per_e is not None:
            return float(self.dn_per_e)
        return (self.top_code - self.black_level_dn) / self.full_well_e

    def dn_per_e_at(self, gain_db: float) -> float:
        """Conversion gain at ``gain_db`` (amplitude scale 10^(gain_db / 20))."""
        return self.dn_per_e_at_0db * 10.0 ** (gain_db / 20.0)

    @property
    def dtype(self) -> type[np.unsignedinteger]:
        return np.uint8 if self.bit_depth == 8 else np.uint16

    # ------------------------------------------------------------------ stages
    def shot(self, electrons: FloatArray, rng: np.random.Generator) -> npt.NDArray[np.float32]:
        """Charge drawn about the mean ``electrons`` (H, W): Poisson, or Gaussian above
        ``exact_poisson_below_e``. Returns float32 (H, W)."""
        mean = np.maximum(np.asarray(electrons, dtype=np.float32), 0.0)
        noise = rng.standard_normal(mean.shape, dtype=np.float32)
        out = mean + np.sqrt(mean) * noise
        small = mean < self.exact_poisson_below_e
        if np.any(small):
            out[small] = rng.poisson(mean[small].astype(np.float64)).astype(np.float32)
        return np.maximum(out, 0.0, out=out)

    def well(self, charge: FloatArray) -> npt.NDArray[np.float32]:
        """Charge held by each pixel of the (H, W) ``charge`` after the knee or clip and blooming, float32."""
        q = np.asarray(charge, dtype=np.float32)
        F = np.float32(self.full_well_e)
        k = self.knee_fraction_of_full_well
        if k < 1.0:
            soft = np.float32((1.0 - k) * self.full_well_e)
            knee = np.float32(k * self.full_well_e)
            above = np.maximum(q - knee, np.float32(0.0))  # no overflow in exp below the knee
            held = np.where(q > knee, F - soft * np.exp(-above / soft), q).astype(np.float32)
        else:
            held = np.minimum(q, F)
        if self.bloom_spill_fraction > 0.0:
            capacity = k * self.full_well_e
            held = _bloom(held, q - held, capacity, self.full_well_e, self.bloom_spill_fraction)
        return held

    def to_dn(self, charge: FloatArray, gain_db: float,
              rng: np.random.Generator | None) -> npt.NDArray[np.float32]:
        """Read noise (if ``rng``), gain, black level: held charge (H, W) -> DN before rounding, float32."""
        q = np.asarray(charge, dtype=np.float32)
        if rng is not None and self.read_noise_e > 0:
            q = q + np.float32(self.read_noise_e) * rng.standard_normal(q.shape, dtype=np.float32)
        return q * np.float32(self.dn_per_e_at(gain_db)) + np.float32(self.black_level_dn)

    # ------------------------------------------------------------------ public
    def digitise(self, electrons: FloatArray, gain_db: float = 0.0,
                 rng: np.random.Generator | None = None,
                 encode: Callable[[npt.NDArray[np.float32]], npt.NDArray[np.float32]] | None = None
                 ) -> npt.NDArray[np.unsignedinteger]:
        """Mean photo-electrons (H, W) -> DN image (H, W), uint8 for 8 bit else uint16.

        With ``rng`` the charge gets shot noise (if ``shot_noise``) and read noise; without it the result is
        the rounded noise-free image (``expected_dn`` rounded). Deterministic for a given generator state.
        ``encode``: an output curve applied to the float DN before rounding (``effects.encode_dn``).
        """
        charge = np.asarray(electrons, dtype=np.float32)
        if rng is not None and self.shot_noise:
            charge = self.shot(charge, rng)
        dn = self.to_dn(self.well(charge), gain_db, rng)
        if encode is not None:
            dn = encode(dn)
        np.rint(dn, out=dn)
        np.clip(dn, 0, self.top_code, out=dn)
        return dn.astype(self.dtype)

    def expected_dn(self, electrons: FloatArray, gain_db: float = 0.0) -> npt.NDArray[np.float64]:
        """Noise-free DN (H, W) float64 of mean ``electrons``: well, gain, black level, clipped to the ADC
        range, not rounded."""
        held = self.well(np.asarray(electrons, dtype=np.float64)).astype(np.float64)
        dn = held * self.dn_per_e_at(gain_db) + self.black_level_dn
        return np.clip(dn, 0.0, float(self.top_code))


def _bloom(held: npt.NDArray[np.float32], excess: npt.NDArray[np.float32], capacity_e: float,
           full_well_e: float, spill_fraction: float) -> npt.NDArray[np.float32]:
    """Spill ``spill_fraction`` of ``excess`` (H, W) along columns into the room left under ``capacity_e``.

    Pixels with excess of their own have no room (spilled charge runs past them); the others take charge up
    to ``capacity_e`` (full well, or the knee with the nonlinear response). Computed in float64 on the
    columns that have any excess. Downward flow first: with ``x_i = spill_i - room_i`` the charge leaving
    pixel i downwards is the Lindley recursion ``W_i = max(0, W_(i-1) + x_i)``, i.e.
    ``S_i - min(0, min_(j<=i) S_j)`` with ``S = cumsum(x)``; pixel i keeps ``W_(i-1) + spill_i - W_i``.
    The upward flow is the same on the reversed columns with the room that remains.
    """
    cols = np.flatnonzero(np.any(excess > 0, axis=0))
    if cols.size == 0:
        return held
    # Work on (columns, rows) contiguous float64 copies: cumulative sums then run along memory.
    h = np.ascontiguousarray(held[:, cols].T, dtype=np.float64)
    spill = np.ascontiguousarray(excess[:, cols].T, dtype=np.float64)
    spill *= 0.5 * spill_fraction
    leaking = spill > 0
    for direction in ("down", "up"):
        if direction == "up":
            h, spill, leaking = h[:, ::-1].copy(), spill[:, ::-1].copy(), leaking[:, ::-1].copy()
        room = np.subtract(capacity_e, h)
        np.maximum(room, 0.0, out=room)
        room[leaking] = 0.0
        w = spill - room
        np.cumsum(w, axis=1, out=w)
        low = np.minimum.accumulate(w, axis=1)
        np.minimum(low, 0.0, out=low)
        w -= low  # W_i: charge flowing out of pixel i onwards
        # A pixel with room takes min(room, inflow); pixels with their own excess have no room.
        np.minimum(room[:, 1:], w[:, :-1], out=room[:, 1:])
        room[:, 0] = 0.0
        h += room
    out = held.copy()
    out[:, cols] = np.minimum(h[:, ::-1].T, full_well_e)
    return out
