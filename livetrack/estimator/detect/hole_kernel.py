"""Whether a binary image has a hole, in one compiled flood fill: a white (0) region that no 4-connected white path
joins to the image's edge. ``cv2.findContours(..., RETR_CCOMP)`` reports a contour with a parent exactly then (it
takes the image as surrounded by white, holes as 4-connected, dark blobs as 8-connected), so a crop without one
gives no ellipse pair and need not be traced: on textured ground three quarters of the closed crops the detector
retries (``pairs._pairs_closed``, ~900 per frame) have none, and the fill costs ~2 us against ~20 us for tracing
them and walking the contours. Without numba every image counts as having a hole (the caller traces it)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

try:  # numba is a dependency; without it (a broken install) the caller traces every crop
    import numba
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None


if numba is not None:

    @numba.njit(cache=True, nogil=True)
    def _has_hole(binary):  # pragma: no cover - compiled
        h, w = binary.shape
        # 1 where white (0); the fill turns what it reaches to 2
        state = np.empty((h + 2, w + 2), np.uint8)  # a white frame around: the outside
        state[0, :] = 1
        state[h + 1, :] = 1
        for y in range(h):
            state[y + 1, 0] = 1
            state[y + 1, w + 1] = 1
            for x in range(w):
                state[y + 1, x + 1] = 1 if binary[y, x] == 0 else 0
        stack = np.empty((h + 2) * (w + 2), np.int64)
        stride = w + 2
        flat = state.ravel()
        flat[0] = 2
        stack[0] = 0
        top = 1
        size = flat.size
        while top > 0:  # depth-first fill of the white 4-connected to the outside
            top -= 1
            i = stack[top]
            for j in (i - stride, i + stride, i - 1, i + 1):
                if 0 <= j < size and flat[j] == 1:
                    flat[j] = 2
                    stack[top] = j
                    top += 1
        for i in range(size):  # white out of reach: a hole
            if flat[i] == 1:
                return True
        return False


def has_hole(binary: npt.NDArray[np.uint8]) -> bool:
    """True when the (H, W) uint8 ``binary`` (0 = white, non-zero = dark) has a white region out of 4-connected
    reach of its edge, i.e. when ``cv2.findContours(binary, RETR_CCOMP, ...)`` reports a hole; always True
    without numba."""
    if numba is None or binary.size == 0:
        return numba is None
    return bool(_has_hole(binary))
