"""Recordings under faults (issue 12): a command never destroys the recording it reads, ``--overwrite`` replaces
atomically (a failed or killed run keeps the old recording), and the recorder never drops an acquired frame
(back-pressure) while the ids it writes are the source's (gaps show what the source dropped)."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from livetrack.camera import CameraModel
from livetrack.pipeline import Pipeline, PipelineOptions
from livetrack.recording import Recording, RecordingWriter
from livetrack.sinks.recording_sink import RecordingSink
from livetrack.sinks.runner import DropSlot
from livetrack.sources.base import Frame
from livetrack.targets.spec import TargetSpec
from tests.test_pipeline import FakeSource, FakeTracker, ListSink, run_bounded
from tests.test_run_cli import RUNNER, SUBPROCESS_TIMEOUT_S

CAMERA = CameraModel(width=64, height=48, fx=60.0, fy=60.0, cx=31.5, cy=23.5)
TARGETS = [TargetSpec.default(3, 0.1)]

# A small, fast simulated camera for the subprocess runs (160x120, 8 bit, 60 fps).
SMALL_SCENARIO = """\
name: small
seed: 3
camera: {width: 160, height: 120, fx: 150, fy: 150, cx: 79.5, cy: 59.5, bit_depth: 8}
sensor: {full_well_e: 10000, read_noise_e: 5, black_level_dn: 0}
optics: {psf_sigma_px: 0.8}
targets:
  - {id: 3, outer_radius_m: 0.125}
poses:
  - {t_m: [0.0, 0.0, 1.0], tilt_deg: 10, tilt_axis_deg: 0, roll_deg: 0}
  - {t_m: [0.05, 0.02, 1.1], tilt_deg: 20, tilt_axis_deg: 30, roll_deg: 10}
exposure: {nominal_us: auto, white_fraction_of_full_well: 0.55, factors: [0.5, 1, 2], gain_db: 0}
timing: {fps: 60}
"""


def small_scenario(tmp_path: Path) -> Path:
    path = tmp_path / "small.yaml"
    path.write_text(SMALL_SCENARIO)
    return path


def write_small(path: Path, n: int = 3, seed: int = 0, **kwargs) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    images = [rng.integers(0, 256, (48, 64)).astype(np.uint8) for _ in range(n)]
    with RecordingWriter(path, CAMERA, TARGETS, png_compression=0, **kwargs) as writer:
        for i, image in enumerate(images):
            writer.write_frame(image, timestamp_ns=1000 * i, exposure_us=100.0, gain_db=0.0)
    return images


def digest(path: Path) -> dict[str, str]:
    """Every file under ``path`` (relative name -> sha256)."""
    return {str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(path.rglob("*")) if p.is_file()}


def hidden_siblings(path: Path) -> list[Path]:
    return sorted(p for p in path.parent.iterdir() if p.name.startswith(f".{path.name}."))


# ---------------------------------------------------------------------------------------------- finding 3
@pytest.mark.parametrize("record", ["same", "same-overwrite", "trailing-slash", "inside", "parent", "symlink"])
def test_replay_never_records_over_the_recording_it_reads(tmp_path, record):
    from livetrack.cli import main

    rec = tmp_path / "R"
    write_small(rec, n=3)
    before = digest(rec)
    source = str(rec)
    args = ["--record"]
    if record == "same":
        args.append(str(rec))
    elif record == "same-overwrite":
        args += [str(rec), "--overwrite"]
    elif record == "trailing-slash":
        source, args = str(rec) + "/", args + [str(tmp_path / "x" / ".." / "R"), "--overwrite"]
    elif record == "inside":
        args.append(str(rec / "frames" / "again"))
    elif record == "parent":
        args += [str(tmp_path), "--overwrite"]
    else:
        (tmp_path / "L").symlink_to(rec)
        source, args = str(tmp_path / "L"), args + [str(rec), "--overwrite"]
    assert main(["replay", source, *args, "--quiet"]) == 2
    assert digest(rec) == before  # not one byte changed
    again = Recording.open(rec)
    assert again.complete and len(again) == 3


def test_replay_refusal_names_the_flag_and_the_rule(tmp_path, capsys):
    from livetrack.cli import main

    rec = tmp_path / "R"
    write_small(rec, n=2)
    assert main(["replay", str(rec), "--record", str(rec), "--overwrite", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--record" in err and "is the recording being replayed" in err and "never writes over" in err


def test_overwrite_replaces_only_once_the_new_recording_is_complete(tmp_path):
    path = tmp_path / "R"
    write_small(path, n=3)
    old, mode = digest(path), path.stat().st_mode & 0o777
    writer = RecordingWriter(path, CAMERA, TARGETS, overwrite=True, png_compression=0)
    writer.write_frame(np.zeros((48, 64), np.uint8), timestamp_ns=5, exposure_us=1.0, gain_db=0.0)
    assert digest(path) == old  # the old recording is untouched while the new one is written
    assert writer.directory != path and writer.directory.parent == path.parent
    writer.close()
    new = Recording.open(path)
    assert new.complete and len(new) == 1
    assert hidden_siblings(path) == []  # nothing left beside it
    assert path.stat().st_mode & 0o777 == mode  # not the 0700 of a temporary directory


def test_overwrite_by_a_run_that_fails_keeps_the_old_recording(tmp_path):
    path = tmp_path / "R"
    write_small(path, n=3)
    old = digest(path)
    with pytest.raises(RuntimeError, match="disk on fire"), \
            RecordingWriter(path, CAMERA, TARGETS, overwrite=True, png_compression=0) as writer:
        writer.write_frame(np.zeros((48, 64), np.uint8), timestamp_ns=5, exposure_us=1.0, gain_db=0.0)
        raise RuntimeError("disk on fire")
    assert digest(path) == old
    (kept,) = hidden_siblings(path)  # the new one, complete, for whoever wants it
    assert Recording.open(kept).complete and len(Recording.open(kept)) == 1


def test_sim_out_onto_an_existing_recording_needs_overwrite_and_says_so(tmp_path, capsys):
    from livetrack.cli import main

    path = tmp_path / "R"
    write_small(path, n=2)
    old = digest(path)
    assert main(["sim", "--scenario", str(small_scenario(tmp_path)), "--out", str(path), "--max-frames", "2"]) == 2
    err = capsys.readouterr().err
    assert "--overwrite" in err and "overwrite=True" not in err
    assert digest(path) == old
    assert main(["sim", "--scenario", str(small_scenario(tmp_path)), "--out", str(path), "--max-frames", "2",
                 "--overwrite"]) == 0
    new = Recording.open(path)
    assert new.complete and len(new) == 2 and new.camera.width == 160
    assert hidden_siblings(path) == []


def test_kill_9_during_run_record_overwrite_keeps_the_old_recording(tmp_path):
    path = tmp_path / "R"
    write_small(path, n=3)
    old = digest(path)
    proc = subprocess.Popen([sys.executable, "-c", RUNNER, "run", "--source", f"sim:{small_scenario(tmp_path)}",
                             "--record", str(path), "--overwrite", "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + SUBPROCESS_TIMEOUT_S
        while time.monotonic() < deadline and proc.poll() is None:
            new = [p for p in hidden_siblings(path) if (p / "frames.csv").is_file()]
            if new and len((new[0] / "frames.csv").read_text().splitlines()) > 3:
                break
            time.sleep(0.05)
        assert proc.poll() is None, proc.communicate()
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.communicate(timeout=SUBPROCESS_TIMEOUT_S)
    assert digest(path) == old
    assert Recording.open(path).complete and len(Recording.open(path)) == 3
    (partial,) = hidden_siblings(path)  # the interrupted new recording, readable
    assert len(Recording.open(partial)) >= 3


# ---------------------------------------------------------------------------------------------- finding 9
def test_lossless_slot_waits_instead_of_dropping_and_counts_refusals():
    slot: DropSlot[int] = DropSlot(1, lossless=True)
    assert slot.put(0)
    threading.Timer(0.1, slot.get, args=(1.0,)).start()
    t0 = time.monotonic()
    assert slot.put(1)  # waited for the reader
    assert time.monotonic() - t0 >= 0.05 and slot.waited == 1 and slot.dropped == 0
    slot.close()
    assert not slot.put(2) and slot.dropped == 1  # refused after close: counted, never silent


def test_a_slow_recorder_gets_every_acquired_frame_through_back_pressure():
    recorder = ListSink("rec", consumes="frames", delay_s=0.01)
    recorder.lossless = True  # type: ignore[attr-defined]
    source = FakeSource(n=40, live=True, period_s=0.001)
    summary = run_bounded(Pipeline(source, FakeTracker(), [recorder], PipelineOptions(),
                                   sink_queue_sizes={"rec": 2}))
    assert [f.frame_id for f in recorder.items] == list(range(40))
    stats = summary.sinks["rec"]
    assert stats["dropped"] == 0 and stats["waited"] > 0 and stats["wait_ms"] > 0


class GappySource(FakeSource):
    """A live source whose ids skip (frames it dropped before livetrack saw them), and then restart."""

    IDS = [0, 1, 2, 5, 6, 9, 3, 4]

    def read(self, timeout_s: float = 1.0) -> Frame | None:
        if self.next_id >= len(self.IDS):
            raise EOFError
        frame = super().read(timeout_s)
        assert frame is not None
        return Frame(image=frame.image, frame_id=self.IDS[frame.frame_id], timestamp_ns=frame.timestamp_ns,
                     host_timestamp_ns=frame.host_timestamp_ns, exposure_us=frame.exposure_us, gain_db=0.0)


def test_recording_sink_writes_the_source_ids_so_gaps_show(tmp_path, caplog):
    sink = RecordingSink(tmp_path / "rec", CAMERA, TARGETS, png_compression=0, fsync_every_n_frames=0)
    summary = run_bounded(Pipeline(GappySource(n=None), FakeTracker(), [sink], PipelineOptions()))
    rec = Recording.open(tmp_path / "rec")
    assert rec.complete and not rec.skipped
    # gaps kept; after the counter went back (9 -> 3), the next free ids, the source's kept beside them
    assert [f.frame_id for f in rec.frames] == [0, 1, 2, 5, 6, 9, 10, 11]
    assert [f.extra["source_frame_id"] for f in rec.frames] == [str(i) for i in GappySource.IDS]
    assert summary.sinks["record"]["renumbered"] == 2 and summary.sinks["record"]["dropped"] == 0
    assert "written as 10" in caplog.text
    for record, image in rec.iter_images():
        assert int(image[0, 0]) == rec.frames.index(record)  # each id names its own frame


def test_writer_frame_ids_must_increase(tmp_path):
    with RecordingWriter(tmp_path / "r", CAMERA, TARGETS, png_compression=0) as writer:
        image = np.zeros((48, 64), np.uint8)
        assert writer.write_frame(image, timestamp_ns=0, exposure_us=1.0, gain_db=0.0, frame_id=4) == 4
        with pytest.raises(ValueError, match="greater than the previous"):
            writer.write_frame(image, timestamp_ns=0, exposure_us=1.0, gain_db=0.0, frame_id=4)
        assert writer.write_frame(image, timestamp_ns=0, exposure_us=1.0, gain_db=0.0) == 5
    rec = Recording.open(tmp_path / "r")
    assert [f.frame_id for f in rec.frames] == [4, 5] and [f.file for f in rec.frames] == [
        "frames/000004.png", "frames/000005.png"]


def test_run_record_under_load_loses_no_acquired_frame_and_shows_source_drops(tmp_path):
    """The issue's case: a live source faster than the recorder (fsync every frame, full PNG compression)."""
    out = tmp_path / "rec"
    config = tmp_path / "c.yaml"
    config.write_text("outputs:\n  record:\n    png_compression: 9\n    fsync_every_n_frames: 1\n    queue_size: 1\n")
    proc = subprocess.run([sys.executable, "-c", RUNNER, "run", "--source", f"sim:{small_scenario(tmp_path)}",
                           "--config", str(config), "--record", str(out), "--max-frames", "90", "--quiet"],
                          capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT_S)
    assert proc.returncode == 0, proc.stderr
    rec = Recording.open(out)
    summary = proc.stdout
    acquired = int(summary.split(" acquired")[0].split(" of ")[-1])
    assert rec.complete and len(rec) == acquired and "sink record: handled" in summary
    assert "sink record 0" in summary  # drops: none at the recorder
    ids = [f.frame_id for f in rec.frames]
    assert ids == sorted(ids) and [int(f.extra["source_frame_id"]) for f in rec.frames] == ids
    source_dropped = int(summary.split("source: ")[1].split("dropped ")[1].split()[0].rstrip(","))
    assert ids[-1] + 1 - len(ids) <= source_dropped  # every gap is a frame the source says it dropped


def test_a_hung_recorder_cannot_hang_shutdown_and_what_it_held_is_counted(caplog):
    """A disk that stops answering: acquisition waits for the recorder (it must not lose frames), but stop()
    still ends the run within the close timeouts, and the frames it never wrote are counted and warned."""
    release = threading.Event()

    class HungRecorder(ListSink):
        lossless = True

        def handle(self, item):
            release.wait(30.0)  # the disk hangs (released at the end of the test)
            super().handle(item)

    recorder = HungRecorder("rec", consumes="frames")
    pipeline = Pipeline(FakeSource(n=None, live=True, period_s=0.005), FakeTracker(), [recorder],
                        PipelineOptions(sink_close_timeout_s=0.5, read_timeout_s=0.1), sink_queue_sizes={"rec": 2})
    pipeline.start()
    time.sleep(0.3)
    pipeline.stop("test")
    t0 = time.monotonic()
    try:
        assert pipeline.wait(10.0)
        summary = pipeline.close()
    finally:
        release.set()
    assert time.monotonic() - t0 < 8.0
    stats = summary.sinks["rec"]
    assert stats["dropped"] >= 2 and stats["waited"] >= 1  # the queued frames (and any refused one), counted
    assert summary.frames_acquired == stats["handled"] + stats["dropped"] + (1 if not stats["closed"] else 0)
    assert "discarding" in caplog.text and "data lost" in caplog.text


# The recorder's encoder hangs (as a slow PNG encoder that the camera outruns, for good): frames the pipeline
# handed over are spooled in submit(), before they wait for the encoder.
KILL_WHILE_ENCODING = """
import sys, threading, time
import numpy as np
from livetrack.camera import CameraModel
from livetrack.sinks.recording_sink import RecordingSink
from livetrack.sinks.runner import SinkRunner
from livetrack.sources.base import Frame
from livetrack.targets.spec import TargetSpec

camera = CameraModel(width=64, height=48, fx=60.0, fy=60.0, cx=31.5, cy=23.5)
sink = RecordingSink(sys.argv[1], camera, [TargetSpec.default(3, 0.1)], png_compression=0)
runner = SinkRunner(sink, queue_size=4)
runner.start()
sink._writer.convert = lambda spooled: threading.Event().wait()  # the encoder never finishes
for i in range(5):  # one in the encoder, four queued: the queue is full
    runner.submit(Frame(image=np.full((48, 64), i, np.uint8), frame_id=i, timestamp_ns=i,
                        host_timestamp_ns=time.time_ns(), exposure_us=100.0, gain_db=0.0))
print("handed over", flush=True)
time.sleep(60)
"""


def test_kill_9_loses_no_frame_that_awaits_the_encoder(tmp_path):
    """Before spooling, the frames queued for the PNG encoder were in memory only: a kill -9 lost them all."""
    out = tmp_path / "rec"
    proc = subprocess.Popen([sys.executable, "-c", KILL_WHILE_ENCODING, str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line == "handed over\n", proc.stderr.read() if proc.stderr else ""
    finally:
        proc.kill()  # SIGKILL
        proc.communicate(timeout=SUBPROCESS_TIMEOUT_S)
    assert proc.returncode == -signal.SIGKILL
    rec = Recording.open(out)
    assert not rec.complete and [f.frame_id for f in rec.frames] == [0, 1, 2, 3, 4]
    images = list(rec.iter_images())
    assert not rec.skipped and [int(image[0, 0]) for _, image in images] == [0, 1, 2, 3, 4]
    assert sorted(p.suffix for p in (out / "frames").iterdir()) == [".pgm"] * 5  # none encoded, none lost


def test_a_failing_prepare_counts_as_the_sinks_error_and_is_not_queued(caplog):
    from livetrack.sinks.runner import SinkRunner

    class Failing(ListSink):
        def prepare(self, item):
            if item == 1:
                raise OSError("disk full")
            return item * 10

    sink = Failing("f", consumes="frames")
    runner = SinkRunner(sink, queue_size=4)
    runner.start()
    assert [runner.submit(i) for i in (0, 1, 2)] == [True, False, True]
    runner.close(5.0)
    assert sink.items == [0, 20]
    summary = runner.summary()
    assert summary["errors"] == 1 and summary["handled"] == 2 and "error #1 in prepare" in caplog.text


def test_overwrite_whose_final_rename_fails_puts_the_old_recording_back(tmp_path, monkeypatch):
    path = tmp_path / "R"
    write_small(path, n=3)
    old = digest(path)
    writer = RecordingWriter(path, CAMERA, TARGETS, overwrite=True, png_compression=0)
    writer.write_frame(np.zeros((48, 64), np.uint8), timestamp_ns=5, exposure_us=1.0, gain_db=0.0)
    real_replace = os.replace

    def failing_replace(src, dst):
        if Path(src) == writer.directory:
            raise OSError("injected: rename failed")
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(OSError, match="injected"):
        writer.close()
    monkeypatch.undo()
    assert digest(path) == old  # the old recording is back in place
    (new,) = hidden_siblings(path)  # the complete new one, beside it
    assert Recording.open(new).complete and len(Recording.open(new)) == 1
