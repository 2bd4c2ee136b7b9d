"""The compiled code-dot windows and turn search (``surround_kernels.dots_centroids``, ``dots_brightness``) against
their numpy reference (``surround_geometry.dots_scale`` and ``_dots_turn_rad`` with ``LIVETRACK_KERNELS=numpy``), on
the calls a search makes in frames of the detection sweep's scenes (distorted lenses, 8 and 16 bits, several targets,
under- and over-exposed) and on a small target's truth, a pose 6 % too near and one whose dots leave the frame."""

from __future__ import annotations

import pytest

from livetrack.estimator import edge_kernels, surround_geometry
from livetrack.estimator.detect import detect
from livetrack.estimator.tracker import Tracker
from livetrack.geometry import Pose
from tests.sweep_frames import sweep_frame
from tests.test_tracker import _small_scene


def _both(monkeypatch, fn, *args):
    """``fn(*args)`` with the compiled kernels and with the numpy reference."""
    out = []
    for choice in ("numba", "numpy"):
        monkeypatch.setenv("LIVETRACK_KERNELS", choice)
        edge_kernels.reset_kernels()
        out.append(fn(*args))
    edge_kernels.reset_kernels()
    return out


def _agree(got, ref):
    assert (got is None) == (ref is None)
    if ref is not None:
        assert abs(got - ref) < 1e-9


@pytest.mark.parametrize("seed, name, factors", [(9, "single-007", (1.0, 32.0)), (3, "multi-001", (0.25, 4.0)),
                                                 (3, "border-002", (1.0, 16.0))])
def test_the_compiled_dot_windows_are_the_numpy_reference_on_sweep_frames(seed, name, factors, monkeypatch):
    """Every ``dots_scale`` and ``white_disks`` call of a search of the frame: the same scale and turn within 1e-9."""
    calls = []
    scale, disks = surround_geometry.dots_scale, surround_geometry.white_disks

    def recorded(*args):
        calls.append(args)
        return scale(*args)

    monkeypatch.setattr(surround_geometry, "dots_scale", recorded)
    for factor in factors:
        scenario, image = sweep_frame(seed, name, factor)
        Tracker(scenario.camera, list(scenario.targets)).process(image, scenario.nominal_exposure_us * factor)
    assert calls
    found = 0
    for camera, pose, levels, frame, sigma_px in calls:
        got, ref = _both(monkeypatch, scale, camera, pose, levels, frame, sigma_px)
        _agree(got, ref)
        found += ref is not None
        got, ref = _both(monkeypatch, disks, camera, pose, levels, 2.0, sigma_px, frame)
        assert (got is None) == (ref is None)
        if ref is not None:
            assert abs(got.turn_rad - ref.turn_rad) < 1e-9
    assert found >= 1


@pytest.mark.parametrize("bits, factor", [(12, 0.25), (12, 32.0), (8, 1.0)])
def test_the_compiled_dot_windows_are_the_numpy_reference_on_a_small_target(bits, factor, monkeypatch):
    """A 50 px target: its truth (scale ~1), a pose 6 % too near (~0.94) and one moved until its dots' windows leave
    the frame (None from both)."""
    scene = _small_scene(bits, 1.5, [factor], levels=1)
    frame = scene.render_frame(0)
    truth = frame.truth[5]
    (cand,) = detect(frame.image, list(scene.targets))
    for t_m, expected in ((truth.t, 1.0), (0.94 * truth.t, 0.94), (truth.t + [0.47, 0.0, 0.0], None)):
        got, ref = _both(monkeypatch, surround_geometry.dots_scale, scene.camera, Pose(truth.R, t_m), [cand],
                         frame.image)
        _agree(got, ref)
        assert (ref is None) if expected is None else abs(ref - expected) < 0.03
