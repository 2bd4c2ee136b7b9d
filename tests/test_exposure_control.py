"""Target-aware auto-exposure (livetrack/exposure_control.py) in closed loop with the simulator's image formation
and the real tracker: a light level ramping 100x keeps every pose valid, steps settle in a few frames, a steady
scene makes no steps (no hunting), and scene metering without a target. Seeded, bounded."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from livetrack.config.app import load_config
from livetrack.estimator.tracker import FrameResult, Tracker
from livetrack.exposure_control import ExposureController, ExposureControlOptions
from livetrack.sim.scenario import Scenario
from tests.test_sources_aravis import fake, fake_camera, full_frame_options  # noqa: F401 - fixtures


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


def test_an_srgb_camera_is_metered_in_linear_light():
    """A webcam's values are sRGB-encoded: metered as they are, the scene's median would settle at 35 % of full
    scale ENCODED, i.e. 10 % of the light; decoded (``camera.encoding.linear_dn``), at 35 % of the light."""
    from livetrack.camera.encoding import linear_dn
    from livetrack.sim.effects import encode_dn

    full_scale = 255
    reflectance = np.random.default_rng(3).uniform(0.1, 0.9, (120, 160))

    def settle(decode):
        controller = ExposureController(full_scale, ExposureControlOptions(settle_frames=1), decode)
        exposure_us = 100.0
        for _ in range(30):
            linear = np.clip(reflectance * exposure_us * 0.5, 0, full_scale).astype(np.float32)
            image = np.rint(encode_dn(linear, 0.0, full_scale, True, None)).astype(np.uint8)
            new = controller.update(image, FrameResult(targets=[]), exposure_us)
            exposure_us = new if new is not None else exposure_us
        return np.median(np.clip(reflectance * exposure_us * 0.5, 0, full_scale)) / full_scale

    assert 0.35 / 1.15 <= settle(linear_dn("srgb", 8)) <= 0.35 * 1.15
    assert settle(None) < 0.15
    # the live pipeline's sink builds its controller so from the camera's encoding
    from livetrack.sinks.exposure_control_sink import ExposureControlSink

    class Source:
        def set_exposure(self, exposure_us=None, gain_db=None):
            return exposure_us, gain_db

    sink = ExposureControlSink(Source(), full_scale, ExposureControlOptions(), encoding="srgb")
    np.testing.assert_allclose(sink.controller.decode(np.array([0.0, 128.0, 255.0])), [0.0, 55.03, 255.0], atol=0.02)
    assert ExposureControlSink(Source(), full_scale, ExposureControlOptions()).controller.decode is None


# ---------------------------------------------------------------------------------------------- wired in
def _tracked(frame, result):
    from livetrack.sinks.base import TrackedFrame

    return TrackedFrame(sequence=0, frame=frame, result=result, stage_ms={}, handoff_ns=0, latency_ms=0.0)


def test_against_the_fake_aravis_camera(fake):  # noqa: F811 - the fixture of tests/test_sources_aravis.py
    """The sink writes the camera's exposure register and the controller acts on what it reads back: from 1/20
    of the nominal exposure the target's white comes up to the goal and every later pose is valid."""
    from livetrack.sinks.exposure_control_sink import ExposureControlSink
    from livetrack.sources import open_source
    from tests.test_sources import read_frames

    start_us = fake.nominal_exposure_us / 20
    with open_source("aravis:127.0.0.1", full_frame_options(fake, exposure_us=start_us)) as source:
        camera = source.camera
        tracker = Tracker(camera, source.targets, load_config().tracker)
        sink = ExposureControlSink(source, 2**camera.bit_depth - 1, ExposureControlOptions())
        rows = []
        for _ in range(24):
            (frame,) = read_frames(source, 1)
            result = tracker.process(frame.image, frame.exposure_us)
            sink.handle(_tracked(frame, result))
            m = sink.controller.last_metering
            rows.append((frame.exposure_us, bool(result.targets) and bool(result.targets[0].fit.ok),
                         None if m is None or m.white_dn is None else m.white_dn / (2**camera.bit_depth - 1)))
        read_back = source.set_exposure()
    exposures = [e for e, _, _ in rows]
    assert exposures[0] == pytest.approx(start_us, abs=1.0)
    assert sink.stats["exposure_changes"] >= 1 and read_back[0] == pytest.approx(exposures[-1], abs=1.0)
    assert exposures[-1] > 5 * start_us, exposures
    assert all(ok for _, ok, _ in rows[-6:]), rows
    assert 0.5 < rows[-1][2] < 0.95, rows


def test_config_section():
    from livetrack.config.checks import ConfigError

    assert load_config().exposure_control is None  # off by default
    for bad, key in [({"enabled": True, "min_exposure_us": 5e4}, "exposure_control.min_exposure_us"),
                     ({"white_goal": 1.2}, "exposure_control.white_goal"),
                     ({"black_min": 0.8}, "exposure_control.black_min"), ({"gain": 1}, "exposure_control.gain")]:
        with pytest.raises(ConfigError) as info:
            load_config(None, {"exposure_control": bad})
        assert info.value.path == key
    options = load_config(None, {"exposure_control": {"enabled": True, "white_goal": 0.6}}).exposure_control
    assert options is not None and options.white_goal == 0.6


def test_demo_tool_with_a_two_frame_camera_latency(tmp_path):
    """``python -m livetrack.tools.exposure_demo`` in small: requests that apply 2 frames late do not hunt."""
    from livetrack.tools.exposure_demo import main

    assert main(["--out", str(tmp_path / "ae.png"), "--json", str(tmp_path / "ae.json"), "--fps", "3",
                 "--seconds", "6"]) == 0
    import json

    report = json.loads((tmp_path / "ae.json").read_text())
    assert report["ok_frames"] == report["frames"] == 18
    assert report["steps"] <= 12 and (tmp_path / "ae.png").stat().st_size > 1000
