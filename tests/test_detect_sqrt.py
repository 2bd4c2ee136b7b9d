"""The square-root map computed (``sqrt_kernel``): the table's 8-bit image bit for bit wherever ``exact_factor``
allows it, the first pyramid level as ``pyramid_kernel.lut16_halved``'s, and the numpy reference's arithmetic."""

import cv2
import numpy as np
import pytest

from livetrack.estimator import lut_kernel
from livetrack.estimator.detect import pyramid_kernel, sqrt_kernel
from livetrack.estimator.detect.threshold import _normalise_halved, _sqrt_factor, _sqrt_table, _WorkImages

pytestmark = pytest.mark.skipif(sqrt_kernel.numba is None, reason="the computed map needs numba")

SHAPES = [(1200 // 4, 1920 // 4), (3, 3), (3, 4), (4, 3), (5, 5), (10, 11), (37, 53), (121, 67)]


def test_the_kernel_is_its_numpy_reference_on_every_input():
    values = np.arange(65536, dtype=np.uint16)
    for full in (255.0, 1023.0, 4000.0, 4095.0, 65535.0, 3.7):
        factor = np.float32(255.0 / np.sqrt(full))
        for width in (65536, 255):
            src = np.resize(values, -(-65536 // width) * width).reshape(-1, width)
            got = np.full(src.shape, 7, np.uint8)
            assert sqrt_kernel.sqrt16(src, factor, got) == 65535
            assert np.array_equal(got, sqrt_kernel.reference(src, factor)), (full, width)


def test_exact_factor_only_where_the_map_is_the_tables():
    for full in (255.0, 1023.0, 4095.0, 16383.0, 65535.0):
        assert sqrt_kernel.exact_factor(full, _sqrt_table(full, 65536)) is not None, full
    # float32 rounds one input of full = 4000 differently from the table's float64: the table is looked up
    table = _sqrt_table(4000.0, 65536)
    assert not np.array_equal(sqrt_kernel.reference(np.arange(65536, dtype=np.uint16), 255.0 / np.sqrt(4000.0)),
                              table)
    assert sqrt_kernel.exact_factor(4000.0, table) is None and _sqrt_factor(4000.0) is None
    # a table that is not the map's is refused
    wrong = _sqrt_table(4095.0, 65536).copy()
    wrong[1234] ^= 1
    assert sqrt_kernel.exact_factor(4095.0, wrong) is None


@pytest.mark.parametrize("shape", SHAPES)
def test_sqrt16_halved_is_the_look_up_then_opencvs_pyr_down(shape):
    rng = np.random.default_rng(sum(shape) + 7)
    for full in (4095.0, 65535.0):
        table = _sqrt_table(full, 65536)
        factor = _sqrt_factor(full)
        assert factor is not None
        for src in (rng.integers(0, int(full) + 1, shape).astype(np.uint16), np.full(shape, int(full), np.uint16),
                    rng.integers(0, 65536, (shape[0] + 3, shape[1] + 5)).astype(np.uint16)[1:-2, 2:-3]):  # a view
            want = np.empty(shape, np.uint8)
            want_top = lut_kernel.lut16(src, table, want)
            alone = np.full(shape, 1, np.uint8)
            assert sqrt_kernel.sqrt16(src, factor, alone) == want_top and np.array_equal(alone, want)
            got, half = np.full(shape, 1, np.uint8), np.full(((shape[0] + 1) // 2, (shape[1] + 1) // 2), 1, np.uint8)
            assert sqrt_kernel.sqrt16_halved(src, factor, got, half) == want_top
            assert np.array_equal(got, want) and np.array_equal(half, cv2.pyrDown(want)), shape
            if pyramid_kernel.numba is not None:
                half_lut = np.empty_like(half)
                pyramid_kernel.lut16_halved(src, table, np.empty(shape, np.uint8), half_lut)
                assert np.array_equal(half, half_lut)


def test_normalise_halved_looks_the_table_up_where_the_map_is_not_exact():
    rng = np.random.default_rng(5)
    img = rng.integers(0, 4001, (40, 60)).astype(np.uint16)
    img[0, 0] = 4000
    for full in (4000.0, 4095.0):
        table = _sqrt_table(full, 65536)
        half = np.empty((20, 30), np.uint8)
        got8, _, top, halved = _normalise_halved(img, full, _WorkImages(), half)
        assert halved and np.array_equal(got8, table[img]) and top == int(table[img].max())
        assert np.array_equal(half, cv2.pyrDown(table[img]))
        got8, _, top, halved = _normalise_halved(img, full, _WorkImages(), None)
        assert not halved and np.array_equal(got8, table[img]) and top == int(table[img].max())
