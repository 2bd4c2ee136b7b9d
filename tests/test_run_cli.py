"""``livetrack run / replay / listen / dump-config`` end to end: config validation, the simulated default, UDP on
loopback, SIGINT and SIGKILL during a recording, and a corrupt frame in a replayed recording."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

import livetrack.cli as cli
from livetrack.config.app import load_config, resolved_config_path
from livetrack.config.checks import ConfigError
from livetrack.recording import Recording, RecordingWriter
from livetrack.sim.scenario import Scenario
from livetrack.sinks.pose_message import decode
from livetrack.sinks.recording_sink import CONFIG_FILE_NAME
from livetrack.sinks.udp import UdpSink
from tests.test_sinks import tracked_frames

MY_COMMANDS = ["livetrack.commands.run", "livetrack.commands.replay", "livetrack.commands.listen",
               "livetrack.commands.dump_config"]
SUBPROCESS_TIMEOUT_S = 90.0
# Runs the CLI with this helper's commands registered even before they are added to cli.COMMAND_MODULES.
RUNNER = f"""
import sys
import livetrack.cli as cli
for name in {MY_COMMANDS!r}:
    if name not in cli.COMMAND_MODULES:
        cli.COMMAND_MODULES.append(name)
sys.exit(cli.main(sys.argv[1:]))
"""


@pytest.fixture
def main(monkeypatch):
    monkeypatch.setattr(cli, "COMMAND_MODULES", cli.COMMAND_MODULES + [m for m in MY_COMMANDS
                                                                       if m not in cli.COMMAND_MODULES])
    return cli.main


def write_yaml(path: Path, data) -> Path:
    path.write_text(yaml.safe_dump(data))
    return path


# ---------------------------------------------------------------------------------------------- config
def test_defaults_are_valid_and_everything_off():
    config = load_config()
    assert config.source.uri == "sim:"
    out = config.outputs
    assert out.rerun.mode == "off" and out.udp.destination is None and out.zmq.endpoint is None
    assert out.record.dir is None and out.rerun.serve_bind == "127.0.0.1"


@pytest.mark.parametrize("data, path, problem", [
    ({"outputs": {"udp": {"destinaton": "x:1"}}}, "outputs.udp.destinaton", "unknown key"),
    ({"tracker": {"edge_spacing_px": -1}}, "tracker.edge_spacing_px", "> 0"),
    ({"outputs": {"udp": {"destination": "localhost"}}}, "outputs.udp.destination", "HOST:PORT"),
    ({"outputs": {"rerun": {"mode": "sav:x.rrd"}}}, "outputs.rerun.mode", "save:PATH"),
    ({"outputs": {"zmq": {"endpoint": "udp://1.2.3.4:5"}}}, "outputs.zmq.endpoint", "tcp://"),
    ({"pipeline": {"max_frames": 0}}, "pipeline.max_frames", ">= 1"),
    ({"camera": {"width": 10}}, "camera.height", "missing"),
    ({"targets": [{"id": 1, "outer_radius_m": 0.1}, {"id": 1, "outer_radius_m": 0.2}]}, "targets", "duplicate"),
    ({"logging": {"level": "loud"}}, "logging.level", "one of"),
    ({"extra": 1}, "extra", "unknown key"),
])
def test_config_errors_name_the_file_key_and_problem(tmp_path, data, path, problem):
    file = write_yaml(tmp_path / "bad.yaml", data)
    with pytest.raises(ConfigError) as info:
        load_config(file)
    assert str(info.value).startswith(f"{file}: {path}")
    assert problem in info.value.problem


def test_config_file_paths_are_relative_to_the_file_and_yaml_off_is_off(tmp_path):
    write_yaml(tmp_path / "targets.yaml", {"targets": [{"id": 5, "outer_radius_m": 0.05}]})
    (tmp_path / "c.yaml").write_text("targets: {file: targets.yaml}\noutputs:\n  rerun: {mode: off}\n"
                                     "  record: {dir: rec}\n")
    config = load_config(tmp_path / "c.yaml")
    assert [t.id for t in config.targets] == [5]
    assert config.outputs.rerun.mode == "off"
    assert config.outputs.record.dir == tmp_path / "rec"


def test_camera_file_optics_reach_the_tracker_unless_the_tracker_keys_say_otherwise(tmp_path):
    write_yaml(tmp_path / "cam.yaml", {
        "camera": {"width": 960, "height": 600, "fx": 900, "fy": 900, "cx": 479.5, "cy": 299.5, "bit_depth": 12},
        "optics": {"psf_sigma_px": 0.8, "halo_fraction": 0.03, "halo_sigma_px": 6.0},
        "response": {"read_noise_dn": 2.0}})
    tracker = load_config(write_yaml(tmp_path / "c.yaml", {"camera": {"file": "cam.yaml"}})).tracker
    assert (tracker.psf_sigma_px, tracker.psf_halo, tracker.clip_margin_dn) == (0.8, (0.03, 6.0), 6.0)
    mine = load_config(write_yaml(tmp_path / "d.yaml", {"camera": {"file": "cam.yaml"},
                                                        "tracker": {"psf_halo": [0.05, 4.0], "clip_margin_dn": 0}}))
    assert (mine.tracker.psf_sigma_px, mine.tracker.psf_halo, mine.tracker.clip_margin_dn) == (0.8, (0.05, 4.0), 0)
    plain = load_config(None).tracker
    assert (plain.psf_sigma_px, plain.psf_halo, plain.clip_margin_dn) == (None, None, None)  # None: 1 % of the top code
    with pytest.raises(ConfigError, match=r"tracker\.psf_halo"):
        load_config(write_yaml(tmp_path / "e.yaml", {"tracker": {"psf_halo": [0.03]}}))


def test_overrides_win_and_another_source_drops_foreign_options(tmp_path):
    file = write_yaml(tmp_path / "c.yaml", {"source": {"uri": "sim:", "options": {"realtime": False}}})
    config = load_config(file, {"source": {"uri": "replay:somewhere"}, "outputs": {"udp": {"destination": "h:9"}}})
    assert config.source.uri == "replay:somewhere" and config.source.options == {}
    assert config.outputs.udp.destination == ("h", 9)


def test_dump_config_prints_the_resolved_config(main, tmp_path, capsys):
    file = write_yaml(tmp_path / "c.yaml", {"tracker": {"edge_spacing_px": 2.0}})
    assert main(["dump-config", "--config", str(file), "--udp", "127.0.0.1:7000"]) == 0
    dumped = yaml.safe_load(capsys.readouterr().out)
    assert dumped["tracker"]["edge_spacing_px"] == 2.0
    assert dumped["outputs"]["udp"]["destination"] == "127.0.0.1:7000"
    assert load_config(write_yaml(tmp_path / "again.yaml", dumped)).resolved == dumped  # a fixed point


def test_bad_option_exits_2_naming_the_flag(main, capsys):
    assert main(["run", "--udp", "nohost"]) == 2
    assert "--udp" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------- run, listen
def test_run_simulated_default_streams_udp_and_prints_summary(main, tmp_path, capsys):
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(0.5)
    rrd = tmp_path / "out" / "run.rrd"
    try:
        code = main(["run", "--max-frames", "3", "--udp", f"127.0.0.1:{receiver.getsockname()[1]}",
                     "--rerun", f"save:{rrd}"])
        messages = []
        while True:
            try:
                messages.append(decode(receiver.recv(65536)))
            except TimeoutError:
                break
    finally:
        receiver.close()
    assert code == 0
    out = capsys.readouterr().out
    assert "3 frames processed" in out and "latency" in out and "id 3:" in out
    assert len(messages) == 3 and [m.sequence for m in messages] == [0, 1, 2]
    assert all(m.target_id == 3 and m.ok for m in messages)
    assert all(1.0 < m.distance_m < 3.0 for m in messages)  # the demo scenario's target is 1.6-2.7 m away
    assert rrd.is_file() and "camera:" in resolved_config_path(rrd).read_text()


def test_listen_prints_what_arrives(tmp_path):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-c", RUNNER, "listen", "--udp", f"127.0.0.1:{port}", "--count", "2",
                             "--duration", "60"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _, items = tracked_frames()
    sink = UdpSink("127.0.0.1", port, encoding="json")
    sink.open()
    try:
        deadline = time.monotonic() + SUBPROCESS_TIMEOUT_S
        while proc.poll() is None and time.monotonic() < deadline:  # until the listener is up and has 2
            sink.handle(items[0])
            time.sleep(0.1)
    finally:
        sink.close()
    out, err = proc.communicate(timeout=SUBPROCESS_TIMEOUT_S)
    assert proc.returncode == 0, err
    lines = out.strip().splitlines()
    assert len(lines) == 2 and all(" id   3 " in line and "ok" in line for line in lines)
    assert "2 messages, 0 invalid" in err


# ---------------------------------------------------------------------------------------------- signals
def _start_recording_run(out: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", RUNNER, "run", "--record", str(out), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_frames(out: Path, n: int, proc: subprocess.Popen) -> None:
    deadline = time.monotonic() + SUBPROCESS_TIMEOUT_S
    while time.monotonic() < deadline and proc.poll() is None:
        csv = out / "frames.csv"
        if csv.is_file() and len(csv.read_text().splitlines()) > n:
            return
        time.sleep(0.1)
    proc.kill()
    raise AssertionError(f"no {n} frames recorded: {proc.communicate()}")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_during_recording_stops_cleanly_and_completes_it(tmp_path, sig):
    out = tmp_path / "rec"
    proc = _start_recording_run(out)
    _wait_for_frames(out, 3, proc)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=SUBPROCESS_TIMEOUT_S)
    assert proc.returncode == 0, stderr
    assert f"stopped by {sig.name}" in stdout and f"{sig.name}: stopping" in stderr
    rec = Recording.open(out)
    assert rec.complete and len(rec) >= 3
    assert sum(1 for _ in rec.iter_images()) == len(rec) and not rec.skipped
    assert (out / CONFIG_FILE_NAME).is_file()


def test_sigkill_during_recording_leaves_a_readable_recording(tmp_path):
    out = tmp_path / "rec"
    proc = _start_recording_run(out)
    _wait_for_frames(out, 2, proc)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=SUBPROCESS_TIMEOUT_S)
    rec = Recording.open(out)
    assert not rec.complete and len(rec) >= 2
    assert sum(1 for _ in rec.iter_images()) == len(rec)  # every listed frame is complete


# ---------------------------------------------------------------------------------------------- replay
def _small_recording(path: Path, n: int = 4) -> Recording:
    scenario = Scenario.default()
    with RecordingWriter(path, scenario.camera, scenario.targets, png_compression=0) as writer:
        for k in range(n):
            sim = scenario.render_frame(k, noise=False)
            writer.write_frame(sim.image, timestamp_ns=sim.timestamp_ns, exposure_us=sim.exposure_us,
                               gain_db=sim.gain_db, truth=sim.truth)
    return Recording.open(path)


def test_replay_skips_and_reports_a_corrupt_frame(main, tmp_path, capsys):
    rec = _small_recording(tmp_path / "rec")
    corrupt = rec.path / rec.frames[1].file
    corrupt.write_bytes(corrupt.read_bytes()[:200])  # truncated PNG
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(0.5)
    try:
        code = main(["replay", str(rec.path), "--udp", f"127.0.0.1:{receiver.getsockname()[1]}", "--quiet"])
        frame_ids = []
        while True:
            try:
                frame_ids.append(decode(receiver.recv(65536)).frame_id)
            except TimeoutError:
                break
    finally:
        receiver.close()
    assert code == 0
    out = capsys.readouterr().out
    assert "3 frames processed of 3 acquired" in out and "skipped 1" in out
    assert frame_ids == [0, 2, 3]


def test_replay_of_recording_with_its_own_truth_matches(main, tmp_path, capsys):
    rec = _small_recording(tmp_path / "rec", n=3)
    out = tmp_path / "again"
    assert main(["replay", str(rec.path), "--record", str(out), "--quiet"]) == 0
    again = Recording.open(out)
    assert again.complete and len(again) == 3
    for (_, a), (_, b) in zip(rec.iter_images(), again.iter_images(), strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(again.truth(again.frames[0].frame_id)[3].t, rec.truth(rec.frames[0].frame_id)[3].t)


def test_output_that_cannot_open_exits_1_with_a_hint(main, tmp_path, capsys):
    rec = _small_recording(tmp_path / "rec", n=1)
    other = _small_recording(tmp_path / "other", n=2)
    assert main(["replay", str(rec.path), "--record", str(other.path), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "cannot open an output" in err and "--overwrite" in err and "overwrite=True" not in err
    assert Recording.open(other.path).complete and len(Recording.open(other.path)) == 2  # untouched


def test_source_option_errors_name_the_config_key(main, tmp_path, capsys):
    file = write_yaml(tmp_path / "c.yaml", {"source": {"uri": "sim:", "options": {"bogus": 1}}})
    assert main(["run", "--config", str(file)]) == 2
    assert "source.options.bogus: unknown key" in capsys.readouterr().err
