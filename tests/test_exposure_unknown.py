""""Exposure unknown" has one spelling, None: from the sources, through recordings (an empty cell), the tracker
and the outputs (the pose stream keeps NaN / null on the wire, None in Python)."""

import math
import struct

import numpy as np
import pytest

from livetrack.camera import CameraModel
from livetrack.estimator.pose_fit import PoseFit
from livetrack.estimator.tracker import FrameResult, TargetResult
from livetrack.geometry import Pose
from livetrack.recording import Recording, RecordingWriter
from livetrack.sinks.base import TrackedFrame
from livetrack.sinks.console import format_line
from livetrack.sinks.pose_message import PoseMessage, decode
from livetrack.sources.base import Frame
from livetrack.sources.replay import ReplaySource
from livetrack.sources.v4l2_source import EXPOSURE_TIME_ABSOLUTE, GAIN, V4L2Source
from livetrack.targets.spec import TargetSpec
from tests.test_sources import read_frames
from tests.test_sources_v4l2 import FakeV4L2Device

CAMERA = CameraModel(64, 48, 60.0, 60.0, 31.5, 23.5, bit_depth=12)


def test_a_recording_keeps_unknown_exposure_and_gain_as_empty_cells_read_back_as_none(tmp_path):
    image = np.full((48, 64), 1000, np.uint16)
    with RecordingWriter(tmp_path / "rec", CAMERA, [TargetSpec.default(3, 0.125)]) as writer:
        writer.write_frame(image, timestamp_ns=0, exposure_us=None, gain_db=None)
        writer.write_frame(image, timestamp_ns=1, exposure_us=250.0, gain_db=1.5)
        with pytest.raises(ValueError, match="exposure_us must be finite"):
            writer.write_frame(image, timestamp_ns=2, exposure_us=math.nan, gain_db=0.0)
    rows = (tmp_path / "rec" / "frames.csv").read_text().splitlines()
    assert rows[1].split(",")[2:4] == ["", ""]
    rec = Recording.open(tmp_path / "rec")
    assert [(f.exposure_us, f.gain_db) for f in rec.frames] == [(None, None), (250.0, 1.5)]
    with ReplaySource(tmp_path / "rec", pace="fast") as source:
        frames = [source.read(), source.read()]
    assert frames[0].exposure_us is None and frames[0].gain_db is None and frames[1].exposure_us == 250.0


class _NoExposureDevice(FakeV4L2Device):
    """A webcam that reports neither exposure nor gain."""

    def get_control(self, name: str) -> float | None:
        return None if name in (EXPOSURE_TIME_ABSOLUTE, GAIN) else super().get_control(name)


def test_a_webcam_without_exposure_control_gives_none_not_nan():
    with V4L2Source(_NoExposureDevice()) as source:
        frames = read_frames(source, 2)
        assert source.set_exposure(exposure_us=1000.0) == (None, None)
    assert all(f.exposure_us is None and f.gain_db is None for f in frames)


def _result(fit_ok: bool = True) -> TargetResult:
    fit = PoseFit(pose=Pose(np.eye(3), np.array([0.1, 0.0, 2.0])), delta_px=0.2, covariance=np.eye(7) * 1e-6,
                  residuals_px=np.zeros(12), residual_rms_px=0.1, iterations=3, ok=fit_ok)
    return TargetResult(target_id=3, levels_used=(0,), fit=fit, heading_known=True, n_edge_points=12,
                        edge_points_px=np.zeros((0, 2)), candidate=None)


def test_the_pose_stream_sends_unknown_exposure_as_nan_or_null_and_decodes_it_as_none():
    message = PoseMessage.from_result(_result(), sequence=1, frame_id=2, device_timestamp_ns=3, host_timestamp_ns=4,
                                      n_targets=1, target_index=0, exposure_us=None, latency_ms=5.0)
    assert message.exposure_us is None
    binary = message.to_binary()
    assert math.isnan(struct.unpack_from("<d", binary, 288)[0])  # the documented wire value
    assert b'"exposure_us":null' in message.to_json()
    assert decode(binary).exposure_us is None and decode(message.to_json()).exposure_us is None
    known = PoseMessage.from_result(_result(), sequence=1, frame_id=2, device_timestamp_ns=3, host_timestamp_ns=4,
                                    n_targets=1, target_index=0, exposure_us=800.0, latency_ms=5.0)
    assert decode(known.to_binary()).exposure_us == 800.0 and decode(known.to_json()).exposure_us == 800.0


def test_the_console_line_says_unknown_exposure_and_failures():
    from livetrack.estimator.tracker import TargetFailure

    frame = Frame(image=np.zeros((48, 64), np.uint16), frame_id=7, timestamp_ns=0, host_timestamp_ns=0,
                  exposure_us=None, gain_db=None)
    failure = TargetFailure(5, 0, (10.0, 20.0), "closed_form", "the closed-form pose is behind the camera")
    result = FrameResult([_result()], {}, [failure])
    line = format_line(TrackedFrame(0, frame, result, {}, 0, 1.0))
    assert "exp unknown" in line and "id 3: " in line
    assert "id 5: no pose (closed_form: the closed-form pose is behind the camera)" in line
