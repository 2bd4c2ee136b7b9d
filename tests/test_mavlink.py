"""MAVLink output: a pymavlink receiver on 127.0.0.1 decodes every message of the sink, and the fields match the
pose carried through hand-written mountings (targets ahead, left, right, above, behind and below the vehicle)
within 1e-6; the rate limit, time_usec, ids; ``livetrack run --mavlink`` and ``livetrack listen --mavlink`` end to
end. Loopback only, bounded waits."""

from __future__ import annotations

import math
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from livetrack.estimator.tracker import FrameResult
from livetrack.frames import (
    Mounting,
    TargetPlacement,
    Transform,
    compose,
    rpy_covariance,
    rpy_from_rotation,
    vehicle_poses,
)
from livetrack.geometry import Pose, rotation_from_quaternion, rotation_from_rotvec
from livetrack.sinks.base import TrackedFrame
from livetrack.sinks.mavlink import MavlinkSink, import_mavutil, parse_connection
from livetrack.sources.base import Frame
from livetrack.targets.spec import TargetSpec

mavutil = import_mavutil()
mavlink = mavutil.mavlink
RECV_TIMEOUT_S = 10.0
TOL = 1e-6
REPO = Path(__file__).resolve().parents[1]

# (rpy_deg, camera axes in body as columns: image right, image down, optical axis), written by hand
MOUNTS = {
    "ahead": ((0, 0, 0), [[0, 1, 0], [0, 0, 1], [1, 0, 0]]),
    "left": ((0, 0, -90), [[1, 0, 0], [0, 0, 1], [0, -1, 0]]),
    "right": ((0, 0, 90), [[-1, 0, 0], [0, 0, 1], [0, 1, 0]]),
    "above": ((0, 90, 0), [[0, 1, 0], [1, 0, 0], [0, 0, -1]]),
    "behind": ((0, 0, 180), [[0, -1, 0], [0, 0, 1], [-1, 0, 0]]),
    "below": ((0, -90, 0), [[0, 1, 0], [-1, 0, 0], [0, 0, 1]]),
}
# where the target must come out in body FRD: the sign of the dominant axis
EXPECTED_SIDE = {"ahead": (0, 1), "left": (1, -1), "right": (1, 1), "above": (2, -1), "behind": (0, -1),
                 "below": (2, 1)}


@pytest.fixture
def receiver():
    conn = mavutil.mavlink_connection("udpin:127.0.0.1:0", dialect="common")
    try:
        yield conn, conn.port.getsockname()[1]
    finally:
        conn.close()


def receive(conn, types: set[str], n: int, timeout_s: float = RECV_TIMEOUT_S) -> list:
    """The next ``n`` messages of ``types`` (bounded wait; every message decoded without error)."""
    out = []
    deadline = time.monotonic() + timeout_s
    while len(out) < n and time.monotonic() < deadline:
        message = conn.recv_match(blocking=True, timeout=0.2)
        if message is None:
            continue
        assert message.get_type() != "BAD_DATA", message
        if message.get_type() in types:
            out.append(message)
    return out


def tracked(poses: list[tuple[int, Pose]], *, host_ns: int, device_ns: int | None = None,
            cov: np.ndarray | None = None, heading_known: bool = True) -> TrackedFrame:
    """A pipeline item whose target results carry just what the sink reads (id, fit.ok, pose, covariance,
    heading_known)."""
    cov = np.eye(6) if cov is None else cov
    targets = [SimpleNamespace(target_id=tid, heading_known=heading_known,
                               fit=SimpleNamespace(ok=True, pose=pose, pose_covariance=cov))
               for tid, pose in poses]
    frame = Frame(image=np.zeros((2, 2), np.uint8), frame_id=1, timestamp_ns=device_ns or 123,
                  host_timestamp_ns=host_ns, exposure_us=100.0, gain_db=0.0)
    return TrackedFrame(sequence=0, frame=frame, result=FrameResult(targets=targets), stage_ms={}, handoff_ns=host_ns,
                        latency_ms=1.0, device_latency_ms=1.0 if device_ns is not None else None)


def quaternion_rotation_wxyz(q) -> np.ndarray:
    w, x, y, z = q
    return rotation_from_quaternion(np.array([x, y, z, w]))


@pytest.mark.parametrize("side", sorted(MOUNTS))
def test_landing_target_fields_match_the_pose(receiver, side):
    conn, port = receiver
    rpy, columns = MOUNTS[side]
    R_bc = np.array(columns, dtype=float).T
    t_bc = np.array([0.12, -0.03, 0.08])
    mounting = Mounting(rotation_rpy_deg=rpy, translation_m=tuple(t_bc))
    rng = np.random.default_rng(sum(map(ord, side)))
    poses = [(3, Pose(rotation_from_rotvec(rng.normal(size=3) * 0.4), np.array([0.3, -0.2, 2.5]))),
             (5, Pose(rotation_from_rotvec(rng.normal(size=3) * 0.4), np.array([-0.4, 0.25, 4.0])))]
    specs = [TargetSpec.from_dict({"id": 3, "outer_radius_m": 0.125}), TargetSpec.from_dict({"id": 5,
                                                                                             "outer_radius_m": 0.2})]
    sink = MavlinkSink(f"udpout:127.0.0.1:{port}", specs, mounting, system_id=42, component_id=191)
    sink.open()
    try:
        host_ns = 1_796_000_000_123_456_789
        sink.handle(tracked(poses, host_ns=host_ns))
        got = receive(conn, {"LANDING_TARGET"}, 2)
    finally:
        sink.close()
    assert len(got) == 2
    for message, (tid, pose) in zip(got, poses, strict=True):
        assert message.get_srcSystem() == 42 and message.get_srcComponent() == 191
        assert message.target_num == tid and message.frame == mavlink.MAV_FRAME_BODY_FRD
        assert message.position_valid == 1 and message.type == mavlink.LANDING_TARGET_TYPE_VISION_FIDUCIAL
        assert message.time_usec == host_ns // 1000
        t = pose.t
        radius = 0.125 if tid == 3 else 0.2
        assert message.angle_x == pytest.approx(math.atan2(t[0], t[2]), abs=TOL)
        assert message.angle_y == pytest.approx(math.atan2(t[1], t[2]), abs=TOL)
        assert message.distance == pytest.approx(np.linalg.norm(t), abs=TOL)
        assert message.size_x == pytest.approx(2 * math.atan(radius / np.linalg.norm(t)), abs=TOL)
        assert message.size_y == pytest.approx(message.size_x, abs=TOL)
        xyz_body = R_bc @ t + t_bc
        np.testing.assert_allclose([message.x, message.y, message.z], xyz_body, atol=TOL)
        axis, sign = EXPECTED_SIDE[side]
        assert np.sign(xyz_body[axis]) == sign and abs(xyz_body[axis]) == np.abs(xyz_body).max()
        np.testing.assert_allclose(quaternion_rotation_wxyz(message.q), R_bc @ pose.R, atol=TOL)
        assert np.linalg.norm(message.q) == pytest.approx(1.0, abs=TOL)


def test_vision_position_estimate_and_heartbeat(receiver):
    conn, port = receiver
    mounting = Mounting((0, -90, 0), (0.1, 0.0, 0.05), {7: TargetPlacement((2.0, -1.5, 0.0), 30.0)})
    # the truth: the vehicle 3 m above a point near the pad, yawed and slightly tilted
    ned_from_body_true = SimpleNamespace(R=rotation_from_rotvec(np.array([0.05, -0.03, 0.8])),
                                         t=np.array([1.6, -1.2, -3.0]))
    T_nb = Transform(ned_from_body_true.R, ned_from_body_true.t)
    cam_from_target = compose(compose(mounting.body_from_camera.inverse(), T_nb.inverse()),
                              mounting.targets_in_world[7].ned_from_target)
    assert cam_from_target.t[2] > 0  # in front of the camera
    rng = np.random.default_rng(7)
    A = rng.normal(size=(6, 6)) * 1e-3
    cov = A @ A.T
    sink = MavlinkSink(f"udpout:127.0.0.1:{port}", [], mounting, system_id=9, component_id=197,
                       vision_position_estimate=True)
    sink.open()
    try:
        device_ns = 1_796_000_000_987_654_321
        # a symmetric code (heading unknown): LANDING_TARGET only, no vehicle pose
        sink.handle(tracked([(7, Pose(cam_from_target.R, cam_from_target.t))], host_ns=device_ns - 10**9,
                            heading_known=False))
        assert [m.get_type() for m in receive(conn, {"VISION_POSITION_ESTIMATE", "LANDING_TARGET"}, 1)] == [
            "LANDING_TARGET"]
        assert sink.stats["heading_unknown"] == 1
        sink.handle(tracked([(7, Pose(cam_from_target.R, cam_from_target.t))], host_ns=device_ns + 5_000_000,
                            device_ns=device_ns, cov=cov))
        got = receive(conn, {"VISION_POSITION_ESTIMATE", "HEARTBEAT", "LANDING_TARGET"}, 3)
    finally:
        sink.close()
    by_type = {m.get_type(): m for m in got}
    assert set(by_type) == {"VISION_POSITION_ESTIMATE", "HEARTBEAT", "LANDING_TARGET"}
    hb = by_type["HEARTBEAT"]
    assert hb.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER and hb.get_srcSystem() == 9 and hb.get_srcComponent() == 197
    assert by_type["LANDING_TARGET"].time_usec == device_ns // 1000  # the device clock is the host's here
    vpe = by_type["VISION_POSITION_ESTIMATE"]
    assert vpe.usec == device_ns // 1000
    np.testing.assert_allclose([vpe.x, vpe.y, vpe.z], T_nb.t, atol=TOL)
    np.testing.assert_allclose([vpe.roll, vpe.pitch, vpe.yaw], rpy_from_rotation(T_nb.R), atol=TOL)
    poses = vehicle_poses(mounting, 7, cam_from_target.R, cam_from_target.t, cov)
    expected = rpy_covariance(poses.ned_covariance, poses.ned_from_body.R)[np.triu_indices(6)]
    np.testing.assert_allclose(vpe.covariance, expected, rtol=1e-6, atol=1e-12)


def test_rate_limit_per_target(receiver):
    conn, port = receiver
    sink = MavlinkSink(f"udpout:127.0.0.1:{port}", [], Mounting(), max_rate_hz=10.0)
    sink.open()
    pose = Pose(np.eye(3), np.array([0.0, 0.0, 2.0]))
    try:
        t0 = 1_796_000_000_000_000_000
        for k in range(100):  # frames at 100 Hz for 0.99 s, two targets; at most 10 Hz on a 100 ms grid
            sink.handle(tracked([(1, pose), (2, pose)], host_ns=t0 + k * 10_000_000))
        got = receive(conn, {"LANDING_TARGET"}, 22, timeout_s=5.0)
        time.sleep(0.2)
        assert receive(conn, {"LANDING_TARGET"}, 1, timeout_s=0.3) == []
    finally:
        sink.close()
    # sent at 0, 100, ..., 900 ms and at 990 ms (within the quarter-period jitter allowance of the 1000 ms slot)
    assert [m.target_num for m in got].count(1) == 11 and [m.target_num for m in got].count(2) == 11
    times = sorted({m.time_usec for m in got})
    assert len(times) == 11 and np.diff(times).min() >= 75_000
    assert sink.stats["rate_limited"] == 200 - 22


def test_connection_parsing():
    assert str(parse_connection("udpout:127.0.0.1:14550")) == "udpout:127.0.0.1:14550"
    c = parse_connection("serial:/dev/ttyUSB0:57600")
    assert (c.kind, c.mavutil_device, c.port_or_baud) == ("serial", "/dev/ttyUSB0", 57600)
    for bad in ("udpin:1.2.3.4:5", "udpout:host", "serial:/dev/ttyS0", "serial:/dev/ttyS0:fast", "tcp:1:2"):
        with pytest.raises(ValueError):
            parse_connection(bad)


def test_run_end_to_end(receiver):
    """livetrack run --mavlink (the simulated camera) to a pymavlink receiver."""
    conn, port = receiver
    cmd = [sys.executable, "-m", "livetrack.cli", "run", "--max-frames", "4", "--quiet",
           "--mavlink", f"udpout:127.0.0.1:{port}"]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr
    got = receive(conn, {"LANDING_TARGET", "HEARTBEAT"}, 100, timeout_s=1.0)
    kinds = [m.get_type() for m in got]
    assert kinds.count("HEARTBEAT") >= 1 and kinds.count("LANDING_TARGET") >= 1, (kinds, proc.stdout)
    for m in got:
        if m.get_type() == "LANDING_TARGET":
            assert m.target_num == 3 and m.position_valid == 1 and 1.0 < m.distance < 5.0
            assert abs(m.time_usec / 1e6 - time.time()) < 600  # host clock, Unix epoch
    assert "sink mavlink" in proc.stdout


def test_listen_prints_mavlink():
    with socket_port() as free_port:
        port = free_port
    listen = subprocess.Popen([sys.executable, "-m", "livetrack.cli", "listen", "--mavlink",
                               f"udpin:127.0.0.1:{port}", "--count", "2", "--duration", "60"], cwd=REPO,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        sink = MavlinkSink(f"udpout:127.0.0.1:{port}", [], Mounting())
        sink.open()
        try:
            pose = Pose(np.eye(3), np.array([0.1, 0.0, 2.0]))
            deadline = time.monotonic() + 60
            k = 0
            while listen.poll() is None and time.monotonic() < deadline:
                sink.handle(tracked([(4, pose)], host_ns=1_796_000_000_000_000_000 + k * 100_000_000))
                k += 1
                time.sleep(0.1)
        finally:
            sink.close()
        out, err = listen.communicate(timeout=30)
    finally:
        if listen.poll() is None:
            listen.kill()
            listen.communicate()
    assert listen.returncode == 0, err
    lines = out.splitlines()
    assert len(lines) == 2 and all("LANDING_TARGET" in line or "HEARTBEAT" in line for line in lines), out
    assert "2 messages" in err


class socket_port:
    """A free UDP port on 127.0.0.1 (bound, then released)."""

    def __enter__(self) -> int:
        import socket

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        return self.sock.getsockname()[1]

    def __exit__(self, *exc) -> None:
        self.sock.close()
