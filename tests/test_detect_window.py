"""The coarse threshold's arithmetic compiled (``detect/window_kernel.py``) against the OpenCV calls it replaced
(``window_kernel.reference``): every (max, min, mean) triple, frames' coarse levels, and ``threshold._dark_box``'s
binary image and box with and without the kernel."""

import cv2
import numpy as np
import pytest

from livetrack.estimator.detect import threshold, window_kernel
from livetrack.estimator.detect.options import DetectOptions

pytestmark = pytest.mark.skipif(window_kernel.numba is None, reason="numba not installed")


def _triples() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every (top, bottom, mean) with top >= bottom, as (256, 32896) uint8 images."""
    low, high = np.triu_indices(256)
    top = np.repeat(high.astype(np.uint8)[None, :], 256, 0)
    bottom = np.repeat(low.astype(np.uint8)[None, :], 256, 0)
    mean = np.repeat(np.arange(256, dtype=np.uint8)[:, None], top.shape[1], 1)
    return top, bottom, mean


@pytest.mark.parametrize("alpha", [0.05, 0.1, 0.37])
def test_every_triple_as_opencv(alpha):
    top, bottom, mean = _triples()
    assert window_kernel.exact(alpha, threshold.SATURATED_RELATIVE_OFFSET)
    for offset, depth in ((8.0, 8.0), (9.5, 2.5), (10.5, 3.4), (24.0, 8.0), (0.0, 0.0), (300.0, 1.0)):
        want = window_kernel.reference(top, bottom, mean, alpha, offset, threshold.SATURATED_RELATIVE_OFFSET,
                                       depth, threshold.SATURATED_LEVEL)
        got = window_kernel.window_threshold(top, bottom, mean, alpha, offset, threshold.SATURATED_RELATIVE_OFFSET,
                                             depth, threshold.SATURATED_LEVEL, np.empty_like(top))
        assert np.array_equal(got, want), (offset, depth)


def test_a_kernel_that_rounds_otherwise_is_refused(monkeypatch):
    """``exact`` catches a kernel off by one level anywhere (here: the spread rounded up at .5)."""
    real = window_kernel._window_threshold

    def off(top, bottom, mean, alpha, offset, alpha_saturated, depth, saturated_level, out):
        real(top, bottom, mean, alpha, offset, alpha_saturated, depth, saturated_level, out)
        span = top.astype(np.float32) - bottom
        half = np.abs(span * alpha) % 1 == 0.5
        out[half & (out > 0)] -= 1

    monkeypatch.setattr(window_kernel, "_window_threshold", off)
    window_kernel.exact.cache_clear()
    try:
        assert not window_kernel.exact(0.1, threshold.SATURATED_RELATIVE_OFFSET)
    finally:
        window_kernel.exact.cache_clear()


def _images(rng: np.random.Generator):
    for k in range(24):
        h, w = int(rng.integers(8, 300)), int(rng.integers(8, 480))
        base = cv2.GaussianBlur(rng.integers(0, 256, (h, w), dtype=np.uint8), (0, 0), float(rng.uniform(0.5, 6)))
        img = np.clip(base.astype(np.float64) * rng.uniform(1.0, 3.0) + rng.normal(0, 4, (h, w)), 0, 255)
        if k % 3 == 0:  # clipped: windows at the saturated level
            img[img > 200] = 255
        yield img.astype(np.uint8)


@pytest.mark.parametrize("window", [51, 23, 9])
def test_dark_box_with_and_without_the_kernel(monkeypatch, window):
    """``_dark_box`` on a 4x image with its coarse level: the same binary image and box as the OpenCV calls."""
    rng = np.random.default_rng(window)
    opts = DetectOptions(threshold_window_px=window)
    for coarse in _images(rng):
        img8 = cv2.resize(coarse, (coarse.shape[1] * 4, coarse.shape[0] * 4), interpolation=cv2.INTER_CUBIC)
        img8 = np.clip(img8.astype(np.int64) + rng.integers(-6, 7, img8.shape), 0, 255).astype(np.uint8)
        offset, depth = float(rng.uniform(3, 24)), float(rng.uniform(1, 24))
        binary, box = threshold._dark_box(img8, coarse, offset, opts, threshold._WorkImages(), depth)
        got = binary.copy(), box
        with monkeypatch.context() as m:
            m.setattr(window_kernel, "exact", lambda *a: False)
            binary, box = threshold._dark_box(img8, coarse, offset, opts, threshold._WorkImages(), depth)
        assert box == got[1] and np.array_equal(binary, got[0])


@pytest.mark.parametrize("window", [51, 23, 9])
def test_dark_box_without_a_coarse_level_with_and_without_the_kernel(monkeypatch, window):
    """``_dark_box`` on a level without its coarse level (the pyramid's last two): the threshold compiled gives the
    OpenCV calls' binary image and box, in a fresh image (not a work image another level may hold)."""
    rng = np.random.default_rng(window + 7)
    opts = DetectOptions(threshold_window_px=window)
    work = threshold._WorkImages()
    dark = 0
    for img8 in _images(rng):
        offset, depth = float(rng.uniform(3, 24)), float(rng.uniform(1, 24))
        binary, box = threshold._dark_box(img8, None, offset, opts, work, depth)
        again, _ = threshold._dark_box(img8, None, offset, opts, work, depth)
        assert again is not binary and not np.shares_memory(again, binary)
        with monkeypatch.context() as m:
            m.setattr(window_kernel, "exact", lambda *a: False)
            want, want_box = threshold._dark_box(img8, None, offset, opts, threshold._WorkImages(), depth)
        assert box == want_box and np.array_equal(binary, want)
        dark += bool(np.count_nonzero(binary))
    assert dark >= 12  # (most test images have dark pixels)


@pytest.mark.parametrize("alpha", [threshold.CLIPPED_RELATIVE_OFFSET, 0.1, 0.37])
def test_clipped_threshold_on_every_pair_as_opencv(alpha):
    """``_clipped_dark_box``'s coarse threshold compiled: every (top, mean) pair, depths from 0 to past 255."""
    assert window_kernel.clipped_exact(alpha)
    top = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 256, 1)
    mean = np.ascontiguousarray(top.T)
    for depth in (0.0, 1.0, 2.5, 3.5, 8.0, 24.4, 254.0, 300.0):
        want = window_kernel.clipped_reference(top, mean, alpha, depth, threshold.SATURATED_LEVEL)
        got = window_kernel.clipped_threshold(top, mean, alpha, depth, threshold.SATURATED_LEVEL, np.empty_like(top))
        assert np.array_equal(got, want), depth


def test_window_statistics_are_remembered_only_for_the_same_image():
    """``_WorkImages.top_and_mean`` gives OpenCV's dilate and blur, again for an equal image (held by a copy), and
    computes them anew once the image (the same buffer) changes."""
    rng = np.random.default_rng(5)
    work = threshold._WorkImages()
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (13, 13))
    src = rng.integers(0, 256, (60, 90), dtype=np.uint8)
    for step in range(4):
        top, mean = work.top_and_mean(src, 13, kernel)
        assert np.array_equal(top, cv2.dilate(src, kernel, borderType=cv2.BORDER_REPLICATE))
        assert np.array_equal(mean, cv2.blur(src, (13, 13), borderType=cv2.BORDER_REPLICATE))
        again = work.top_and_mean(src, 13, kernel)
        assert again[0] is top and again[1] is mean
        src[int(rng.integers(0, 60)), int(rng.integers(0, 90))] ^= 1 << step  # in place: the same buffer


@pytest.mark.parametrize("window", [51, 23])
def test_clipped_dark_box_with_and_without_the_kernels(monkeypatch, window):
    """``_clipped_dark_box`` after ``_dark_box`` on the same level (statistics remembered, threshold compiled):
    the same binary image and box as with OpenCV's calls alone."""
    rng = np.random.default_rng(window + 1)
    opts = DetectOptions(threshold_window_px=window)
    for coarse in _images(rng):
        img8 = cv2.resize(coarse, (coarse.shape[1] * 4, coarse.shape[0] * 4), interpolation=cv2.INTER_CUBIC)
        work = threshold._WorkImages()
        threshold._dark_box(img8, coarse, 8.0, opts, work, 3.0)
        binary, box = threshold._clipped_dark_box(img8, coarse, 3.0, opts, work)
        got = binary.copy(), box
        with monkeypatch.context() as m:
            m.setattr(window_kernel, "clipped_exact", lambda *a: False)
            binary, box = threshold._clipped_dark_box(img8, coarse, 3.0, opts, threshold._WorkImages())
        assert box == got[1] and np.array_equal(binary, got[0])
