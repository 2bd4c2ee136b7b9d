"""The full-resolution blur computed inside the threshold's comparison (``blur_kernel``): the same images bit for
bit as ``cv2.GaussianBlur`` then the comparison, and the same candidates as the detector with OpenCV's blur."""

import pickle

import cv2
import numpy as np
import pytest

from livetrack.estimator.detect import Detector, blur_kernel
from livetrack.estimator.detect import detector as detector_module
from livetrack.estimator.detect.options import DetectOptions
from livetrack.estimator.detect.threshold import _blurred_for_noise, _fused_blur, _noise, _noise_step
from livetrack.estimator.detect.upsample_kernel import dark_and_box
from livetrack.targets.spec import TargetSpec
from tests.test_detect import homography, render

pytestmark = pytest.mark.skipif(blur_kernel.numba is None, reason="the compiled blur needs numba")


def _images(rng: np.random.Generator, shape: tuple[int, int]) -> list[np.ndarray]:
    h, w = shape
    noise = rng.integers(0, 256, shape, dtype=np.uint8)
    smooth = cv2.GaussianBlur(noise, (0, 0), 3.0)
    return [noise, smooth, np.full(shape, 255, np.uint8), np.zeros(shape, np.uint8),
            ((rng.random(shape) < 0.5) * 255).astype(np.uint8),
            (np.add.outer(np.arange(h), np.arange(w)) * 7 % 256).astype(np.uint8)]


@pytest.mark.parametrize("sigma", [0.8, 0.5, 1.0, 0.3])
@pytest.mark.parametrize("shape", [(1200 // 8, 1920 // 8), (2, 2), (2, 9), (9, 2), (3, 3), (37, 61), (64, 255)])
def test_compiled_blur_is_opencvs(shape, sigma):
    taps = blur_kernel.kernel_taps(sigma)
    if sigma == 0.8:
        assert taps == (61, 134)
    if taps is None:  # OpenCV's own rounding of this kernel: the detector then calls it
        return
    rng = np.random.default_rng(sum(shape))
    for img in _images(rng, shape):
        got = np.full_like(img, 17)
        blur_kernel.blur_rows(img, got, 1, *taps)
        assert np.array_equal(got, blur_kernel.reference(img, sigma)), (shape, sigma)
        rows = np.full_like(img, 17)
        blur_kernel.blur_rows(img, rows, 3, *taps)  # every third row only, the others untouched
        assert np.array_equal(rows[::3], got[::3]) and (rows[np.arange(shape[0]) % 3 != 0] == 17).all()


@pytest.mark.parametrize("shape", [(300, 480), (75, 120), (13, 250), (2, 3), (1, 5), (1, 1)])
def test_dark_and_box_blurring_first_is_opencvs_blur_then_the_comparison(shape):
    rng = np.random.default_rng(sum(shape) + 1)
    h, w = shape
    for img in _images(rng, (4 * h, 4 * w)):
        for coarse in (rng.integers(0, 256, shape, dtype=np.uint8), cv2.pyrDown(cv2.pyrDown(img))):
            if coarse.shape != shape:
                continue
            blur = _fused_blur(img, coarse, 0.8)
            if min(img.shape) < 2:
                assert blur is None
                continue
            assert blur is not None
            smooth = cv2.GaussianBlur(img, (3, 3), 0.8)
            want, want_box = dark_and_box(smooth, coarse, np.empty_like(img))
            into = np.full_like(img, 3)
            got, got_box = dark_and_box(into, coarse, np.empty_like(img), blur)
            assert np.array_equal(into, smooth) and np.array_equal(got, want) and got_box == want_box


def test_the_rows_blurred_for_the_noise_give_its_figures():
    rng = np.random.default_rng(5)
    for shape in ((1200, 1920), (600, 960), (300, 480), (37, 64)):
        img = np.clip(rng.normal(120, 9, shape), 0, 255).astype(np.uint8)
        coarse = np.zeros((shape[0] // 4, shape[1] // 4), np.uint8)
        blur = _fused_blur(img, coarse, 0.8) if shape[0] % 4 == 0 and shape[1] % 4 == 0 else None
        if blur is None:
            continue
        rows = _blurred_for_noise(blur, np.full_like(img, 255))
        step = _noise_step(img)
        assert _noise(rows) == _noise(cv2.GaussianBlur(img, (3, 3), 0.8))
        assert (rows[np.arange(shape[0]) % step != 0] == 255).all()


def test_the_fused_blur_gives_the_candidates_of_opencvs(monkeypatch):
    """Frames of 4x-divisible and other sizes (the fused path and OpenCV's), with small targets that the
    full-resolution level finds: the same candidates, pickled, with and without the fused blur."""
    spec = TargetSpec.default(3, 0.1)
    frames = []
    for k, (shape, r) in enumerate((((480, 640), 14.0), ((480, 640), 22.0), ((481, 643), 16.0),
                                     ((360, 480), 40.0))):
        H = homography(shape, r, (shape[1] / 2 + 9 * k, shape[0] / 2), tilt_deg=25.0 * (k % 3))
        frames.append(render(shape, [(spec, H)], noise=0.01, seed=k))
        frames.append(render(shape, [(spec, H)], noise=0.01, seed=k, gain=4.0))

    def run() -> bytes:
        detector = Detector([spec], DetectOptions())
        return pickle.dumps([detector.detect(im) for im in frames])

    fused = run()
    assert any(pickle.loads(fused))
    monkeypatch.setattr(detector_module, "_fused_blur", lambda *args: None)
    assert run() == fused


def test_rows_blurred_for_the_noise_are_not_blurred_again():
    """``_dark_box`` right after ``_blurred_for_noise`` on the same image skips the rows that hold their blur
    (``_rows_blurred``), once; the same binary image, box and blurred image as OpenCV's blur then the comparison.
    Any other image, or a second call, blurs every row."""
    from livetrack.estimator.detect import threshold

    rng = np.random.default_rng(11)
    opts = DetectOptions()
    for shape in ((1200 // 4, 1920 // 4), (64, 96), (8, 12)):
        img = np.clip(rng.normal(120, 30, shape), 0, 255).astype(np.uint8)
        coarse = cv2.pyrDown(cv2.pyrDown(img))
        blur = _fused_blur(img, coarse, 0.8)
        smooth = cv2.GaussianBlur(img, (3, 3), 0.8)
        want = threshold._dark_box(smooth, coarse, 6.0, opts, threshold._WorkImages())
        want = want[0].copy(), want[1]
        work = threshold._WorkImages()
        into = _blurred_for_noise(blur, np.full_like(img, 3), work)
        assert threshold._rows_blurred(np.full_like(img, 3), blur, work) == 0  # another image
        assert threshold._rows_blurred(into, blur, threshold._WorkImages()) == 0  # another Detector's work
        assert threshold._rows_blurred(into, blur, work) == _noise_step(img)
        _blurred_for_noise(blur, into, work)
        got = threshold._dark_box(into, coarse, 6.0, opts, work, blur=blur)
        assert np.array_equal(into, smooth) and np.array_equal(got[0], want[0]) and got[1] == want[1]
        assert threshold._rows_blurred(into, blur, work) == 0  # used once
        into[:] = 3  # nothing recorded now: every row is blurred
        got = threshold._dark_box(into, coarse, 6.0, opts, work, blur=blur)
        assert np.array_equal(into, smooth) and np.array_equal(got[0], want[0]) and got[1] == want[1]
