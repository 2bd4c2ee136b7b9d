"""The pyramid's first level computed in the 16-to-8-bit look-up's pass (``pyramid_kernel``): the same images bit
for bit as ``lut_kernel.lut16`` then ``cv2.pyrDown``, and the same candidates as the detector halving with OpenCV."""

import pickle

import cv2
import numpy as np
import pytest

from livetrack.estimator import lut_kernel
from livetrack.estimator.detect import Detector, pyramid_kernel
from livetrack.estimator.detect import detector as detector_module
from livetrack.estimator.detect.threshold import _normalise_halved, _normalise_top, _sqrt_table, _WorkImages
from livetrack.targets.spec import TargetSpec
from tests.test_detect import homography, render

pytestmark = pytest.mark.skipif(pyramid_kernel.numba is None, reason="the compiled pyramid needs numba")

SHAPES = [(1200 // 4, 1920 // 4), (3, 3), (3, 4), (4, 3), (5, 5), (10, 11), (37, 53), (64, 96), (121, 67)]


@pytest.mark.parametrize("shape", SHAPES)
def test_pyr_down_is_opencvs(shape):
    rng = np.random.default_rng(sum(shape))
    h, w = shape
    for img in (rng.integers(0, 256, shape, dtype=np.uint8), np.full(shape, 255, np.uint8),
                (np.add.outer(np.arange(h), np.arange(w)) * 13 % 256).astype(np.uint8),
                ((rng.random(shape) < 0.5) * 255).astype(np.uint8)):
        want = cv2.pyrDown(img)
        assert np.array_equal(pyramid_kernel.pyr_down(img, np.full_like(want, 9)), want), shape


@pytest.mark.parametrize("shape", SHAPES)
def test_lut16_halved_is_the_look_up_then_opencvs_pyr_down(shape):
    rng = np.random.default_rng(sum(shape) + 1)
    table = _sqrt_table(4095.0, 65536)
    for src in (rng.integers(0, 4096, shape).astype(np.uint16), np.full(shape, 4095, np.uint16),
                rng.integers(0, 65536, (shape[0] + 3, shape[1] + 5)).astype(np.uint16)[1:-2, 2:-3]):  # a view
        want = np.empty(shape, np.uint8)
        want_top = lut_kernel.lut16(src, table, want)
        got, half = np.full(shape, 1, np.uint8), np.full(((shape[0] + 1) // 2, (shape[1] + 1) // 2), 1, np.uint8)
        assert pyramid_kernel.lut16_halved(src, table, got, half) == want_top
        assert np.array_equal(got, want) and np.array_equal(half, cv2.pyrDown(want)), shape


def test_normalise_halved_is_normalise_top_with_or_without_the_half():
    rng = np.random.default_rng(4)
    for img in (rng.integers(0, 4096, (40, 60)).astype(np.uint16), rng.integers(0, 256, (40, 60)).astype(np.uint8),
                rng.random((40, 60)).astype(np.float32), rng.integers(0, 4096, (2, 60)).astype(np.uint16)):
        want8, want_full, want_top = _normalise_top(img, None, _WorkImages())
        half = np.empty(((img.shape[0] + 1) // 2, (img.shape[1] + 1) // 2), np.uint8)
        got8, full, top, halved = _normalise_halved(img, None, _WorkImages(), half)
        assert np.array_equal(got8, want8) and (full, top) == (want_full, want_top)
        assert halved == (img.dtype == np.uint16 and min(img.shape) >= 3)
        if halved:
            assert np.array_equal(half, cv2.pyrDown(want8))


def test_the_fused_pyramid_gives_the_candidates_of_opencvs(monkeypatch):
    """16-bit frames (the fused path), of even and odd sizes, and a window of one: the same candidates, pickled,
    with the first level halved in the look-up's pass and by ``cv2.pyrDown``."""
    spec = TargetSpec.default(3, 0.1)
    frames = []
    for k, (shape, r) in enumerate((((480, 640), 14.0), ((481, 643), 30.0), ((360, 480), 60.0))):
        H = homography(shape, r, (shape[1] / 2 + 9 * k, shape[0] / 2), tilt_deg=25.0 * k)
        for gain in (1.0, 4.0):
            frames.append(render(shape, [(spec, H)], noise=0.01, seed=k, gain=gain, full=4095, dtype=np.uint16))

    def run() -> bytes:
        detector = Detector([spec])
        return pickle.dumps([detector.detect(im, saturation=4095.0) for im in frames]
                            + [detector.detect(frames[0], saturation=4095.0, roi=(100, 60, 541, 421))])

    fused = run()
    assert all(pickle.loads(fused))
    orig = detector_module._normalise_halved
    monkeypatch.setattr(detector_module, "_normalise_halved", lambda img, sat, work, half: orig(img, sat, work, None))
    assert run() == fused
