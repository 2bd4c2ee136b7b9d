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


class _LocalModel:
    """The residuals of ``fit_pose`` with analytic derivatives, fast.

    Measured points are undistorted once; the projection is then a pure pinhole in normalized coordinates, and
    the lens's local 2x2 Jacobian A (pixels per normalized unit, distortion included) at each measured point maps
    normalized offsets to pixels. Residuals are sub-pixel, so this first-order mapping is exact to ~1e-6 px.
    The polar angle of each model point is re-found every iteration by back-projection and held fixed for the
    derivatives (the residual is along the normal, so it is stationary in that angle).
    """

    def __init__(self, camera: CameraModel, obs: CircleEdgePoints):
        self.p_n = camera.pixels_to_normalized(obs.points_px)
        jac = camera._distort_jacobian(self.p_n)  # (N, 2, 2) d(distorted)/d(undistorted)
        self.A = jac * np.array([camera.fx, camera.fy])[None, :, None]
        self.rays = np.column_stack([self.p_n, np.ones(len(obs))])
        self.rho = obs.radius_m
        self.sign = np.where(obs.white_outside, 1.0, -1.0)

    def evaluate(self, R: FloatArray, t: FloatArray, delta: float, jacobian: bool
                 ) -> tuple[FloatArray, FloatArray | None, bool]:
        n = R[:, 2]
        denom = self.rays @ n
        if np.any(denom <= 1e-9):
            return np.full(len(self.rho), np.nan), None, False
        X_ray = self.rays * ((n @ t) / denom)[:, None]
        q = (X_ray - t) @ R
        phi = np.arctan2(q[:, 1], q[:, 0])
        u = np.column_stack([np.cos(phi), np.sin(phi)])
        radial = u @ R[:, :2].T  # (N, 3): R (cos, sin, 0)
        tangent3 = np.column_stack([-u[:, 1], u[:, 0]]) @ R[:, :2].T
        V = radial * self.rho[:, None]  # R Q
        X = V + t
        if np.any(X[:, 2] <= 1e-9):
            return np.full(len(self.rho), np.nan), None, False
        z = X[:, 2]
        m = X[:, :2] / z[:, None]

        def image_dir(d3: FloatArray) -> FloatArray:  # d(m_n) along a 3-D direction, then to pixels
            dm = (d3[:, :2] - m * d3[:, 2:3]) / z[:, None]
            return np.einsum("nij,nj->ni", self.A, dm)

        tan_px = image_dir(tangent3)
        out_px = image_dir(radial)
        normal = np.column_stack([tan_px[:, 1], -tan_px[:, 0]])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        orient = np.sign(np.sum(normal * out_px, axis=1))
        orient[orient == 0] = 1.0
        n_bw = normal * (orient * self.sign)[:, None]
        w = np.einsum("ni,nij->nj", n_bw, self.A)  # row vectors n_bw^T A, (N, 2)
        r = np.sum(w * (self.p_n - m), axis=1) + delta
        if not jacobian:
            return r, None, True
        # dr/dX = -w dm/dX with dm/dX = [[1/z, 0, -x/z], [0, 1/z, -y/z]]
        dr_dX = -np.column_stack([w[:, 0], w[:, 1], -(w[:, 0] * m[:, 0] + w[:, 1] * m[:, 1])]) / z[:, None]
        dr_domega = np.cross(V, dr_dX)  # X = exp([omega]x) V + t  ->  dr/domega = V x dr/dX
        J = np.column_stack([dr_dX, dr_domega @ R[:, 0], dr_domega @ R[:, 1], np.ones(len(r))])
        return r, J, True


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
    Cost: analytic Jacobian, one vectorised model evaluation per iteration (plus step halving when needed);
    typically 3-6 iterations.
    """
    R = initial.R.copy()
    t = initial.t.copy()
    delta = float(delta_px)
    n_params = 6 if estimate_delta else 5
    if len(obs) < n_params + 3:
        return _failed(initial, delta, len(obs), "too few edge points")
    model = _LocalModel(camera, obs)
    weights0 = 1.0 / np.maximum(obs.std_px, 1e-3) ** 2

    def apply(dx: FloatArray, Rm: FloatArray, tv: FloatArray, d: float):
        rot = rotation_from_rotvec(dx[3] * Rm[:, 0] + dx[4] * Rm[:, 1])
        return rot @ Rm, tv + dx[:3], d + (dx[5] if estimate_delta else 0.0)

    r, J, valid = model.evaluate(R, t, delta, jacobian=True)
    if not valid:
        return _failed(initial, delta, len(obs), "edge rays miss the target plane")
    iterations = 0
    converged = False
    for iteration in range(1, max_iterations + 1):
        iterations = iteration
        w = weights0
        if huber_px is not None:
            zs = np.abs(r) * np.sqrt(weights0)
            w = np.where(zs > huber_px, weights0 * huber_px / np.maximum(zs, 1e-12), weights0)
        Jp = J[:, :n_params]
        JtW = Jp.T * w
        try:
            dx = np.linalg.solve(JtW @ Jp, -JtW @ r)
        except np.linalg.LinAlgError:
            return _failed(initial, delta, len(obs), "singular normal equations")
        cost = np.sum(w * r * r)
        step = np.zeros(6)
        for _ in range(8):
            step[:n_params] = dx
            R_new, t_new, d_new = apply(step, R, t, delta)
            r_new, J_new, ok = model.evaluate(R_new, t_new, d_new, jacobian=True)
            if ok and np.sum(w * r_new * r_new) <= cost * (1 + 1e-12):
                break
            dx = 0.5 * dx
        else:
            converged = True  # no decrease possible: at the optimum within numeric precision
            break
        R, t, delta, r, J = R_new, t_new, d_new, r_new, J_new
        if np.all(np.abs(step[:3]) < 1e-9 * max(np.linalg.norm(t), 1.0)) and np.all(np.abs(step[3:5]) < 1e-9):
            converged = True
            break
    # Covariance from the weighted normal matrix, scaled by the a-posteriori variance factor.
    Jp = J[:, :n_params]
    dof = max(len(obs) - n_params, 1)
    variance_factor = float(np.sum(weights0 * r * r) / dof)
    try:
        cov_small = np.linalg.inv((Jp.T * weights0) @ Jp) * variance_factor
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
