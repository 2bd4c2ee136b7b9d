"""``target_map.sample_target_points``' map from target points to pixels in one compiled pass: each point's
projective image ``((H00 u + H01 v + H02) / w, (H10 u + H11 v + H12) / w)``, ``w = H20 u + H21 v + H22``, the same
float64 operations in the same order as the numpy expressions it replaces (no fused multiply-adds: numba's
default), rounded to float32 for ``cv2.remap``'s map, and whether it lies inside the image. Numpy's version made a
dozen passes over arrays of 24-1344 points, ~1-2 us of dispatch each (a detection of the bench's frames reads ~10
such sets: ~22 against ~7 us per call). ``tests/test_detect_levels.py`` holds it to the numpy expressions bit for
bit."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

try:  # numba is a dependency; without it (a broken install) numpy runs
    import numba
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None

FloatArray = npt.NDArray[np.float64]


def map_points(H: FloatArray, tx: FloatArray, ty: FloatArray, width: int, height: int,
               xy: npt.NDArray[np.float32], inside: npt.NDArray[np.bool_]) -> None:
    """Fills ``xy`` (M, 2) float32 with the pixels of the target points (tx, ty) (M,) through ``H`` (3, 3), and
    ``inside`` (M,) with whether each lies within an image of ``width`` x ``height`` pixels (centres from 0 to
    the size less 1, float64). ``tx`` and ``ty`` are made C-contiguous float64 (writeable or not)."""
    h = H.tolist()
    _map_points(h[0][0], h[0][1], h[0][2], h[1][0], h[1][1], h[1][2], h[2][0], h[2][1], h[2][2],
                np.ascontiguousarray(tx, np.float64), np.ascontiguousarray(ty, np.float64),
                float(width - 1), float(height - 1), xy, inside)


if numba is not None:

    @numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
    def _map_points(h00, h01, h02, h10, h11, h12, h20, h21, h22, tx, ty, last_x, last_y, xy,
                    inside):  # pragma: no cover - compiled
        for i in range(tx.size):
            u, v = tx[i], ty[i]
            w = h20 * u + h21 * v + h22
            x = (h00 * u + h01 * v + h02) / w
            y = (h10 * u + h11 * v + h12) / w
            xy[i, 0] = np.float32(x)
            xy[i, 1] = np.float32(y)
            inside[i] = (x >= 0.0) & (y >= 0.0) & (x <= last_x) & (y <= last_y)
