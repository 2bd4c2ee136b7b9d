"""The exposure bias ``delta`` kept per exposure time across frames (``TrackerOptions.keep_delta_across_frames``):
a small least-recently-used cache that takes nearby exposures as one."""

from __future__ import annotations

from collections import OrderedDict

DELTA_CACHE_SIZE = 16
DELTA_CACHE_REL_TOL = 0.01
"""``keep_delta_across_frames`` keeps the delta of at most ``DELTA_CACHE_SIZE`` exposures (the least recently used
is forgotten), and exposures within ``DELTA_CACHE_REL_TOL`` (relative) of a kept one share its delta: a camera's
per-frame exposure (chunk data) jitters by a fraction of a percent, and each jittered value was a new entry, so the
cache grew without bound. Over 1 % of exposure, delta changes by a few thousandths of a pixel (it grows roughly
with the log of the exposure), below its noise."""


class _DeltaCache:
    """The delta last estimated at each exposure (``keep_delta_across_frames``), bounded: at most
    ``DELTA_CACHE_SIZE`` exposures, least recently used forgotten first; an exposure within ``DELTA_CACHE_REL_TOL``
    of a kept one is that one."""

    def __init__(self, size: int = DELTA_CACHE_SIZE, rel_tol: float = DELTA_CACHE_REL_TOL):
        self.size, self.rel_tol = size, rel_tol
        self._deltas: OrderedDict[float, float] = OrderedDict()

    def __len__(self) -> int:
        return len(self._deltas)

    def _key(self, exposure_us: float) -> float | None:
        keys = list(self._deltas)  # a copy: the live pipeline's search thread may put() meanwhile
        return next((k for k in keys if abs(exposure_us - k) <= self.rel_tol * k), None)

    def get(self, exposure_us: float | None) -> float | None:
        """The delta kept for this exposure (px), or None (none kept, exposure unknown)."""
        key = None if exposure_us is None else self._key(float(exposure_us))
        if key is None:
            return None
        self._deltas.move_to_end(key)
        return self._deltas[key]

    def put(self, exposure_us: float, delta_px: float) -> None:
        key = self._key(float(exposure_us))
        key = float(exposure_us) if key is None else key
        self._deltas[key] = float(delta_px)
        self._deltas.move_to_end(key)
        while len(self._deltas) > self.size:
            self._deltas.popitem(last=False)
