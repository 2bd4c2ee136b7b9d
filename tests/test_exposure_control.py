"""Target-aware auto-exposure (livetrack/exposure_control.py) in closed loop with the simulator's image formation
and the real tracker: a light level ramping 100x keeps every pose valid, steps settle in a few frames, a steady
scene makes no steps (no hunting), and scene metering without a target. Seeded, bounded."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from livetrack.app_config import load_config
from livetrack.estimator.tracker import FrameResult, Tracker
from livetrack.exposure_control import ExposureController, ExposureControlOptions
from livetrack.sim.scenario import Scenario


@functools.lru_cache(maxsize=1)
def scene():
    s = Scenario.default()
    optical = [s.formation.optical_image(s.placements_for(k)) for k in range(len(s))]
    return s, optical


def closed_loop(lights: list[float], exposure_us: float, seed: int = 0):
    """Run the tracker and the controller frame by frame; the light level scales the scene's radiance (the same
    as scaling the exposure). Returns per frame (ok, white fraction, exposure in force) and the controller."""
    s, optical = scene()
    tracker = Tracker(s.camera, s.targets, load_config().tracker)
    full_scale = 2**s.camera.bit_depth - 1
    controller = ExposureController(full_scale)
    rows = []
    for i, light in enumerate(lights):
        k = i % len(s)
        image = s.formation.render_from_optical(optical[k], exposure_us * light, s.gain_db,
                                                np.random.default_rng([seed, i]), True)
        result = tracker.process(image, exposure_us)
        ok = len(result.targets) == 1 and bool(result.targets[0].fit.ok)
        new = controller.update(image, result, exposure_us)
        m = controller.last_metering
        rows.append((ok, None if m is None or m.white_dn is None else m.white_dn / full_scale, exposure_us))
        if new is not None:
            exposure_us = new
    return rows, controller


def test_light_ramping_100x_keeps_every_pose_valid():
    n = 40  # 10 s at 4 fps: the light changes 12 % per frame (at 30 fps: 1.6 %)
    lights = [10 ** (-1 + 2 * i / (n - 1)) for i in range(n)]
    rows, controller = closed_loop(lights, Scenario.default().nominal_exposure_us)
    assert all(ok for ok, _, _ in rows), [i for i, (ok, _, _) in enumerate(rows) if not ok]
    whites = [w for _, w, _ in rows[3:]]  # once settled from the start (white at 5 % of full scale)
    assert all(w is not None and 0.5 < w < 0.95 for w in whites), whites
    exposure = np.array([e for _, _, e in rows])
    assert exposure.max() / exposure[-1] > 40  # it followed the light (100x) down
    assert controller.steps < n  # a dead band: not a step every frame


@pytest.mark.parametrize("start_factor", [1 / 30, 30.0])
def test_a_wrong_exposure_settles_in_a_few_frames_then_holds(start_factor):
    s, _ = scene()
    rows, controller = closed_loop([1.0] * 14, s.nominal_exposure_us * start_factor, seed=1)
    exposures = [e for _, _, e in rows]
    settled = next(i for i in range(len(rows)) if exposures[i:] == [exposures[i]] * (len(rows) - i))
    assert settled <= 8, exposures  # frames until the last step took effect
    assert 0.55 < rows[-1][1] < 0.85  # white near the goal (0.7), below saturation
    assert all(ok for ok, _, _ in rows[settled:])


def test_scene_metering_without_a_target():
    full_scale = 4095
    controller = ExposureController(full_scale, ExposureControlOptions(settle_frames=1))
    rng = np.random.default_rng(3)
    reflectance = rng.uniform(0.1, 0.9, (120, 160))
    exposure_us = 100.0
    for _ in range(20):  # the scene's DN are proportional to the exposure
        image = np.clip(reflectance * exposure_us * 2.0, 0, full_scale).astype(np.uint16)
        new = controller.update(image, FrameResult(targets=[]), exposure_us)
        exposure_us = new if new is not None else exposure_us
    median = np.median(np.clip(reflectance * exposure_us * 2.0, 0, full_scale)) / full_scale
    assert 0.35 / 1.15 <= median <= 0.35 * 1.15
    assert controller.update(image, FrameResult(targets=[]), None) is None  # exposure unknown: no decision
