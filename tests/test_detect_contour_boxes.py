"""The detector's contours over a box it is given (``pairs._contours(binary, box)``): the same contours, in the
same order, with the same hierarchy, as ``cv2.findContours`` of the whole image, for any box outside which the
image is zero; the closings' crops (``_WorkImages.written_box``) are such boxes."""

import cv2
import numpy as np
import pytest

from livetrack.estimator.detect.pairs import _contours
from livetrack.estimator.detect.threshold import _DISK7, _KERNEL3, _closed, _WorkImages
from livetrack.estimator.detect.upsample_kernel import box_of


def _binary(rng: np.random.Generator, h: int, w: int, k: int) -> np.ndarray:
    b = np.zeros((h, w), np.uint8)
    for _ in range(int(rng.integers(0, 6))):  # rings, disks, specks, some on the border
        at = (int(rng.integers(-10, w + 10)), int(rng.integers(-10, h + 10)))
        cv2.circle(b, at, int(rng.integers(2, 40)), 255, int(rng.choice([-1, 1, 2, 5])))
        b[int(rng.integers(0, h)), int(rng.integers(0, w))] = 255
    if k % 10 == 0:
        b[:, int(rng.integers(0, w))] = 255
    if k % 7 == 0:  # a corner pixel, a full row
        b[h - 1, w - 1] = 255
        b[int(rng.integers(0, h)), :] = 255
    return b


def _same(got, want) -> None:
    got_c, got_h = got
    want_c, want_h = want
    assert len(got_c) == len(want_c) and all(np.array_equal(g, c) for g, c in zip(got_c, want_c, strict=True))
    assert (got_h is None and want_h is None) or np.array_equal(got_h, want_h)


@pytest.mark.parametrize("seed", range(4))
def test_contours_over_a_given_box_equal_the_full_scan(seed):
    """The tight box, and boxes grown by 0-5 px on each side (past the image too), give the full scan's
    contours; so does an empty image with an empty box. Small images (which skip the box without one) too."""
    rng = np.random.default_rng(seed)
    for k in range(30):
        h, w = (int(rng.integers(20, 200)), int(rng.integers(20, 200))) if k % 3 == 0 else \
               (int(rng.integers(300, 700)), int(rng.integers(300, 700)))
        b = _binary(rng, h, w, k)
        want = cv2.findContours(b, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
        x0, y0, x1, y1 = box_of(b)
        _same(_contours(b, (x0, y0, x1, y1)), want)
        if x1 > x0:
            g = rng.integers(0, 6, 4)
            _same(_contours(b, (x0 - int(g[0]), y0 - int(g[1]), x1 + int(g[2]), y1 + int(g[3]))), want)
        _same(_contours(b), want)


@pytest.mark.parametrize("kernel", [_KERNEL3, _DISK7], ids=["3x3", "disk7"])
def test_the_closings_crop_bounds_their_dark_pixels(kernel):
    """``_closed``'s crop (``written_box``) holds every non-zero pixel of the closed image, whose contours over
    it equal the full scan's: at the image's edges too (the erosion's border there is white)."""
    rng = np.random.default_rng(11)
    work = _WorkImages()
    for k in range(40):
        b = _binary(rng, int(rng.integers(60, 400)), int(rng.integers(60, 400)), k)
        closed = _closed(b, box_of(b), kernel, "closed", work)
        x0, y0, x1, y1 = work.written_box("closed")
        inside = np.zeros(closed.shape, bool)
        inside[y0:y1, x0:x1] = True
        assert not closed[~inside].any()
        _same(_contours(closed, (x0, y0, x1, y1)), cv2.findContours(closed, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE))
