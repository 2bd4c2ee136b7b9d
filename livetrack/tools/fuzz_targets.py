"""Fuzz targets: the parsers of untrusted input, each with the one exception type it documents.

A target takes arbitrary bytes and must return or raise its documented error, never anything else, and never
hang. Shared by the hypothesis tests (``tests/test_fuzz_*.py``) and the long campaign
(``python -m livetrack.tools.fuzz TARGET --seconds N``).

=================  ==========================================================  =================
target             input bytes                                                 documented error
=================  ==========================================================  =================
``pose-message``   one datagram for ``livetrack.sinks.pose_message.decode``     ``MessageError``
``recording``      recording.yaml, frames.csv, truth.csv joined by ``SPLIT``   ``RecordingError``
                   (written into a directory, then ``Recording.open``)
``config``         a ``--config`` file for ``livetrack.config.app.load_config``  ``ConfigError``
=================  ==========================================================  =================
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

SPLIT = b"\n%%%%\n"  # separates the files of a recording input


@dataclass(frozen=True)
class FuzzTarget:
    name: str
    run: Callable[[bytes], object]  # returns a value or raises one of ``errors``
    errors: tuple[type[BaseException], ...]
    seeds: Callable[[], list[bytes]]


# ---------------------------------------------------------------------------------------------- pose message
def run_pose_message(data: bytes) -> object:
    from livetrack.sinks.pose_message import decode

    return decode(data)


def pose_message_seeds() -> list[bytes]:
    import math

    from livetrack.sinks.pose_message import PoseMessage

    message = PoseMessage(sequence=17, frame_id=40, device_timestamp_ns=1333333333,
                          host_timestamp_ns=1795464084563051454, target_id=3, n_targets=2, target_index=1,
                          t_m=(-0.12, -0.04, 2.2), q_xyzw=(0.171, 0.03, 0.087, 0.981),
                          covariance_upper=tuple(1e-8 * (i + 1) for i in range(21)), delta_px=-0.003,
                          delta_std_px=math.nan, exposure_us=505.5, residual_rms_px=0.41, latency_ms=38.2,
                          n_edge_points=1012, ok=True, heading_known=False)
    return [message.to_binary(), message.to_json()]


def _pose_message_errors() -> tuple[type[BaseException], ...]:
    from livetrack.sinks.pose_message import MessageError

    return (MessageError,)


# ---------------------------------------------------------------------------------------------- recording
RECORDING_YAML_SEED = b"""format: livetrack-recording
version: 1
complete: true
frame_count: 3
camera: {width: 64, height: 48, fx: 60.0, fy: 60.0, cx: 31.5, cy: 23.5, dist: [-0.05, 0, 0, 0, 0], bit_depth: 12}
targets:
  - {id: 3, outer_radius_m: 0.1}
  - id: 19
    outer_radius_m: 0.08
    inner_radius_m: 0.032
    code: {slots: 8, ring_radius_m: 0.056, dot_radius_m: 0.008, bits: "00011011"}
meta: {operator: ab, scene: "lab bench, target on a stage"}
"""
FRAMES_CSV_SEED = b"""frame_id,timestamp_ns,exposure_us,gain_db,file,sensor_temp_c
0,1700000000000000000,2000.0,0.0,frames/000000.png,41.5
1,1700000000033333333,4000.0,0.0,frames/000001.png,"41,5"
2,1700000000066666666,8000.0,1.5,frames/000002.png,
"""
TRUTH_CSV_SEED = b"""frame_id,target_id,tx_m,ty_m,tz_m,qx,qy,qz,qw
0,3,0.01,-0.02,1.5,0.0,0.0,0.0,1.0
1,3,0.01,-0.02,1.5,0.0,0.0,0.0,1.0
"""


class RecordingTarget:
    """Writes the input's files into one scratch directory (reused) and opens it as a recording."""

    def __init__(self, base: Path | None = None) -> None:
        self._base = base
        self._dir: Path | None = None

    def directory(self) -> Path:
        """The scratch directory: in ``base`` if given (the caller removes it), else in /dev/shm or the temp dir."""
        if self._dir is None or not self._dir.is_dir():
            base = self._base or (Path("/dev/shm") if Path("/dev/shm").is_dir() else None)
            if base is not None:
                base.mkdir(parents=True, exist_ok=True)
            self._dir = Path(tempfile.mkdtemp(prefix="livetrack-fuzz-", dir=base))
        return self._dir

    def __call__(self, data: bytes) -> object:
        return self.open_files(*data.split(SPLIT, 2))

    def open_files(self, *parts: bytes) -> object:
        """Writes recording.yaml, frames.csv, truth.csv (those given, the others absent) and opens them."""
        from livetrack.recording import Recording

        folder = self.directory()
        names = ("recording.yaml", "frames.csv", "truth.csv")
        for name, part in zip(names, parts, strict=False):
            (folder / name).write_bytes(part)
        for name in names[len(parts):]:
            (folder / name).unlink(missing_ok=True)
        recording = Recording.open(folder)
        for frame in recording.frames:
            recording.truth(frame.frame_id)
        return recording

    def close(self) -> None:
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None


def recording_seeds() -> list[bytes]:
    return [SPLIT.join([RECORDING_YAML_SEED, FRAMES_CSV_SEED, TRUTH_CSV_SEED]),
            SPLIT.join([RECORDING_YAML_SEED.replace(b"complete: true", b"complete: false"),
                        FRAMES_CSV_SEED[:-3]])]


def _recording_errors() -> tuple[type[BaseException], ...]:
    from livetrack.recording import RecordingError

    return (RecordingError,)


# ---------------------------------------------------------------------------------------------- config
class ConfigTarget:
    """Writes the input as a config file (in one reused scratch directory) and loads it over the defaults."""

    def __init__(self, base: Path | None = None) -> None:
        self._recording = RecordingTarget(base)

    def __call__(self, data: bytes) -> object:
        from livetrack.config.app import load_config

        file = self._recording.directory() / "config.yaml"
        file.write_bytes(data)
        return load_config(file)

    def close(self) -> None:
        self._recording.close()


def config_seeds() -> list[bytes]:
    from importlib import resources

    default = resources.files("livetrack").joinpath("data/config/default.yaml").read_bytes()
    return [default, b"""source: {uri: "sim:", options: {realtime: false, max_frames: 10, seed: 3}}
tracker: {edge_spacing_px: 1.5, max_points_per_circle: 360, psf_halo: [0.1, 12.0], noise_model: [4.0, 0.5]}
targets: [{id: 3, outer_radius_m: 0.125}]
camera: {width: 960, height: 600, fx: 900.0, fy: 900.0, cx: 479.5, cy: 299.5, bit_depth: 12}
pipeline: {max_frames: 100, sink_queue_size: 8}
outputs: {udp: {destination: "127.0.0.1:5005", encoding: json}, zmq: {endpoint: "tcp://127.0.0.1:5556"},
          rerun: {mode: "save:out.rrd"}, record: {dir: rec, overwrite: true}}
logging: {level: info, print_every_s: 1.0}
"""]


def _config_errors() -> tuple[type[BaseException], ...]:
    from livetrack.config.checks import ConfigError

    return (ConfigError,)


TARGET_NAMES = ("pose-message", "recording", "config")


def make_target(name: str, scratch: Path | None = None) -> tuple[FuzzTarget, Callable[[], None]]:
    """The target called ``name`` and a function releasing its scratch files (made in ``scratch`` if given)."""
    if name == "pose-message":
        return FuzzTarget(name, run_pose_message, _pose_message_errors(), pose_message_seeds), lambda: None
    if name == "recording":
        recording = RecordingTarget(scratch)
        return FuzzTarget(name, recording, _recording_errors(), recording_seeds), recording.close
    if name == "config":
        config = ConfigTarget(scratch)
        return FuzzTarget(name, config, _config_errors(), config_seeds), config.close
    raise ValueError(f"unknown fuzz target {name!r} (known: {', '.join(TARGET_NAMES)})")
