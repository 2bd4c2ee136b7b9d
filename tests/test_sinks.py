"""Sinks on real tracker output: the pose message layout, UDP and ZeroMQ on loopback (incl. faults), the Rerun
.rrd written and read back, and the recording sink."""

from __future__ import annotations

import functools
import json
import math
import socket
import struct
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zmq

from livetrack.estimator.tracker import Tracker
from livetrack.pipeline import Pipeline, PipelineOptions
from livetrack.recording import Recording
from livetrack.sim.scenario import Scenario
from livetrack.sinks.base import TrackedFrame
from livetrack.sinks.console import format_line
from livetrack.sinks.pose_message import BINARY_SIZE, MAGIC, MessageError, PoseMessage, decode, messages_for_frame
from livetrack.sinks.recording_sink import CONFIG_FILE_NAME, RecordingSink
from livetrack.sinks.udp import UdpSink, parse_host_port
from livetrack.sinks.zmq_pub import ZmqPubSink, topic_for
from livetrack.sources.base import Frame
from tests.test_pipeline import FakeTracker, ListSink, run_bounded

RECV_TIMEOUT_S = 5.0


@functools.lru_cache(maxsize=1)
def tracked_frames() -> tuple[Scenario, tuple[TrackedFrame, ...]]:
    """Two noise-free frames of the default scenario (one target, id 3) through the real tracker."""
    scenario = Scenario.default()
    tracker = Tracker(scenario.camera, scenario.targets)
    out = []
    for seq, k in enumerate((1, 4)):
        sim = scenario.render_frame(k, noise=False)
        host_ns = time.time_ns()
        frame = Frame(image=sim.image, frame_id=k, timestamp_ns=sim.timestamp_ns, host_timestamp_ns=host_ns,
                      exposure_us=sim.exposure_us, gain_db=sim.gain_db, truth=sim.truth)
        result = tracker.process(sim.image, sim.exposure_us)
        assert len(result.targets) == 1 and result.targets[0].fit.ok
        out.append(TrackedFrame(sequence=seq, frame=frame, result=result, stage_ms={}, handoff_ns=host_ns + 5_000_000,
                                latency_ms=5.0 + seq))
    return scenario, tuple(out)


class ReplayOf:
    """A lossless source replaying the given frames (``n`` times over)."""

    def __init__(self, frames: list[Frame], camera, targets, repeat: int = 1, gate: threading.Event | None = None):
        self.camera, self.targets, self.live = camera, targets, False
        self._frames = [f for _ in range(repeat) for f in frames]
        self._i = 0
        self._gate = gate

    def open(self) -> None:
        pass

    def read(self, timeout_s: float = 1.0) -> Frame | None:
        if self._gate is not None and not self._gate.wait(timeout_s):
            return None
        if self._i >= len(self._frames):
            raise EOFError
        self._i += 1
        return self._frames[self._i - 1]

    def close(self) -> None:
        pass

    @property
    def stats(self) -> dict[str, int]:
        return {"frames": self._i}


class ReplayTracker:
    """Returns the precomputed result of each frame (by frame id): fast, real TargetResults."""

    def __init__(self, items: tuple[TrackedFrame, ...]):
        self._results = {t.frame.frame_id: t.result for t in items}

    def process(self, image, exposure_us=None):
        for frame_id, result in self._results.items():
            if np.shares_memory(image, self._images[frame_id]):
                return result
        raise AssertionError("unknown image")

    def bind(self, items: tuple[TrackedFrame, ...]) -> ReplayTracker:
        self._images = {t.frame.frame_id: t.frame.image for t in items}
        return self


def udp_receiver() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(RECV_TIMEOUT_S)
    return sock


# ---------------------------------------------------------------------------------------------- message schema
def test_binary_message_layout_matches_the_documented_offsets():
    _, items = tracked_frames()
    item = items[0]
    target = item.result.targets[0]
    (message,) = messages_for_frame(item.result.targets, first_sequence=41, frame_id=item.frame.frame_id,
                                    device_timestamp_ns=item.frame.timestamp_ns,
                                    host_timestamp_ns=item.frame.host_timestamp_ns,
                                    exposure_us=item.frame.exposure_us, latency_ms=item.latency_ms)
    data = message.to_binary()
    assert len(data) == BINARY_SIZE == 320
    assert data[0:4] == MAGIC == b"LTPS"
    assert struct.unpack_from("<HH", data, 4) == (1, 0b11)  # version 1; flags ok + heading known
    assert struct.unpack_from("<Qqqq", data, 8) == (41, item.frame.frame_id, item.frame.timestamp_ns,
                                                    item.frame.host_timestamp_ns)
    assert struct.unpack_from("<iHH", data, 40) == (3, 1, 0)
    np.testing.assert_array_equal(struct.unpack_from("<3d", data, 48), target.fit.pose.t)
    np.testing.assert_array_equal(struct.unpack_from("<4d", data, 72), target.fit.pose.quaternion)
    cov = np.array(struct.unpack_from("<21d", data, 104))
    np.testing.assert_array_equal(cov, target.fit.pose_covariance[np.triu_indices(6)])
    delta, delta_std, exposure, rms, latency = struct.unpack_from("<5d", data, 272)
    assert delta == target.fit.delta_px and exposure == item.frame.exposure_us and latency == item.latency_ms
    assert rms == target.fit.residual_rms_px and delta_std == pytest.approx(target.fit.delta_std_px)
    assert struct.unpack_from("<II", data, 312) == (target.n_edge_points, 0)
    back = decode(data)
    assert back == message
    np.testing.assert_allclose(back.covariance, target.fit.pose_covariance, rtol=1e-12, atol=0)  # symmetrised


def test_json_message_round_trip_with_non_finite_values():
    _, items = tracked_frames()
    (message,) = messages_for_frame(items[1].result.targets, first_sequence=0, frame_id=4, device_timestamp_ns=1,
                                    host_timestamp_ns=2, exposure_us=10.0, latency_ms=3.0)
    text = message.to_json()
    assert text.startswith(b'{"schema":"livetrack.pose","version":1,')
    assert decode(text) == message
    odd = PoseMessage(**{**message.__dict__, "delta_std_px": math.nan})
    assert b'"delta_std_px":null' in odd.to_json()
    assert math.isnan(decode(odd.to_json()).delta_std_px)


@pytest.mark.parametrize("data, problem", [
    (b"XXXX" + bytes(316), "magic"),
    (MAGIC + struct.pack("<H", 3) + bytes(314), "version 3"),
    (MAGIC + struct.pack("<H", 2) + bytes(314), "version 2 message must be 776 bytes"),
    (MAGIC + struct.pack("<H", 1) + bytes(10), "320 bytes"),
    (b'{"schema": "livetrack.pose", "version": 7}', "version 7"),
    (b'{"schema": "livetrack.pose", "version": 1}', "malformed"),
    (b"{not json", "invalid JSON"),
])
def test_decode_rejects_what_it_does_not_know(data, problem):
    with pytest.raises(MessageError, match=problem):
        decode(data)


def test_parse_host_port():
    assert parse_host_port("127.0.0.1:5005") == ("127.0.0.1", 5005)
    assert parse_host_port("[::1]:7") == ("::1", 7)
    for bad in ("nohost", "host:", "host:x", "host:70000"):
        with pytest.raises(ValueError):
            parse_host_port(bad)


# ---------------------------------------------------------------------------------------------- UDP
@pytest.mark.parametrize("encoding", ["binary", "json"])
def test_udp_sink_sends_one_datagram_per_target_per_frame(encoding):
    _, items = tracked_frames()
    with udp_receiver() as receiver:
        port = receiver.getsockname()[1]
        sink = UdpSink("127.0.0.1", port, encoding=encoding)
        sink.open()
        try:
            for item in items:
                sink.handle(item)
            got = [decode(receiver.recv(65536)) for _ in items]
        finally:
            sink.close()
    assert [m.sequence for m in got] == [0, 1]
    assert [m.frame_id for m in got] == [1, 4]
    for message, item in zip(got, items, strict=True):
        fit = item.result.targets[0].fit
        assert message.target_id == 3 and message.ok and message.heading_known
        np.testing.assert_allclose(message.t_m, fit.pose.t, rtol=0, atol=1e-12)
        assert message.latency_ms == item.latency_ms
        truth = item.frame.truth[3].t
        assert np.linalg.norm(np.array(message.t_m) - truth) < 0.02  # the pose sent is the right one
    assert sink.stats["sent"] == 2 and sink.stats["errors"] == 0


def test_udp_unreachable_destinations_are_counted_not_raised():
    _, items = tracked_frames()
    with udp_receiver() as probe:
        closed_port = probe.getsockname()[1]  # bound then closed: nobody listens there
    refused = UdpSink("127.0.0.1", closed_port)
    refused.open()
    for _ in range(5):
        for item in items:
            refused.handle(item)
        time.sleep(0.01)  # let the ICMP port-unreachable come back
    refused.close()
    assert refused.stats["errors"] >= 1
    assert "ECONNREFUSED" in refused.stats["errors_by_kind"]
    forbidden = UdpSink("255.255.255.255", 9)  # broadcast without SO_BROADCAST: EACCES on every send
    forbidden.open()
    forbidden.handle(items[0])
    forbidden.close()
    assert forbidden.stats["sent"] == 0 and forbidden.stats["errors"] == 1


# ---------------------------------------------------------------------------------------------- ZeroMQ
def _bound_pub(sndhwm: int = 100, encoding: str = "binary") -> ZmqPubSink:
    sink = ZmqPubSink("tcp://127.0.0.1:*", encoding=encoding, sndhwm=sndhwm)
    return sink


def test_zmq_pub_topic_per_target_and_same_payload():
    _, items = tracked_frames()
    context = zmq.Context()
    sink = ZmqPubSink("tcp://127.0.0.1:*", context=context)
    sub = context.socket(zmq.SUB)
    try:
        sink.open()
        sub.setsockopt(zmq.SUBSCRIBE, topic_for(3))
        sub.connect(sink.bound_endpoint)
        deadline = time.monotonic() + RECV_TIMEOUT_S
        received = None
        while received is None and time.monotonic() < deadline:  # slow joiner: publish until one arrives
            sink.handle(items[0])
            if sub.poll(100):
                received = sub.recv_multipart()
        assert received is not None, "no message within the timeout"
        topic, payload = received
        assert topic == b"livetrack/pose/3"
        message = decode(payload)
        assert message.target_id == 3 and message.frame_id == items[0].frame.frame_id
        assert sink.bound_endpoint.startswith("tcp://127.0.0.1:")
    finally:
        sub.close(linger=0)
        sink.close()
        context.term()


def test_slow_zmq_subscriber_does_not_stall_publisher_or_tracking():
    scenario, items = tracked_frames()
    context = zmq.Context()
    pub = ZmqPubSink("tcp://127.0.0.1:*", sndhwm=5, context=context)
    gate = threading.Event()  # the source delivers nothing until the subscriber is connected
    source = ReplayOf([t.frame for t in items], scenario.camera, scenario.targets, repeat=300, gate=gate)
    pipeline = Pipeline(source, ReplayTracker(items).bind(items), [pub], PipelineOptions(sink_queue_size=1000))
    sub = context.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 5)
    sub.setsockopt(zmq.RCVBUF, 4096)
    sub.setsockopt(zmq.SUBSCRIBE, b"livetrack/pose/")
    read_while_running = 0
    try:
        pipeline.start()
        sub.connect(pub.bound_endpoint)
        time.sleep(0.3)  # ZeroMQ's slow joiner: let the subscription reach the publisher
        gate.set()
        while not pipeline.wait(0.05):  # read at most one message per 50 ms: far slower than published
            if sub.poll(0):
                sub.recv_multipart()
                read_while_running += 1
        summary = pipeline.close()
        read_after = sum(1 for _ in range(20) if sub.poll(50) and sub.recv_multipart())
    finally:
        pipeline.close()
        sub.close(linger=0)
        context.term()
    assert summary.frames_processed == 600
    assert summary.sinks["zmq"]["handled"] == 600 and summary.sinks["zmq"]["dropped"] == 0  # never waited
    assert read_while_running + read_after >= 1  # the subscriber was connected and got messages
    assert read_while_running < 600


# ---------------------------------------------------------------------------------------------- Rerun
def _rrd_columns(path: Path) -> dict[str, dict]:
    """entity path -> {"static": bool, column name -> list of values} from an .rrd file."""
    import pyarrow as pa
    from rerun.chunk import RrdReader

    out: dict[str, dict] = {}
    for chunk in RrdReader(path).stream().collect().stream():
        entry = out.setdefault(chunk.entity_path, {"static": chunk.is_static})
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            column = batch.column(name)
            if pa.types.is_timestamp(column.type):
                column = column.cast(pa.int64())
            entry.setdefault(name, []).extend(column.to_pylist())
    return out


def test_rerun_save_writes_entities_and_values(tmp_path):
    from livetrack.sinks.rerun_sink import RerunSink

    scenario, items = tracked_frames()
    rrd = tmp_path / "run.rrd"
    sink = RerunSink("save", scenario.camera, scenario.targets, argument=str(rrd), config_text="a: 1\n")
    handed = ListSink("handed")
    summary = run_bounded(Pipeline(ReplayOf([t.frame for t in items], scenario.camera, scenario.targets),
                                   ReplayTracker(items).bind(items), [sink, handed],
                                   PipelineOptions(sink_queue_size=10)))
    assert summary.sinks["rerun"]["handled"] == 2
    from rerun.chunk import RrdReader

    reader = RrdReader(rrd)
    assert [r.application_id for r in reader.recordings()] == ["livetrack"]
    views = {c.entity_path for c in reader.stream(store=reader.blueprints()[0]).collect().stream()}
    assert sum(1 for v in views if v.startswith("/view/") and v.count("/") == 2) == 6  # the blueprint's views
    data = _rrd_columns(rrd)
    for entity in ("/world/camera/image", "/world/camera/image/ellipses", "/world/camera/image/edges",
                   "/world/camera/image/ids", "/world/targets/3", "/world/targets/3/geometry",
                   "/series/distance_m/3", "/series/delta_px/3", "/series/exposure_us", "/series/latency_ms",
                   "/config"):
        assert entity in data, f"{entity} missing from {sorted(data)}"
    assert data["/world/targets/3/geometry"]["static"] and data["/config"]["static"]
    pinhole = [e for p, e in data.items() if p == "/world/camera/image" and e["static"]]
    assert pinhole, "the camera intrinsics are logged static"
    fits = [t.result.targets[0].fit for t in items]
    frames_logged = [e for e in data["/world/targets/3"]["frame"]]
    assert frames_logged == [1, 4]
    np.testing.assert_allclose(data["/world/targets/3"]["Transform3D:translation"],
                               [[list(f.pose.t)] for f in fits], rtol=1e-6)
    np.testing.assert_allclose(np.ravel(data["/series/distance_m/3"]["Scalars:scalars"]),
                               [f.pose.distance_m for f in fits], rtol=1e-12)
    np.testing.assert_allclose(np.ravel(data["/series/latency_ms"]["Scalars:scalars"]),
                               [t.latency_ms for t in handed.items], rtol=1e-12)
    labels = data["/world/camera/image/ids"]["Points2D:labels"]
    assert labels[0][0].startswith("3: ")
    # the 2D overlay is in Rerun's image coordinates: livetrack pixel centre + 0.5
    centre = np.asarray(items[0].result.targets[0].candidate.outer.centre_px)
    np.testing.assert_allclose(data["/world/camera/image/ids"]["Points2D:positions"][0][0], centre + 0.5,
                               rtol=1e-6)


def test_rerun_connect_without_viewer_warns_counts_everything_undelivered_and_closes_at_once(caplog):
    """Issue 12, finding 10: no warning, errors 0 while nothing was delivered, 20 s of extra shutdown."""
    from livetrack.sinks.rerun_sink import RerunSink

    scenario, items = tracked_frames()
    with udp_receiver() as probe:  # a free port number; no gRPC server listens there
        port = probe.getsockname()[1]
    sink = RerunSink("connect", scenario.camera, scenario.targets, argument=f"rerun+http://127.0.0.1:{port}/proxy")
    pipeline = Pipeline(ReplayOf([t.frame for t in items], scenario.camera, scenario.targets, repeat=20),
                        ReplayTracker(items).bind(items), [sink], PipelineOptions())
    pipeline.start()
    assert pipeline.wait(RECV_TIMEOUT_S * 6)
    t0 = time.monotonic()
    summary = pipeline.close()
    assert time.monotonic() - t0 < 2.0  # shutdown not held up by the missing viewer
    stats = summary.sinks["rerun"]
    assert summary.frames_processed == 40 and stats["closed"]
    assert stats["dropped"] == 40  # every item accounted for: undelivered or dropped from the queue
    assert stats["undelivered"] == stats["handled"] > 0 and stats["errors"] >= 1
    warnings = [r for r in caplog.records if r.levelname == "WARNING" and "no viewer at" in r.getMessage()]
    assert len(warnings) == 1  # warned once
    assert f"sink rerun {stats['dropped']}" in summary.format()


def test_rerun_connect_streams_to_a_running_server():
    from livetrack.sinks.rerun_sink import RerunSink

    scenario, items = tracked_frames()
    with udp_receiver() as probe:
        port = probe.getsockname()[1]
    server = RerunSink("serve", scenario.camera, scenario.targets, serve_port=port)  # stands in for a viewer
    server.open()
    try:
        client = RerunSink("connect", scenario.camera, scenario.targets,
                           argument=f"rerun+http://127.0.0.1:{port}/proxy")
        summary = run_bounded(Pipeline(ReplayOf([t.frame for t in items], scenario.camera, scenario.targets),
                                       ReplayTracker(items).bind(items), [client], PipelineOptions()))
    finally:
        server.close()
    assert summary.sinks["rerun"]["logged"] == 2 and summary.sinks["rerun"]["errors"] == 0
    assert "flush_error" not in summary.sinks["rerun"]  # everything was delivered


# ---------------------------------------------------------------------------------------------- recording, console
def test_recording_sink_writes_acquired_frames_with_metadata(tmp_path):
    scenario, items = tracked_frames()
    sink = RecordingSink(tmp_path / "rec", scenario.camera, scenario.targets, meta={"source_uri": "test"},
                         config_text="x: 1\n", png_compression=0)
    frames = [t.frame for t in items]
    summary = run_bounded(Pipeline(ReplayOf(frames, scenario.camera, scenario.targets), FakeTracker(), [sink],
                                   PipelineOptions(), sink_queue_sizes={"record": 10}))
    assert summary.sinks["record"]["written"] == 2
    rec = Recording.open(tmp_path / "rec")
    assert rec.complete and len(rec) == 2 and rec.meta["source_uri"] == "test"
    assert (tmp_path / "rec" / CONFIG_FILE_NAME).read_text() == "x: 1\n"
    for (record, image), frame in zip(rec.iter_images(), frames, strict=True):
        np.testing.assert_array_equal(image, frame.image)
        assert record.exposure_us == frame.exposure_us and record.timestamp_ns == frame.timestamp_ns
        assert record.extra["host_timestamp_ns"] == str(frame.host_timestamp_ns)
        np.testing.assert_allclose(rec.truth(record.frame_id)[3].t, frame.truth[3].t)


def test_console_line_names_id_distance_delta_latency():
    _, items = tracked_frames()
    line = format_line(items[0])
    fit = items[0].result.targets[0].fit
    assert f"id 3: {fit.pose.distance_m:7.4f} m" in line and "latency" in line and "delta" in line


def test_sinks_run_in_their_own_named_threads():
    scenario, items = tracked_frames()
    seen: list[str] = []

    class Probe(UdpSink):
        def handle(self, item):
            seen.append(threading.current_thread().name)
            super().handle(item)

    with udp_receiver() as receiver:
        sink = Probe("127.0.0.1", receiver.getsockname()[1])
        run_bounded(Pipeline(ReplayOf([t.frame for t in items], scenario.camera, scenario.targets),
                             ReplayTracker(items).bind(items), [sink], PipelineOptions(sink_queue_size=10)))
    assert seen == ["livetrack-sink-udp"] * 2


@pytest.mark.skipif(not Path("/proc/net/tcp").is_file(), reason="reads the Linux socket table")
def test_rerun_serve_binds_localhost_by_default():
    from livetrack.sinks.rerun_sink import RerunSink

    scenario, items = tracked_frames()
    with udp_receiver() as probe:
        port = probe.getsockname()[1]
    sink = RerunSink("serve", scenario.camera, scenario.targets, serve_port=port)
    sink.open()
    try:
        sink.handle(items[0])
        table = Path("/proc/net/tcp").read_text().splitlines()[1:]
        local = [line.split()[1] for line in table if line.split()[1].endswith(f":{port:04X}")]
        with socket.create_connection(("127.0.0.1", port), timeout=RECV_TIMEOUT_S):
            pass
    finally:
        sink.close()
    assert local and all(address.startswith("0100007F:") for address in local)  # 127.0.0.1 only
    assert sink.uri == f"rerun+http://127.0.0.1:{port}/proxy"


# ---------------------------------------------------------------------------------------------- hostile input
def sample_message(**changes) -> PoseMessage:
    """A valid message built by hand (no tracker), with ``changes`` applied."""
    fields = dict(sequence=5, frame_id=4, device_timestamp_ns=1, host_timestamp_ns=2, target_id=3, n_targets=1,
                  target_index=0, t_m=(0.1, -0.2, 2.0), q_xyzw=(0.0, 0.0, 0.0, 1.0),
                  covariance_upper=tuple(1e-8 * (i + 1) for i in range(21)), delta_px=-0.003,
                  delta_std_px=0.004, exposure_us=505.5, residual_rms_px=0.41, latency_ms=38.2, n_edge_points=1012,
                  ok=True, heading_known=True)
    return PoseMessage(**{**fields, **changes})


def _valid_json_message() -> dict:
    return json.loads(sample_message().to_json())


@pytest.mark.parametrize("text", [
    b'"sequence":Infinity', b'"sequence":-Infinity', b'"sequence":1e400', b'"sequence":' + b"7" * 5000,
    b'"sequence":NaN', b'"delta_px":1e400', b'"delta_px":' + b"9" * 400,
])
def test_issue12_finding1_overflowing_numbers_are_a_message_error(text):
    base = _valid_json_message()
    name = text.split(b'"')[1].decode()
    data = json.dumps(base).encode().replace(f'"{name}": {json.dumps(base[name])}'.encode(), text)
    assert text in data
    with pytest.raises(MessageError) as info:
        decode(data)
    assert info.value.reason in ("json-syntax", "malformed")


def test_issue12_finding1_deep_nesting_is_a_message_error():
    for data in (b'{"schema":' + b"[" * 30000, b'{"a":' * 12000, b'{"t_m":' + b"[" * 30000 + b"]" * 30000 + b"}"):
        with pytest.raises(MessageError, match="nested too deeply") as info:
            decode(data)
        assert info.value.reason == "json-syntax"
    with pytest.raises(MessageError, match="at most 65536") as info:
        decode(b'{"a":' * 30000)
    assert info.value.reason == "size"


@pytest.mark.parametrize("field, value", [
    ("ok", "false"), ("heading_known", 1), ("sequence", "12"), ("sequence", 1.9), ("sequence", -1),
    ("sequence", 2**64), ("frame_id", 2**63), ("target_id", 2**31), ("n_targets", 70000), ("n_edge_points", -3),
    ("target_index", 1), ("n_targets", True), ("delta_px", "0.1"), ("t_m", [1, 2]), ("q_xyzw", "abcd"),
    ("covariance_upper", [0.0] * 20 + [False]), ("version", True), ("version", 1.0),
])
def test_issue12_finding2_json_fields_are_strictly_typed(field, value):
    data = _valid_json_message()
    data[field] = value
    with pytest.raises(MessageError) as info:
        decode(json.dumps(data).encode())
    assert info.value.reason in ("malformed", "version")


def test_issue12_finding2_valid_extremes_accepted_and_unknown_or_duplicate_keys_rejected():
    data = _valid_json_message()
    data.update(sequence=2**64 - 1, frame_id=-(2**63), target_id=-(2**31), delta_px=None, exposure_us=3)
    message = decode(json.dumps(data).encode())
    assert message.sequence == 2**64 - 1 and math.isnan(message.delta_px) and message.exposure_us == 3.0
    assert type(message.exposure_us) is float
    with pytest.raises(MessageError, match="unknown field"):
        decode(json.dumps({**data, "extra": 1}).encode())
    with pytest.raises(MessageError, match="duplicate"):
        decode(json.dumps(data).encode()[:-1] + b',"ok":false}')


def _run_listen(monkeypatch, capsys, payloads, *extra):
    from livetrack.cli import build_parser
    from livetrack.commands import listen

    monkeypatch.setattr(listen, "_udp_payloads", lambda host, port, deadline: iter(payloads))
    args = build_parser().parse_args(["listen", *extra])
    assert listen.run(args) == 0
    return capsys.readouterr()


def test_issue12_finding1_listen_survives_any_datagram_and_counts_rejections_by_reason(monkeypatch, capsys):
    good = _valid_json_message()
    hostile = [b'{"t_m":' + b"[" * 30000, json.dumps(good).encode().replace(b'"sequence": 5', b'"sequence": 1e400'),
               b'{"x":' + b"1" * 5000 + b"}", b"LTPS\x03\x00" + bytes(314), b"LTPS\x01\x00", b"", b"\xff\xfe{",
               json.dumps({**good, "ok": "false"}).encode()]
    out = _run_listen(monkeypatch, capsys, [*hostile, json.dumps(good).encode()])
    assert len(out.out.strip().splitlines()) == 1
    assert ("1 messages, 8 invalid (json-syntax 2, malformed 2, not-a-message 2, size 1, version 1), "
            "0 missing sequence numbers") in out.err


def test_issue12_finding12_listen_json_prints_null_not_nan_and_sane_gaps(monkeypatch, capsys):
    good = _valid_json_message()
    stream = [{**good, "sequence": s, "delta_std_px": None} for s in (0, 1, 4, 2**64 - 1, 3, 5)]
    out = _run_listen(monkeypatch, capsys, [json.dumps(m).encode() for m in stream], "--json")
    lines = out.out.strip().splitlines()
    assert len(lines) == 6 and "NaN" not in out.out
    assert all(json.loads(line)["delta_std_px"] is None for line in lines)
    assert all(decode(line.encode()).sequence == m["sequence"] for line, m in zip(lines, stream, strict=True))
    # 0 1 [2 3 missing] 4, jump to 2**64-1 and back to 3: restarts, not 1.8e19 missing; 3 -> 5: 1 missing
    assert "3 missing sequence numbers, 2 sequence restarts" in out.err


def test_issue12_finding1_listen_zmq_counts_malformed_multipart_messages(capsys):
    from livetrack.cli import build_parser
    from livetrack.commands import listen

    context = zmq.Context()
    pub = context.socket(zmq.PUB)
    pub.setsockopt(zmq.LINGER, 0)
    port = pub.bind_to_random_port("tcp://127.0.0.1")
    args = build_parser().parse_args(["listen", "--zmq", f"tcp://127.0.0.1:{port}", "--count", "1", "--duration",
                                      "30"])
    done = threading.Event()
    worker = threading.Thread(target=lambda: (listen.run(args), done.set()), daemon=True)
    worker.start()
    try:
        deadline = time.monotonic() + 30
        while not done.is_set() and time.monotonic() < deadline:  # until the subscriber is up and has one
            pub.send_multipart([topic_for(3), b"x", b"y"])
            pub.send_multipart([topic_for(3), sample_message().to_binary()])
            time.sleep(0.05)
        worker.join(10)
    finally:
        pub.close()
        context.term()
    err = capsys.readouterr().err
    assert done.is_set() and "1 messages" in err
    assert "zmq-frames" in err and "3 frames (a pose message is topic + payload)" in err


class _FlakyRecording:
    """A Rerun recording stand-in whose first ``fail`` flushes raise as Rerun's gRPC client does."""

    def __init__(self, fail: int) -> None:
        self.fail = fail

    def flush(self, timeout_sec: float) -> None:
        if self.fail > 0:
            self.fail -= 1
            raise RuntimeError("gRPC connection is open, but flush still failed")

    def disconnect(self) -> None:
        pass


def test_rerun_delivery_error_cleared_by_a_later_delivery():
    """A delivery check that fails (a viewer that came up late, the SDK's flush failing once) counts the items not
    confirmed as undelivered and reports the error; a later delivery that succeeds clears it, the loss still counted
    (``flush_error`` stands only while nothing was delivered since: under load in CI a late viewer's first flush
    failed and the run's summary kept the error though every later item arrived)."""
    from livetrack.sinks.rerun_sink import RerunSink

    scenario, _ = tracked_frames()
    sink = RerunSink("connect", scenario.camera, scenario.targets, argument="rerun+http://127.0.0.1:9/proxy")
    sink._rec, sink._connected, sink._logged = _FlakyRecording(fail=1), True, 7
    assert not sink._check_delivery(0.1)
    assert sink.stats["undelivered"] == 7 and "flush_error" in sink.stats and sink.stats["errors"] == 1
    sink._rec, sink._connected, sink._logged = _FlakyRecording(fail=0), True, 12
    assert sink._check_delivery(0.1)
    assert sink.stats["undelivered"] == 7 and "flush_error" not in sink.stats and sink.stats["errors"] == 1
