"""``refine.outer_edge_seen``: where the image shows a ring's outer edge, independent of any threshold."""

from __future__ import annotations

import cv2
import numpy as np

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect.refine import outer_edge_seen


def _ring(size: int, outer_px: float, inner_px: float, ground: float) -> np.ndarray:
    """A blurred black disk with a white inner disk on a ground of ``ground`` (8-bit levels, float32)."""
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    c = 0.5 * (size - 1)
    r = np.hypot(xx - c, yy - c)
    img = np.where(r <= outer_px, 20.0, ground)
    img = np.where(r <= inner_px, 230.0, img)
    return cv2.GaussianBlur(img.astype(np.float32), (0, 0), 1.0)


def test_edge_found_where_the_image_shows_it():
    img = _ring(101, 20.0, 8.0, 150.0)
    c = np.array([50.0, 50.0])
    inner = Ellipse(c, np.array([8.0, 8.0]), 0.0)
    share, k = outer_edge_seen(img, Ellipse(c, np.array([23.0, 23.0]), 0.0), inner)  # 15 % too large
    assert share == 1.0
    assert abs(23.0 * k - 20.0) < 0.6  # the radius sampled every 0.025 of it (0.6 px here)


def test_edge_merged_with_dark_ground_on_one_side_is_seen_on_the_others():
    img = _ring(101, 20.0, 8.0, 150.0)
    img[:, :40] = np.minimum(img[:, :40], 25.0)  # dark texture joined to the ring's left
    c = np.array([50.0, 50.0])
    share, k = outer_edge_seen(img, Ellipse(c, np.array([20.0, 20.0]), 0.0), Ellipse(c, np.array([8.0, 8.0]), 0.0))
    assert 0.5 <= share < 0.9
    assert abs(20.0 * k - 20.0) < 0.6


def test_no_edge_in_dark_ground():
    img = _ring(101, 20.0, 8.0, 25.0)  # the ground as dark as the ring: a bright hole in dark texture
    rng = np.random.default_rng(3)
    img += rng.normal(0.0, 6.0, img.shape).astype(np.float32)
    c = np.array([50.0, 50.0])
    share, _ = outer_edge_seen(img, Ellipse(c, np.array([20.0, 20.0]), 0.0), Ellipse(c, np.array([8.0, 8.0]), 0.0))
    assert share < 0.3
