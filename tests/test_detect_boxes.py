"""The dark pixels' bounding box found by the upsampled-threshold pass, and the closings computed over it alone:
the same images bit for bit as the plain OpenCV calls."""

import cv2
import numpy as np
import pytest

from livetrack.estimator.detect.threshold import _DISK7, _KERNEL3, _closed, _WorkImages
from livetrack.estimator.detect.upsample_kernel import box_of, dark_and_box, dark_by_upsampled_threshold


def _bounding(binary: np.ndarray) -> tuple[int, int, int, int]:
    x, y, w, h = cv2.boundingRect(binary)
    return (x, y, x + w, y + h) if w else (0, 0, 0, 0)


def _sparse(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """A binary image (0 / 255): empty, full, a pixel, or a few blobs and specks anywhere (on the edges too)."""
    h, w = shape
    kind = int(rng.integers(0, 6))
    img = np.zeros(shape, np.uint8)
    if kind == 0:
        return img
    if kind == 1:
        img[:] = 255
        return img
    if kind == 2:
        img[int(rng.integers(0, h)), int(rng.integers(0, w))] = 255
        return img
    for _ in range(int(rng.integers(1, 6))):
        cx, cy = int(rng.integers(0, w)), int(rng.integers(0, h))
        cv2.ellipse(img, (cx, cy), (int(rng.integers(1, 12)), int(rng.integers(1, 12))), float(rng.uniform(0, 180)),
                    0, 360, 255, int(rng.choice([-1, 1, 2])))
    img[rng.random(shape) < 0.002 * kind] = 255
    if kind == 5:  # gaps of one or two pixels for the closing to fill
        img[:, int(rng.integers(0, w)) :: 3] = 0
    return img


@pytest.mark.parametrize("shape", [(300, 480), (75, 120), (13, 250), (7, 9), (2, 3), (1, 5), (1, 1)])
def test_dark_and_box_gives_the_binary_and_its_bounding_box(shape):
    rng = np.random.default_rng(sum(shape) + 5)
    h, w = shape
    for k in range(12):
        coarse = rng.integers(0, 256, (h, w), dtype=np.uint8)
        for big in ((4 * h, 4 * w), (4 * h + 1, 4 * w + 3)):
            img = rng.integers(0, 256, big, dtype=np.uint8)
            if k % 4 == 0:
                img[:] = 255  # nothing dark
            elif k % 4 == 1:  # dark pixels only here and there
                img[rng.random(big) > 0.002] = 255
            elif k % 4 == 2:  # a dark pixel in a corner or on an edge
                img[:] = 255
                img[int(rng.choice([0, big[0] - 1])), int(rng.integers(0, big[1]))] = 0
            want = cv2.compare(img, cv2.resize(coarse, big[::-1], interpolation=cv2.INTER_LINEAR), cv2.CMP_LE)
            got, box = dark_and_box(img, coarse, np.full_like(img, 7))
            assert np.array_equal(got, want), (shape, k, big)
            assert box == _bounding(want) == box_of(want), (shape, k, big, box)
            assert np.array_equal(dark_by_upsampled_threshold(img, coarse, np.full_like(img, 9)), want)


def test_closing_over_the_box_is_the_closing_of_the_image():
    """One set of work images through calls of changing shapes and boxes (inside the last, beside it, empty,
    after a new store): each result equals ``cv2.morphologyEx`` over the whole image, zeros included."""
    rng = np.random.default_rng(7)
    work = _WorkImages()
    shapes = [(120, 160), (120, 160), (60, 80), (120, 160), (1, 1), (3, 40), (200, 260), (120, 160)]
    for k in range(240):
        shape = shapes[k % len(shapes)] if k % 5 else (int(rng.integers(1, 90)), int(rng.integers(1, 90)))
        binary = _sparse(rng, shape)
        for kernel, name in ((_KERNEL3, "closed"), (_DISK7, "wide")):
            want = cv2.morphologyEx(binary, cv2.MORPH_CLOSE, kernel)
            got = _closed(binary, _bounding(binary), kernel, name, work)
            assert got.shape == binary.shape
            assert np.array_equal(got, want), (k, shape, name)
