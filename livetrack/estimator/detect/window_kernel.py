"""The local threshold's arithmetic on the coarse level in one compiled pass (``threshold._dark_box``): from the
window's max, min and mean (OpenCV's dilate, erode and blur, fast as they are) to the threshold image, in place
of OpenCV's eight elementwise calls (subtract, convertScaleAbs, max, addWeighted, max, subtract, compare,
countNonZero and, in clipped frames, four more: ~0.14-0.17 ms on a 480x300 level, each a pass over the image and
a few microseconds of dispatch; this pass ~0.04 ms).

The arithmetic is OpenCV's, in float32 on values that are all small integers (exact): ``convertScaleAbs`` rounds
``|f32(span) * f32(alpha)|`` half to even (and saturates, which cannot change a threshold here: a spread of 255
or more leaves 0 either way); ``addWeighted`` of two 8-bit images by 0.5 each is their sum halved, half to even.
``exact`` runs the kernel on every (max, min) pair against OpenCV's calls once per pair of factors before it is
used; factors that fail, and installs without numba, go through OpenCV. ``tests/test_detect_window.py`` holds it
to OpenCV's calls on every (max, min, mean) triple and on frames."""

from __future__ import annotations

import functools

import cv2
import numpy as np
import numpy.typing as npt

try:  # numba is a dependency; without it (a broken install) OpenCV runs
    import numba
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None


def reference(top: npt.NDArray[np.uint8], bottom: npt.NDArray[np.uint8], mean: npt.NDArray[np.uint8],
              alpha: float, offset: float, alpha_saturated: float, depth: float,
              saturated_level: int) -> npt.NDArray[np.uint8]:
    """The OpenCV calls the kernel replaces (``threshold._dark_box``'s, as they were): max(mean, (top + bottom) /
    2) - max(convertScaleAbs(top - bottom, alpha), round(offset)), saturated at 0; where ``top`` >=
    ``saturated_level``, at least top - max(convertScaleAbs(top - bottom, alpha_saturated), round(depth))."""
    span = cv2.subtract(top, bottom)
    spread = cv2.max(cv2.convertScaleAbs(span, alpha=alpha), int(round(offset)))
    middle = cv2.addWeighted(top, 0.5, bottom, 0.5, 0.0)
    threshold = cv2.subtract(cv2.max(mean, middle), spread)
    saturated = cv2.compare(top, saturated_level, cv2.CMP_GE)
    if cv2.countNonZero(saturated):
        spread = cv2.max(cv2.convertScaleAbs(span, alpha=alpha_saturated), int(round(depth)))
        np.copyto(threshold, cv2.max(threshold, cv2.subtract(top, spread)), where=saturated.view(bool))
    return threshold


@functools.lru_cache(maxsize=16)
def exact(alpha: float, alpha_saturated: float) -> bool:
    """Whether the kernel gives ``reference``'s image for these factors on every (top, bottom) pair (top >=
    bottom, as a window's max and min are), each with a mean of its own, at offsets and depths 0-40 (~2 ms, once
    per pair of factors). False without numba."""
    if numba is None:
        return False
    low, high = np.triu_indices(256)  # low <= high
    top, bottom = high.astype(np.uint8)[None, :], low.astype(np.uint8)[None, :]
    mean = ((top.astype(np.int64) * 7 + bottom * 3) % 256).astype(np.uint8)
    for offset, depth in ((0, 0), (8, 3), (13, 40), (40, 13)):
        want = reference(top, bottom, mean, alpha, offset, alpha_saturated, depth, 254)
        got = window_threshold(top, bottom, mean, alpha, offset, alpha_saturated, depth, 254, np.empty_like(top))
        if not np.array_equal(got, want):
            return False
    return True


def window_threshold(top: npt.NDArray[np.uint8], bottom: npt.NDArray[np.uint8], mean: npt.NDArray[np.uint8],
                     alpha: float, offset: float, alpha_saturated: float, depth: float, saturated_level: int,
                     out: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """``reference``'s image into ``out``; all five (H, W) uint8 and C-contiguous (``exact`` must hold for the
    factors)."""
    _window_threshold(top.ravel(), bottom.ravel(), mean.ravel(), np.float32(alpha), np.float32(int(round(offset))),
                      np.float32(alpha_saturated), np.float32(int(round(depth))), np.float32(saturated_level),
                      out.reshape(-1))
    return out


def clipped_reference(top: npt.NDArray[np.uint8], mean: npt.NDArray[np.uint8], alpha: float, depth: float,
                      saturated_level: int) -> npt.NDArray[np.uint8]:
    """The OpenCV calls ``clipped_threshold`` replaces (``threshold._clipped_dark_box``'s, as they were): top -
    max(convertScaleAbs(top - mean, alpha), round(depth)), saturated at 0; 0 where ``top`` < ``saturated_level``."""
    spread = cv2.max(cv2.convertScaleAbs(cv2.subtract(top, mean), alpha=alpha), int(round(depth)))
    threshold = cv2.subtract(top, spread)
    threshold[top < saturated_level] = 0
    return threshold


@functools.lru_cache(maxsize=16)
def clipped_exact(alpha: float) -> bool:
    """Whether ``clipped_threshold`` gives ``clipped_reference``'s image for ``alpha`` on every (top, mean) pair at
    depths 0-300 (~1 ms, once per factor). False without numba."""
    if numba is None:
        return False
    top = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 256, 1)
    mean = np.ascontiguousarray(top.T)
    for depth in (0.0, 2.5, 3.0, 13.4, 40.0, 300.0):
        got = clipped_threshold(top, mean, alpha, depth, 254, np.empty_like(top))
        if not np.array_equal(got, clipped_reference(top, mean, alpha, depth, 254)):
            return False
    return True


def clipped_threshold(top: npt.NDArray[np.uint8], mean: npt.NDArray[np.uint8], alpha: float, depth: float,
                      saturated_level: int, out: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """``clipped_reference``'s image into ``out`` in one compiled pass (~0.01 against ~0.05 ms on a 480x300 level);
    all three (H, W) uint8 and C-contiguous (``clipped_exact`` must hold for ``alpha``)."""
    _clipped_threshold(top.ravel(), mean.ravel(), np.float32(alpha), np.float32(min(int(round(depth)), 255)),
                       np.float32(saturated_level), out.reshape(-1))
    return out


if numba is not None:

    @numba.njit(cache=True, nogil=True, fastmath=True)
    def _clipped_threshold(top, mean, alpha, depth, saturated_level, out):  # pragma: no cover - compiled
        """As ``_window_threshold``: float32 on small integers (exact), branch-free."""
        zero = np.float32(0.0)
        for x in range(out.size):
            t = np.float32(top[x])
            span = max(t - np.float32(mean[x]), zero)
            spread = max(np.rint(span * alpha), depth)
            out[x] = np.uint8(max(t - spread, zero) if t >= saturated_level else zero)

    @numba.njit(cache=True, nogil=True, fastmath=True)
    def _window_threshold(top, bottom, mean, alpha, offset, alpha_saturated, depth, saturated_level,
                          out):  # pragma: no cover - compiled
        """In float32 (every value a small integer: exact; fastmath lets the maxima vectorise, no NaN here), one
        branch-free pass."""
        zero, half = np.float32(0.0), np.float32(0.5)
        for x in range(out.size):
            t = np.float32(top[x])
            b = np.float32(bottom[x])
            span = t - b
            spread = max(np.rint(abs(span * alpha)), offset)
            middle = np.rint((t + b) * half)
            threshold = max(max(np.float32(mean[x]), middle) - spread, zero)
            deep = max(np.rint(abs(span * alpha_saturated)), depth)
            lifted = max(t - deep, threshold)
            out[x] = np.uint8(lifted if t >= saturated_level else threshold)
