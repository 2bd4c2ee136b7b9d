"""``livetrack record-sweep``: an exposure sweep recorded from the simulated camera and from Aravis's fake GigE Vision
camera (tests/aravis_fake.py; with LIVETRACK_REQUIRE_ARAVIS=1 a missing Aravis fails instead of skipping)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from livetrack.cli import main as cli_main
from livetrack.commands.record_sweep import parse_exposures, record_sweep, settled
from livetrack.config.checks import ConfigError
from livetrack.recording import Recording, RecordingWriter
from livetrack.sim.scenario import Scenario
from livetrack.sources import open_source
from livetrack.sources.sim_source import SimSource
from tests.test_sources_aravis import fake, fake_camera, full_frame_options  # noqa: F401 (fixtures)


def test_exposure_list_is_parsed_and_checked() -> None:
    assert parse_exposures("500, 1000,2000.5,") == [500.0, 1000.0, 2000.5]
    for bad in ("", "500,abc", "500,-1", "0"):
        with pytest.raises(ConfigError, match="--exposures"):
            parse_exposures(bad)


@dataclass
class _Frame:
    exposure_us: float
    meta: dict = field(default_factory=dict)


def test_a_frame_counts_only_once_the_exposure_is_in_force() -> None:
    assert settled(_Frame(1000.0, {"frames_since_change": 2}), 1000.0)
    assert not settled(_Frame(1000.0, {"frames_since_change": 1}), 1000.0)  # default: 2 frames to settle
    assert settled(_Frame(1000.0, {"frames_since_change": 1}), 1000.0, settle_frames=1)
    assert settled(_Frame(1000.4, {}), 1000.0)  # the sim: per-frame exposure, no read-back counter
    assert not settled(_Frame(500.0, {"frames_since_change": 3}), 1000.0)  # the old exposure
    assert not settled(_Frame(1000.0, {"frames_since_change": 0}), 1000.0)  # maybe exposed before the change
    assert settled(_Frame(1000.0, {"frames_since_change": 0, "exposure_source": "chunk"}), 1000.0)


def test_sweep_of_the_simulated_camera(tmp_path) -> None:
    scenario = Scenario.default()
    exposures = [300.0, 900.0, 2700.0]
    with SimSource(scenario, realtime=False, noise=False) as source, \
            RecordingWriter(tmp_path / "rec", source.camera, source.targets) as writer:
        summary = record_sweep(source, writer, exposures, 2)
    assert summary.written == [2, 2, 2] and summary.applied_us == exposures
    rec = Recording.open(tmp_path / "rec")
    assert rec.complete and [f.exposure_us for f in rec.frames] == [300.0, 300.0, 900.0, 900.0, 2700.0, 2700.0]
    means = [float(image.mean()) for _, image in rec.iter_images()]
    assert means[2] > 2.0 * means[0] and means[4] > 2.0 * means[2]  # the images follow the exposure
    assert all(rec.truth(f.frame_id) for f in rec.frames)  # the sim's truth poses are kept
    assert [t.id for t in rec.targets] == [t.id for t in scenario.targets]


def test_command_records_and_refuses_to_overwrite(tmp_path, capsys) -> None:
    out = tmp_path / "sweep"
    args = ["record-sweep", "--source", "sim:", "--exposures", "500,2000,8000", "--frames-per-exposure", "1",
            "--out", str(out)]
    assert cli_main(args) == 0
    rec = Recording.open(out)
    assert [f.exposure_us for f in rec.frames] == [500.0, 2000.0, 8000.0]
    assert rec.meta["recorded_by"] == "livetrack record-sweep"
    assert cli_main(args) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert cli_main([*args[:-1], str(out), "--overwrite", "--exposures", "1000,4000"]) == 0
    assert [f.exposure_us for f in Recording.open(out).frames] == [1000.0, 4000.0]


def test_replay_cannot_set_the_exposure(tmp_path, capsys) -> None:
    out = tmp_path / "sweep"
    assert cli_main(["record-sweep", "--source", "sim:", "--exposures", "500", "--frames-per-exposure", "1",
                     "--out", str(out)]) == 0
    assert cli_main(["record-sweep", "--source", f"replay:{out}", "--exposures", "500",
                     "--out", str(tmp_path / "again")]) == 1
    assert "cannot set the exposure" in capsys.readouterr().err


def test_sweep_of_the_fake_gige_camera(fake, tmp_path) -> None:  # noqa: F811 (fixture)
    nominal = fake.nominal_exposure_us
    exposures = [round(nominal * f) for f in (0.5, 1.0, 2.0, 4.0)]
    with open_source("aravis:127.0.0.1", full_frame_options(fake, exposure_us=nominal)) as source, \
            RecordingWriter(tmp_path / "rec", source.camera, source.targets) as writer:
        summary = record_sweep(source, writer, exposures, 3)
    assert summary.written == [3, 3, 3, 3]
    assert [abs(a - e) <= 1.0 for a, e in zip(summary.applied_us, exposures, strict=True)] == [True] * 4
    rec = Recording.open(tmp_path / "rec")
    assert len(rec.frames) == 12 and [t.id for t in rec.targets] == [3]
    for frame, image in rec.iter_images():
        # every recorded frame is the fake camera's drawing at the exposure its metadata gives: none was
        # exposed with the previous value
        assert np.array_equal(image, fake.image_at(int(frame.exposure_us)))
    assert sorted({f.exposure_us for f in rec.frames}) == sorted(summary.applied_us)
