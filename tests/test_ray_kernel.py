"""The compiled ray kernel of the coarse detector's merged-ring search against its numpy reference."""

import numpy as np
import pytest

from livetrack.estimator.ray_kernel import ray_exits, ray_exits_numpy


@pytest.mark.parametrize("seed", range(6))
def test_compiled_equals_numpy_reference(seed):
    """Random binaries (blobs, noise, image borders crossed): every ray's exit equal, NaN where none."""
    rng = np.random.default_rng(seed)
    h, w = rng.integers(20, 90, 2)
    binary = np.where(rng.random((h, w)) < rng.uniform(0.3, 0.9), 255, 0).astype(np.uint8)
    t = np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False)
    frame = (rng.uniform(0, w), rng.uniform(0, h), rng.uniform(2, 9), rng.uniform(1, 5),
             np.cos(rng.uniform(0, np.pi)), 0.0)
    frame = frame[:5] + (float(np.sqrt(1.0 - frame[4] ** 2)),)
    step, count, reach, length = rng.uniform(0.05, 0.3), int(rng.integers(10, 60)), rng.uniform(1.5, 6.0), 3
    a = ray_exits(binary, frame, np.cos(t), np.sin(t), step, count, reach, length)
    b = ray_exits_numpy(binary, frame, np.cos(t), np.sin(t), step, count, reach, length)
    np.testing.assert_array_equal(a, b)


def test_exit_of_a_ring():
    """A dark ring (radii 5 to 12 px) round a white hole of radius 5: every ray leaves it at about 12 px."""
    yy, xx = np.mgrid[0:60, 0:60]
    r = np.hypot(xx - 30.0, yy - 30.0)
    binary = np.where((r > 5.0) & (r <= 12.0), 255, 0).astype(np.uint8)
    t = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
    at = ray_exits(binary, (30.0, 30.0, 5.0, 5.0, 1.0, 0.0), np.cos(t), np.sin(t), 0.05, 100, 4.0, 4)
    assert np.all(np.abs(5.0 * at - 12.0) <= 0.8)
    # Beyond reach: no exit.
    assert np.all(np.isnan(ray_exits(binary, (30.0, 30.0, 5.0, 5.0, 1.0, 0.0), np.cos(t), np.sin(t), 0.05, 100,
                                      2.0, 4)))
