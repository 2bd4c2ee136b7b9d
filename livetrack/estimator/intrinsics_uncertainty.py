"""The camera's calibration uncertainty in the pose covariance (first order).

A pose fit's covariance (``PoseFit.covariance``) holds the edge measurement noise only: the camera is taken as
exact. A calibrated camera is not: ``livetrack calibrate`` writes the 1-sigma of fx, fy, cx, cy, k1, k2, p1, p2, k3
(the camera file's ``uncertainty`` section). With the same edge points, a different camera gives a different pose;
to first order

    d theta = D d p,   D = -(J^T W J)^-1 J^T W (dr/dp)

where theta is the fit's parameters (t, two tilts[, delta]), J = dr/dtheta its Jacobian at the optimum, W the edge
weights (1/std^2) and dr/dp the residuals' sensitivity to the camera parameters p at the fitted pose (central
differences, one step of each parameter's own 1-sigma). The covariance the camera adds, D diag(sigma_p^2) D^T
(the parameters taken as independent: the file keeps no correlations), is mapped to the fit's (t, rotation
vector, delta) 7x7 order and added to the measurement covariance. This is the implicit-function derivative of the
re-solved pose: the Monte-Carlo test (tests/test_intrinsics_uncertainty.py) re-solves the fit with cameras drawn
from the stated uncertainty and finds the predicted spread within a few percent of the empirical one.

Cost per target: 2 residual evaluations (one undistortion of the edge points each) per camera parameter whose
sigma is not 0 (12 for a targets-mode camera, 18 for a chessboard one) and one 6x6 solve: about 1-2 ms of a
target's ~5-50 ms. Huber weights are left out of W (they down-weight only outliers). Pure, no I/O.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.estimator.pose_fit import CircleEdgePoints, PoseFit, _expand_covariance, _LocalModel

FloatArray = npt.NDArray[np.float64]

CAMERA_PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def perturbed(camera: CameraModel, index: int, step: float) -> CameraModel:
    """``camera`` with parameter ``CAMERA_PARAMS[index]`` moved by ``step``."""
    values = [camera.fx, camera.fy, camera.cx, camera.cy, *camera.dist]
    values[index] += step
    return dataclasses.replace(camera, fx=values[0], fy=values[1], cx=values[2], cy=values[3],
                               dist=tuple(values[4:9]))


def pose_sensitivity(camera: CameraModel, obs: CircleEdgePoints, fit: PoseFit, camera_std: FloatArray,
                     estimate_delta: bool = True) -> FloatArray:
    """D (n, 9): the change of the fit's parameters (tx, ty, tz in m; tilts about the target's x and y axes in
    rad; [delta px]) per unit change of each camera parameter (fx, fy, cx, cy, k1, k2, p1, p2, k3); columns of
    parameters whose sigma is 0 are 0."""
    n = 6 if estimate_delta else 5
    R, t, delta = fit.pose.R, fit.pose.t, fit.delta_px
    _, J, ok = _LocalModel(camera, obs).evaluate(R, t, delta, jacobian=True)
    if not ok or J is None:
        return np.full((n, len(CAMERA_PARAMS)), np.nan)
    Jp = J[:, :n]
    weights = 1.0 / np.maximum(obs.std_px, 1e-3) ** 2
    normal = (Jp.T * weights) @ Jp
    D = np.zeros((n, len(CAMERA_PARAMS)))
    for k, sd in enumerate(np.asarray(camera_std, dtype=np.float64)):
        if not sd > 0:
            continue
        r_plus, _, ok_plus = _LocalModel(perturbed(camera, k, sd), obs).evaluate(R, t, delta, jacobian=False)
        r_minus, _, ok_minus = _LocalModel(perturbed(camera, k, -sd), obs).evaluate(R, t, delta, jacobian=False)
        if not (ok_plus and ok_minus):
            return np.full((n, len(CAMERA_PARAMS)), np.nan)
        dr_dp = (r_plus - r_minus) / (2.0 * sd)
        D[:, k] = -np.linalg.solve(normal, (Jp.T * weights) @ dr_dp)
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
