"""Property-based fuzzing of the pose-message decoder (binary and JSON): whatever the bytes, ``decode`` returns a
message or raises ``MessageError`` (with a known reason), never anything else, and never hangs (deadline). Valid
messages round-trip exactly. Seeded (derandomized) and bounded, so the default run stays fast."""

from __future__ import annotations

import json
import math
import struct
from datetime import timedelta

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from livetrack.sinks.pose_message import (
    BINARY_SIZE,
    JSON_INT_FIELDS,
    MAGIC,
    REJECT_REASONS,
    MessageError,
    PoseMessage,
    decode,
)
from livetrack.tools.fuzz_targets import pose_message_seeds

FUZZ = settings(max_examples=300, deadline=timedelta(seconds=5), derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])


def decode_or_reject(data: bytes) -> PoseMessage | None:
    """The invariant: a message or a MessageError with a known reason."""
    try:
        message = decode(data)
    except MessageError as exc:
        assert exc.reason in REJECT_REASONS, exc.reason
        assert str(exc)
        return None
    assert isinstance(message, PoseMessage)
    return message


floats = st.floats(allow_nan=True, allow_infinity=True)
finite = st.floats(allow_nan=False, allow_infinity=False)


def int_field(name: str) -> st.SearchStrategy[int]:
    low, high = JSON_INT_FIELDS[name]
    return st.integers(low, high)


messages = st.builds(
    PoseMessage, sequence=int_field("sequence"), frame_id=int_field("frame_id"),
    device_timestamp_ns=int_field("device_timestamp_ns"), host_timestamp_ns=int_field("host_timestamp_ns"),
    target_id=int_field("target_id"), n_targets=st.just(2**16 - 1), target_index=int_field("target_index"),
    t_m=st.tuples(floats, floats, floats), q_xyzw=st.tuples(finite, finite, finite, finite),
    covariance_upper=st.tuples(*[floats] * 21), delta_px=floats, delta_std_px=floats, exposure_us=st.none() | finite,
    residual_rms_px=floats, latency_ms=floats, n_edge_points=int_field("n_edge_points"), ok=st.booleans(),
    heading_known=st.booleans(),
).filter(lambda m: m.target_index < m.n_targets)


@FUZZ
@given(messages)
def test_valid_messages_round_trip_in_both_encodings(message):
    binary = message.to_binary()
    assert decode(binary).to_binary() == binary  # bit-exact, NaN and infinities included
    text = message.to_json()
    back = decode(text)
    assert back.to_json() == text  # non-finite values travel as null and come back as NaN
    assert back.sequence == message.sequence and back.ok == message.ok and back.t_m[:1] == message.t_m[:1] or (
        not math.isfinite(message.t_m[0]))


@FUZZ
@given(st.binary(max_size=400))
def test_arbitrary_bytes(data):
    decode_or_reject(data)


@FUZZ
@given(st.integers(0, 3), st.binary(min_size=0, max_size=BINARY_SIZE + 8))
def test_binary_with_a_valid_header(version, body):
    data = (MAGIC + struct.pack("<H", version) + body)[: BINARY_SIZE + 8]
    message = decode_or_reject(data)
    if len(data) == BINARY_SIZE and version == 1 and message is not None:
        assert message.to_binary()[:6] == data[:6]


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats() | st.text(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=4),
    max_leaves=12,
)
SEED = json.loads(pose_message_seeds()[1])


@FUZZ
@given(st.dictionaries(st.sampled_from(sorted(SEED)), json_values, min_size=1, max_size=4),
       st.lists(st.sampled_from(sorted(SEED)), max_size=2))
def test_json_with_wrong_values(changes, removed):
    data = {**SEED, **changes}
    for key in removed:
        data.pop(key, None)
    message = decode_or_reject(json.dumps(data).encode())  # NaN / Infinity literals included
    if message is not None:
        assert all(type(getattr(message, k)) is int for k in JSON_INT_FIELDS)
        assert type(message.ok) is bool and type(message.heading_known) is bool


@FUZZ
@given(st.integers(0, 2000), st.binary(max_size=64), st.integers(0, 5000))
def test_json_text_splices_and_deep_nesting(position, insert, depth):
    seed = pose_message_seeds()[1]
    position = min(position, len(seed))
    decode_or_reject(seed[:position] + insert + seed[position:])
    decode_or_reject(seed[:position] + b"[" * depth + seed[position:])
