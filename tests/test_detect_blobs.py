"""``pairs._pairs``' choice of blobs compiled (``detect/blob_kernel.py``) against its numpy
(``top_blobs_reference``): the same indices, in the same order, on the hierarchies of real contours and of random
ones, with and without holes, at and around the length limit."""

import cv2
import numpy as np
import pytest

from livetrack.estimator.detect import blob_kernel

pytestmark = pytest.mark.skipif(blob_kernel.numba is None, reason="numba not installed")


def _contour_hierarchies(rng: np.random.Generator):
    for _ in range(40):
        binary = np.where(rng.random((60, 80)) < rng.uniform(0.2, 0.7), 255, 0).astype(np.uint8)
        binary = cv2.morphologyEx(binary, cv2.MORPH_OPEN, np.ones((2, 2), np.uint8))
        contours, hierarchy = cv2.findContours(binary, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
        if hierarchy is None:
            continue
        lengths = np.fromiter(map(len, contours), dtype=np.int64, count=len(contours))
        yield hierarchy.reshape(-1, 4), lengths


def test_the_same_blobs_as_numpy():
    rng = np.random.default_rng(13)
    cases = 0
    for hier, lengths in _contour_hierarchies(rng):
        for min_len in (0, 6, 12, int(np.median(lengths)), int(lengths.max()), int(lengths.max()) + 1):
            for with_hole in (True, False):
                got = blob_kernel.top_blobs(hier, lengths, min_len, with_hole)
                want = blob_kernel.top_blobs_reference(hier, lengths, min_len, with_hole)
                assert got.dtype == want.dtype and np.array_equal(got, want)
                cases += len(want) > 0
    for _ in range(200):  # random hierarchies (parents, first children), including empty ones
        k = int(rng.integers(0, 30))
        hier = rng.integers(-1, max(k, 1), (k, 4)).astype(np.int32)
        lengths = rng.integers(0, 40, k).astype(np.int64)
        for with_hole in (True, False):
            assert np.array_equal(blob_kernel.top_blobs(hier, lengths, 12, with_hole),
                                  blob_kernel.top_blobs_reference(hier, lengths, 12, with_hole))
    assert cases > 100


def test_a_known_hierarchy():
    # 0: top, hole, long; 1: its hole; 2: top, no hole, long; 3: top, hole, short; 4: top, no hole, short
    hier = np.array([[2, -1, 1, -1], [-1, -1, -1, 0], [3, 0, -1, -1], [4, 2, 5, -1], [-1, 3, -1, -1],
                     [-1, -1, -1, 3]], np.int32)
    lengths = np.array([20, 15, 30, 5, 4, 3], np.int64)
    assert blob_kernel.top_blobs(hier, lengths, 12, True).tolist() == [0]
    assert blob_kernel.top_blobs(hier, lengths, 12, False).tolist() == [2]
    assert blob_kernel.top_blobs(hier, lengths, 4, True).tolist() == [0, 3]
    assert blob_kernel.top_blobs(hier, lengths, 4, False).tolist() == [2, 4]
