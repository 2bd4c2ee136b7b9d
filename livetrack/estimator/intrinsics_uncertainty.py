"""The camera's calibration uncertainty in the pose covariance (first order).

A pose fit's covariance (``PoseFit.covariance``) holds the edge measurement noise only: the camera is taken as
exact. A calibrated camera is not: ``livetrack calibrate`` writes the 1-sigma of fx, fy, cx, cy, k1, k2, p1, p2, k3
(the camera file's ``uncertainty`` section). With the same edge points, a different camera gives a different pose;
to first order

    d theta = D d p,   D = -(J^T W J)^-1 J^T W (dr/dp)

where theta is the fit's parameters (t, two tilts[, delta]), J = dr/dtheta its Jacobian at the optimum, W the edge
weights (1/std^2) and dr/dp the residuals' sensitivity to the camera parameters p at the fitted pose: the
residuals' gradient in the measured points' undistorted normalized coordinates (central differences) times how
each parameter moves those coordinates, the pixel positions held (analytic, :func:`normalized_sensitivity`). The
covariance the camera adds, D diag(sigma_p^2) D^T (the parameters taken as independent: the file keeps no
correlations), is mapped to the fit's (t, rotation vector, delta) 7x7 order and added to the measurement
covariance. This is the implicit-function derivative of the re-solved pose: the Monte-Carlo test
(tests/test_calibrate_uncertainty.py) re-solves the fit with cameras drawn from the stated uncertainty and finds
the predicted spread of t and of the distance within 0.5-4 % of the empirical one (1000 draws, two poses).

Cost per target: 4 residual evaluations, one 2x2 inverse per edge point and one 6x6 solve: 1.4-1.6 ms of CPU
for 160-480 edge points (a pose fit from its optimum: ~0.5 ms), measured on a loaded 2-core machine. Huber
weights are left out of W (they down-weight only outliers). Pure, no I/O.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.estimator.pose_fit import CircleEdgePoints, PoseFit, _expand_covariance, _LocalModel

FloatArray = npt.NDArray[np.float64]

CAMERA_PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
NORMALIZED_STEP = 1e-6  # central-difference step of the residuals' gradient, normalized units (~4e-4 px at f 400)


def normalized_sensitivity(camera: CameraModel, points_normalized: FloatArray) -> FloatArray:
    """(9, N, 2): the change of each measured point's undistorted normalized coordinates (N, 2) per unit change of
    fx, fy, cx, cy, k1, k2, p1, p2, k3, the pixel positions held (p_n = undistort(K^-1 u): the distortion's Jacobian
    J gives dp_n = J^-1 (d(K^-1 u) - d distort / dk dk))."""
    p = np.asarray(points_normalized, dtype=np.float64)
    x, y = p[:, 0], p[:, 1]
    d = camera.distort(p)  # the distorted normalized coordinates, (u - c) / f
    r2 = x * x + y * y
    dd = np.zeros((len(CAMERA_PARAMS), len(p), 2))
    dd[0, :, 0] = -d[:, 0] / camera.fx
    dd[1, :, 1] = -d[:, 1] / camera.fy
    dd[2, :, 0] = -1.0 / camera.fx
    dd[3, :, 1] = -1.0 / camera.fy
    # minus d distort / d (k1, k2, p1, p2, k3) at the undistorted point (OpenCV's model, CameraModel.distort)
    dd[4] = -np.column_stack([x * r2, y * r2])
    dd[5] = -np.column_stack([x * r2**2, y * r2**2])
    dd[6] = -np.column_stack([2 * x * y, r2 + 2 * y * y])
    dd[7] = -np.column_stack([r2 + 2 * x * x, 2 * x * y])
    dd[8] = -np.column_stack([x * r2**3, y * r2**3])
    J_inv = np.linalg.inv(camera._distort_jacobian(p))  # (N, 2, 2)
    return np.einsum("nij,knj->kni", J_inv, dd)


def pose_sensitivity(camera: CameraModel, obs: CircleEdgePoints, fit: PoseFit, camera_std: FloatArray,
                     estimate_delta: bool = True) -> FloatArray:
    """D (n, 9): the change of the fit's parameters (tx, ty, tz in m; tilts about the target's x and y axes in
    rad; [delta px]) per unit change of each camera parameter (fx, fy, cx, cy, k1, k2, p1, p2, k3); columns of
    parameters whose sigma is 0 are 0.

    dr/dp = (dr/dp_n) (dp_n/dp): the residuals' gradient in the measured points' undistorted normalized coordinates
    (central differences) times :func:`normalized_sensitivity`. The lens's local Jacobian in the residual's
    weights is held: it moves r by (its relative change) x (the residual), second order at the optimum."""
    n = 6 if estimate_delta else 5
    R, t, delta = fit.pose.R, fit.pose.t, fit.delta_px
    model = _LocalModel(camera, obs)
    _, J, ok = model.evaluate(R, t, delta, jacobian=True)
    if not ok or J is None:
        return np.full((n, len(CAMERA_PARAMS)), np.nan)
    Jp = J[:, :n]
    weights = 1.0 / np.maximum(obs.std_px, 1e-3) ** 2
    normal = (Jp.T * weights) @ Jp
    # dr/dp_n: the residual's gradient in each point's own normalized coordinates (the polar angle of its model
    # point is stationary), by central differences of all points at once
    gradient = np.empty((len(obs), 2))
    shifted = copy.copy(model)
    for axis in (0, 1):
        r_pm = []
        for sign in (1.0, -1.0):
            shifted.px = model.px + (sign * NORMALIZED_STEP if axis == 0 else 0.0)
            shifted.py = model.py + (sign * NORMALIZED_STEP if axis == 1 else 0.0)
            r, _, ok = shifted.evaluate(R, t, delta, jacobian=False)
            if not ok:
                return np.full((n, len(CAMERA_PARAMS)), np.nan)
            r_pm.append(r)
        gradient[:, axis] = (r_pm[0] - r_pm[1]) / (2.0 * NORMALIZED_STEP)
    moves = normalized_sensitivity(camera, np.column_stack([model.px, model.py]))  # (9, N, 2)
    dr_dp = np.einsum("kni,ni->nk", moves, gradient)  # (N, 9)
    D = -np.linalg.solve(normal, (Jp.T * weights) @ dr_dp)
    D[:, ~(np.asarray(camera_std, dtype=np.float64) > 0)] = 0.0
    return D


def camera_covariance(camera: CameraModel, obs: CircleEdgePoints, fit: PoseFit, camera_std: FloatArray,
                      estimate_delta: bool = True) -> FloatArray:
    """(7, 7) covariance that the camera's uncertainty adds to the fit's (t m, rotation vector rad, delta px)
    covariance; NaN where the model cannot be evaluated."""
    std = np.asarray(camera_std, dtype=np.float64)
    D = pose_sensitivity(camera, obs, fit, std, estimate_delta)
    small = (D * std**2) @ D.T
    return _expand_covariance(small, fit.pose.R, 0.0, estimate_delta)


def with_camera_uncertainty(fit: PoseFit, camera: CameraModel, obs: CircleEdgePoints,
                            camera_std: FloatArray | tuple[float, ...], estimate_delta: bool = True) -> PoseFit:
    """``fit`` with the camera's uncertainty added to its covariance (first order, module docstring). A failed
    fit, or one whose covariance cannot be extended, is returned as it is."""
    if not fit:
        return fit
    added = camera_covariance(camera, obs, fit, np.asarray(camera_std, dtype=np.float64), estimate_delta)
    if not np.all(np.isfinite(added)):
        return fit
    return dataclasses.replace(fit, covariance=fit.covariance + added)
