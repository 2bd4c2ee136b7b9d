"""The coarse stage's 16-to-8-bit square-root map computed, not looked up: ``round(255 sqrt(v / full))`` as
``rint(sqrt(float32(v)) * c)`` with ``c = float32(255 / sqrt(full))``, clipped at 255, in vector lanes (a 1920x1200
frame's map ~0.16 ms on one core, where the table look-up of ``lut_kernel``, a gather per pixel, takes ~0.43).

Only where it gives the table's value for every one of the 65536 inputs (``exact_factor`` runs the kernel itself
on all of them, once per ``full``; float32 rounds differently from the table's float64 for a few ``full``: 4000
has one input off), so the 8-bit image is the table's bit for bit; otherwise the caller looks the table up.
Every operation is IEEE (no fastmath): the vector body and the scalar remainder of a row give the same numbers.
``tests/test_detect_sqrt.py`` holds it to the table on frames and to ``pyramid_kernel.lut16_halved``."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

try:  # numba is a dependency; without it (a broken install) the table look-up runs
    import numba
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None


def reference(src: npt.NDArray[np.uint16], factor: float) -> npt.NDArray[np.uint8]:
    """The kernel's arithmetic in numpy (float32 throughout): ``min(rint(sqrt(src) * factor), 255)``."""
    v = np.sqrt(src.astype(np.float32)) * np.float32(factor)
    return np.minimum(np.rint(v), np.float32(255.0)).astype(np.uint8)


def exact_factor(full: float, table: npt.NDArray[np.uint8]) -> np.float32 | None:
    """``float32(255 / sqrt(full))`` when the compiled map with it gives ``table`` (``threshold._sqrt_table(full,
    65536)``) for every 16-bit input, in one row (the vector loop) and in rows of 31 (its scalar remainder); else
    None (and None without numba). ~1 ms, once per ``full`` (the caller caches it)."""
    if numba is None or table.shape != (65536,):
        return None
    factor = np.float32(255.0 / np.sqrt(full))
    values = np.arange(65536, dtype=np.uint16)
    for width in (65536, 31):
        n = -(-65536 // width) * width
        src = np.resize(values, n).reshape(-1, width)
        dst = np.empty(src.shape, np.uint8)
        if sqrt16(src, factor, dst) != 65535 or not np.array_equal(dst.ravel()[:65536], table):
            return None
        if not np.array_equal(dst.ravel()[65536:], table[: n - 65536]):
            return None
    return factor


def sqrt16(src: npt.NDArray[np.uint16], factor: np.float32, dst: npt.NDArray[np.uint8]) -> int:
    """``dst`` = the map of ``src`` (H, W; any strides) with ``factor``; returns the largest value of ``src`` (0
    when empty), as ``lut_kernel.lut16`` does. Needs numba."""
    return int(_sqrt16(src, np.float32(factor), dst))


def sqrt16_halved(src: npt.NDArray[np.uint16], factor: np.float32, dst: npt.NDArray[np.uint8],
                  half: npt.NDArray[np.uint8]) -> int:
    """``sqrt16`` and ``half`` = ``cv2.pyrDown(dst)`` in one pass (``pyramid_kernel.lut16_halved`` with the map
    computed): H and W >= 3, ``dst`` and ``half`` C-contiguous. Needs numba."""
    h, w = dst.shape
    scratch = np.empty((w + 6) // 2 + 1, np.uint32)
    return int(_sqrt16_halved(src, np.float32(factor), dst, half, scratch.view(np.uint16), scratch))


if numba is not None:
    from livetrack.estimator.detect.pyramid_kernel import pyr_down_row

    @numba.njit(cache=True, nogil=True, fastmath=False)
    def _sqrt_row(row, out, factor):  # pragma: no cover - compiled
        """One row's map and its largest input (two loops of their own: each vectorises)."""
        top255 = np.float32(255.0)
        for x in range(out.size):
            out[x] = np.uint8(min(np.rint(np.sqrt(np.float32(row[x])) * factor), top255))
        top = np.uint16(0)
        for x in range(row.size):
            v = row[x]
            top = v if v > top else top
        return top

    @numba.njit(cache=True, nogil=True, fastmath=False)
    def _sqrt16(src, factor, dst):  # pragma: no cover - compiled
        top = np.uint16(0)
        for y in range(src.shape[0]):
            t = _sqrt_row(src[y], dst[y], factor)
            top = t if t > top else top
        return top

    @numba.njit(cache=True, nogil=True, fastmath=False)
    def _sqrt16_halved(src, factor, dst, half, vv, vw):  # pragma: no cover - compiled
        """The map row by row, each row of ``half`` as soon as the rows it reads are mapped
        (``pyramid_kernel._lut16_halved``'s order)."""
        h = src.shape[0]
        top = np.uint16(0)
        done = 0  # rows of ``half`` written
        for y in range(h):
            t = _sqrt_row(src[y], dst[y], factor)
            top = t if t > top else top
            # row yo reads up to 2 yo + 2 (reflected into the image at the bottom edge)
            while done < half.shape[0] and min(2 * done + 2, h - 1) <= y:
                pyr_down_row(dst, done, half[done], vv, vw)
                done += 1
        return top
