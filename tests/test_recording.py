"""Recording format v1: write/read round trips, crash safety and the reader's handling of damaged files."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from livetrack.camera import CameraModel
from livetrack.geometry import Pose
from livetrack.recording import FrameRecord, Recording, RecordingError, RecordingWriter
from livetrack.targets.spec import TargetSpec

WIDTH, HEIGHT = 40, 32
TARGETS = [TargetSpec.default(3, 0.1), TargetSpec.default(7, 0.05, levels=1)]


def make_camera(bit_depth: int) -> CameraModel:
    return CameraModel(WIDTH, HEIGHT, 55.5, 56.25, 19.5, 15.5, dist=(-0.1, 0.01, 1e-4, -2e-4, 0.0),
                       bit_depth=bit_depth)


def random_image(rng: np.random.Generator, bit_depth: int) -> np.ndarray:
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    return rng.integers(0, 2**bit_depth, size=(HEIGHT, WIDTH)).astype(dtype)


def write_recording(path: Path, bit_depth: int = 8, n_frames: int = 4, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    images = [random_image(rng, bit_depth) for _ in range(n_frames)]
    with RecordingWriter(path, make_camera(bit_depth), TARGETS) as writer:
        for i, image in enumerate(images):
            writer.write_frame(image, timestamp_ns=1_000_000 * i, exposure_us=250.0, gain_db=0.0)
    return images


def warnings_text(caplog: pytest.LogCaptureFixture) -> str:
    return "\n".join(r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING)


# ---------------------------------------------------------------------- round trip
@pytest.mark.parametrize("bit_depth", [8, 12, 16])
def test_round_trip_is_exact(tmp_path: Path, bit_depth: int) -> None:
    rng = np.random.default_rng(42)
    camera = make_camera(bit_depth)
    meta = {"operator": "test", "lens": {"f_mm": 8.0}, "notes": [1, 2.5, "x"]}
    images, truths, extras, stamps = [], [], [], []
    path = tmp_path / "rec"
    with RecordingWriter(path, camera, TARGETS, meta=meta) as writer:
        for i in range(5):
            image = random_image(rng, bit_depth)
            image[0, 0] = 2**bit_depth - 1  # the full range must survive
            truth = {3: Pose.from_rotvec(rng.normal(size=3), rng.normal(size=3) + [0, 0, 2.0])}
            if i % 2:
                truth[7] = Pose.from_rotvec(rng.normal(size=3), rng.normal(size=3) + [0, 0, 1.0])
            extra = {"sensor_temp_c": f"{40 + rng.random():.6f}", "note": "a, \"quoted\" value" if i else ""}
            timestamp_ns = 1_700_000_000_000_000_000 + 33_333_333 * i
            exposure_us = float(rng.uniform(10, 20000))
            frame_id = writer.write_frame(image, timestamp_ns=timestamp_ns, exposure_us=exposure_us,
                                          gain_db=1.0 / 3.0, truth=truth, extra=extra)
            assert frame_id == i
            images.append(image)
            truths.append(truth)
            extras.append(extra)
            stamps.append((timestamp_ns, exposure_us))

    rec = Recording.open(path)
    assert rec.complete
    assert len(rec) == 5
    assert rec.camera == camera and rec.camera.dist == camera.dist
    assert rec.targets == TARGETS
    assert rec.meta == meta
    assert rec.skipped == []
    for i, frame in enumerate(rec.frames):
        expected = FrameRecord(i, stamps[i][0], stamps[i][1], 1.0 / 3.0, f"frames/{i:06d}.png", extras[i])
        assert frame == expected
        image = rec.read_image(i)
        assert image.dtype == images[i].dtype
        np.testing.assert_array_equal(image, images[i])
        truth = rec.truth(i)
        assert sorted(truth) == sorted(truths[i])
        for target_id, pose in truths[i].items():
            np.testing.assert_array_equal(truth[target_id].t, pose.t)
            # Stored as a quaternion: exactly what the quaternion gives, and the original R to rounding.
            np.testing.assert_array_equal(truth[target_id].R, Pose.from_quaternion(pose.quaternion, pose.t).R)
            np.testing.assert_allclose(truth[target_id].R, pose.R, atol=1e-14)
    assert [f.frame_id for f, _ in rec.iter_images()] == list(range(5))
    assert rec.truth(99) == {}


def test_exception_in_with_block_still_closes_the_recording(tmp_path: Path) -> None:
    path = tmp_path / "rec"
    image = np.zeros((HEIGHT, WIDTH), np.uint8)
    with pytest.raises(RuntimeError, match="boom"), RecordingWriter(path, make_camera(8), TARGETS) as writer:
        writer.write_frame(image, timestamp_ns=0, exposure_us=100.0, gain_db=0.0)
        raise RuntimeError("boom")
    rec = Recording.open(path)
    assert rec.complete and len(rec) == 1
    assert yaml.safe_load((path / "recording.yaml").read_text())["frame_count"] == 1


class FailingCsv:
    """Stands in for the frames.csv writer: writes half a row, then fails as on a full disk."""

    def __init__(self, file):
        self.file = file

    def writerow(self, row):
        self.file.write(",".join(row)[:7])
        self.file.flush()
        raise OSError(28, "No space left on device")


def test_failed_row_write_leaves_recording_incomplete(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "rec"
    image = np.zeros((HEIGHT, WIDTH), np.uint8)
    with pytest.raises(OSError, match="No space"), RecordingWriter(path, make_camera(8), TARGETS) as writer:
        for i in range(3):
            writer.write_frame(image, timestamp_ns=i, exposure_us=100.0, gain_db=0.0)
        writer._frames_csv = FailingCsv(writer._frames_file)  # white-box: simulate the disk filling up
        writer.write_frame(image, timestamp_ns=3, exposure_us=100.0, gain_db=0.0)
    with caplog.at_level(logging.WARNING, logger="livetrack.recording"):
        rec = Recording.open(path)
    assert not rec.complete and len(rec) == 3 and rec.skipped == []
    assert "torn" in warnings_text(caplog)


def test_empty_recording_reads_as_complete_and_empty(tmp_path: Path) -> None:
    with RecordingWriter(tmp_path / "rec", make_camera(8), []):
        pass
    rec = Recording.open(tmp_path / "rec")
    assert rec.complete and len(rec) == 0 and rec.targets == []


# ---------------------------------------------------------------------- writer validation
@pytest.mark.parametrize(("bit_depth", "image", "match"), [
    (8, np.zeros((HEIGHT, WIDTH + 1), np.uint8), "does not match"),
    (8, np.zeros((HEIGHT, WIDTH, 3), np.uint8), "single-channel"),
    (8, np.zeros((HEIGHT, WIDTH), np.uint16), "bit depth"),
    (12, np.zeros((HEIGHT, WIDTH), np.uint8), "bit depth"),
    (12, np.full((HEIGHT, WIDTH), 4096, np.uint16), "exceeds"),
    (10, np.full((HEIGHT, WIDTH), 1 << 15, np.uint16), "LSB-aligned"),
])
def test_writer_rejects_invalid_image_and_writes_nothing(tmp_path: Path, bit_depth: int, image: np.ndarray,
                                                          match: str) -> None:
    path = tmp_path / "rec"
    with RecordingWriter(path, make_camera(bit_depth), TARGETS) as writer:
        with pytest.raises(ValueError, match=match):
            writer.write_frame(image, timestamp_ns=0, exposure_us=100.0, gain_db=0.0)
        assert list((path / "frames").iterdir()) == []
        good = np.zeros((HEIGHT, WIDTH), np.uint8 if bit_depth == 8 else np.uint16)
        assert writer.write_frame(good, timestamp_ns=0, exposure_us=100.0, gain_db=0.0) == 0
    assert len(Recording.open(path)) == 1


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"exposure_us": 0.0}, "exposure_us"),
    ({"exposure_us": float("nan")}, "exposure_us"),
    ({"timestamp_ns": 1.5}, "timestamp_ns"),
    ({"truth": {99: Pose.identity()}}, "target 99"),
    ({"extra": {"file": "x"}}, "extra column"),
    ({"extra": {"note": "two\nlines"}}, "line breaks"),
])
def test_writer_rejects_invalid_metadata(tmp_path: Path, kwargs: dict, match: str) -> None:
    args = {"timestamp_ns": 0, "exposure_us": 100.0, "gain_db": 0.0, **kwargs}
    with RecordingWriter(tmp_path / "rec", make_camera(8), TARGETS) as writer:
        with pytest.raises(ValueError, match=match):
            writer.write_frame(np.zeros((HEIGHT, WIDTH), np.uint8), **args)
        assert writer.frame_count == 0
    assert len(Recording.open(tmp_path / "rec")) == 0


def test_writer_refuses_to_overwrite(tmp_path: Path) -> None:
    path = tmp_path / "rec"
    write_recording(path, n_frames=3)
    with pytest.raises(FileExistsError, match="not empty"):
        RecordingWriter(path, make_camera(8), TARGETS)
    assert len(Recording.open(path)) == 3  # untouched
    with RecordingWriter(path, make_camera(8), TARGETS, overwrite=True) as writer:
        writer.write_frame(np.zeros((HEIGHT, WIDTH), np.uint8), timestamp_ns=5, exposure_us=1.0, gain_db=0.0)
    assert len(Recording.open(path)) == 1

    other = tmp_path / "photos"
    other.mkdir()
    (other / "holiday.jpg").write_bytes(b"precious")
    with pytest.raises(FileExistsError, match="not a recording"):
        RecordingWriter(other, make_camera(8), TARGETS, overwrite=True)
    assert (other / "holiday.jpg").read_bytes() == b"precious"


# ---------------------------------------------------------------------- crash safety
KILL_SCRIPT = """
import sys, numpy as np
from livetrack.camera import CameraModel
from livetrack.geometry import Pose
from livetrack.recording import RecordingWriter
from livetrack.targets.spec import TargetSpec
cam = CameraModel(int(sys.argv[2]), int(sys.argv[3]), 50.0, 50.0, 19.5, 15.5, bit_depth=12)
w = RecordingWriter(sys.argv[1], cam, [TargetSpec.default(3, 0.1)], fsync_every_n_frames=0)
i = 0
while True:
    w.write_frame(np.full((cam.height, cam.width), i % 4096, np.uint16), timestamp_ns=i, exposure_us=100.0,
                  gain_db=0.0, truth={3: Pose.identity()}, extra={"i": i})
    i += 1
"""


def test_killed_writer_leaves_a_readable_incomplete_recording(tmp_path: Path,
                                                              caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "rec"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    command = [sys.executable, "-c", KILL_SCRIPT, str(path), str(WIDTH), str(HEIGHT)]
    proc = subprocess.Popen(command, env=env, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 20.0
        frames_csv = path / "frames.csv"
        while time.monotonic() < deadline and proc.poll() is None:
            if frames_csv.exists() and frames_csv.read_bytes().count(b"\n") > 30:
                break
            time.sleep(0.01)
        assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
        if proc.stderr:
            proc.stderr.close()

    with caplog.at_level(logging.WARNING, logger="livetrack.recording"):
        rec = Recording.open(path)
        assert not rec.complete
        assert len(rec) >= 30
        assert [f.frame_id for f in rec.frames] == list(range(len(rec)))
        read = 0
        for frame, image in rec.iter_images():
            assert np.all(image == frame.frame_id % 4096)
            assert frame.extra == {"i": str(frame.frame_id)}
            read += 1
    assert read == len(rec) and rec.skipped == []
    assert "incomplete" in warnings_text(caplog)
    assert 3 in rec.truth(len(rec) - 1)


def test_torn_last_line_of_incomplete_recording_is_ignored(tmp_path: Path,
                                                           caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "rec"
    images = write_recording(path, n_frames=4)
    header = yaml.safe_load((path / "recording.yaml").read_text())
    header["complete"] = False
    del header["frame_count"]
    (path / "recording.yaml").write_text(yaml.safe_dump(header))
    text = (path / "frames.csv").read_text()
    (path / "frames.csv").write_text(text[:-12])  # kill mid-row
    with caplog.at_level(logging.WARNING, logger="livetrack.recording"):
        rec = Recording.open(path)
    assert not rec.complete and len(rec) == 3
    assert "frames.csv line 5: torn" in warnings_text(caplog)
    for frame, image in rec.iter_images():
        np.testing.assert_array_equal(image, images[frame.frame_id])


def test_incomplete_recording_without_frames_csv_is_empty(tmp_path: Path) -> None:
    path = tmp_path / "rec"
    RecordingWriter(path, make_camera(8), TARGETS)  # "killed" before the first frame
    rec = Recording.open(path)
    assert not rec.complete and len(rec) == 0


# ---------------------------------------------------------------------- damaged images
def test_corrupt_png_is_reported_and_skipped(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "rec"
    write_recording(path, bit_depth=12, n_frames=4)
    png = path / "frames" / "000001.png"
    png.write_bytes(png.read_bytes()[: png.stat().st_size // 2])
    rec = Recording.open(path)
    with pytest.raises(RecordingError, match=r"000001\.png.*truncated or corrupt"):
        rec.read_image(1)
    with caplog.at_level(logging.WARNING, logger="livetrack.recording"):
        ids = [frame.frame_id for frame, _ in rec.iter_images()]
    assert ids == [0, 2, 3]
    assert len(rec.skipped) == 1 and rec.skipped[0][0] == 1 and "000001.png" in rec.skipped[0][1]
    assert "skipping frame 1" in warnings_text(caplog)


def test_missing_image_is_reported_and_open_is_lazy(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "rec"
    write_recording(path, n_frames=3)
    for png in (path / "frames").iterdir():
        png.unlink()
    rec = Recording.open(path)  # does not touch the images
    assert len(rec) == 3
    with pytest.raises(RecordingError, match=r"000002\.png.*missing"):
        rec.read_image(2)
    with caplog.at_level(logging.WARNING, logger="livetrack.recording"):
        assert list(rec.iter_images()) == []
    assert [frame_id for frame_id, _ in rec.skipped] == [0, 1, 2]


@pytest.mark.parametrize(("bit_depth", "replacement", "match"), [
    (8, np.zeros((HEIGHT + 2, WIDTH), np.uint8), "size 40x34 does not match the camera's 40x32"),
    (8, np.zeros((HEIGHT, WIDTH, 3), np.uint8), "single-channel"),
    (12, np.zeros((HEIGHT, WIDTH), np.uint8), "wrong bit depth: image dtype is uint8"),
    # MSB-aligned 12-bit data:
    (12, np.full((HEIGHT, WIDTH), 4096 * 15, np.uint16), "wrong bit depth: value 61440 exceeds"),
    (8, np.zeros((HEIGHT, WIDTH), np.uint16), "wrong bit depth"),
])
def test_wrong_image_size_or_depth_is_reported(tmp_path: Path, bit_depth: int, replacement: np.ndarray,
                                               match: str) -> None:
    path = tmp_path / "rec"
    write_recording(path, bit_depth=bit_depth, n_frames=2)
    assert cv2.imwrite(str(path / "frames" / "000000.png"), replacement)
    rec = Recording.open(path)
    with pytest.raises(RecordingError, match=match) as info:
        rec.read_image(0)
    assert "000000.png" in str(info.value)
    assert rec.read_image(1).shape == (HEIGHT, WIDTH)


# ---------------------------------------------------------------------- damaged CSV / YAML
@pytest.mark.parametrize(("bad_row", "skipped_id", "reason"), [
    ("x,1000000,250.0,0.0,frames/000001.png", -1, "frame_id is not an integer: 'x'"),
    ("1,1000000,250.0,frames/000001.png", -1, "expected 5 fields, got 4"),
    ("1,1000000,fast,0.0,frames/000001.png", 1, "exposure_us is not a number: 'fast'"),
    ("1,1000000,-3,0.0,frames/000001.png", 1, "exposure_us must be finite and > 0"),
    ("1,1000000,250.0,0.0,/etc/passwd", 1, "relative path"),
    ("0,1000000,250.0,0.0,frames/000001.png", 0, "duplicate frame_id 0"),
])
def test_malformed_row_is_skipped_with_file_and_line(tmp_path: Path, caplog: pytest.LogCaptureFixture,
                                                     bad_row: str, skipped_id: int, reason: str) -> None:
    path = tmp_path / "rec"
    write_recording(path, n_frames=4)
    lines = (path / "frames.csv").read_text().splitlines()
    lines[2] = bad_row  # frame 1, line 3 of the file
    (path / "frames.csv").write_text("\n".join(lines) + "\n")
    with caplog.at_level(logging.WARNING, logger="livetrack.recording"):
        rec = Recording.open(path)
    assert [f.frame_id for f in rec.frames] == [0, 2, 3]
    assert len(rec.skipped) == 1
    frame_id, message = rec.skipped[0]
    assert frame_id == skipped_id
    assert "frames.csv line 3" in message and reason in message
    assert "frames.csv line 3" in warnings_text(caplog)
    assert "frame_count is 4" not in warnings_text(caplog)  # the bad row still counts as a row


@pytest.mark.parametrize("header", ["frame_id,timestamp_ns,exposure_us,file", "frame_id,timestamp_ns,"
                                    "exposure_us,gain_db,file,file"])
def test_malformed_header_is_rejected(tmp_path: Path, header: str) -> None:
    path = tmp_path / "rec"
    write_recording(path, n_frames=2)
    lines = (path / "frames.csv").read_text().splitlines()
    (path / "frames.csv").write_text("\n".join([header, *lines[1:]]) + "\n")
    with pytest.raises(RecordingError, match=r"frames\.csv line 1: header"):
        Recording.open(path)


def edit_yaml(path: Path, edit) -> None:
    data = yaml.safe_load((path / "recording.yaml").read_text())
    edit(data)
    (path / "recording.yaml").write_text(yaml.safe_dump(data))


@pytest.mark.parametrize(("edit", "match"), [
    (lambda d: d["camera"].pop("fx"), r"camera\.fx: missing"),
    (lambda d: d["camera"].update(bit_depth=7), r"camera\.bit_depth: must be one of"),
    (lambda d: d["targets"][1].update(outer_radius_m=-1), r"targets\[1\]\.outer_radius_m: must be > 0"),
    (lambda d: d.update(version=2), "version: unsupported version 2"),
    (lambda d: d.update(format="something-else"), "format: must be one of"),
    (lambda d: d.pop("complete"), "complete: missing"),
    (lambda d: d.update(colour="red"), "colour: unknown key"),
])
def test_bad_recording_yaml_names_file_and_key(tmp_path: Path, edit, match: str) -> None:
    path = tmp_path / "rec"
    write_recording(path, n_frames=1)
    edit_yaml(path, edit)
    with pytest.raises(RecordingError, match=r"recording\.yaml: " + match):
        Recording.open(path)


def test_not_a_recording(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="no recording.yaml"):
        Recording.open(tmp_path)
    (tmp_path / "recording.yaml").write_text("format: [unclosed\n")
    with pytest.raises(RecordingError, match="not valid YAML"):
        Recording.open(tmp_path)


def test_complete_recording_without_frames_csv_is_rejected(tmp_path: Path) -> None:
    path = tmp_path / "rec"
    write_recording(path, n_frames=1)
    (path / "frames.csv").unlink()
    with pytest.raises(RecordingError, match=r"frames\.csv: missing"):
        Recording.open(path)


def test_malformed_truth_row_is_skipped(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "rec"
    with RecordingWriter(path, make_camera(8), TARGETS) as writer:
        for i in range(3):
            writer.write_frame(np.zeros((HEIGHT, WIDTH), np.uint8), timestamp_ns=i, exposure_us=1.0,
                               gain_db=0.0, truth={3: Pose.identity()})
    lines = (path / "truth.csv").read_text().splitlines()
    lines[2] = lines[2].rsplit(",", 1)[0] + ",one"  # frame 1's qw
    (path / "truth.csv").write_text("\n".join(lines) + "\n")
    with caplog.at_level(logging.WARNING, logger="livetrack.recording"):
        rec = Recording.open(path)
    assert rec.truth(1) == {} and 3 in rec.truth(0) and 3 in rec.truth(2)
    assert "truth.csv line 3" in warnings_text(caplog)


def test_recording_written_by_another_tool(tmp_path: Path) -> None:
    """The documented example, written by hand: short-form target, reordered and extra columns."""
    (tmp_path / "recording.yaml").write_text(
        "format: livetrack-recording\nversion: 1\ncomplete: true\n"
        f"camera: {{width: {WIDTH}, height: {HEIGHT}, fx: 1450.0, fy: 1450.0, cx: 19.5, cy: 15.5, "
        "bit_depth: 12}\n"
        "targets:\n  - {id: 3, outer_radius_m: 0.1}\n")
    (tmp_path / "frames.csv").write_text(
        "file,frame_id,exposure_us,timestamp_ns,gain_db,sensor_temp_c\n"
        "img/a.png,10,2000,1700000000000000000,0,41.5\n"
        "img/b.png,11,4000.5,1700000000033333333,6.0,41.5")  # no final newline: fine when complete
    (tmp_path / "truth.csv").write_text("frame_id,target_id,tx_m,ty_m,tz_m,qx,qy,qz,qw\n"
                                        "11,3,0.01,-0.02,1.5,0,0,0,1\n")
    (tmp_path / "img").mkdir()
    image = np.arange(HEIGHT * WIDTH, dtype=np.uint16).reshape(HEIGHT, WIDTH) % 4096
    assert cv2.imwrite(str(tmp_path / "img" / "a.png"), image)
    assert cv2.imwrite(str(tmp_path / "img" / "b.png"), image[::-1].copy())
    rec = Recording.open(tmp_path)
    assert rec.complete and rec.targets == [TargetSpec.default(3, 0.1)]
    assert rec.frames[1] == FrameRecord(11, 1_700_000_000_033_333_333, 4000.5, 6.0, "img/b.png",
                                        {"sensor_temp_c": "41.5"})
    np.testing.assert_array_equal(rec.read_image(1), image[::-1])
    assert rec.truth(10) == {}
    np.testing.assert_array_equal(rec.truth(11)[3].t, [0.01, -0.02, 1.5])
    np.testing.assert_array_equal(rec.truth(11)[3].R, np.eye(3))


# ---------------------------------------------------------------------- hostile recordings (issue 12)
def _frames_lines(path: Path) -> list[bytes]:
    return (path / "frames.csv").read_bytes().split(b"\n")


@pytest.mark.parametrize(("damage", "reason"), [
    (lambda line: line.replace(b"250.0", b'250"0'), "exposure_us"),
    (lambda line: line.replace(b",250.0,", b',"250.0,'), "not valid CSV"),  # swallowed every later row
    (lambda line: line + b',"x"', "expected 5 fields"),
    (lambda line: line.replace(b"250.0", b"250\xff0"), "not UTF-8"),
    (lambda line: line.replace(b"frames/", b"fr\x00mes/"), "control character"),
])
def test_issue12_finding4_a_damaged_row_costs_that_row_only(tmp_path: Path, caplog: pytest.LogCaptureFixture,
                                                             damage, reason: str) -> None:
    path = tmp_path / "rec"
    write_recording(path, n_frames=8)
    lines = _frames_lines(path)
    lines[3] = damage(lines[3])  # line 4 of the file: frame 2
    (path / "frames.csv").write_bytes(b"\n".join(lines))
    with caplog.at_level(logging.WARNING):
        rec = Recording.open(path)
    assert [f.frame_id for f in rec.frames] == [0, 1, 3, 4, 5, 6, 7]
    assert len(rec.skipped) == 1 and "frames.csv line 4:" in rec.skipped[0][1], rec.skipped
    assert reason in rec.skipped[0][1]
    assert "frames.csv line 4:" in warnings_text(caplog)
    assert len(list(rec.iter_images())) == 7


def test_issue12_finding4_a_header_that_is_not_utf8_is_a_recording_error(tmp_path: Path) -> None:
    path = tmp_path / "rec"
    write_recording(path)
    data = (path / "frames.csv").read_bytes()
    (path / "frames.csv").write_bytes(b"\xfe" + data)
    with pytest.raises(RecordingError, match=r"frames.csv line 1: header: not UTF-8"):
        Recording.open(path)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
@pytest.mark.parametrize("name", ["frames/000001.png", "frames.csv", "truth.csv", "recording.yaml"])
def test_issue12_finding5_a_fifo_is_refused_not_waited_on(tmp_path: Path, name: str) -> None:
    path = tmp_path / "rec"
    write_recording(path)
    (path / name).unlink(missing_ok=True)
    os.mkfifo(path / name)  # opening it for reading would block forever without a writer
    if name != "frames/000001.png":
        with pytest.raises(RecordingError, match="not a regular file"):
            Recording.open(path)
        return
    rec = Recording.open(path)
    with pytest.raises(RecordingError, match="not a regular file"):
        rec.read_image(1)
    assert [f.frame_id for f, _ in rec.iter_images()] == [0, 2, 3]
    assert rec.skipped[0][0] == 1


def test_issue12_finding5_symlinks_leading_outside_are_not_followed(tmp_path: Path) -> None:
    path = tmp_path / "rec"
    images = write_recording(path)
    secret = tmp_path / "secret.png"
    cv2.imwrite(str(secret), images[2])
    (path / "frames" / "000002.png").unlink()
    os.symlink(secret, path / "frames" / "000002.png")
    os.symlink("000001.png", path / "frames" / "inside.png")  # a link inside the recording is fine
    lines = _frames_lines(path)
    lines[2] = lines[2].replace(b"frames/000001.png", b"frames/inside.png")
    (path / "frames.csv").write_bytes(b"\n".join(lines))
    rec = Recording.open(path)
    with pytest.raises(RecordingError, match="outside the recording"):
        rec.read_image(2)
    np.testing.assert_array_equal(rec.read_image(1), images[1])
    (path / "truth.csv").unlink(missing_ok=True)
    os.symlink(secret, path / "truth.csv")
    with pytest.raises(RecordingError, match="truth.csv: is a link to .*outside the recording"):
        Recording.open(path)


def test_issue12_finding7_recording_yaml_that_is_not_utf8_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "rec"
    write_recording(path)
    text = (path / "recording.yaml").read_bytes()
    (path / "recording.yaml").write_bytes(text.replace(b"format:", b"# caf\xe9\nformat:"))
    with pytest.raises(RecordingError, match=r"recording.yaml: not UTF-8 text: byte 0xe9 at offset \d+ \(line 1\)"):
        Recording.open(path)
    (path / "recording.yaml").write_bytes(text + b"meta: " + b"[" * 5000 + b"]" * 5000 + b"\n")
    with pytest.raises(RecordingError, match="recording.yaml: not valid YAML"):
        Recording.open(path)


def test_issue12_recording_yaml_with_a_recursive_alias_is_a_recording_error(tmp_path: Path) -> None:
    path = tmp_path / "rec"
    write_recording(path)
    text = (path / "recording.yaml").read_text()
    (path / "recording.yaml").write_text(text + "meta: &m {a: [*m]}\n")
    with pytest.raises(RecordingError, match="recording.yaml: not valid YAML for livetrack: an alias inside"):
        Recording.open(path)


# ---------------------------------------------------------------------- spooled frames (run --record)
@pytest.mark.parametrize("bit_depth", [8, 12, 16])
def test_a_spooled_frame_reads_back_from_its_pgm_until_converted(tmp_path: Path, bit_depth: int) -> None:
    rng = np.random.default_rng(7)
    path = tmp_path / "rec"
    images = [random_image(rng, bit_depth) for _ in range(3)]
    writer = RecordingWriter(path, make_camera(bit_depth), TARGETS)
    spooled = [writer.spool_frame(image, timestamp_ns=i, exposure_us=100.0, gain_db=0.0, frame_id=10 + i)
               for i, image in enumerate(images)]
    writer.convert(spooled[0])
    assert sorted(p.name for p in (path / "frames").iterdir()) == ["000010.png", "000011.pgm", "000012.pgm"]
    # as a killed writer leaves it: listed under the PNG's name, read from the PGM
    rec = Recording.open(path)
    assert not rec.complete and [f.file for f in rec.frames] == [f"frames/0000{i}.png" for i in (10, 11, 12)]
    read = list(rec.iter_images())
    assert len(read) == 3 and not rec.skipped
    for (_, image), expected in zip(read, images, strict=True):
        assert image.dtype == expected.dtype and np.array_equal(image, expected)
    pgm = (path / "frames" / "000011.pgm").read_bytes()
    assert pgm.startswith(f"P5\n{WIDTH} {HEIGHT}\n{2**bit_depth - 1}\n".encode())  # a plain binary PGM
    writer.close()  # converts what is still spooled
    assert sorted(p.name for p in (path / "frames").iterdir()) == ["000010.png", "000011.png", "000012.png"]
    rec = Recording.open(path)
    assert rec.complete and [int(f.frame_id) for f in rec.frames] == [10, 11, 12]
    assert all(np.array_equal(image, expected) for (_, image), expected in zip(rec.iter_images(), images,
                                                                               strict=True))


def test_a_conversion_that_fails_at_close_leaves_the_frame_readable_and_the_recording_incomplete(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "rec"
    image = random_image(np.random.default_rng(1), 8)
    writer = RecordingWriter(path, make_camera(8), TARGETS)
    spooled = writer.spool_frame(image, timestamp_ns=0, exposure_us=100.0, gain_db=0.0)

    def disk_full(*args: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(writer, "_write_png", disk_full)
    with pytest.raises(OSError):
        writer.convert(spooled)  # in the recorder's thread: counted as its error
    writer.close()  # tries again, fails again
    assert "cannot write its PNG" in caplog.text
    rec = Recording.open(path)
    assert not rec.complete and len(rec) == 1 and np.array_equal(rec.read_image(0), image)


def test_spooling_checks_its_arguments_like_write_frame(tmp_path: Path) -> None:
    writer = RecordingWriter(tmp_path / "rec", make_camera(12), TARGETS)
    with pytest.raises(ValueError, match="exceeds the 12-bit maximum"):
        writer.spool_frame(np.full((HEIGHT, WIDTH), 4096, np.uint16), timestamp_ns=0, exposure_us=1.0,
                           gain_db=0.0)
    writer.spool_frame(np.zeros((HEIGHT, WIDTH), np.uint16), timestamp_ns=0, exposure_us=1.0, gain_db=0.0,
                       frame_id=5)
    with pytest.raises(ValueError, match="greater than the previous"):
        writer.write_frame(np.zeros((HEIGHT, WIDTH), np.uint16), timestamp_ns=0, exposure_us=1.0, gain_db=0.0,
                           frame_id=5)
    writer.close()
    assert [p.name for p in (tmp_path / "rec" / "frames").iterdir()] == ["000005.png"]
