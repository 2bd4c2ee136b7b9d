"""``levels._child_seen``: a nested ring in a pair's inner disk (then the pair is not its design's deepest level),
on drawn targets seen face-on."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from livetrack.estimator.detect.geometry import _Entry
from livetrack.estimator.detect.levels import _child_seen
from livetrack.targets.spec import TargetSpec

BLACK, WHITE = 100.0, 3000.0


def _drawn(outer_px: float, child_level: float | None, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """A 12-bit-like image of a pair seen face-on at the centre (outer radius ``outer_px``): its black ring, white
    inner disk (0.4 R) and, with ``child_level`` (its black's share of the contrast above BLACK), a nested ring of
    the default design inside (0.2 R, its inner disk 0.08 R), blurred (1 px)."""
    size = int(4 * outer_px)
    img = np.full((size, size), WHITE, np.float32)
    c = (size // 2, size // 2)
    scale = 16  # cv2.circle's shift: sub-pixel radii
    def disk(r_px: float, value: float) -> None:
        cv2.circle(img, (c[0] * scale, c[1] * scale), int(round(r_px * scale)), value, -1, cv2.LINE_AA, 4)
    disk(outer_px, BLACK)
    disk(0.4 * outer_px, WHITE)
    if child_level is not None:
        disk(0.2 * outer_px, BLACK + child_level * (WHITE - BLACK))
        disk(0.08 * outer_px, WHITE)
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    if noise:
        img = img + np.random.default_rng(seed).normal(0.0, noise * (WHITE - BLACK), img.shape).astype(np.float32)
    return img


@pytest.mark.parametrize("outer_px", [25.0, 60.0])
def test_a_nested_ring_is_seen_and_a_plain_inner_disk_is_not(outer_px):
    top = TargetSpec.default(1, 0.125)
    deepest = _Entry(target_id=1, level=1, spec=top.child, parent=top)
    size = int(4 * outer_px)
    H0 = np.array([[outer_px, 0.0, size // 2], [0.0, outer_px, size // 2], [0.0, 0.0, 1.0]])
    contrast = WHITE - BLACK
    for noise, seed in ((0.0, 0), (0.05, 1), (0.05, 2)):
        assert _child_seen(_drawn(outer_px, 0.0, noise, seed), H0, deepest, top, BLACK, contrast)
        assert not _child_seen(_drawn(outer_px, None, noise, seed), H0, deepest, top, BLACK, contrast)
    # lifted (over-exposure, blur) but for 0.2 of the contrast: too faint to say
    assert not _child_seen(_drawn(outer_px, 0.8), H0, deepest, top, BLACK, contrast)
    # most of it outside the image: not judged
    shifted = H0.copy()
    shifted[0, 2] = -0.1 * outer_px
    assert not _child_seen(_drawn(outer_px, 0.0), shifted, deepest, top, BLACK, contrast)
