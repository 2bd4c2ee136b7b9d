"""The code of a small, heavily blurred pair read against the blurred hypotheses (``detect.blurred``)."""

from __future__ import annotations

import cv2
import numpy as np

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect import Detector
from livetrack.estimator.detect import blurred as blurred_code
from livetrack.estimator.detect.geometry import _geometry_groups
from livetrack.estimator.target_map import centre_homography
from livetrack.targets.spec import TargetSpec
from tests.sweep_frames import sweep_frame


def test_a_small_blurred_target_is_read_by_its_blurred_code():
    """Seed 3's optics-006 at x1: id 1 (two dots) of 11.6 px semi-minor axis on foliage, a PSF of ~2.5 px; its
    black bands read 0.54-0.62 of the contrast, its dots 0.39-0.57: refused as "black bands not dark" at every
    exposure before. Its code fits the image 1.7x better than any other code or rotation."""
    scenario, image = sweep_frame(3, "optics-006", 1.0)
    truth = scenario.camera.project(scenario.truth_for(0)[1].t[None, :])[0]
    found = Detector(scenario.targets).detect(image, saturation=float(scenario.camera.saturation_level))
    assert [(c.target_id, c.level) for c in found] == [(1, 0)]
    assert np.hypot(*(found[0].outer.centre_px - truth)) < 1.0
    assert found[0].code_margin == 0.0  # the blurred reading, ranked below every clean one


def _blurred_ring(bits: str | None, sigma_px: float, radius_px: float = 11.0) -> tuple[np.ndarray, Ellipse, Ellipse]:
    """A grey image (black 20, white 200, ground 150) of a ring of the default geometry with the code ``bits`` (none:
    no dots) at 3x oversampling, area-averaged and blurred by ``sigma_px``; its outer and inner circles."""
    size, over = 64, 3
    c = (size - 1) / 2.0
    ys, xs = np.mgrid[0 : size * over, 0 : size * over]
    x, y = (xs + 0.5) / over - 0.5 - c, (ys + 0.5) / over - 0.5 - c
    r = np.hypot(x, y) / radius_px
    white = (r < 0.4) | (r >= 1.0)
    white &= ~((r >= 0.08) & (r < 0.2))  # the child's black ring
    if bits is not None:
        for j, bit in enumerate(bits):
            a = 2.0 * np.pi * j / len(bits)
            if bit == "1":
                white |= np.hypot(x / radius_px - 0.7 * np.cos(a), y / radius_px - 0.7 * np.sin(a)) < 0.1
    level = np.where(white, 200.0, 20.0)
    level[r >= 1.0] = 150.0
    img = level.reshape(size, over, size, over).mean(axis=(1, 3))
    img = cv2.GaussianBlur(img, (0, 0), sigma_px).astype(np.float32)
    centre = np.array([c, c])
    outer = Ellipse(centre, np.array([radius_px, radius_px]), 0.0)
    return img, outer, Ellipse(centre, 0.4 * outer.semi_axes_px, 0.0)


def _read(img: np.ndarray, outer: Ellipse, inner: Ellipse) -> tuple[str, int] | str:
    groups = _geometry_groups([TargetSpec.default(i, 0.125) for i in (1, 3, 5, 8, 12)])
    (g, entries), = groups.items()
    return blurred_code.read_blurred_code(img, centre_homography(outer, inner), g, entries, 0.0, 4095.0)


def test_the_blurred_reading_gives_the_drawn_code_and_refuses_a_plain_ring():
    """A drawn 11 px id 1 blurred by 2.5 px reads as id 1 at rotation 0; the same ring without dots (an uncoded
    decoy) reads as none."""
    img, outer, inner = _blurred_ring("00000101", 2.5)
    assert _read(img, outer, inner) == ("00000101", 0)  # slot j (at 2 pi j / 8 from +x) holds bit j
    img, outer, inner = _blurred_ring(None, 2.5)
    assert isinstance(_read(img, outer, inner), str)
