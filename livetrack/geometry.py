"""Rigid poses and rotations.

A ``Pose`` maps target coordinates to camera coordinates: ``X_cam = R @ X_target + t`` (metres).
Quaternions are Hamilton, scalar last: (qx, qy, qz, qw), as in ``truth.csv`` and the pose streams.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def rotation_from_rotvec(rotvec: FloatArray) -> FloatArray:
    """Rodrigues: rotation vector (3,) in radians -> (3, 3) rotation matrix."""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    theta = float(np.linalg.norm(rotvec))
    if theta < 1e-12:
        kx, ky, kz = rotvec
        return np.eye(3) + np.array([[0, -kz, ky], [kz, 0, -kx], [-ky, kx, 0]])
    k = rotvec / theta
    kx, ky, kz = k
    skew = np.array([[0, -kz, ky], [kz, 0, -kx], [-ky, kx, 0]])
    return np.eye(3) + np.sin(theta) * skew + (1 - np.cos(theta)) * (skew @ skew)


def rotvec_from_rotation(R: FloatArray) -> FloatArray:
    """(3, 3) rotation matrix -> rotation vector (3,), via the quaternion (stable near 0 and pi)."""
    q = quaternion_from_rotation(R)
    xyz, w = q[:3], q[3]
    s = float(np.linalg.norm(xyz))
    if s < 1e-15:
        return 2.0 * xyz
    angle = 2.0 * np.arctan2(s, w)
    return xyz / s * angle


def quaternion_from_rotation(R: FloatArray) -> FloatArray:
    """(3, 3) rotation -> unit quaternion (qx, qy, qz, qw) with qw >= 0."""
    R = np.asarray(R, dtype=np.float64)
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = np.array([(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s])
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = np.array([0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s])
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = np.array([(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = np.array([(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s])
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def rotation_from_quaternion(q: FloatArray) -> FloatArray:
    """Quaternion (qx, qy, qz, qw), normalised here -> (3, 3) rotation."""
    x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def rotation_angle_deg(R: FloatArray) -> float:
    """Angle of a rotation matrix in degrees (0..180)."""
    c = (np.trace(R) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def look_rotation(tilt_deg: float, tilt_axis_deg: float = 0.0, roll_deg: float = 0.0) -> FloatArray:
    """Target-to-camera rotation of a target tilted by ``tilt_deg`` about an in-plane axis.

    The axis lies in the target plane at ``tilt_axis_deg`` from +x toward +y; ``roll_deg`` first rotates the
    target about its own normal. ``tilt_deg = roll_deg = 0`` gives R = I (frontal).
    """
    a = np.radians(tilt_axis_deg)
    axis = np.array([np.cos(a), np.sin(a), 0.0])
    roll = rotation_from_rotvec(np.array([0.0, 0.0, np.radians(roll_deg)]))
    return rotation_from_rotvec(axis * np.radians(tilt_deg)) @ roll


@dataclass(frozen=True)
class Pose:
    """Target-to-camera rigid transform: ``X_cam = R @ X_target + t`` (metres)."""

    R: FloatArray
    t: FloatArray

    @classmethod
    def identity(cls) -> Pose:
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def from_quaternion(cls, q_xyzw: FloatArray, t_m: FloatArray) -> Pose:
        return cls(rotation_from_quaternion(q_xyzw), np.asarray(t_m, dtype=np.float64).copy())

    @classmethod
    def from_rotvec(cls, rotvec: FloatArray, t_m: FloatArray) -> Pose:
        return cls(rotation_from_rotvec(rotvec), np.asarray(t_m, dtype=np.float64).copy())

    @property
    def quaternion(self) -> FloatArray:
        """(qx, qy, qz, qw)."""
        return quaternion_from_rotation(self.R)

    @property
    def rotvec(self) -> FloatArray:
        return rotvec_from_rotation(self.R)

    @property
    def distance_m(self) -> float:
        """Distance from the camera centre to the target origin."""
        return float(np.linalg.norm(self.t))

    @property
    def normal_cam(self) -> FloatArray:
        """Target +z axis (pointing away from the viewer for a visible target) in the camera frame."""
        return self.R[:, 2].copy()

    def apply(self, points_target: FloatArray) -> FloatArray:
        """Target-frame points (..., 3) -> camera frame (..., 3)."""
        return np.asarray(points_target, dtype=np.float64) @ self.R.T + self.t

    def inverse(self) -> Pose:
        return Pose(self.R.T.copy(), -self.R.T @ self.t)

    def compose(self, other: Pose) -> Pose:
        """``self ∘ other``: apply ``other`` first."""
        return Pose(self.R @ other.R, self.R @ other.t + self.t)

    def plane_to_normalized_homography(self) -> FloatArray:
        """3x3 homography from target-plane (x, y, 1) in metres to undistorted normalized image (x, y, 1)."""
        return np.column_stack([self.R[:, 0], self.R[:, 1], self.t])
