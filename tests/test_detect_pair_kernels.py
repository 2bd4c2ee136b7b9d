"""The compiled parts of the ellipse pairs (``detect.fit_kernel``, ``detect.hole_kernel``) against their numpy
references (and the convex hull's area against OpenCV's)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect import fit_kernel, hole_kernel, pairs


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
    """``fit_kernel.hull_area`` (``pairs._convex``'s hull area) gives ``cv2.contourArea(cv2.convexHull(...))``'s
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
        assert (hole_kernel.dark_on_bands(binary, outer, bands, pairs.HOLE_PAIR_ANGLES)
                == hole_kernel.dark_on_bands_reference(binary, outer, bands, pairs.HOLE_PAIR_ANGLES))


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


def test_ring_on_outline_matches_the_reference():
    rng = np.random.default_rng(7)
    compared = found = 0
    for _ in range(30):
        contours, hierarchy = cv2.findContours(_merged_rings(rng), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
        hier = hierarchy.reshape(-1, 4)
        for i in np.flatnonzero((hier[:, 3] < 0) & (hier[:, 2] >= 0)):
            boxes, ref_boxes = {}, {}
            j = hier[i, 2]
            while j >= 0:
                inner = pairs._fit(contours[j], -0.5, 0.1)
                if inner is not None:
                    for rho in (0.3, 0.4, 0.55):
                        got = pairs._ring_on_outline(contours, hier, i, j, inner, rho, boxes)
                        ref = pairs._outer_on_outline(pairs._outline_near(contours, hier, i, j, inner, rho,
                                                                          ref_boxes), inner, rho)
                        assert (got is None) == (ref is None)
                        if got is not None:
                            assert got[1] == ref[1]
                            np.testing.assert_array_equal(got[0].semi_axes_px, ref[0].semi_axes_px)
                            np.testing.assert_array_equal(got[0].centre_px, ref[0].centre_px)
                            found += 1
                        compared += 1
                j = hier[j, 0]
    assert compared >= 200 and found >= 15
