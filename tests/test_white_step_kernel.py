"""The compiled next-edge distance (``surround_kernels.white_step``) against its numpy reference
(``surround_geometry.white_step_px`` with ``LIVETRACK_KERNELS=numpy``)."""

from __future__ import annotations

import numpy as np
import pytest

from livetrack.estimator import surround_geometry
from livetrack.estimator.detect import detect
from livetrack.estimator.tracker import Tracker, group_levels
from tests.test_tracker import _small_scene


@pytest.mark.parametrize("distance_m", [3.0, 9.0])
def test_the_compiled_white_step_is_the_numpy_reference(distance_m, monkeypatch):
    """Every circle of a target (the nested ring inside its inner circle, none outside the top level; with the nested
    level, the parent's inner circle outside it), its points jittered, one circle cut to 2 points (too few: none):
    the same distances within 1e-9 px (the centres are summed in another order) and the same step flags."""
    scene = _small_scene(12, distance_m, [1.0])
    frame = scene.render_frame(0)
    (group,) = group_levels(detect(frame.image, list(scene.targets)))
    tracker = Tracker(scene.camera, list(scene.targets))
    points, normals, radius, _, _ = tracker._samples(group)
    rng = np.random.default_rng(1)
    points = points + rng.normal(0.0, 0.3, points.shape)
    cases = [(points, normals, radius)]
    radii = np.unique(radius)
    assert len(radii) >= 2
    few = radius == radii[0]
    keep = ~few | (np.cumsum(few) <= 2)
    cases.append((points[keep], normals[keep], radius[keep]))
    for case, (pts, nrm, rad) in enumerate(cases):
        out = {}
        for choice in ("numba", "numpy"):
            monkeypatch.setenv("LIVETRACK_KERNELS", choice)
            out[choice] = surround_geometry.white_step_px(pts, nrm, rad, group)
        (step, black), (ref_step, ref_black) = out["numba"], out["numpy"]
        np.testing.assert_array_equal(np.isfinite(step), np.isfinite(ref_step))
        if case == 0:
            assert np.isfinite(ref_step).sum() >= 10
        else:  # the circle cut to 2 points has no step
            assert not np.isfinite(ref_step[rad == radii[0]]).any()
        finite = np.isfinite(ref_step)
        assert np.abs(step[finite] - ref_step[finite]).max(initial=0.0) < 1e-9
        np.testing.assert_array_equal(black, ref_black)
