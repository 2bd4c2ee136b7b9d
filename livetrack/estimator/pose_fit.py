"""Rigorous pose: least squares of circle edge points onto their circles, jointly with the exposure bias.

Each measured edge point belongs to one circle of the target (radius ``radius_m`` in the target plane, any
fractal level). The model point is the circle point at the same polar angle (found by back-projecting the
measured point onto the current plane), projected through the full camera model (distortion included). The
residual is measured along the image normal pointing from black to white, in pixels:

    r_i = n_bw,i . (p_i - m_i) + delta

``delta`` (pixels, positive when white grows) is the exposure bias: the apparent edge sits at m_i - delta n_bw,i,
i.e. moved into the black side. On a ring it moves the outer edge inward and the inner edge outward, which a
change of distance cannot do, so delta and the pose are separable (see METHOD.md, "Compensation").

The rotation about the target normal (yaw) does not change any circle: it is held fixed here (it comes from the
code) and only the two tilt angles are estimated.

Parameter / covariance order: (tx, ty, tz) in metres, then (rx, ry, rz) a small rotation in the camera frame
(radians, R = exp([r]x) R_est), then delta in pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.geometry import Pose, rotation_from_rotvec

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class CircleEdgePoints:
    """Edge points of circles of one target.

    points_px: (N, 2) measured edge positions (distorted pixels).
    radius_m: (N,) radius, in the target plane, of the circle each point belongs to.
    white_outside: (N,) True where white lies outside the circle (outer edge of a black disk).
    std_px: (N,) 1-sigma position uncertainty along the normal (weights), pixels.
    """

    points_px: FloatArray
    radius_m: FloatArray
    white_outside: BoolArray
    std_px: FloatArray

    def __len__(self) -> int:
        return int(self.points_px.shape[0])

    def subset(self, mask: BoolArray) -> CircleEdgePoints:
        return CircleEdgePoints(self.points_px[mask], self.radius_m[mask], self.white_outside[mask],
                                self.std_px[mask])


@dataclass(frozen=True)
class PoseFit:
    """Result of ``fit_pose``. A failed fit has ``ok`` False and a ``reason``; it is falsy."""

    pose: Pose
    delta_px: float
    covariance: FloatArray  # (7, 7): t (3), rotation (3), delta; yaw variance from ``yaw_std_rad``
    residuals_px: FloatArray  # (N,) at the optimum
    residual_rms_px: float
    iterations: int
    ok: bool
    reason: str = ""

    def __bool__(self) -> bool:
        return self.ok

    @property
    def pose_covariance(self) -> FloatArray:
        return self.covariance[:6, :6]

    @property
    def delta_std_px(self) -> float:
        return float(np.sqrt(self.covariance[6, 6]))


def _model(camera: CameraModel, rays: FloatArray, obs: CircleEdgePoints, R: FloatArray, t: FloatArray,
           eps_rad: float = 1e-4) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Model points (N, 2) px, black-to-white unit normals (N, 2), and validity (ray meets the plane in front)."""
    n = R[:, 2]
    denom = rays @ n
    valid = denom > 1e-9
    scale = (n @ t) / np.where(valid, denom, 1.0)
    X = rays * scale[:, None]
    q = (X - t) @ R  # target-plane coordinates (rows: R^T (X - t))
    phi = np.arctan2(q[:, 1], q[:, 0])
    rho = obs.radius_m
    circle = np.zeros((len(rho), 3))
    circle_t = np.zeros((len(rho), 3))
    c, s = np.cos(phi), np.sin(phi)
    circle[:, 0], circle[:, 1] = rho * c, rho * s
    circle_t[:, 0], circle_t[:, 1] = -rho * s, rho * c  # d/dphi
    m = camera.project(circle @ R.T + t)
    m_phi = camera.project((circle + eps_rad * circle_t) @ R.T + t)
    tangent = m_phi - m
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    # Orient outward: compare with the direction from the projected centre.
    centre = camera.project(t[None, :])[0]
    outward = np.sign(np.sum(normal * (m - centre), axis=1))
    outward[outward == 0] = 1.0
    sign = np.where(obs.white_outside, 1.0, -1.0)
    return m, normal * (outward * sign)[:, None], valid


def _residuals(camera: CameraModel, rays: FloatArray, obs: CircleEdgePoints, R: FloatArray, t: FloatArray,
               delta: float) -> tuple[FloatArray, BoolArray]:
    m, n_bw, valid = _model(camera, rays, obs, R, t)
    r = np.sum(n_bw * (obs.points_px - m), axis=1) + delta
    return r, valid


def fit_pose(camera: CameraModel, obs: CircleEdgePoints, initial: Pose, *, estimate_delta: bool = True,
             delta_px: float = 0.0, yaw_std_rad: float = np.pi, max_iterations: int = 15,
             huber_px: float | None = 3.0) -> PoseFit:
    """Gauss-Newton over (t, two tilt angles[, delta]), starting from ``initial`` (e.g. the closed form).

    estimate_delta: estimate the exposure bias jointly (livetrack's method); False keeps it at ``delta_px``
        (baseline "rigorous fit without compensation", or a delta carried over from earlier frames).
    yaw_std_rad: standard deviation reported for the rotation about the normal (from the code: about a slot
        width / sqrt(12); pi when the code gives no heading).
    huber_px: Huber threshold on the normalised residual (in units of std) to down-weight outliers; None: plain
        least squares.
    Cost: N points x 7 residual evaluations per iteration (numeric Jacobian); typically 3-6 iterations.
    """
    rays = camera.unproject(obs.points_px)
    R = initial.R.copy()
    t = initial.t.copy()
    delta = float(delta_px)
    n_params = 6 if estimate_delta else 5
    if len(obs) < n_params + 3:
        return _failed(initial, delta, len(obs), "too few edge points")
    weights0 = 1.0 / np.maximum(obs.std_px, 1e-3) ** 2
    eps = np.array([1e-6 * max(np.linalg.norm(t), 1e-3)] * 3 + [1e-6, 1e-6, 1e-4])

    def tilt_axes(Rm: FloatArray) -> tuple[FloatArray, FloatArray]:
        return Rm[:, 0], Rm[:, 1]

    def apply(params: FloatArray, Rm: FloatArray, tv: FloatArray, d: float):
        a1, a2 = tilt_axes(Rm)
        rot = rotation_from_rotvec(params[3] * a1 + params[4] * a2)
        d_new = d + (params[5] if estimate_delta else 0.0)
        return rot @ Rm, tv + params[:3], d_new

    r, valid = _residuals(camera, rays, obs, R, t, delta)
    if not np.all(valid):
        return _failed(initial, delta, len(obs), "edge rays miss the target plane")
    iterations = 0
    converged = False
    for iteration in range(1, max_iterations + 1):
        iterations = iteration
        w = weights0.copy()
        if huber_px is not None:
            z = np.abs(r) * np.sqrt(weights0)
            w = np.where(z > huber_px, weights0 * huber_px / np.maximum(z, 1e-12), weights0)
        J = np.empty((len(obs), n_params))
        for k in range(n_params):
            step = np.zeros(6)
            step[k] = eps[k]
            Rk, tk, dk = apply(step, R, t, delta)
            rk, _ = _residuals(camera, rays, obs, Rk, tk, dk)
            J[:, k] = (rk - r) / eps[k]
        JtW = J.T * w
        try:
            dx = np.linalg.solve(JtW @ J, -JtW @ r)
        except np.linalg.LinAlgError:
            return _failed(initial, delta, len(obs), "singular normal equations")
        cost = np.sum(w * r * r)
        step_scale = 1.0
        for _ in range(6):
            params = np.zeros(6)
            params[:n_params] = dx * step_scale
            R_new, t_new, d_new = apply(params, R, t, delta)
            r_new, valid_new = _residuals(camera, rays, obs, R_new, t_new, d_new)
            if np.all(valid_new) and np.sum(w * r_new * r_new) <= cost * (1 + 1e-12):
                break
            step_scale *= 0.5
        else:
            converged = True  # no decrease possible: at the optimum within numeric precision
            break
        R, t, delta, r = R_new, t_new, d_new, r_new
        if np.all(np.abs(params[:3]) < 1e-9 * max(np.linalg.norm(t), 1.0)) and np.all(np.abs(params[3:5]) < 1e-9):
            converged = True
            break
    # Covariance from the weighted normal matrix, scaled by the a-posteriori variance factor.
    w = weights0
    J = np.empty((len(obs), n_params))
    for k in range(n_params):
        step = np.zeros(6)
        step[k] = eps[k]
        Rk, tk, dk = apply(step, R, t, delta)
        rk, _ = _residuals(camera, rays, obs, Rk, tk, dk)
        J[:, k] = (rk - r) / eps[k]
    dof = max(len(obs) - n_params, 1)
    variance_factor = float(np.sum(w * r * r) / dof)
    try:
        cov_small = np.linalg.inv((J.T * w) @ J) * variance_factor
    except np.linalg.LinAlgError:
        return _failed(Pose(R, t), delta, len(obs), "singular covariance")
    cov = _expand_covariance(cov_small, R, yaw_std_rad, estimate_delta)
    return PoseFit(pose=Pose(R, t), delta_px=delta, covariance=cov, residuals_px=r,
                   residual_rms_px=float(np.sqrt(np.mean(r * r))), iterations=iterations,
                   ok=bool(converged or iterations == max_iterations))


def _expand_covariance(cov_small: FloatArray, R: FloatArray, yaw_std_rad: float,
                       estimate_delta: bool) -> FloatArray:
    """(t, tilt1, tilt2[, delta]) covariance -> (t, camera-frame rotation vector, delta) 7x7."""
    n = cov_small.shape[0]
    # Map: rotation vector = a1 * e1 + a2 * e2 + yaw * e3 (e_k the target axes in the camera frame).
    A = np.zeros((7, n + 1))
    A[:3, :3] = np.eye(3)
    A[3:6, 3] = R[:, 0]
    A[3:6, 4] = R[:, 1]
    A[3:6, n] = R[:, 2]  # yaw, independent
    if estimate_delta:
        A[6, 5] = 1.0
    full = np.zeros((n + 1, n + 1))
    full[:n, :n] = cov_small
    full[n, n] = yaw_std_rad**2
    return A @ full @ A.T


def _failed(pose: Pose, delta: float, n: int, reason: str) -> PoseFit:
    return PoseFit(pose=pose, delta_px=delta, covariance=np.full((7, 7), np.nan), residuals_px=np.full(n, np.nan),
                   residual_rms_px=float("nan"), iterations=0, ok=False, reason=reason)
