"""Compiled (numba) table look-ups: 16-bit to 8-bit images, the coarse detector's square-root map of a 1920x1200
frame in ~0.8 ms on one core (numpy's fancy indexing takes ~5-10 ms, a float32 pass through OpenCV ~1.5 ms); and
8 or 16-bit to 16-bit images, an encoded camera's frames linearised (``camera.encoding``: ~0.43 ms per 1920x1200
frame, ``np.take`` ~1.2 ms). Fall back to numpy where numba is missing. The same compilation and cache rules as
:mod:`livetrack.estimator.edge_kernels` (``cache=True``)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

try:  # numba is a dependency; without it (a broken install) numpy indexing runs
    import numba
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None


def _lut16_python(src: npt.NDArray[np.uint16], table: npt.NDArray[np.uint8], dst: npt.NDArray[np.uint8]) -> int:
    np.take(table, src, out=dst)
    return int(src.max()) if src.size else 0


if numba is not None:

    @numba.njit(cache=True, nogil=True)
    def _lut16_compiled(src, table, dst):  # pragma: no cover - compiled
        h, w = src.shape
        top = np.uint16(0)
        for y in range(h):
            row, out = src[y], dst[y]
            for x in range(w):
                out[x] = table[row[x]]
            # the row's max in a loop of its own (vectorised, the row in cache: ~0 ms per frame; folded into
            # the look-up's loop it cost ~0.8 ms per 1920x1200 frame)
            for x in range(w):
                v = row[x]
                top = v if v > top else top
        return top


def lut16(src: npt.NDArray[np.uint16], table: npt.NDArray[np.uint8], dst: npt.NDArray[np.uint8]) -> int:
    """``dst[y, x] = table[src[y, x]]`` for a (H, W) uint16 image (any strides), a (65536,) uint8 table and a
    (H, W) uint8 output. Returns the largest value of ``src`` (0 when empty): with a non-decreasing table,
    ``table[top]`` is the largest of ``dst``, without another pass over it."""
    if numba is not None:
        return int(_lut16_compiled(src, table, dst))
    return _lut16_python(src, table, dst)


if numba is not None:

    @numba.njit(cache=True, nogil=True)
    def _lut_to16_compiled(src, table, dst):  # pragma: no cover - compiled
        h, w = src.shape
        for y in range(h):
            row, out = src[y], dst[y]
            for x in range(w):
                out[x] = table[row[x]]


def lut_to16(src: npt.NDArray[np.uint8] | npt.NDArray[np.uint16], table: npt.NDArray[np.uint16],
             dst: npt.NDArray[np.uint16]) -> npt.NDArray[np.uint16]:
    """``dst[y, x] = table[src[y, x]]`` for a (H, W) uint8 or uint16 image (any strides), a uint16 table with an
    entry for every value of the source's type (256 or 65536: no index can fall outside it; ValueError otherwise)
    and a (H, W) uint16 output, returned."""
    if table.size < (256 if src.dtype == np.uint8 else 65536) or src.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"a table of {table.size} entries cannot map every {src.dtype} value")
    if numba is not None:
        _lut_to16_compiled(src, table, dst)
        return dst
    return np.take(table, src, out=dst)
