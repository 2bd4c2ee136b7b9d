"""The compiled residual check of an ellipse fit (``detect.fit_kernel``) against its numpy reference."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from livetrack.estimator.detect import fit_kernel


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
