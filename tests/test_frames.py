"""The frame chain (livetrack/frames.py): mounting presets against hand-written axis tables, round trips through
camera -> body -> NED on known truth, and the covariances against finite differences. Seeded, pure numpy."""

from __future__ import annotations

import math

import numpy as np
import pytest

from livetrack.config.app import load_config
from livetrack.config.checks import ConfigError
from livetrack.frames import (
    Mounting,
    TargetPlacement,
    Transform,
    compose,
    rotation_from_rpy,
    rpy_covariance,
    rpy_from_rotation,
    vehicle_poses,
)
from livetrack.geometry import rotation_from_quaternion, rotation_from_rotvec, rotvec_from_rotation

# Columns: the camera's x (image right), y (image down), z (optical axis) in body FRD, written out by hand.
MOUNT_AXES = {
    "forward": ((0, 0, 0), [[0, 1, 0], [0, 0, 1], [1, 0, 0]]),
    "down": ((0, -90, 0), [[0, 1, 0], [-1, 0, 0], [0, 0, 1]]),
    "up": ((0, 90, 0), [[0, 1, 0], [1, 0, 0], [0, 0, -1]]),
    "left": ((0, 0, -90), [[1, 0, 0], [0, 0, 1], [0, -1, 0]]),
    "right": ((0, 0, 90), [[-1, 0, 0], [0, 0, 1], [0, 1, 0]]),
    "back": ((0, 0, 180), [[0, -1, 0], [0, 0, 1], [-1, 0, 0]]),
}


@pytest.mark.parametrize("name", sorted(MOUNT_AXES))
def test_mounting_presets_match_the_axis_table(name):
    rpy, columns = MOUNT_AXES[name]
    R = Mounting(rotation_rpy_deg=rpy).body_from_camera.R
    np.testing.assert_allclose(R, np.array(columns, dtype=float).T, atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0)


def _random_transform(rng: np.random.Generator, scale_m: float = 2.0) -> Transform:
    return Transform(rotation_from_rotvec(rng.normal(size=3)), rng.normal(size=3) * scale_m)


def test_vehicle_pose_round_trip_on_known_truth():
    rng = np.random.default_rng(14)
    for _ in range(50):
        rpy = tuple(rng.uniform(-180, 180, 3) * [1, 0.49, 1])
        mounting = Mounting(rotation_rpy_deg=rpy, translation_m=tuple(rng.normal(size=3) * 0.3),
                            targets_in_world={7: TargetPlacement(tuple(rng.normal(size=3) * 10),
                                                                 float(rng.uniform(-180, 180)))})
        ned_from_body = _random_transform(rng, 10.0)  # the truth
        ned_from_target = mounting.targets_in_world[7].ned_from_target
        cam_from_target = compose(compose(mounting.body_from_camera.inverse(), ned_from_body.inverse()),
                                  ned_from_target)
        poses = vehicle_poses(mounting, 7, cam_from_target.R, cam_from_target.t, np.eye(6))
        assert poses.ned_from_body is not None
        np.testing.assert_allclose(poses.ned_from_body.R, ned_from_body.R, atol=1e-12)
        np.testing.assert_allclose(poses.ned_from_body.t, ned_from_body.t, atol=1e-11)
        body_from_target = compose(ned_from_body.inverse(), ned_from_target)
        np.testing.assert_allclose(poses.body_from_target.t, body_from_target.t, atol=1e-11)
        assert vehicle_poses(mounting, 8, cam_from_target.R, cam_from_target.t, np.eye(6)).ned_from_body is None


def test_target_heading_is_the_bearing_of_its_x_axis():
    east = TargetPlacement((0.0, 0.0, 0.0), 90.0).ned_from_target.R
    np.testing.assert_allclose(east @ [1, 0, 0], [0, 1, 0], atol=1e-15)  # +x points east
    np.testing.assert_allclose(east @ [0, 0, 1], [0, 0, 1], atol=1e-15)  # printed face up: target z down


def _chain(mounting: Mounting, R_ct: np.ndarray, t_ct: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The vehicle's (position, rotation vector in NED relative to the unperturbed) after perturbing the camera
    pose by x = (dt, w), w on the left."""
    R = rotation_from_rotvec(x[3:]) @ R_ct
    poses = vehicle_poses(mounting, 1, R, t_ct + x[:3], np.zeros((6, 6)))
    assert poses.ned_from_body is not None
    return poses.ned_from_body


def test_covariances_match_finite_differences():
    rng = np.random.default_rng(3)
    mounting = Mounting((5.0, -70.0, 20.0), (0.1, -0.05, 0.2), {1: TargetPlacement((4.0, -2.0, 0.5), 33.0)})
    R_ct, t_ct = rotation_from_rotvec(rng.normal(size=3) * 0.3), np.array([0.3, -0.2, 3.0])
    A = rng.normal(size=(6, 6)) * 1e-3
    cov_cam = A @ A.T
    poses = vehicle_poses(mounting, 1, R_ct, t_ct, cov_cam)
    base = _chain(mounting, R_ct, t_ct, np.zeros(6))
    eps = 1e-6
    J_body, J_ned = np.zeros((6, 6)), np.zeros((6, 6))
    R_bc = mounting.body_from_camera.R
    for i in range(6):
        x = np.zeros(6)
        x[i] = eps
        b = vehicle_poses(mounting, 1, rotation_from_rotvec(x[3:]) @ R_ct, t_ct + x[:3], cov_cam).body_from_target
        J_body[:3, i] = (b.t - poses.body_from_target.t) / eps
        J_body[3:, i] = rotvec_from_rotation(b.R @ poses.body_from_target.R.T) / eps
        n = _chain(mounting, R_ct, t_ct, x)
        J_ned[:3, i] = (n.t - base.t) / eps
        J_ned[3:, i] = rotvec_from_rotation(n.R @ base.R.T) / eps
    np.testing.assert_allclose(J_body[:3, :3], R_bc, atol=1e-6)
    np.testing.assert_allclose(poses.body_covariance, J_body @ cov_cam @ J_body.T, rtol=1e-4, atol=1e-12)
    np.testing.assert_allclose(poses.ned_covariance, J_ned @ cov_cam @ J_ned.T, rtol=1e-4, atol=1e-11)

    # roll, pitch, yaw: finite differences of the angles under a left (NED) rotation
    R = base.R
    rpy0 = np.array(rpy_from_rotation(R))
    J_rpy = np.eye(6)
    for i in range(3):
        w = np.zeros(3)
        w[i] = eps
        J_rpy[3:, 3 + i] = (np.array(rpy_from_rotation(rotation_from_rotvec(w) @ R)) - rpy0) / eps
    cov = poses.ned_covariance
    np.testing.assert_allclose(rpy_covariance(cov, R), J_rpy @ cov @ J_rpy.T, rtol=1e-4, atol=1e-12)


def test_rpy_round_trip():
    rng = np.random.default_rng(5)
    for roll, pitch, yaw in rng.uniform(-1, 1, (100, 3)) * [math.pi, math.pi / 2 * 0.99, math.pi]:
        assert rpy_from_rotation(rotation_from_rpy(roll, pitch, yaw)) == pytest.approx((roll, pitch, yaw), abs=1e-12)


def test_mounting_config(tmp_path):
    assert load_config().mounting is None
    file = tmp_path / "m.yaml"
    file.write_text("mounting:\n  camera_to_body: {rotation_rpy_deg: [0, -90, 0], translation_m: [0.1, 0, 0.05]}\n"
                    "  targets_in_world: {3: {position_ned_m: [1, 2, 0], heading_deg: 45}}\n")
    m = load_config(file).mounting
    assert m is not None and m.rotation_rpy_deg == (0, -90, 0) and m.translation_m == (0.1, 0, 0.05)
    assert m.targets_in_world == {3: TargetPlacement((1.0, 2.0, 0.0), 45.0)}
    for text, where in [
        ("mounting: {camera_to_body: {rotation_rpy_deg: [0, 0], translation_m: [0, 0, 0]}}",
         "mounting.camera_to_body.rotation_rpy_deg"),
        ("mounting: {camera_to_body: {rotation_rpy_deg: [0, 0, 0]}}", "mounting.camera_to_body.translation_m"),
        ("mounting: {camera_to_body: {rotation_rpy_deg: [0, 0, 0], translation_m: [0, 0, 0], x: 1}}",
         "mounting.camera_to_body.x"),
        ("mounting: {targets_in_world: {3: {position_ned_m: [0, 0, 0], heading_deg: 0}}}",
         "mounting.targets_in_world"),
        ("mounting: {camera_to_body: {rotation_rpy_deg: [0, 0, 0], translation_m: [0, 0, 0]}, "
         "targets_in_world: {a: {position_ned_m: [0, 0, 0], heading_deg: 0}}}", "mounting.targets_in_world.a"),
        ("mounting: {camera_to_body: {rotation_rpy_deg: [0, 0, 0], translation_m: [0, 0, 0]}, "
         "targets_in_world: {3: {position_ned_m: [0, 0, .nan], heading_deg: 0}}}",
         "mounting.targets_in_world[3].position_ned_m"),
        ("outputs: {mavlink: {connection: 'udpin:1.2.3.4:5'}}", "outputs.mavlink.connection"),
        ("outputs: {mavlink: {system_id: 0}}", "outputs.mavlink.system_id"),
    ]:
        file.write_text(text + "\n")
        with pytest.raises(ConfigError) as info:
            load_config(file)
        assert where in info.value.path, (text, info.value.path)


# ---------------------------------------------------------------------------------------------- pose stream v2
def _result(target_id: int, R: np.ndarray, t: np.ndarray, cov: np.ndarray):
    """What PoseMessage.from_result reads of a TargetResult."""
    from types import SimpleNamespace

    from livetrack.geometry import Pose

    cov7 = np.zeros((7, 7))
    cov7[:6, :6] = cov
    cov7[6, 6] = 1e-4
    fit = SimpleNamespace(pose=Pose(R, t), pose_covariance=cov, covariance=cov7, delta_px=0.01, residual_rms_px=0.3,
                          ok=True)
    return SimpleNamespace(target_id=target_id, fit=fit, n_edge_points=500, heading_known=True)


def _messages(mounting):
    from livetrack.sinks.pose_message import messages_for_frame

    rng = np.random.default_rng(11)
    A = rng.normal(size=(6, 6)) * 1e-3
    cov = A @ A.T
    results = [_result(3, rotation_from_rotvec(rng.normal(size=3) * 0.3), np.array([0.2, -0.1, 2.5]), cov),
               _result(4, rotation_from_rotvec(rng.normal(size=3) * 0.3), np.array([-0.3, 0.2, 3.5]), cov)]
    return results, messages_for_frame(results, first_sequence=0, frame_id=1, device_timestamp_ns=2,
                                       host_timestamp_ns=3, exposure_us=None, latency_ms=4.0, mounting=mounting)


def test_pose_stream_version_2_carries_the_frames_and_round_trips():
    from livetrack.sinks.pose_message import BINARY_SIZE, BINARY_SIZE_FRAMES, decode

    _, plain = _messages(None)
    assert all(m.version == 1 and m.frames is None and len(m.to_binary()) == BINARY_SIZE for m in plain)
    assert b'"version":1,' in plain[0].to_json() and b"frames" not in plain[0].to_json()

    mounting = Mounting((0, -90, 0), (0.1, 0, 0.05), {3: TargetPlacement((1.0, 2.0, 0.0), 30.0)})
    results, messages = _messages(mounting)
    for result, message in zip(results, messages, strict=True):
        assert message.version == 2 and len(message.to_binary()) == BINARY_SIZE_FRAMES
        poses = vehicle_poses(mounting, result.target_id, result.fit.pose.R, result.fit.pose.t,
                              result.fit.pose_covariance)
        body = message.frames.target_in_body
        np.testing.assert_allclose(body.t_m, poses.body_from_target.t, atol=1e-15)
        np.testing.assert_allclose(rotation_from_quaternion(np.array(body.q_xyzw)), poses.body_from_target.R,
                                   atol=1e-12)
        np.testing.assert_allclose(body.covariance_upper, poses.body_covariance[np.triu_indices(6)], atol=1e-18)
        if result.target_id == 3:
            np.testing.assert_allclose(message.frames.vehicle_in_ned.t_m, poses.ned_from_body.t, atol=1e-15)
        else:
            assert message.frames.vehicle_in_ned is None
        for data in (message.to_binary(), message.to_json()):
            back = decode(data)
            assert back == message or back.to_binary() == message.to_binary()  # NaN compares unequal
            assert back.frames == message.frames
        assert decode(message.to_json()).to_json() == message.to_json()


def test_pose_stream_version_2_is_decoded_strictly():
    import json

    from livetrack.sinks.pose_message import MessageError, decode

    mounting = Mounting((0, 0, 0), (0, 0, 0), {3: TargetPlacement((0.0, 0.0, 0.0), 0.0)})
    _, messages = _messages(mounting)
    good = json.loads(messages[0].to_json())
    bad_cases = [
        {**good, "frames": None}, {**good, "frames": {}}, {**good, "frames": {**good["frames"], "x": 1}},
        {**good, "frames": {**good["frames"], "target_in_body": None}},
        {**good, "frames": {**good["frames"], "vehicle_in_ned": {"t_m": [0, 0, 0]}}},
        {**good, "frames": {**good["frames"], "target_in_body": {**good["frames"]["target_in_body"],
                                                                 "t_m": [0, 0, "1"]}}},
        {k: v for k, v in good.items() if k != "frames"},  # version 2 without frames
        {**good, "version": 1},  # version 1 with frames
    ]
    for data in bad_cases:
        with pytest.raises(MessageError) as info:
            decode(json.dumps(data).encode())
        assert info.value.reason == "malformed", data
    binary = messages[0].to_binary()
    for data in (binary[:-1], binary + b"\0", binary[:320]):
        with pytest.raises(MessageError) as info:
            decode(data)
        assert info.value.reason == "size"


# ---------------------------------------------------------------------------------------------- Rerun
def test_rerun_shows_the_vehicle_and_the_pad(tmp_path):
    from livetrack.sinks.rerun_sink import RerunSink
    from tests.test_sinks import _rrd_columns, tracked_frames

    scenario, items = tracked_frames()
    mounting = Mounting((0, 0, 0), (0.2, 0.0, -0.1), {3: TargetPlacement((5.0, 1.0, 0.0), 90.0)})
    rrd = tmp_path / "vehicle.rrd"
    sink = RerunSink("save", scenario.camera, scenario.targets, argument=str(rrd), mounting=mounting)
    sink.open()
    try:
        for item in items:
            sink.handle(item)
    finally:
        sink.close()
    data = _rrd_columns(rrd)
    for entity in ("/world/vehicle", "/world/vehicle/axes", "/world/targets/3/pad", "/world/targets/3/pad/heading",
                   "/world/ned", "/world/ned/axes"):
        assert entity in data, f"{entity} missing from {sorted(data)}"
    assert data["/world/vehicle"]["static"] and data["/world/targets/3/pad"]["static"]
    assert data["/world/ned"]["frame"] == [1, 4]
    camera_from_body = mounting.body_from_camera.inverse()
    np.testing.assert_allclose(data["/world/vehicle"]["Transform3D:translation"][0][0], camera_from_body.t,
                               atol=1e-6)
    # the NED origin seen from the camera: the target's pose composed with the pad's placement
    pose = items[1].result.targets[0].fit.pose
    expected = compose(Transform(pose.R, pose.t), mounting.targets_in_world[3].ned_from_target.inverse()).t
    np.testing.assert_allclose(data["/world/ned"]["Transform3D:translation"][1][0], expected, rtol=1e-6)


# ---------------------------------------------------------------------------------------------- v2 fuzz
def test_pose_stream_version_2_survives_mutations():
    """Version 2 bytes and JSON mutated at random: decode returns a message or raises MessageError with a known
    reason, nothing else (seeded, bounded; the version 1 fuzz tests are tests/test_fuzz_pose_message.py)."""
    import json

    from livetrack.sinks.pose_message import REJECT_REASONS, MessageError, PoseMessage, decode

    mounting = Mounting((0, -90, 0), (0, 0, 0), {3: TargetPlacement((1.0, 2.0, 0.0), 30.0)})
    _, messages = _messages(mounting)
    rng = np.random.default_rng(2026)
    seeds = [m.to_binary() for m in messages] + [m.to_json() for m in messages]
    values = [None, True, 1, -1, 2**64, 1e308, "x", [], {}, [0.0] * 3, [0.0] * 28, {"t_m": None}]
    for _ in range(3000):
        data = bytearray(seeds[rng.integers(len(seeds))])
        kind = rng.integers(3)
        if kind == 0:  # flip bytes
            for i in rng.integers(0, len(data), rng.integers(1, 8)):
                data[i] = int(rng.integers(256))
        elif kind == 1:  # cut or extend
            data = data[: rng.integers(len(data) + 1)] + bytes(rng.integers(0, 256, rng.integers(0, 9)).tolist())
        elif data[:1] == b"{":  # replace a member of the frames block
            obj = json.loads(data)
            name = ("target_in_body", "vehicle_in_ned")[rng.integers(2)]
            key = ("t_m", "q_xyzw", "covariance_upper", None)[rng.integers(4)]
            value = values[rng.integers(len(values))]
            if key is None or obj["frames"][name] is None:
                obj["frames"][name] = value
            else:
                obj["frames"][name][key] = value
            data = bytearray(json.dumps(obj).encode())
        try:
            assert isinstance(decode(bytes(data)), PoseMessage)
        except MessageError as exc:
            assert exc.reason in REJECT_REASONS
