"""The compiled parts of the ellipse pairs (``detect.fit_kernel``, ``detect.hole_kernel``) against their numpy
references (and the convex hull's area against OpenCV's)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect import fit_kernel, fits, hole_kernel, hole_pairs, places, small_blobs


def _ellipse_contour(rng: np.random.Generator, cx: float, cy: float, a: float, b: float, angle_deg: float):
    """A dark ellipse with noise on its edge, drawn and traced as the detector traces its blobs."""
    size = int(2 * a + 20)
    img = np.zeros((size, size), np.uint8)
    cv2.ellipse(img, ((size / 2 + cx, size / 2 + cy), (2 * a, 2 * b), angle_deg), 255, -1)
    img[rng.random(img.shape) < 0.02] ^= 255
    contours, _ = cv2.findContours(img, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    return [c for c in contours if len(c) >= 6]


def _args(contour):
    (cx, cy), (w, h), angle_deg = cv2.fitEllipse(contour)
    a, b = 0.5 * max(w, h), 0.5 * min(w, h)
    theta = math.radians(angle_deg) + (0.0 if w >= h else 0.5 * math.pi)
    return cx, cy, math.cos(theta), math.sin(theta), a, b


def test_fit_distances_match_the_reference():
    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(40):
        a = float(rng.uniform(4, 120))
        for contour in _ellipse_contour(rng, rng.uniform(-3, 3), rng.uniform(-3, 3), a, a * rng.uniform(0.2, 1),
                                        rng.uniform(0, 180)):
            args = _args(contour)
            if not (math.isfinite(args[4]) and args[5] >= 1.0):
                continue
            ref = fit_kernel.fit_distances_reference(contour, *args)
            dist, worst = fit_kernel.fit_distances(contour, *args)
            # numpy's 2x2 products go through BLAS: with FMA (x86-64 since Haswell) the same numbers bit for bit
            np.testing.assert_allclose(dist, ref, rtol=1e-13, atol=1e-13)
            assert worst == pytest.approx(max(float(ref.max()), -float(ref.min())), rel=1e-13, abs=1e-13)
            checked += 1
    assert checked >= 40


def test_fit_distances_of_points_on_the_ellipse_are_small():
    t = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    c, s, a, b = math.cos(0.3), math.sin(0.3), 40.0, 20.0
    x, y = 100 + a * np.cos(t) * c - b * np.sin(t) * s, 80 + a * np.cos(t) * s + b * np.sin(t) * c
    contour = np.rint(np.stack([x, y], axis=1)).astype(np.int32).reshape(-1, 1, 2)
    dist, worst = fit_kernel.fit_distances(contour, 100.0, 80.0, c, s, a, b)
    assert worst <= 0.75 and worst == pytest.approx(np.abs(dist).max())


def test_hull_area_is_opencv_s():
    """``fit_kernel.hull_area`` (``fits._convex``'s hull area) gives ``cv2.contourArea(cv2.convexHull(...))``'s
    float exactly, on traced noisy ellipses with holes, random blobs (thin, notched, one pixel, lines) and a few
    contours not from ``cv2.findContours`` (rows skipped, collinear points, a strided copy)."""
    rng = np.random.default_rng(8)
    contours = []
    for _ in range(40):
        a = float(rng.uniform(2, 150))
        contours += _ellipse_contour(rng, 0.0, 0.0, a, a * rng.uniform(0.1, 1), rng.uniform(0, 180))
    for _ in range(200):
        img = (rng.random((int(rng.integers(2, 90)), int(rng.integers(2, 90)))) < rng.uniform(0.05, 0.8))
        contours += cv2.findContours(img.astype(np.uint8) * 255, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)[0]
    contours += [np.array(p, np.int32).reshape(-1, 1, 2) for p in (
        [[0, 0], [10, 10], [20, 20]], [[3, 1]], [[5, 0], [0, 9], [7, 30], [12, 2]], [[0, 0], [4, 0], [9, 0], [2, 0]])]
    contours.append(np.ascontiguousarray(contours[5][::2]))
    assert len(contours) > 2000
    for contour in contours:
        got = fit_kernel.hull_area(contour)
        assert type(got) is float and got == abs(cv2.contourArea(cv2.convexHull(contour))), contour.reshape(-1, 2)


def test_dark_on_bands_match_the_reference():
    rng = np.random.default_rng(5)
    for t in range(3000):
        h, w = (int(v) for v in rng.integers(20, 200, 2))
        binary = ((rng.random((h, w)) < 0.5) * 255).astype(np.uint8)
        centre = rng.uniform(-10, (w + 10, h + 10))
        axes, angle = rng.uniform(1, 80, 2), float(rng.uniform(-4, 4))
        if t % 3 == 0:  # centres and axes on half pixels, axis-aligned or diagonal: points on rounding ties
            centre, axes = np.round(centre * 2) / 2, np.round(axes * 2) / 2 + 0.5
            angle = float(rng.choice([0.0, math.pi / 2, math.pi / 4, angle]))
        outer = Ellipse(centre, axes, angle)
        bands = (float(rng.uniform(0.3, 1.0)), 0.95, 1.2)
        assert (hole_kernel.dark_on_bands(binary, outer, bands, hole_pairs.HOLE_PAIR_ANGLES)
                == hole_kernel.dark_on_bands_reference(binary, outer, bands, hole_pairs.HOLE_PAIR_ANGLES))


def _merged_rings(rng: np.random.Generator) -> np.ndarray:
    """Dark rings (some with dark dots in their hole, some touching dark blobs), on noise: blobs with holes."""
    img = np.zeros((240, 320), np.uint8)
    for _ in range(12):
        c = (int(rng.integers(20, 300)), int(rng.integers(20, 220)))
        r = int(rng.integers(6, 40))
        cv2.ellipse(img, (c, (2 * r, int(2 * r * rng.uniform(0.5, 1))), float(rng.uniform(0, 180))), 255, -1)
        inner = (int(0.8 * r), int(0.8 * r * rng.uniform(0.4, 1)))
        cv2.ellipse(img, c, inner, float(rng.uniform(0, 180)), 0, 360, 0, -1)
        if rng.random() < 0.5:
            cv2.circle(img, (c[0] + int(rng.integers(-r, r)), c[1]), int(rng.integers(1, 4)), 255, -1)
    img[rng.random(img.shape) < 0.01] ^= 255
    return img


@pytest.mark.parametrize("cut_from", [None, 0])
def test_ring_on_outline_matches_the_reference(monkeypatch, cut_from):
    """The compiled path (its outline cut to the hole's reach first, ``hole_pairs._near_x``: every outline with
    ``cut_from`` 0) gives the numpy reference's ring, to the last bit."""
    if cut_from is not None:
        monkeypatch.setattr(hole_pairs, "NEAR_X_FROM_POINTS", cut_from)
    rng = np.random.default_rng(7)
    compared = found = 0
    for _ in range(30):
        contours, hierarchy = cv2.findContours(_merged_rings(rng), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
        hier = hierarchy.reshape(-1, 4)
        for i in np.flatnonzero((hier[:, 3] < 0) & (hier[:, 2] >= 0)):
            boxes, ref_boxes = {}, {}
            j = hier[i, 2]
            while j >= 0:
                inner = fits._fit(contours[j], -0.5, 0.1)
                if inner is not None:
                    for rho in (0.3, 0.4, 0.55):
                        got = hole_pairs._ring_on_outline(contours, hier, i, j, inner, rho, boxes)
                        near = hole_pairs._outline_near(contours, hier, i, j, inner, rho, ref_boxes)
                        ref = hole_pairs._outer_on_outline(near, inner, rho)
                        assert (got is None) == (ref is None)
                        if got is not None:
                            assert got[1] == ref[1]
                            np.testing.assert_array_equal(got[0].semi_axes_px, ref[0].semi_axes_px)
                            np.testing.assert_array_equal(got[0].centre_px, ref[0].centre_px)
                            found += 1
                        compared += 1
                j = hier[j, 0]
    assert compared >= 200 and found >= 15



@pytest.mark.skipif(hole_kernel.numba is None, reason="numba not installed")
def test_directions_seen_match_the_reference():
    rng = np.random.default_rng(11)
    scale = 16.0 / math.pi
    edges = np.arange(-16, 17) * (math.pi / 16)  # the bins' edges, and a hair either side of them
    special = np.concatenate([edges, np.nextafter(edges, 4.0), np.nextafter(edges, -4.0), [0.0, -0.0, -1e-300]])
    for k in range(300):
        n = int(rng.integers(0, 60))
        angles = np.arctan2(rng.normal(size=n), rng.normal(size=n))
        if k % 3 == 0:
            angles = np.concatenate([angles, rng.choice(special, 10)])
        got = hole_kernel.directions_seen(angles, scale)
        assert got == hole_kernel.directions_seen_reference(angles, scale)
    assert hole_kernel.directions_seen(special, scale) == hole_kernel.directions_seen_reference(special, scale) == 32
    assert hole_kernel.directions_seen(np.array([0.1, np.nan]), scale) == -1  # the caller counts in numpy then
    assert hole_kernel.directions_seen(np.array([-0.05, 0.05, 3.0]), scale) == 2  # (both of the first in bin 0)

def _textured(rng: np.random.Generator, shape=(90, 120)) -> np.ndarray:
    """An 8-bit image of smoothed noise with a few bright and dark disks (small blobs' surroundings)."""
    img = cv2.GaussianBlur(rng.integers(0, 256, shape, dtype=np.uint8), (0, 0), 2.0)
    for _ in range(6):
        cv2.circle(img, (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0]))), int(rng.integers(2, 12)),
                   int(rng.integers(0, 256)), -1)
    return img


def test_small_blob_probes_match_the_reference():
    """The compiled probes of a small blob's box (its middle, its surroundings clamped to the image, its darkest
    pixel) are the Python ones, on boxes anywhere in the image, at its edges and corners too."""
    rng = np.random.default_rng(11)
    for _ in range(40):
        img = _textured(rng)
        for _ in range(50):
            w, h = int(rng.integers(1, 40)), int(rng.integers(1, 40))
            x, y = int(rng.integers(0, img.shape[1] - w + 1)), int(rng.integers(0, img.shape[0] - h + 1))
            assert small_blobs._probes(img, (x, y, w, h)) == small_blobs._probes_reference(img, (x, y, w, h))


def test_ring_around_middle_matches_the_reference():
    """The compiled cheap test of an arc's box is the Python one, on random binary images (boxes at the edges,
    probes outside the image)."""
    from livetrack.estimator.detect import arcs

    rng = np.random.default_rng(12)
    outcomes = set()
    for _ in range(40):
        binary = np.where(_textured(rng) < 110, 255, 0).astype(np.uint8)
        for _ in range(50):
            w, h = int(rng.integers(1, 50)), int(rng.integers(1, 50))
            x, y = int(rng.integers(0, binary.shape[1] - w + 1)), int(rng.integers(0, binary.shape[0] - h + 1))
            got = arcs._ring_around_middle(binary, x, y, w, h)
            assert got == arcs._ring_around_middle_reference(binary, x, y, w, h)
            outcomes.add(got)
    assert outcomes == {True, False}


def test_the_distance_is_at_least_either_component():
    """``_places_match`` and ``_dedupe_ellipses`` test |dx| and |dy| against the reach before the distance: numpy's
    and Python's hypot are never below either component (faithful rounding), so the answers are those of the
    distance alone."""
    rng = np.random.default_rng(13)
    x = rng.normal(0.0, 1.0, 200_000) * 10.0 ** rng.integers(-3, 4, 200_000)
    y = rng.normal(0.0, 1.0, 200_000) * 10.0 ** rng.integers(-3, 4, 200_000)
    biggest = np.maximum(np.abs(x), np.abs(y))
    assert np.all(np.hypot(x, y) >= biggest)
    assert all(math.hypot(a, b) >= c for a, b, c in zip(x[:20_000].tolist(), y[:20_000].tolist(),
                                                        biggest[:20_000].tolist(), strict=True))


def test_an_outline_of_n_points_holds_at_most_n_squared_over_2_pi():
    """``_pair_of`` and ``_hole_pairs`` skip the area of a hole whose n outline points (neighbours, steps of at most
    sqrt 2 px) cannot hold enough: OpenCV's area of every contour of random blobs, holes and rings is within
    n^2 / (2 pi)."""
    rng = np.random.default_rng(14)
    checked = 0
    for _ in range(30):
        img = _merged_rings(rng)
        img[rng.random(img.shape) < 0.05] ^= 255
        contours, _ = cv2.findContours(img, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
        for c in contours:
            assert abs(cv2.contourArea(c)) <= len(c) ** 2 / (2.0 * math.pi)
            checked += 1
    assert checked > 1000


def test_same_place_is_the_distance_test():
    """``_same_place`` (plain floats, the components before the distance) answers as numpy's distance test on the
    ellipses, near the reach and the size ratio too."""
    from livetrack.estimator.conics import Ellipse

    rng = np.random.default_rng(15)
    answers = set()
    for _ in range(20_000):
        b1, b2 = rng.uniform(1.0, 30.0, 2)
        a1, a2 = b1 * rng.uniform(1.0, 3.0), b2 * rng.uniform(1.0, 3.0)
        reach = 0.25 * min(b1, b2) + 1.0
        c1 = rng.uniform(0.0, 500.0, 2)
        c2 = c1 + reach * rng.uniform(0.6, 1.2) * np.array([math.cos(t := rng.uniform(0, 2 * math.pi)), math.sin(t)])
        e1, e2 = Ellipse(c1, np.array([a1, b1]), 0.3), Ellipse(c2, np.array([a2, b2]), 1.1)
        for ratio in (1.4, 1.25):
            ref = (np.hypot(e1.centre_px[0] - e2.centre_px[0], e1.centre_px[1] - e2.centre_px[1])
                   <= 0.25 * min(e1.b, e2.b) + 1.0 and 1.0 / ratio <= e1.a / e2.a <= ratio)
            got = places._same_place(e1, e2, ratio)
            assert bool(got) == bool(ref)
            answers.add(bool(got))
    assert answers == {True, False}


def test_near_count_matches_the_reference_bit_for_bit():
    """``fit_kernel.near_count`` (``refine._sampled_start``'s count of the points near an ellipse through 5 of
    them) gives the numpy reference's count, also with the reach at a point's own distance (a last-bit
    difference would change it there)."""
    rng = np.random.default_rng(5)
    checked = 0
    for _ in range(60):
        n = int(rng.integers(8, 300))
        points = rng.normal(0.0, 1.0, (n, 2)) * rng.uniform(1, 200) + rng.uniform(0, 1500, 2)
        for _ in range(20):
            (cx, cy), (w, h), angle_deg = cv2.fitEllipse(points.astype(np.float32)[rng.choice(n, 5, replace=False)])
            if not (math.isfinite(w) and math.isfinite(h) and min(w, h) >= 2.0):
                continue
            theta = math.radians(angle_deg)
            args = (cx, cy, math.cos(theta), math.sin(theta), 0.5 * w, 0.5 * h)
            ref = np.abs(fit_kernel.fit_distances_reference(points, *args))
            for reach in (0.75 + 0.015 * math.sqrt(w * h), *ref[:4]):
                assert fit_kernel.near_count(points, *args, reach) == np.count_nonzero(ref <= reach)
                checked += 1
    assert checked >= 1000


def test_sampled_start_draws_are_the_generators():
    """``refine._samples``: the draws ``rng.choice(n, 5, replace=False)`` of a generator seeded with 0, in order."""
    from livetrack.estimator.detect import refine

    for n in (8, 64, 100):
        rng = np.random.default_rng(0)
        expected = [rng.choice(n, 5, replace=False) for _ in range(refine.EDGE_PAIR_SAMPLES)]
        np.testing.assert_array_equal(refine._samples(n), np.array(expected))
