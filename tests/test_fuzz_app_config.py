"""Property-based fuzzing of the config loader: whatever a ``--config`` file holds, ``load_config`` returns a
validated config or raises ``ConfigError`` naming the file, never anything else, never hangs (deadline); what it
accepts is within the sane ranges. Seeded (derandomized) and bounded."""

from __future__ import annotations

from datetime import timedelta

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from livetrack.config import app as app_config
from livetrack.config.app import AppConfig, default_config_data
from livetrack.config.checks import ConfigError
from livetrack.tools.fuzz_targets import ConfigTarget, config_seeds

FUZZ = settings(max_examples=80, deadline=timedelta(seconds=5), derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])
DEFAULTS = default_config_data()
SECTION_KEYS = [(section, key) for section, value in DEFAULTS.items() if isinstance(value, dict) for key in value]


@pytest.fixture(scope="module")
def target():
    target = ConfigTarget()
    yield target
    target.close()


def load_or_reject(target: ConfigTarget, data: bytes) -> AppConfig | None:
    try:
        config = target(data)
    except ConfigError as exc:
        assert "config.yaml" in str(exc)  # names the file
        return None
    assert isinstance(config, AppConfig)
    p = config.pipeline
    assert 1 <= p.sink_queue_size <= app_config.MAX_QUEUE and 1 <= p.slot_size <= app_config.MAX_QUEUE
    assert 24 <= config.tracker.max_points_per_circle <= app_config.MAX_POINTS_PER_CIRCLE
    return config


scalars = (st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats() | st.text(max_size=10)
           | st.sampled_from(["sim:", "replay:x", "aravis:", "v4l2:/dev/video0", "bogus:", "127.0.0.1:5005",
                              "tcp://127.0.0.1:1", "save:x.rrd", "off", "spawn", "1GiB", "binary", "json"]))
values = st.recursive(scalars, lambda children: st.lists(children, max_size=3)
                      | st.dictionaries(st.text(max_size=6), children, max_size=3), max_leaves=8)


@FUZZ
@given(st.lists(st.tuples(st.sampled_from(SECTION_KEYS), values), min_size=1, max_size=4))
def test_known_keys_with_any_values(target, changes):
    data: dict = {}
    for (section, key), value in changes:
        data.setdefault(section, {})[key] = value
    load_or_reject(target, yaml.safe_dump(data).encode())


@FUZZ
@given(st.dictionaries(st.sampled_from([*DEFAULTS, "extra"]), values, max_size=3))
def test_sections_with_any_values(target, data):
    load_or_reject(target, yaml.safe_dump(data).encode())


@FUZZ
@given(st.integers(0, 1), st.integers(0, 5000), st.binary(max_size=40), st.integers(0, 40))
def test_byte_splices_of_real_configs(target, which, position, insert, cut):
    seed = config_seeds()[which]
    position = min(position, len(seed))
    load_or_reject(target, seed[:position] + insert + seed[position + cut:])
