"""The full-resolution level's 3x3 Gaussian blur computed inside the local threshold's comparison
(``upsample_kernel``), so that the blurred image is not written by one pass and read back by the next:
``cv2.GaussianBlur(img8, (3, 3), sigma)`` then the 4x upsampled threshold's comparison cost 1.25-1.30 ms per
1920x1200 frame on one core, the fused pass 1.04-1.10 and the noise's rows ~0.06 (inside a detection ~0.07 ms
saved: the README's speed section, session 14).

The blur repeats OpenCV's fixed-point arithmetic for 8-bit images: the kernel in 8-bit fixed point (for sigma
0.8, 61 / 134 / 61 over 256), a horizontal and a vertical pass without intermediate rounding, and one rounding
shift, ``(sum k_i k_j p_ij + 2^15) >> 16``, with ``BORDER_REFLECT_101`` at the edges. ``kernel_taps`` derives the
taps and checks the compiled blur against ``cv2.GaussianBlur`` on test images before it is used (None when they
differ, or without numba: the caller then runs OpenCV). ``tests/test_detect_blur.py`` holds the fused pass to
``cv2.GaussianBlur`` + ``upsample_kernel.dark_and_box``."""

from __future__ import annotations

import functools

import cv2
import numpy as np
import numpy.typing as npt

try:  # numba is a dependency; without it (a broken install) OpenCV runs
    import numba
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None


def reference(img8: npt.NDArray[np.uint8], sigma: float) -> npt.NDArray[np.uint8]:
    """The OpenCV call the compiled blur repeats (``Detector.detect``'s full-resolution blur)."""
    return cv2.GaussianBlur(img8, (3, 3), sigma)


@functools.lru_cache(maxsize=8)
def kernel_taps(sigma: float) -> tuple[int, int] | None:
    """(side, centre): the 3x3 blur's taps over 256 for ``sigma``, when the compiled blur then gives
    ``reference``'s images (checked once per sigma on noise, ramps, flat and binary images of odd and even
    sizes); None otherwise, or without numba."""
    if numba is None:
        return None
    k = cv2.getGaussianKernel(3, sigma, cv2.CV_64F).ravel()
    side = int(round(k[0] * 256.0))
    centre = 256 - 2 * side
    if side < 0 or centre < 0:
        return None
    rng = np.random.default_rng(13)
    tests = [rng.integers(0, 256, (37, 53), dtype=np.uint8), rng.integers(0, 256, (64, 96), dtype=np.uint8),
             np.full((5, 7), 255, np.uint8), np.zeros((3, 3), np.uint8),
             (np.add.outer(np.arange(40), np.arange(60)) * 3 % 256).astype(np.uint8),
             (rng.random((50, 70)) < 0.5).astype(np.uint8) * 255]
    for img in tests:
        got = np.empty_like(img)
        blur_rows(img, got, 1, side, centre)
        if not np.array_equal(got, reference(img, sigma)):
            return None
    return side, centre


def blur_rows(src: npt.NDArray[np.uint8], dst: npt.NDArray[np.uint8], step: int, side: int,
              centre: int) -> npt.NDArray[np.uint8]:
    """Rows 0, ``step``, 2 ``step``, ... of ``reference(src)`` into the same rows of ``dst`` (the others are left
    as they were); ``src`` and ``dst`` (H, W) uint8, H and W >= 2, not sharing memory."""
    _blur_rows(src, dst, step, np.uint16(side), np.uint16(centre), np.empty(src.shape[1], np.uint16))
    return dst


if numba is not None:

    @numba.njit(cache=True, nogil=True)
    def blur_row(src, y, out, side, centre, v):  # pragma: no cover - compiled
        """Row ``y`` of the blur of ``src`` (H >= 2, W >= 2) into ``out`` (W,): the vertical pass into ``v`` (W,
        uint16: at most 256 x 255), then the horizontal one and the rounding shift; rows and columns beyond the
        edges reflected without repeating the edge (``BORDER_REFLECT_101``). Integer arithmetic, exact, in 16-bit
        lanes: with v = 256 h + l (h = v >> 8, l = v & 255), ``(sum k v + 2^15) >> 16`` is ``(sum k h + ((sum k
        l) >> 8) + 128) >> 8`` (nested floor divisions), every term under 2^16."""
        h, w = src.shape
        a = src[y - 1] if y > 0 else src[1]
        c = src[y + 1] if y < h - 1 else src[h - 2]
        b = src[y]
        k0, k1 = np.uint16(side), np.uint16(centre)
        for x in range(w):
            v[x] = np.uint16(k0 * np.uint16(np.uint16(a[x]) + np.uint16(c[x]))) + np.uint16(k1 * np.uint16(b[x]))
        out[0] = _tap3(v[1], v[0], v[1], k0, k1)
        out[w - 1] = _tap3(v[w - 2], v[w - 1], v[w - 2], k0, k1)
        # over slices from 0 (see ``upsample_kernel._dark_row``): the loop vectorises
        left, mid, right, inner = v[: w - 2], v[1 : w - 1], v[2:], out[1 : w - 1]
        for x in range(inner.size):
            inner[x] = _tap3(left[x], mid[x], right[x], k0, k1)

    @numba.njit(cache=True, nogil=True, inline="always")
    def _tap3(p, q, r, k0, k1):  # pragma: no cover - compiled
        """``(k0 (p + r) + k1 q + 2^15) >> 16`` of three uint16 in 16-bit arithmetic (see ``blur_row``)."""
        eight, byte = np.uint16(8), np.uint16(255)
        high = np.uint16(k0 * np.uint16(np.uint16(p >> eight) + np.uint16(r >> eight))) + np.uint16(
            k1 * np.uint16(q >> eight))
        low = np.uint16(k0 * np.uint16(np.uint16(p & byte) + np.uint16(r & byte))) + np.uint16(k1 * np.uint16(q & byte))
        return np.uint8(np.uint16(np.uint16(high + np.uint16(low >> eight)) + np.uint16(128)) >> eight)

    @numba.njit(cache=True, nogil=True)
    def _blur_rows(src, dst, step, side, centre, v):  # pragma: no cover - compiled
        for y in range(0, src.shape[0], step):
            blur_row(src, y, dst[y], side, centre, v)
