"""Frame sources: the URI factory, the live hand-off helpers, the simulated camera and recording replay."""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from livetrack.camera import CameraModel
from livetrack.config.checks import ConfigError
from livetrack.geometry import Pose
from livetrack.recording import RecordingWriter
from livetrack.sim.scenario import Scenario
from livetrack.sources import Backoff, LatestSlot, make_source, open_source
from livetrack.sources.base import Frame, SourceError
from livetrack.sources.replay import ReplaySource
from livetrack.sources.sim_source import SimSource
from livetrack.targets.spec import TargetSpec

TINY_SCENARIO = """
name: tiny
seed: 3
camera: {width: 160, height: 120, fx: 150, fy: 150, cx: 79.5, cy: 59.5, bit_depth: 12}
scene: {supersampling: 4}
targets: [{id: 3, outer_radius_m: 0.125}]
poses:
  - {t_m: [0.0, 0.0, 2.0]}
  - {t_m: [0.05, 0.0, 1.8], tilt_deg: 20}
exposure: {nominal_us: 1000, factors: [0.5, 2]}
timing: {fps: FPS}
"""


def tiny_scenario(tmp_path: Path, fps: float = 50.0) -> Path:
    path = tmp_path / "tiny.yaml"
    path.write_text(TINY_SCENARIO.replace("FPS", str(fps)))
    return path


def frame(i: int) -> Frame:
    return Frame(np.zeros((2, 2), np.uint8), i, i, i, 100.0, 0.0)


# ---------------------------------------------------------------------- factory
@pytest.mark.parametrize("uri, match", [
    ("nothing", "must be a URI"),
    ("ftp:somewhere", "unknown scheme 'ftp'"),
    ("replay:", "needs a directory"),
    ("v4l2:", "needs a device path"),
])
def test_factory_rejects_bad_uris(uri: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        make_source(uri)


@pytest.mark.parametrize("uri", ["sim:", "replay:some/dir", "aravis:", "v4l2:/dev/video0"])
def test_factory_rejects_unknown_options_by_name(uri: str) -> None:
    with pytest.raises(ConfigError, match="source.exposure_ms: unknown key"):
        make_source(uri, {"exposure_ms": 3})


def test_factory_checks_option_values() -> None:
    with pytest.raises(ConfigError, match="source.pace: must be one of"):
        make_source("replay:x", {"pace": "slow"})
    with pytest.raises(ConfigError, match="source.roi: must have 4 numbers"):
        make_source("aravis:", {"roi": [0, 0, 10]})
    with pytest.raises(ConfigError, match="source.pixel_format: must be one of"):
        make_source("aravis:", {"pixel_format": "Mono12Packed"})


def test_missing_files_raise_source_error(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match="no such scenario file"):
        open_source(f"sim:{tmp_path / 'none.yaml'}")
    with pytest.raises(SourceError, match="not a recording"):
        open_source(f"replay:{tmp_path}")


# ---------------------------------------------------------------------- helpers
def test_latest_slot_keeps_the_newest_frame_and_counts_drops() -> None:
    slot = LatestSlot()
    assert slot.get(0.01) is None
    for i in range(3):
        slot.put(frame(i))
    got = slot.get(0.01)
    assert got is not None and got.frame_id == 2
    assert slot.dropped == 2
    assert slot.get(0.01) is None


def test_latest_slot_wakes_a_waiting_reader() -> None:
    slot = LatestSlot()
    threading.Timer(0.05, slot.put, args=(frame(7),)).start()
    started = time.monotonic()
    got = slot.get(2.0)
    assert got is not None and got.frame_id == 7
    assert time.monotonic() - started < 1.0
    slot.close()
    assert slot.get(2.0) is None  # closed and empty: at once


def test_backoff_doubles_up_to_the_cap_and_resets() -> None:
    backoff = Backoff(0.5, 3.0)
    assert [backoff.next_delay_s() for _ in range(5)] == [0.5, 1.0, 2.0, 3.0, 3.0]
    backoff.reset()
    assert backoff.next_delay_s() == 0.5


def read_to_end(source) -> tuple[list[float], list]:
    """Read a finite source until EOFError: (monotonic arrival times, frames); no read may time out."""
    arrivals, frames = [], []
    while True:
        try:
            f = source.read(1.0)
        except EOFError:
            return arrivals, frames
        assert f is not None
        arrivals.append(time.monotonic())
        frames.append(f)


def read_frames(source, n: int, timeout_s: float = 5.0, poll_s: float = 0.5) -> list:
    """The next n frames of a live source (reads that time out are retried), failing after ``timeout_s``."""
    frames = []
    deadline = time.monotonic() + timeout_s
    while len(frames) < n:
        assert time.monotonic() < deadline, f"only {len(frames)} of {n} frames in {timeout_s} s"
        frame = source.read(poll_s)
        if frame is not None:
            frames.append(frame)
    return frames


# ---------------------------------------------------------------------- sim
def test_sim_fast_loops_the_scenario_with_truth_and_changing_exposure(tmp_path: Path) -> None:
    path = tiny_scenario(tmp_path)
    scenario = Scenario.from_file(path)
    with open_source(f"sim:{path}", {"realtime": False, "max_frames": 10}) as source:
        assert not source.live
        assert source.camera == scenario.camera and [t.id for t in source.targets] == [3]
        frames = [source.read() for _ in range(10)]
        with pytest.raises(EOFError):
            source.read()
        assert source.stats["frames"] == 10
    assert [f.frame_id for f in frames] == list(range(10))
    assert [f.exposure_us for f in frames[:4]] == [500.0, 2000.0, 500.0, 2000.0]
    assert [f.meta["scenario_frame"] for f in frames] == [0, 1, 2, 3, 0, 1, 2, 3, 0, 1]
    # timestamps keep increasing across loops at the scenario's fps
    assert np.all(np.diff([f.timestamp_ns for f in frames]) == 20_000_000)
    # the target moves: the truth follows the pose steps, and the image changes with it
    assert np.allclose(frames[0].truth[3].t, [0.0, 0.0, 2.0]) and np.allclose(frames[2].truth[3].t, [0.05, 0, 1.8])
    assert frames[1].image.dtype == np.uint16 and frames[1].image.shape == (120, 160)
    assert frames[1].image.mean() > 3 * frames[0].image.mean()  # 4x the exposure, same pose
    # a loop renders the same scene with fresh noise
    assert not np.array_equal(frames[0].image, frames[4].image)
    assert abs(float(frames[0].image.mean()) - float(frames[4].image.mean())) < 2.0


def test_sim_prerender_repeats_one_loop_of_frames_unless_the_exposure_is_overridden(tmp_path: Path) -> None:
    with open_source(f"sim:{tiny_scenario(tmp_path)}", {"realtime": False, "prerender": True}) as source:
        frames = [source.read() for _ in range(5)]
        assert np.array_equal(frames[0].image, frames[4].image)  # the same pixels, loop after loop
        assert frames[0].image is not frames[4].image and frames[4].image.flags.writeable
        assert [f.frame_id for f in frames] == list(range(5)) and frames[4].exposure_us == frames[0].exposure_us
        source.set_exposure(exposure_us=1000.0)
        rendered = source.read()
        assert rendered.exposure_us == 1000.0 and not np.array_equal(rendered.image, frames[1].image)


def test_sim_realtime_paces_frames_at_the_scenario_fps(tmp_path: Path) -> None:
    path = tiny_scenario(tmp_path, fps=25.0)
    source = SimSource(Scenario.from_file(path), realtime=True, max_frames=13)
    source.open()
    try:
        assert source.live
        arrivals, frames = read_to_end(source)
        ids = [f.frame_id for f in frames]
    finally:
        source.close()
    assert ids == list(range(13))  # read promptly: nothing dropped
    period = np.diff(arrivals[1:])  # the first frame includes the first render
    assert 0.030 < np.median(period) < 0.050, period  # 25 fps (loose: the CI machine may be busy)
    assert source.stats["dropped"] == 0


def test_sim_realtime_drops_unread_frames(tmp_path: Path) -> None:
    source = SimSource(Scenario.from_file(tiny_scenario(tmp_path, fps=100.0)), realtime=True, max_frames=30)
    with source:
        time.sleep(0.5)
        ids = []
        while True:
            try:
                f = source.read(1.0)
            except EOFError:
                break
            ids.append(f.frame_id)
    assert ids[-1] == 29
    assert source.stats["dropped"] >= 20
    assert source.stats["frames"] == 30


def test_sim_reports_rendering_slower_than_the_fps(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    source = SimSource(Scenario.from_file(tiny_scenario(tmp_path, fps=400.0)), realtime=True, max_frames=6)
    original = source._render

    def slow_render(i: int) -> Frame:
        time.sleep(0.02)  # 20 ms per frame against a 2.5 ms period
        return original(i)

    source._render = slow_render  # type: ignore[method-assign]
    with caplog.at_level(logging.WARNING), source:
        count = 0
        while True:
            try:
                count += source.read(1.0) is not None
            except EOFError:
                break
    assert source.stats["late"] >= 3
    assert "rendering is slower than 400 fps" in caplog.text


def test_sim_set_exposure_overrides_the_scenario(tmp_path: Path) -> None:
    with open_source(f"sim:{tiny_scenario(tmp_path)}", {"realtime": False, "noise": False}) as source:
        first = source.read()
        assert source.set_exposure(exposure_us=4000.0) == (4000.0, 0.0)
        second, third = source.read(), source.read()
    assert first.exposure_us == 500.0
    assert second.exposure_us == third.exposure_us == 4000.0
    assert second.meta["exposure_factor"] is None


def test_sim_default_scenario() -> None:
    with open_source("sim:default", {"realtime": False, "max_frames": 1, "seed": 2}) as source:
        f = source.read()
    assert f.image.shape == (600, 960) and set(f.truth) == {3}


# ---------------------------------------------------------------------- replay
CAMERA = CameraModel(32, 24, 30.0, 30.0, 15.5, 11.5, bit_depth=8)


def write_recording(path: Path, n: int = 5, interval_ns: int = 50_000_000) -> list[np.ndarray]:
    rng = np.random.default_rng(1)
    images = [rng.integers(0, 256, (24, 32)).astype(np.uint8) for _ in range(n)]
    with RecordingWriter(path, CAMERA, [TargetSpec.default(3, 0.1)]) as writer:
        for i, image in enumerate(images):
            truth = {3: Pose(np.eye(3), np.array([0.0, 0.0, 1.0 + i]))}
            writer.write_frame(image, timestamp_ns=10**9 + i * interval_ns, exposure_us=100.0 * (i + 1),
                               gain_db=1.5, truth=truth)
    return images


def test_replay_fast_is_lossless_with_metadata_and_truth(tmp_path: Path) -> None:
    images = write_recording(tmp_path / "rec")
    with open_source(f"replay:{tmp_path / 'rec'}", {"pace": "fast"}) as source:
        assert not source.live and source.camera == CAMERA and [t.id for t in source.targets] == [3]
        frames = [source.read() for _ in range(5)]
        with pytest.raises(EOFError):
            source.read()
    for i, f in enumerate(frames):
        assert np.array_equal(f.image, images[i])
        assert (f.frame_id, f.timestamp_ns, f.exposure_us, f.gain_db) == (i, 10**9 + i * 50_000_000,
                                                                        100.0 * (i + 1), 1.5)
        assert np.allclose(f.truth[3].t, [0, 0, 1.0 + i])
    assert source.stats == {"frames": 5, "skipped": 0}


def test_replay_recorded_pace_follows_the_timestamps(tmp_path: Path) -> None:
    write_recording(tmp_path / "rec", n=6, interval_ns=60_000_000)
    with open_source(f"replay:{tmp_path / 'rec'}") as source:
        arrivals, _ = read_to_end(source)
    assert len(arrivals) == 6
    # frames are due at absolute times from the first one: a late frame does not delay the next ones
    assert abs(np.median(np.diff(arrivals)) - 0.060) < 0.006, np.diff(arrivals)
    assert abs((arrivals[-1] - arrivals[0]) - 0.300) < 0.030


def test_replay_read_times_out_before_a_far_frame(tmp_path: Path) -> None:
    write_recording(tmp_path / "rec", n=2, interval_ns=2_000_000_000)
    with open_source(f"replay:{tmp_path / 'rec'}", {"pace": "recorded"}) as source:
        assert source.read(0.05) is not None
        started = time.monotonic()
        assert source.read(0.1) is None  # the next frame is due in 2 s
        assert 0.08 < time.monotonic() - started < 0.5


def test_replay_skips_and_counts_corrupt_frames(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    images = write_recording(tmp_path / "rec")
    frame_files = sorted((tmp_path / "rec" / "frames").iterdir())
    frame_files[1].write_bytes(frame_files[1].read_bytes()[:40])  # truncated PNG
    frame_files[3].unlink()  # missing
    with caplog.at_level(logging.WARNING), open_source(f"replay:{tmp_path / 'rec'}", {"pace": "fast"}) as source:
        frames = []
        while True:
            try:
                frames.append(source.read())
            except EOFError:
                break
    assert [f.frame_id for f in frames] == [0, 2, 4]
    assert np.array_equal(frames[1].image, images[2])
    assert source.stats == {"frames": 3, "skipped": 2}
    assert "skipping frame 1" in caplog.text and "skipping frame 3" in caplog.text


def test_replay_max_frames(tmp_path: Path) -> None:
    write_recording(tmp_path / "rec")
    with open_source(f"replay:{tmp_path / 'rec'}", {"pace": "fast", "max_frames": 2}) as source:
        assert source.read() is not None and source.read() is not None
        with pytest.raises(EOFError, match="max_frames"):
            source.read()


def test_replay_source_class_is_usable_directly(tmp_path: Path) -> None:
    write_recording(tmp_path / "rec", n=1)
    source = ReplaySource(tmp_path / "rec", pace="fast")
    with pytest.raises(SourceError, match="not open"):
        source.read()
    source.open()
    assert source.read().frame_id == 0
    source.close()
