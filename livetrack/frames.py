"""The chain of frames from the camera to the vehicle and the world (pure: numpy only, no I/O).

Frames (all right-handed, metres; docs/vehicle.md and the README's Conventions):

- **camera**: x right, y down, z forward (optical axis); the estimator's poses are target-to-camera,
  ``X_cam = R_cam_target X_target + t_cam_target``.
- **body** (FRD): x forward, y right, z down, origin at the vehicle's reference point. The mounting gives
  camera-to-body: ``X_body = R_body_cam X_cam + t_body_cam_m`` (``t_body_cam_m``: the camera centre in body).
- **local NED** (world): x north, y east, z down. A static target's placement gives target-to-world:
  ``X_ned = R_ned_target X_target + t_ned_target_m``.

A transform ``T_a_b = (R_a_b, t_a_b)`` maps coordinates in frame b to frame a; ``compose(T_a_b, T_b_c) = T_a_c``.

Rotation of the camera in the body: ``rotation_rpy_deg = [roll, pitch, yaw]`` turns a *forward-looking* camera
(camera z = body x, camera x = body y, camera y = body z: image right = vehicle right, image down = vehicle down)
by ``Rz(yaw) Ry(pitch) Rx(roll)`` in the body frame (aerospace ZYX angles). ``[0, -90, 0]``: looking straight
down with the top of the image toward the vehicle's front; ``[0, 0, 180]``: looking back; ``[0, 0, -90]``:
looking left; ``[0, 90, 0]``: looking up.

A target's placement: ``heading_deg`` is the bearing (clockwise from north, toward east) of the target's +x
axis; the target lies flat, printed face up (target z = down, so that ``R_ned_target = Rz(heading)``).

Covariances are 6x6 over (translation m, rotation vector rad), the rotation a small rotation applied on the left
(as in the pose stream); they are carried through each transform to first order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from livetrack.geometry import quaternion_from_rotation

FloatArray = npt.NDArray[np.float64]

# Camera axes of a forward-looking camera in the body frame: columns are camera x, y, z in body FRD.
R_BODY_CAMERA_FORWARD = np.array([[0.0, 0.0, 1.0],
                                  [1.0, 0.0, 0.0],
                                  [0.0, 1.0, 0.0]])


@dataclass(frozen=True)
class Transform:
    """Rigid transform ``X_a = R X_b + t`` (frame b to frame a), R (3, 3), t (3,) metres."""

    R: FloatArray
    t: FloatArray

    @classmethod
    def identity(cls) -> Transform:
        return cls(np.eye(3), np.zeros(3))

    def apply(self, points: FloatArray) -> FloatArray:
        """Points (3,) or (N, 3) in frame b -> frame a."""
        return np.asarray(points, dtype=np.float64) @ self.R.T + self.t

    def inverse(self) -> Transform:
        return Transform(self.R.T, -self.R.T @ self.t)

    @property
    def quaternion_xyzw(self) -> FloatArray:
        """(qx, qy, qz, qw), qw >= 0."""
        return quaternion_from_rotation(self.R)


def compose(a_b: Transform, b_c: Transform) -> Transform:
    """``T_a_c = T_a_b T_b_c``."""
    return Transform(a_b.R @ b_c.R, a_b.R @ b_c.t + a_b.t)


def rot_x(angle_rad: float) -> FloatArray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle_rad: float) -> FloatArray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle_rad: float) -> FloatArray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_from_rpy(roll_rad: float, pitch_rad: float, yaw_rad: float) -> FloatArray:
    """Aerospace ZYX: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    return rot_z(yaw_rad) @ rot_y(pitch_rad) @ rot_x(roll_rad)


def rpy_from_rotation(R: FloatArray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in rad of ``R = Rz(yaw) Ry(pitch) Rx(roll)``; pitch in [-pi/2, pi/2]."""
    pitch = math.asin(max(-1.0, min(1.0, -float(R[2, 0]))))
    roll = math.atan2(float(R[2, 1]), float(R[2, 2]))
    yaw = math.atan2(float(R[1, 0]), float(R[0, 0]))
    return roll, pitch, yaw


def skew(v: FloatArray) -> FloatArray:
    """``skew(v) @ u == cross(v, u)``."""
    x, y, z = (float(c) for c in v)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


@dataclass(frozen=True)
class TargetPlacement:
    """A static target in local NED: its centre ``position_ned_m`` and the bearing of its +x axis."""

    position_ned_m: tuple[float, float, float]
    heading_deg: float

    @property
    def ned_from_target(self) -> Transform:
        return Transform(rot_z(math.radians(self.heading_deg)), np.asarray(self.position_ned_m, dtype=np.float64))


@dataclass(frozen=True)
class Mounting:
    """Where the camera sits on the vehicle and where static targets sit in the world.

    rotation_rpy_deg: the camera's rotation from a forward-looking camera, in the body frame (module docstring).
    translation_m: the camera centre in body FRD, metres.
    targets_in_world: target id -> its placement in local NED (may be empty).
    """

    rotation_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    translation_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    targets_in_world: dict[int, TargetPlacement] = field(default_factory=dict)

    @property
    def body_from_camera(self) -> Transform:
        roll, pitch, yaw = (math.radians(a) for a in self.rotation_rpy_deg)
        R = rotation_from_rpy(roll, pitch, yaw) @ R_BODY_CAMERA_FORWARD
        return Transform(R, np.asarray(self.translation_m, dtype=np.float64))


@dataclass(frozen=True)
class VehiclePoses:
    """One target's pose carried through the frame chain (one frame).

    body_from_target: the target in body FRD. body_covariance: its 6x6 covariance (t m, left rotation vector rad
    in body). ned_from_body: the vehicle in local NED from the target's known placement (None without one);
    ned_covariance: its 6x6 covariance (position m, left rotation vector rad in NED).
    """

    body_from_target: Transform
    body_covariance: FloatArray
    ned_from_body: Transform | None = None
    ned_covariance: FloatArray | None = None


def rotate_covariance(cov: FloatArray, R: FloatArray) -> FloatArray:
    """A (t, left rotvec) covariance expressed in another frame: both blocks rotated by R."""
    J = np.zeros((6, 6))
    J[:3, :3] = R
    J[3:, 3:] = R
    return J @ np.asarray(cov, dtype=np.float64) @ J.T


def vehicle_from_body_target(body_from_target: Transform, body_cov: FloatArray,
                             ned_from_target: Transform) -> tuple[Transform, FloatArray]:
    """The vehicle pose in NED, ``T_ned_body = T_ned_target T_body_target^-1``, with its covariance.

    A perturbation (dt, w) of the target in body gives, to first order, dp = -R_nb (dt + [t_bt]x w) on the
    vehicle position and w_ned = -R_nb w on its attitude (R_nb = R_ned_body).
    """
    ned_from_body = compose(ned_from_target, body_from_target.inverse())
    R_nb = ned_from_body.R
    J = np.zeros((6, 6))
    J[:3, :3] = -R_nb
    J[:3, 3:] = -R_nb @ skew(body_from_target.t)
    J[3:, 3:] = -R_nb
    return ned_from_body, J @ np.asarray(body_cov, dtype=np.float64) @ J.T


def vehicle_poses(mounting: Mounting, target_id: int, R_cam_target: FloatArray, t_cam_target_m: FloatArray,
                  cov_cam: FloatArray) -> VehiclePoses:
    """Carry one estimator pose (target-to-camera, 6x6 covariance in camera) through the chain."""
    body_from_camera = mounting.body_from_camera
    body_from_target = compose(body_from_camera, Transform(np.asarray(R_cam_target, dtype=np.float64),
                                                           np.asarray(t_cam_target_m, dtype=np.float64)))
    body_cov = rotate_covariance(cov_cam, body_from_camera.R)
    placement = mounting.targets_in_world.get(target_id)
    if placement is None:
        return VehiclePoses(body_from_target, body_cov)
    ned_from_body, ned_cov = vehicle_from_body_target(body_from_target, body_cov, placement.ned_from_target)
    return VehiclePoses(body_from_target, body_cov, ned_from_body, ned_cov)


def euler_rate_matrix(roll_rad: float, pitch_rad: float, yaw_rad: float) -> FloatArray:
    """E with ``w = E d(roll, pitch, yaw)``: a left (world-frame) rotation vector from ZYX angle steps."""
    Rz, Ry = rot_z(yaw_rad), rot_y(pitch_rad)
    return np.column_stack([Rz @ Ry @ np.array([1.0, 0.0, 0.0]), Rz @ np.array([0.0, 1.0, 0.0]),
                            np.array([0.0, 0.0, 1.0])])


def rpy_covariance(cov: FloatArray, R: FloatArray) -> FloatArray:
    """A (t, left rotvec) 6x6 covariance of a pose with rotation R as (t, roll, pitch, yaw) covariance (rad^2).
    Singular at pitch = +-90 degrees (gimbal lock): there the angle variances are infinite."""
    roll, pitch, yaw = rpy_from_rotation(R)
    E = euler_rate_matrix(roll, pitch, yaw)
    J = np.eye(6)
    try:
        J[3:, 3:] = np.linalg.inv(E)
    except np.linalg.LinAlgError:
        out = np.asarray(cov, dtype=np.float64).copy()
        out[3:, :] = out[:, 3:] = math.inf
        return out
    return J @ np.asarray(cov, dtype=np.float64) @ J.T


def upper_triangle(cov: FloatArray) -> list[float]:
    """The 21 values of a 6x6's upper triangle, row by row (the MAVLink and pose-stream order)."""
    return [float(v) for v in np.asarray(cov, dtype=np.float64)[np.triu_indices(6)]]
