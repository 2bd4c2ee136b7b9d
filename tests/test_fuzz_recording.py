"""Property-based fuzzing of the recording reader (frames.csv, truth.csv, recording.yaml): whatever the files
hold, ``Recording.open`` returns a recording or raises ``RecordingError``, never anything else, never hangs
(deadline); a damaged frames.csv line costs that line only, reported at its line number. Seeded (derandomized)
and bounded."""

from __future__ import annotations

import re
from datetime import timedelta

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from livetrack.recording import RecordingError
from livetrack.tools.fuzz_targets import (
    FRAMES_CSV_SEED,
    RECORDING_YAML_SEED,
    TRUTH_CSV_SEED,
    RecordingTarget,
)

FUZZ = settings(max_examples=120, deadline=timedelta(seconds=5), derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])
HEADER = b"frame_id,timestamp_ns,exposure_us,gain_db,file,note\n"


@pytest.fixture(scope="module")
def target():
    target = RecordingTarget()
    yield target
    target.close()


def open_or_reject(target: RecordingTarget, yaml_text: bytes, frames: bytes | None, truth: bytes | None = None):
    parts = [yaml_text] + [p for p in (frames, truth) if p is not None]
    try:
        return target.open_files(*parts)
    except RecordingError as exc:
        assert str(exc).startswith(exc.file)
        return None


text_no_newline = st.binary(max_size=60).map(lambda b: b.replace(b"\n", b""))
csv_noise = st.lists(st.sampled_from([b'"', b",", b"\xff", b"\x00", b"\r", b"1e400", b"-1", b"nan", b"..",
                                      b"/etc/passwd", b" ", b"frames/x.png", b"0", b"\xc3\xa9"]), max_size=10).map(
    b"".join)
bad_line = st.one_of(text_no_newline, csv_noise)


@FUZZ
@given(st.lists(st.one_of(st.tuples(st.just("good"), st.integers(0, 10**9), st.text(max_size=8)),
                          st.tuples(st.just("bad"), bad_line)), max_size=12))
def test_a_damaged_frames_line_costs_that_line_only(target, lines):
    body, good, bad_numbers, number = [HEADER], {}, set(), 1
    for kind, *rest in lines:
        number += 1
        if kind == "good":
            frame_id, note = 10**12 + rest[0], rest[1]
            quoted = '"' + note.replace('"', '""').replace("\n", " ").replace("\r", " ") + '"'
            body.append(f"{frame_id},{frame_id * 7},250.5,0.0,frames/{frame_id}.png,{quoted}\n".encode())
            good.setdefault(frame_id, number)
        else:
            body.append(rest[0] + b"\n")
            bad_numbers.add(number)
    rec = open_or_reject(target, RECORDING_YAML_SEED, b"".join(body))
    assert rec is not None
    kept = {f.frame_id for f in rec.frames}
    assert set(good) <= kept  # every good row survives whatever surrounds it
    for frame_id, reason in rec.skipped:
        line = int(re.search(r"frames.csv line (\d+):", reason).group(1))
        assert line in bad_numbers or (frame_id in good and line != good[frame_id]), reason  # a duplicate id


@FUZZ
@given(st.lists(st.tuples(st.integers(-2, 5), st.integers(-2, 5), *[st.floats() | st.text(max_size=4)] * 7),
                max_size=8))
def test_truth_rows_never_break_the_recording(target, rows):
    truth = TRUTH_CSV_SEED + b"".join(",".join(str(v) for v in row).encode() + b"\n" for row in rows)
    rec = open_or_reject(target, RECORDING_YAML_SEED, FRAMES_CSV_SEED, truth)
    assert rec is not None and len(rec.frames) == 3
    for frame in rec.frames:
        for pose in rec.truth(frame.frame_id).values():
            assert pose.R.shape == (3, 3)


yaml_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats() | st.text(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=10,
)
SEED_YAML = yaml.safe_load(RECORDING_YAML_SEED)
CAMERA_KEYS = sorted(SEED_YAML["camera"]) + ["image_formation", "extra"]
TARGET_KEYS = ["id", "outer_radius_m", "inner_radius_m", "code", "child", "centre_dot_radius_m", "levels"]


@FUZZ
@given(st.dictionaries(st.sampled_from([*sorted(SEED_YAML), "extra"]), yaml_values, max_size=3),
       st.dictionaries(st.sampled_from(CAMERA_KEYS), yaml_values, max_size=3),
       st.dictionaries(st.sampled_from(TARGET_KEYS), yaml_values, max_size=3))
def test_recording_yaml_with_wrong_values(target, top, camera, spec):
    data = {**SEED_YAML, **top}
    if isinstance(data.get("camera"), dict):
        data["camera"] = {**data["camera"], **camera}
    if isinstance(data.get("targets"), list) and data["targets"] and isinstance(data["targets"][0], dict):
        data["targets"] = [{**data["targets"][0], **spec}, *data["targets"][1:]]
    open_or_reject(target, yaml.safe_dump(data).encode(), FRAMES_CSV_SEED)


@FUZZ
@given(st.integers(0, 3), st.integers(0, 2000), st.binary(max_size=40), st.integers(0, 40))
def test_byte_splices_in_any_file(target, which, position, insert, cut):
    files = [RECORDING_YAML_SEED, FRAMES_CSV_SEED, TRUTH_CSV_SEED]
    index = which % 3
    data = files[index]
    position = min(position, len(data))
    files[index] = data[:position] + insert + data[position + cut:]
    open_or_reject(target, *files)
    if which == 3:  # also as an incomplete recording (torn last lines dropped)
        open_or_reject(target, files[0].replace(b"complete: true", b"complete: false"), files[1][:-1], files[2])
