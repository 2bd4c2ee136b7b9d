"""The detector's fast paths against the plain computations they replace: equal bit for bit."""

import math
import threading
import warnings

import cv2
import numpy as np
import pytest

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect import Detector
from livetrack.estimator.detect.fits import _FIT_MEMO, _fit, _fit_once
from livetrack.estimator.detect.hole_kernel import closed_with_hole, has_hole
from livetrack.estimator.detect.levels import _row_nanmedian
from livetrack.estimator.detect.places import _dedupe_ellipses, _dedupe_pairs, _same_place
from livetrack.estimator.detect.threshold import NOISE_MIN_UNCLIPPED, NOISE_TILES, SATURATED_LEVEL, _noise
from livetrack.estimator.detect.upsample_kernel import dark_by_upsampled_threshold, is_exact_4x
from livetrack.targets.spec import TargetSpec
from tests.test_detect import homography, render


def test_row_nanmedian_is_numpys_nanmedian():
    rng = np.random.default_rng(3)
    for k in range(400):
        values = rng.normal(100.0, 50.0, (int(rng.integers(1, 60)), int(rng.integers(1, 30))))
        if k % 3 == 0:
            values = np.round(values)  # ties
        values[rng.random(values.shape) < rng.random()] = np.nan  # rows of every fill, all-NaN ones included
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows
            want = np.nanmedian(values, axis=1)
        assert np.array_equal(_row_nanmedian(values), want, equal_nan=True)


@pytest.mark.parametrize("shape", [(300, 480), (150, 240), (75, 120), (37, 61), (13, 250), (7, 9), (2, 3), (1, 5),
                                   (1, 1)])
def test_dark_by_upsampled_threshold_is_opencvs_resize_and_compare(shape):
    """Exact 4x scales (the compiled path; 1920x1200 frames meet them on levels 0-2) and others (OpenCV's)."""
    rng = np.random.default_rng(sum(shape))
    h, w = shape
    for kind in ("noise", "smooth", "near white"):
        coarse = rng.integers(0, 256, (h, w), dtype=np.uint8)
        if kind == "smooth":
            coarse = cv2.GaussianBlur(coarse, (0, 0), 2.0)
        elif kind == "near white":
            coarse[:] = rng.integers(250, 256, (h, w))
        for big in ((4 * h, 4 * w), (4 * h + 1, 4 * w + 3)):
            img = rng.integers(0, 256, big, dtype=np.uint8)
            want = cv2.compare(img, cv2.resize(coarse, big[::-1], interpolation=cv2.INTER_LINEAR), cv2.CMP_LE)
            got = dark_by_upsampled_threshold(img, coarse, np.full_like(img, 7))
            assert is_exact_4x(coarse.shape, img.shape) == (big == (4 * h, 4 * w))
            assert np.array_equal(got, want), (shape, kind, big)


def test_noise_is_the_least_tile_median_by_partition():
    """``_noise``'s order statistics by a radix sort equal the plain computation's (np.partition; the lower
    middle of each tile's sorted unclipped pairs)."""
    rng = np.random.default_rng(11)
    for k in range(40):
        h, w = int(rng.integers(20, 400)), int(rng.integers(20, 600))
        img = np.clip(rng.normal(rng.uniform(0, 255), rng.uniform(0, 30), (h, w)), 0, 255).astype(np.uint8)
        if k % 4 == 0:
            img[: h // 2] = 255  # clipped half
        step = max(1, int(np.sqrt(img.size / 20_000)))
        left, right = img[::step, 0 : w - 2 : step].astype(int), img[::step, 2:w:step].astype(int)
        diff = np.abs(right - left)
        diff[(np.maximum(left, right) >= SATURATED_LEVEL) | (np.minimum(left, right) == 0)] = 255
        rows, cols = diff.shape
        th, tw = max(rows // NOISE_TILES, 1), max(cols // NOISE_TILES, 1)
        ny, nx = rows // th, cols // tw
        tiles = diff[: ny * th, : nx * tw].reshape(ny, th, nx, tw).swapaxes(1, 2).reshape(ny * nx, th * tw)
        least = int(np.partition(tiles, (th * tw - 1) // 2, axis=1)[:, (th * tw - 1) // 2].min())
        # the median of an even count of unclipped pairs: the lower of the middle two, as _noise takes it
        fine = [int(np.sort(t[t < 255])[(np.count_nonzero(t < 255) - 1) // 2]) for t in tiles
                if np.count_nonzero(t < 255) >= max(NOISE_MIN_UNCLIPPED * t.size, 1)]
        assert _noise(img) == ((0.0 if least == 255 else least / 0.954), (min(fine) / 0.954 if fine else 0.0))


def test_remembered_fits_are_the_fits_and_last_one_call():
    rng = np.random.default_rng(2)
    _FIT_MEMO.clear()
    contours = []
    for _ in range(30):
        img = np.zeros((120, 120), np.uint8)
        cv2.ellipse(img, (60, 60), (int(rng.integers(8, 50)), int(rng.integers(8, 50))), float(rng.uniform(0, 180)),
                    0, 360, 255, -1)
        img[rng.random(img.shape) < 0.02] = 0  # ragged outlines: some fits fail
        contours += cv2.findContours(img, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)[0]
    for contour in contours:
        for offset, area in ((0.5, None), (-0.5, 100.0)):
            want = _fit_once(contour, offset, 0.2, area)
            for _ in range(2):  # computed, then remembered
                got = _fit(contour, offset, 0.2, area)
                assert (got is None) == (want is None)
                if want is not None:
                    assert np.array_equal(got.centre_px, want.centre_px)
                    assert np.array_equal(got.semi_axes_px, want.semi_axes_px)
                    assert got.angle_rad == want.angle_rad
    assert _FIT_MEMO
    Detector([TargetSpec.default(1, 0.1)]).detect(np.zeros((100, 100), np.uint8))
    assert not _FIT_MEMO


def test_detectors_in_two_threads_find_what_one_finds():
    """The fit memo is shared by every Detector: two threads detecting at once (each emptying it at every call)
    find what one thread finds alone."""
    spec = TargetSpec.default(3, 0.1)
    images = [render((360, 480), [(spec, homography((360, 480), r, (240 + 7 * k, 180), tilt_deg=20.0 * k))],
                     noise=0.01, seed=k) for k, r in enumerate((14.0, 30.0, 60.0))]

    def summary(cands):
        return [(c.target_id, c.level, *c.outer.centre_px, *c.outer.semi_axes_px, c.outer.angle_rad) for c in cands]

    want = [summary(Detector([spec]).detect(im)) for im in images]
    assert all(want)
    got: list[list] = [[], []]

    def run(slot: int) -> None:
        detector = Detector([spec])
        for _ in range(5):
            got[slot].append([summary(detector.detect(im)) for im in images])

    threads = [threading.Thread(target=run, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(rounds == want for slot in got for rounds in slot)


def test_has_hole_is_findcontours_reporting_a_hole():
    rng = np.random.default_rng(4)
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    for k in range(3000):
        binary = ((rng.random(tuple(rng.integers(1, 40, 2))) < rng.uniform(0.0, 0.9)) * 255).astype(np.uint8)
        if k % 3 == 0:  # closed crops, as the detector's retries make them
            binary = cv2.morphologyEx(binary, cv2.MORPH_CLOSE, disk, borderType=cv2.BORDER_CONSTANT, borderValue=0)
        if k % 7 == 0:
            binary = binary[1:, 2:]  # a view
        hierarchy = cv2.findContours(np.ascontiguousarray(binary), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)[1]
        want = hierarchy is not None and bool((hierarchy.reshape(-1, 4)[:, 3] >= 0).any())
        assert has_hole(binary) == want
    ring = np.zeros((9, 9), np.uint8)
    ring[2:7, 2:7] = 255
    assert not has_hole(ring)
    ring[4, 4] = 0  # one white pixel inside: a hole
    assert has_hole(ring)
    ring[4, 3] = ring[3, 3] = 0
    ring[3, 2] = 0  # joined to the outside through the edge of the dark square (4-connected): none
    assert not has_hole(ring)


def test_closed_with_hole_is_opencvs_closing_with_a_hole():
    """The bit-mask closing and hole test against ``cv2.morphologyEx`` and ``has_hole``: crops up to 64 px wide
    (the compiled path) and wider ones, views, pixels neither 0 nor 255 (OpenCV's path), the detector's disks,
    a square and an element whose rows are not centred runs."""
    rng = np.random.default_rng(21)
    odd = np.array([[1, 0, 0], [1, 1, 0], [0, 1, 1]], np.uint8)
    elements = [cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5)),
                cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7)), np.ones((3, 3), np.uint8), odd]
    compiled = 0
    for k in range(6000):
        shape = (int(rng.integers(1, 80)), int(rng.integers(1, 72)))
        binary = ((rng.random(shape) < rng.uniform(0.0, 0.95)) * 255).astype(np.uint8)
        if k % 5 == 0:
            binary = binary[1:, 2:]  # a view
        if k % 13 == 0 and binary.size:
            binary[rng.integers(binary.shape[0]), rng.integers(binary.shape[1])] = rng.integers(1, 255)
        if binary.size == 0:
            continue
        disk = elements[k % len(elements)]
        closed = cv2.morphologyEx(binary, cv2.MORPH_CLOSE, disk, borderType=cv2.BORDER_CONSTANT, borderValue=0)
        got = closed_with_hole(binary, disk)
        if has_hole(closed):
            assert got is not None and got.dtype == np.uint8 and np.array_equal(got, closed)
        else:
            assert got is None
        compiled += binary.shape[1] <= 64 and k % 4 != 3
    assert compiled > 3000


def test_dedupe_by_place_grid_is_the_test_against_every_kept_one():
    """``_dedupe_ellipses`` and ``_dedupe_pairs`` (kept places looked up in ``_PlaceGrid``) against the test of
    each ellipse with every kept one: clusters of near-duplicates, sizes from 1 px to beyond the grid (a reach
    over more squares than are filled), centres off the image."""
    rng = np.random.default_rng(21)

    def same(e, k):  # ``_dedupe_ellipses``' test (math.hypot), as it ran against every kept ellipse
        (x, y), (a, b) = e.centre_px.tolist(), e.semi_axes_px.tolist()
        (kx, ky), (ka, kb) = k.centre_px.tolist(), k.semi_axes_px.tolist()
        reach = 0.25 * min(b, kb) + 1.0
        return (abs(x - kx) <= reach and abs(y - ky) <= reach and math.hypot(x - kx, y - ky) <= reach
                and 1.0 / 1.4 <= a / ka <= 1.4)

    def plain_ellipses(ellipses):
        kept = []
        for e in ellipses:
            if not any(same(e, k) for k in kept):
                kept.append(e)
        return kept

    def plain_pairs(pairs):
        kept = []
        for pair in sorted(pairs, key=lambda p: p[0]):
            if not any(_same_place(pair[1], k[1]) for k in kept):
                kept.append(pair)
        return kept

    for _ in range(300):
        n = int(rng.integers(1, 120))
        centres = rng.uniform(-50.0, 400.0, (max(1, n // 6), 2))
        ellipses = []
        for _ in range(n):
            b = float(rng.choice([rng.uniform(1.0, 12.0), rng.uniform(12.0, 300.0)], p=[0.8, 0.2]))
            c = centres[rng.integers(len(centres))] + rng.normal(0.0, rng.choice([0.5, 3.0, 20.0]), 2)
            ellipses.append(Ellipse(c, np.array([b * rng.uniform(1.0, 1.6), b]), float(rng.uniform(0, np.pi))))
        assert [id(e) for e in _dedupe_ellipses(ellipses)] == [id(e) for e in plain_ellipses(ellipses)]
        pairs = [(int(rng.integers(0, 4)), e, e, "plain") for e in ellipses]
        assert [id(p) for p in _dedupe_pairs(pairs)] == [id(p) for p in plain_pairs(pairs)]
