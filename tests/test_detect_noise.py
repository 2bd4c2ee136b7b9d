"""The detector's noise figures compiled (``threshold._noise``, ``detect/noise_kernel.py``) against the numpy
they replaced (``threshold._noise_reference``): the same two figures, bit for bit, on noisy, textured, clipped,
blank and small images, and on strided views."""

import cv2
import numpy as np
import pytest

from livetrack.estimator.detect import noise_kernel, threshold

pytestmark = pytest.mark.skipif(noise_kernel.numba is None, reason="numba not installed")


def _images(rng: np.random.Generator):
    for k in range(120):
        if k < 20:
            h, w = int(rng.integers(3, 60)), int(rng.integers(3, 60))
        else:
            h, w = int(rng.integers(40, 1300)), int(rng.integers(40, 2000))
        level = rng.uniform(0, 300)
        img = np.full((h, w), level) + rng.normal(0, rng.uniform(0, 12), (h, w))
        if k % 4 == 1:  # texture over part of the frame
            tex = cv2.resize(rng.uniform(-80, 80, (max(h // 8, 1), max(w // 8, 1))), (w, h))
            img[:, : w // 2] += tex[:, : w // 2]
        if k % 4 == 2:  # clipped: over-exposed, or black
            img[rng.random((h, w)) < rng.uniform(0.1, 0.9)] = 255 if k % 8 == 2 else 0
        yield np.clip(np.rint(img), 0, 255).astype(np.uint8)


def test_the_same_figures_as_numpy():
    rng = np.random.default_rng(3)
    seen = set()
    for img in _images(rng):
        want = threshold._noise_reference(img)
        assert threshold._noise(img) == want, img.shape
        assert threshold._noise(img[1:, 3:]) == threshold._noise_reference(img[1:, 3:])  # a strided view
        seen.add(want[0] == want[1])
    assert seen == {True, False}  # some images with clipped pairs that change the second figure


def test_blank_and_saturated():
    for value in (0, 128, 255):
        img = np.full((600, 960), value, np.uint8)
        assert threshold._noise(img) == threshold._noise_reference(img)
