"""``pairs._pairs``' choice of the blobs it examines, compiled: the top-level contours (no parent) with or without
a hole and of at least ``min_len`` points, from ``cv2.findContours``' hierarchy, in one pass instead of numpy's
three comparisons, two ands and a ``flatnonzero`` (~3 us a call on the few to few dozen contours of a level or
crop, ~20 calls a bench frame; this ~1 us). Integer tests only: the same indices in the same order as
``top_blobs_reference`` (``tests/test_detect_blobs.py`` holds one to the other)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

try:  # numba is a dependency; without it (a broken install) numpy runs
    import numba
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None

IntArray = npt.NDArray[np.int64]


def top_blobs(hier: np.ndarray, lengths: IntArray, min_len: int, with_hole: bool) -> IntArray:
    """Indices (ascending, int64) of the contours without a parent (``hier[:, 3] < 0``), with a hole
    (``hier[:, 2] >= 0``) or without one as ``with_hole`` says, of at least ``min_len`` points (``lengths``);
    ``hier``: (K, 4) as ``cv2.findContours`` gives it, reshaped."""
    if numba is None:
        return top_blobs_reference(hier, lengths, min_len, with_hole)
    return _top_blobs(hier, lengths, min_len, with_hole)


def top_blobs_reference(hier: np.ndarray, lengths: IntArray, min_len: int, with_hole: bool) -> IntArray:
    """``top_blobs`` in numpy."""
    hole = hier[:, 2] >= 0 if with_hole else hier[:, 2] < 0
    return np.flatnonzero((hier[:, 3] < 0) & hole & (lengths >= min_len))


if numba is not None:

    @numba.njit(cache=True, nogil=True)
    def _top_blobs(hier, lengths, min_len, with_hole):  # pragma: no cover - compiled
        out = np.empty(hier.shape[0], np.int64)
        n = 0
        for i in range(hier.shape[0]):
            if hier[i, 3] < 0 and (hier[i, 2] >= 0) == with_hole and lengths[i] >= min_len:
                out[n] = i
                n += 1
        return out[:n]
