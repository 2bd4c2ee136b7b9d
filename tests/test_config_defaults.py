"""One home for each default: the config's tracker and pipeline sections are completed from TrackerOptions and
PipelineOptions; default.yaml holds only what the live config sets otherwise. And ``pipeline.search_worker``."""

import dataclasses
from importlib import resources

import pytest
import yaml

from livetrack.config.app import PIPELINE_KEYS, load_config
from livetrack.config.checks import ConfigError
from livetrack.estimator.tracker import TrackerOptions
from livetrack.pipeline import PipelineOptions, build_pipeline


def _default_yaml() -> dict:
    text = resources.files("livetrack").joinpath("data/config/default.yaml").read_text(encoding="utf-8")
    return yaml.safe_load(text)


def test_default_yaml_repeats_no_dataclass_default():
    """A key of default.yaml's tracker / pipeline section that equals the dataclass default is a second home for
    that default: write it in the dataclass only."""
    raw = _default_yaml()
    tracker_defaults, pipeline_defaults = TrackerOptions(), PipelineOptions()
    for key, value in (raw.get("tracker") or {}).items():
        if hasattr(tracker_defaults, key):
            assert getattr(tracker_defaults, key) != value, f"tracker.{key}: the TrackerOptions default again"
    for key, value in (raw.get("pipeline") or {}).items():
        assert key != "search_worker" and getattr(pipeline_defaults, key) != value, f"pipeline.{key} repeated"


def test_the_loaded_defaults_are_the_dataclasses_with_the_live_settings():
    raw = _default_yaml()
    config = load_config(None)
    live = {k: v for k, v in raw["tracker"].items() if k != "propagate_camera_uncertainty"}
    assert config.tracker == dataclasses.replace(TrackerOptions(), **live)
    defaults = PipelineOptions()
    assert {k: getattr(config.pipeline, k) for k in PIPELINE_KEYS} == {k: getattr(defaults, k) for k in PIPELINE_KEYS}
    dumped = yaml.safe_load(config.to_yaml())  # dump-config: every key with its value
    fields = [f.name for f in dataclasses.fields(TrackerOptions) if f.name != "camera_std"]
    assert list(dumped["tracker"]) == [*fields, "propagate_camera_uncertainty"]
    assert dumped["tracker"]["edge_half_width_px"] == TrackerOptions().edge_half_width_px
    assert list(dumped["pipeline"]) == PIPELINE_KEYS and dumped["pipeline"]["search_worker"] == "auto"


@pytest.mark.parametrize(("value", "expected"), [("auto", None), ("on", True), ("off", False), (True, True),
                                                 (False, False)])
def test_search_worker_key(value, expected):
    config = load_config(None, {"pipeline": {"search_worker": value}})
    assert config.pipeline.search_worker is expected
    assert yaml.safe_load(config.to_yaml())["pipeline"]["search_worker"] == {None: "auto", True: "on",
                                                                              False: "off"}[expected]


@pytest.mark.parametrize("value", ["sometimes", None, 1, ["on"]])
def test_a_bad_search_worker_names_the_key(value):
    with pytest.raises(ConfigError, match=r"pipeline\.search_worker.*auto, on or off"):
        load_config(None, {"pipeline": {"search_worker": value}})


def test_yaml_on_off_in_a_file_and_build_pipeline_follows_the_config(tmp_path):
    file = tmp_path / "c.yaml"
    file.write_text("pipeline:\n  search_worker: off\n", encoding="utf-8")
    config = load_config(file, {"source": {"uri": "sim:", "options": {"max_frames": 1}}})
    assert config.pipeline.search_worker is False
    for given, expected in ((None, False), (True, True)):
        pipeline = build_pipeline(config, console=False, search_worker=given)
        try:
            assert pipeline.search_worker is expected
        finally:
            pipeline.source.close()
