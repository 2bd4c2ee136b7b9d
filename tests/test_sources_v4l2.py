"""``v4l2:`` source driven by a fake ``V4L2Device`` (no V4L2 device exists on the build machines): frames, the
exposure control and its 100 us unit, and a device that is unplugged and plugged back."""

from __future__ import annotations

import logging
import threading
import time

import numpy as np
import pytest

from livetrack.camera import CameraModel
from livetrack.sources import open_source
from livetrack.sources.base import SourceError
from livetrack.sources.v4l2_source import (
    AUTO_EXPOSURE,
    AUTO_EXPOSURE_MANUAL,
    EXPOSURE_TIME_ABSOLUTE,
    GAIN,
    OpenCVV4L2Device,
    V4L2Device,
    V4L2Source,
)
from tests.test_sources import read_frames

WIDTH, HEIGHT = 64, 48


class FakeV4L2Device:
    """A webcam at ``fps`` whose BGR image brightness is exposure_time_absolute (100 us units) / 4 + gain;
    ``unplug()`` makes grabs fail and open raise, ``plug()`` undoes it."""

    def __init__(self, path: str = "/dev/video7", fps: float = 100.0):
        self.path = path
        self.period_s = 1.0 / fps
        self.controls = {AUTO_EXPOSURE: 3.0, EXPOSURE_TIME_ABSOLUTE: 156.0, GAIN: 0.0}
        self.present = True
        self.is_open = False
        self.opens = 0
        self.set_calls: list[tuple[str, float]] = []
        self._lock = threading.Lock()

    def open(self) -> None:
        if not self.present:
            raise OSError(f"{self.path}: No such device")
        self.is_open = True
        self.opens += 1

    def grab(self):
        time.sleep(self.period_s)
        with self._lock:
            if not self.present or not self.is_open:
                return None
            level = min(255, int(self.controls[EXPOSURE_TIME_ABSOLUTE] / 4 + self.controls[GAIN]))
        image = np.full((HEIGHT, WIDTH, 3), level, np.uint8)
        image[10:20, 10:20] = 0  # something dark
        return image, time.monotonic_ns()

    def set_control(self, name: str, value: float) -> None:
        with self._lock:
            if not self.present:
                raise OSError(f"{self.path}: No such device")
            self.controls[name] = float(value)
            self.set_calls.append((name, float(value)))

    def get_control(self, name: str) -> float | None:
        return self.controls.get(name)

    def close(self) -> None:
        self.is_open = False

    def unplug(self) -> None:
        with self._lock:
            self.present = False
            self.is_open = False

    def plug(self) -> None:
        with self._lock:
            self.present = True


def test_the_fake_device_satisfies_the_protocol() -> None:
    device: V4L2Device = FakeV4L2Device()  # type-checked; and at run time it has every method
    assert all(callable(getattr(device, name)) for name in ("open", "grab", "set_control", "get_control", "close"))


def test_frames_are_grey_with_the_exposure_in_force() -> None:
    device = FakeV4L2Device()
    with V4L2Source(device, exposure_us=2000.0, gain=3.0) as source:
        assert source.live and (source.camera.width, source.camera.height) == (WIDTH, HEIGHT)
        frames = read_frames(source, 3)
    # manual exposure was selected, and 2000 us went to the device as 20 steps of 100 us
    assert device.set_calls[:3] == [(AUTO_EXPOSURE, AUTO_EXPOSURE_MANUAL), (EXPOSURE_TIME_ABSOLUTE, 20.0),
                                    (GAIN, 3.0)]
    for f in frames:
        assert f.image.shape == (HEIGHT, WIDTH) and f.image.dtype == np.uint8
        assert f.exposure_us == 2000.0 and f.gain_db == 3.0 and f.meta["gain_unit"] == "raw"
        assert f.image[0, 0] == 20 // 4 + 3 and f.image[15, 15] == 0
    ids = [f.frame_id for f in frames]
    assert ids == sorted(ids) and len(set(ids)) == 3


def test_set_exposure_rounds_to_100us_and_reads_back() -> None:
    device = FakeV4L2Device()
    with V4L2Source(device) as source:
        first = read_frames(source, 1)[0]
        assert first.exposure_us == 15600.0  # the device's own (auto) value, read back
        assert source.set_exposure(exposure_us=849.0) == (800.0, 0.0)
        later = read_frames(source, 6)
    assert device.controls[AUTO_EXPOSURE] == AUTO_EXPOSURE_MANUAL and device.controls[EXPOSURE_TIME_ABSOLUTE] == 8.0
    # a frame grabbed before the change may still be waiting in the slot: it keeps its old metadata
    changed = [i for i, f in enumerate(later) if f.exposure_us == 800.0]
    assert len(changed) >= 3 and changed == list(range(changed[0], 6))
    assert all(f.exposure_us == 15600.0 for f in later[:changed[0]])
    assert [later[i].meta["frames_since_change"] for i in changed[:2]] == [0, 1]
    assert later[-1].image[0, 0] == 8 // 4


def test_an_unplugged_device_is_reported_and_reopened(caplog: pytest.LogCaptureFixture) -> None:
    device = FakeV4L2Device()
    source = V4L2Source(device, exposure_us=1000.0, fail_limit=3, reconnect_initial_s=0.05, reconnect_max_s=0.2)
    with caplog.at_level(logging.INFO), source:
        before = read_frames(source, 3)
        device.unplug()
        started, nones = time.monotonic(), 0
        while time.monotonic() - started < 0.6:
            nones += source.read(0.05) is None
        assert "device lost (3 failed grabs in a row)" in caplog.text
        assert source.set_exposure(exposure_us=3000.0) is None  # away: applied when it is back
        device.plug()
        after = read_frames(source, 3)
        stats = source.stats
    assert nones >= 5
    assert stats["reconnects"] == 1 and stats["lost_events"] == 1 and device.opens == 2
    assert after[0].frame_id > before[-1].frame_id
    assert all(f.exposure_us == 3000.0 for f in after)
    assert "device back after" in caplog.text


def test_a_camera_file_of_another_size_is_refused() -> None:
    camera = CameraModel(640, 480, 500.0, 500.0, 319.5, 239.5)
    with pytest.raises(SourceError, match="camera file is for 640x480"):
        V4L2Source(FakeV4L2Device(), camera=camera).open()


def test_a_missing_device_is_a_source_error() -> None:
    with pytest.raises(SourceError, match="cannot open"):
        open_source("v4l2:/dev/video-livetrack-none", {"exposure_us": 1000})


def test_opencv_device_maps_controls_to_opencv_properties() -> None:
    import cv2

    assert OpenCVV4L2Device.PROPS == {AUTO_EXPOSURE: cv2.CAP_PROP_AUTO_EXPOSURE,
                                      EXPOSURE_TIME_ABSOLUTE: cv2.CAP_PROP_EXPOSURE, GAIN: cv2.CAP_PROP_GAIN}
