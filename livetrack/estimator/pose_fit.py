"""Rigorous pose: least squares of circle edge points onto their circles, jointly with the exposure bias.

Each measured edge point belongs to one circle of the target (radius ``radius_m`` in the target plane, any
fractal level). The model point is the circle point at the same polar angle (found by back-projecting the
measured point onto the current plane), projected through the full camera model (distortion included). The
residual is measured along the image normal pointing from black to white, in pixels:

    r_i = n_bw,i . (p_i - m_i) + w_i delta

``delta`` (pixels, positive when white grows) is the exposure bias: the apparent edge sits at m_i - delta n_bw,i,
i.e. moved into the black side. On a ring it moves the outer edge inward and the inner edge outward, which a
change of distance cannot do, so delta and the pose are separable (see METHOD.md, "Compensation"). ``w_i`` is 1
but for the outer edge of a ring on ground darker than its ink (``bias_weights``): ink against ground, both far
from the paper's white, where the bias of the paper's white does not reach.

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
from livetrack.estimator import pose_kernels
from livetrack.estimator.edge_glue_kernels import median_where
from livetrack.estimator.edge_kernels import kernels
from livetrack.geometry import Pose, rotation_from_rotvec

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


STEP_TOL = 1e-6
"""Convergence: a Gauss-Newton step smaller than this (relative to the distance for t, radians for the tilts) is
taken without being evaluated, and the fit ends. The fit converges linearly (~20x per iteration; the polar angles
are held fixed in the Jacobian), so the pose is then within ~5e-8 (relative) of the optimum, far below its noise
(5e-6 relative at the Cramer-Rao bound of the paper-lab poses, ~1e-4 typically). (Until 2026-12-01 the tolerance
was 1e-8 and the last step was not taken: ~2 more evaluations per fit for a change below 1e-8.)"""

HUBER_SCALE_MIN = 2.0
"""Huber threshold scaling: when the robust standard deviation of the normalised residuals at the end of the fit
(``_residual_scale``) exceeds this, the edge uncertainties understate the residuals (JPEG, sharpening, an
uncalibrated lens: the phone photos' residuals are ~0.4-2.3 px against edge uncertainties of a few hundredths),
and a Huber threshold of ``huber_px`` in their units would down-weight most points (62-69 % in those photos): an
L1 fit, whose reweighted iterations converge slowly (x0.7-0.85 per iteration: 20-36 iterations). The fit then
continues with the threshold at ``huber_px`` robust standard deviations, which down-weights only outliers: all 14
photos then converge, in 8-15 iterations (2 of 14 did within 15 iterations before). On the paper-lab sweep (one
tracker per method, 2026-12-02) the scale has median 1.06; the compensated fits' mean |distance error| is unchanged
(0.00585 %); the uncompensated baseline, whose residuals hold the exposure bias it does not estimate, goes from
0.117 % to 0.114 %. Cost: a second, short run of the iterations, only then."""

SCALE_CHECK_ITERATIONS = 5
"""The residuals' scale is checked after this many iterations (or at convergence, if sooner): a fit whose
threshold is rescaled then gets ``max_iterations`` more; one whose threshold stands continues to ``max_iterations``
in all (the same iterates as one uninterrupted run)."""

STEP_SIGMA_TOL = 0.05
"""Convergence at the iteration cap: a fit that reaches ``max_iterations`` without a step below ``STEP_TOL`` has
still converged when its next Gauss-Newton step is shorter than this many standard deviations (the step's
Mahalanobis length under the fit's own covariance): what is left to move is noise-negligible, a twentieth of the
pose's own uncertainty. (0.01 until 2026-12-02: in the detection sweeps three visible targets, small ones at the
wide lens's border and a large tilted one at x32, were reported as failed with a next step of 0.012-0.022.)
Huber-weighted fits of noisy edges converge linearly and slowly (iteratively reweighted: the weights move with
the residuals): the phone photos of the printed targets (residual RMS 0.4-2.3 px) need ~20 iterations to reach
``STEP_TOL``, the last ones moving the distance by ~1e-5 (relative), a small fraction of its standard deviation.
Otherwise the fit is not ok ("iteration cap"). Cost: one solve of the normal equations, only for fits that reach
the cap."""


EXTEND_STEP_SIGMA = 1.0
"""A fit at the iteration cap whose next step is between ``STEP_SIGMA_TOL`` and this many standard deviations is
given ``max_iterations`` more (once) before it is judged: a 17 px target at the wide lens's border, Huber-weighted,
stopped with a next step of 0.064 sd and was reported as failed."""


@dataclass(frozen=True)
class CircleEdgePoints:
    """Edge points of circles of one target.

    points_px: (N, 2) measured edge positions (distorted pixels).
    radius_m: (N,) radius, in the target plane, of the circle each point belongs to.
    white_outside: (N,) True where white lies outside the circle (outer edge of a black disk).
    std_px: (N,) 1-sigma position uncertainty along the normal (weights), pixels.
    bias_share: None, or (N,) each point's share of the exposure bias ``delta`` where it is not the white's
        (``bias_weights``; e.g. ``exposure_bias.outer_bias_share``: the outer edge of a target printed without a
        sheet, against grey ground).
    """

    points_px: FloatArray
    radius_m: FloatArray
    white_outside: BoolArray
    std_px: FloatArray
    bias_share: FloatArray | None = None

    def __len__(self) -> int:
        return int(self.points_px.shape[0])

    def subset(self, mask: BoolArray) -> CircleEdgePoints:
        return CircleEdgePoints(self.points_px[mask], self.radius_m[mask], self.white_outside[mask],
                                self.std_px[mask], None if self.bias_share is None else self.bias_share[mask])


@dataclass(frozen=True)
class PoseFit:
    """Result of ``fit_pose``. ``ok`` means converged (a step below ``STEP_TOL``, or no further decrease of the
    cost). A failed fit has ``ok`` False and a ``reason`` ("too few edge points", "iteration cap (...)", ...); it
    is falsy. A fit stopped at the iteration cap keeps the pose, covariance and residuals it reached."""

    pose: Pose
    delta_px: float
    covariance: FloatArray  # (7, 7): t (3), rotation (3), delta; yaw variance from ``yaw_std_rad``
    residuals_px: FloatArray  # (N,) at the optimum
    residual_rms_px: float
    iterations: int
    ok: bool
    reason: str = ""
    # (n_params, C): the change of (t m, two tilts rad[, delta px]) per px of a bias shared by every edge point of
    # each of the C circles (``circle_bias_gain``; circles by ascending radius); None where not computed
    circle_bias_gain: FloatArray | None = None

    def __bool__(self) -> bool:
        return self.ok

    @property
    def pose_covariance(self) -> FloatArray:
        return self.covariance[:6, :6]

    @property
    def delta_std_px(self) -> float:
        return float(np.sqrt(self.covariance[6, 6]))


UNDISTORT_ITERATIONS = 20
UNDISTORT_TOL = 1e-14
"""``CameraModel.undistort``'s defaults, which :func:`pixels_to_normalized` passes to the compiled kernel (a test
holds them equal)."""


def pixels_to_normalized(camera: CameraModel, pixels_px: FloatArray) -> FloatArray:
    """``camera.pixels_to_normalized`` of (N, 2) pixels: (N, 2) undistorted normalized coordinates, compiled
    (:func:`livetrack.estimator.pose_kernels.pixels_to_normalized`: the same arithmetic, the same numbers, ~15x
    faster for a target's ~500 edge points) unless ``LIVETRACK_KERNELS=numpy``."""
    if kernels() != "numba":
        return camera.pixels_to_normalized(pixels_px)
    return pose_kernels.pixels_to_normalized(
        np.ascontiguousarray(pixels_px, dtype=np.float64).reshape(-1, 2), float(camera.fx), float(camera.fy),
        float(camera.cx), float(camera.cy), *(float(d) for d in camera.dist), UNDISTORT_ITERATIONS, UNDISTORT_TOL)


def unproject(camera: CameraModel, pixels_px: FloatArray) -> FloatArray:
    """``camera.unproject`` of (N, 2) pixels: (N, 3) unit viewing rays, through :func:`pixels_to_normalized`."""
    xy = pixels_to_normalized(camera, pixels_px)
    rays = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
    return rays / np.linalg.norm(rays, axis=-1, keepdims=True)


def project(camera: CameraModel, points_m: FloatArray) -> FloatArray:
    """``camera.project`` of (N, 3) camera-frame points: (N, 2) pixels, compiled (the same numbers) unless
    ``LIVETRACK_KERNELS=numpy``."""
    if kernels() != "numba":
        return camera.project(points_m)
    return pose_kernels.project(np.ascontiguousarray(points_m, dtype=np.float64).reshape(-1, 3), float(camera.fx),
                                float(camera.fy), float(camera.cx), float(camera.cy),
                                *(float(d) for d in camera.dist))


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


def bias_weights(obs: CircleEdgePoints) -> FloatArray:
    """(N,) each edge point's share of the exposure bias ``delta``: 1 (or ``obs.bias_share``), but 0 on the
    outermost circle of the points when its white lies inside (a ring printed without a sheet on ground darker
    than its ink: ``Candidate.darker_outside``). That edge is ink against ground, both dark and unclipped up to
    x16 where the paper's white clips; the edge model places it without the white's bias (halo, PSF tails), and
    taking the white's delta for it put an x16 target on black velvet 0.23 % off."""
    if len(obs.radius_m) == 0:
        return np.ones(0)
    reversed_outer = (obs.radius_m >= obs.radius_m.max()) & ~obs.white_outside
    return np.where(reversed_outer, 0.0, 1.0 if obs.bias_share is None else obs.bias_share)


def _residuals(camera: CameraModel, rays: FloatArray, obs: CircleEdgePoints, R: FloatArray, t: FloatArray,
               delta: float) -> tuple[FloatArray, BoolArray]:
    m, n_bw, valid = _model(camera, rays, obs, R, t)
    r = np.sum(n_bw * (obs.points_px - m), axis=1) + bias_weights(obs) * delta
    return r, valid


class _LocalModel:
    """The residuals of ``fit_pose`` with analytic derivatives, fast.

    Measured points are undistorted once; the projection is then a pure pinhole in normalized coordinates, and
    the lens's local 2x2 Jacobian A (pixels per normalized unit, distortion included) at each measured point maps
    normalized offsets to pixels. Residuals are sub-pixel, so this first-order mapping is exact to ~1e-6 px.
    The polar angle of each model point is re-found every iteration by back-projection and held fixed for the
    derivatives (the residual is along the normal, so it is stationary in that angle).
    """

    def __init__(self, camera: CameraModel, obs: CircleEdgePoints, points_normalized: FloatArray | None = None):
        self.p_n = pixels_to_normalized(camera, obs.points_px) if points_normalized is None else points_normalized
        # components as contiguous (N,) arrays: the evaluation is ~60 small element-wise operations
        if kernels() == "numba":  # the same numbers, compiled
            A = pose_kernels.lens_jacobian(np.ascontiguousarray(self.p_n, dtype=np.float64), float(camera.fx),
                                           float(camera.fy), *(float(d) for d in camera.dist))
            self.a00, self.a01, self.a10, self.a11 = A[0], A[1], A[2], A[3]
        else:
            jac = camera._distort_jacobian(self.p_n)  # (N, 2, 2) d(distorted)/d(undistorted)
            A = jac * np.array([camera.fx, camera.fy])[None, :, None]
            self.a00, self.a01, self.a10, self.a11 = (np.ascontiguousarray(A[:, i, j]) for i in (0, 1)
                                                      for j in (0, 1))
        self.px, self.py = np.ascontiguousarray(self.p_n[:, 0]), np.ascontiguousarray(self.p_n[:, 1])
        self.rho = obs.radius_m
        self.sign = np.where(obs.white_outside, 1.0, -1.0)
        self.bias = bias_weights(obs)

    def evaluate(self, R: FloatArray, t: FloatArray, delta: float, jacobian: bool
                 ) -> tuple[FloatArray, FloatArray | None, bool]:
        px, py = self.px, self.py
        nx, ny, nz = R[:, 2]
        denom = px * nx + py * ny + nz
        if np.any(denom <= 1e-9):
            return np.full(len(self.rho), np.nan), None, False
        scale = (nx * t[0] + ny * t[1] + nz * t[2]) / denom
        dx, dy, dz = px * scale - t[0], py * scale - t[1], scale - t[2]  # back-projection minus t
        q0 = R[0, 0] * dx + R[1, 0] * dy + R[2, 0] * dz  # target-plane coordinates R^T (X - t)
        q1 = R[0, 1] * dx + R[1, 1] * dy + R[2, 1] * dz
        length = np.hypot(q0, q1)
        nonzero = length > 0
        safe = np.where(nonzero, length, 1.0)
        cos, sin = np.where(nonzero, q0 / safe, 1.0), q1 / safe  # the polar angle (atan2(0, 0) = 0 at the centre)
        radial = [R[k, 0] * cos + R[k, 1] * sin for k in range(3)]  # R (cos, sin, 0)
        tangent = [R[k, 1] * cos - R[k, 0] * sin for k in range(3)]  # R (-sin, cos, 0)
        V = [radial[k] * self.rho for k in range(3)]  # R Q
        z = V[2] + t[2]
        if np.any(z <= 1e-9):
            return np.full(len(self.rho), np.nan), None, False
        inv_z = 1.0 / z
        m0, m1 = (V[0] + t[0]) * inv_z, (V[1] + t[1]) * inv_z

        def image_dir(d: list[FloatArray]) -> tuple[FloatArray, FloatArray]:  # d(m_n) along a 3-D direction, in px
            dm0, dm1 = (d[0] - m0 * d[2]) * inv_z, (d[1] - m1 * d[2]) * inv_z
            return self.a00 * dm0 + self.a01 * dm1, self.a10 * dm0 + self.a11 * dm1

        tan0, tan1 = image_dir(tangent)
        out0, out1 = image_dir(radial)
        # black-to-white normal: the image tangent turned by -90 degrees, outward, then by the circle's colours
        orient = np.sign(tan1 * out0 - tan0 * out1)
        orient[orient == 0] = 1.0
        k_n = orient * self.sign / np.hypot(tan0, tan1)
        nb0, nb1 = tan1 * k_n, -tan0 * k_n
        w0, w1 = nb0 * self.a00 + nb1 * self.a10, nb0 * self.a01 + nb1 * self.a11  # n_bw^T A
        r = w0 * (px - m0) + w1 * (py - m1) + self.bias * delta
        if not jacobian:
            return r, None, True
        # dr/dX = -w dm/dX with dm/dX = [[1/z, 0, -x/z], [0, 1/z, -y/z]]
        g0, g1, g2 = -w0 * inv_z, -w1 * inv_z, (w0 * m0 + w1 * m1) * inv_z
        # X = exp([omega]x) V + t  ->  dr/domega = V x dr/dX
        c0, c1, c2 = V[1] * g2 - V[2] * g1, V[2] * g0 - V[0] * g2, V[0] * g1 - V[1] * g0
        J = np.empty((len(r), 6))
        J[:, 0], J[:, 1], J[:, 2] = g0, g1, g2
        J[:, 3] = c0 * R[0, 0] + c1 * R[1, 0] + c2 * R[2, 0]
        J[:, 4] = c0 * R[0, 1] + c1 * R[1, 1] + c2 * R[2, 1]
        J[:, 5] = self.bias
        return r, J, True


def fit_pose(camera: CameraModel, obs: CircleEdgePoints, initial: Pose, *, estimate_delta: bool = True,
             delta_px: float = 0.0, yaw_std_rad: float = np.pi, max_iterations: int = 15,
             huber_px: float | None = 3.0, points_normalized: FloatArray | None = None) -> PoseFit:
    """Gauss-Newton over (t, two tilt angles[, delta]), starting from ``initial`` (e.g. the closed form).

    estimate_delta: estimate the exposure bias jointly (livetrack's method); False keeps it at ``delta_px``
        (baseline "rigorous fit without compensation", or a delta carried over from earlier frames).
    yaw_std_rad: standard deviation reported for the rotation about the normal (from the code: about a slot
        width / sqrt(12); pi when the code gives no heading).
    huber_px: Huber threshold on the normalised residual (in units of std) to down-weight outliers; None: plain
        least squares.
    points_normalized: (N, 2) ``camera.pixels_to_normalized(obs.points_px)`` when the caller has it already
        (saves the undistortion); None computes it.
    Cost: analytic Jacobian, one vectorised model evaluation per iteration (plus step halving when needed);
    typically 2-4 iterations from the closed form, 1-2 from the last frame's pose of a slow target; a step
    below ``STEP_TOL`` is taken without being evaluated and ends the fit. The iterations run compiled
    (:func:`livetrack.estimator.pose_kernels.gauss_newton`) unless ``LIVETRACK_KERNELS=numpy`` selects the numpy
    reference (:func:`_gauss_newton_numpy`); both give the same fit to rounding.
    """
    R = initial.R.copy()
    t = initial.t.copy()
    delta = float(delta_px)
    n_params = 6 if estimate_delta else 5
    if len(obs) < n_params + 3:
        return _failed(initial, delta, len(obs), "too few edge points")
    model = _LocalModel(camera, obs, points_normalized)
    weights0 = 1.0 / np.maximum(obs.std_px, 1e-3) ** 2

    first = max_iterations if huber_px is None else min(max_iterations, SCALE_CHECK_ITERATIONS)
    R, t, delta, r, J, iterations, converged, failure = _gauss_newton(
        model, R, t, delta, weights0, huber_px, estimate_delta, first)
    scale = 1.0 if failure or huber_px is None else _residual_scale(r, weights0)
    if scale > HUBER_SCALE_MIN:
        # the edge uncertainties understate the residuals: Huber at huber_px would down-weight most points (an L1
        # fit, which converges slowly); refit from here with the threshold at huber_px residual standard deviations
        huber_px = huber_px * scale
        R, t, delta, r, J, more, converged, failure = _gauss_newton(
            model, R, t, delta, weights0, huber_px, estimate_delta, max_iterations)
        iterations += more
    elif not (converged or failure) and first < max_iterations:  # the same iterations, continued
        R, t, delta, r, J, more, converged, failure = _gauss_newton(
            model, R, t, delta, weights0, huber_px, estimate_delta, max_iterations - first)
        iterations += more
    if failure:
        return _failed(initial, delta, len(obs), failure)
    next_step_sd = 0.0 if converged else _next_step_sd(J[:, :n_params], r, weights0, huber_px)
    if not converged and STEP_SIGMA_TOL <= next_step_sd < EXTEND_STEP_SIGMA:
        # still moving, but by less than its own uncertainty: a slow (reweighted) convergence, given as many
        # iterations again rather than a looser tolerance
        R, t, delta, r, J, more, converged, failure = _gauss_newton(
            model, R, t, delta, weights0, huber_px, estimate_delta, max_iterations)
        iterations += more
        if failure:
            return _failed(initial, delta, len(obs), failure)
        next_step_sd = 0.0 if converged else _next_step_sd(J[:, :n_params], r, weights0, huber_px)
    converged = converged or next_step_sd < STEP_SIGMA_TOL
    # Covariance from the weighted normal matrix, scaled by the a-posteriori variance factor.
    if kernels() == "numba":  # the lines below in one compiled loop (the same figures to rounding)
        cov, status = pose_kernels.pose_covariance(np.ascontiguousarray(J, dtype=np.float64), weights0, r, n_params,
                                                   np.ascontiguousarray(R, dtype=np.float64),
                                                   float(yaw_std_rad) ** 2, bool(estimate_delta))
        if status != 0:
            return _failed(Pose(R, t), delta, len(obs), "singular covariance")
    else:
        Jp = J[:, :n_params]
        dof = max(len(obs) - n_params, 1)
        variance_factor = float(np.sum(weights0 * r * r) / dof)
        try:
            cov_small = np.linalg.inv((Jp.T * weights0) @ Jp) * variance_factor
        except np.linalg.LinAlgError:
            return _failed(Pose(R, t), delta, len(obs), "singular covariance")
        cov = _expand_covariance(cov_small, R, yaw_std_rad, estimate_delta)
    # A fit stopped by the cap has not converged: its pose, covariance and residuals are returned (they may be
    # close), but it is not ok and says why.
    return PoseFit(pose=Pose(R, t), delta_px=delta, covariance=cov, residuals_px=r,
                   residual_rms_px=float(np.sqrt(np.mean(r * r))), iterations=iterations, ok=converged,
                   reason="" if converged else f"iteration cap ({iterations} iterations without convergence: "
                   f"the next step is {next_step_sd:.2g} standard deviations)",
                   circle_bias_gain=circle_bias_gain(J[:, :n_params], weights0, obs.radius_m))


def circle_bias_gain(Jp: FloatArray, weights: FloatArray, radius_m: FloatArray) -> FloatArray | None:
    """(n, C): how a converged fit's parameters (the n columns of ``Jp``, the residuals' Jacobian at the optimum)
    move per px of a bias ``b_c`` shared by every edge point of circle c (its residuals all ``+ b_c``; circles by
    ascending ``radius_m``): ``-(Jp^T W Jp)^-1 Jp^T W 1_c``, the weighted least-squares solution's first-order
    response (W = ``weights``, the edge weights without Huber's). A bias common to every circle whose points carry
    the whole exposure bias is a change of ``delta`` (its Jacobian column is then theirs summed): only the circles'
    differences move the pose. None when the normal equations are singular. Compiled
    (:func:`livetrack.estimator.pose_kernels.circle_bias_gain`, ~5 us for 700 points) unless
    ``LIVETRACK_KERNELS=numpy`` selects :func:`circle_bias_gain_reference`."""
    if len(radius_m) == 0:
        return None
    if kernels() != "numba":
        return circle_bias_gain_reference(Jp, weights, radius_m)
    gain, status = pose_kernels.circle_bias_gain(np.ascontiguousarray(Jp, dtype=np.float64),
                                                 np.ascontiguousarray(weights, dtype=np.float64),
                                                 np.ascontiguousarray(radius_m, dtype=np.float64), Jp.shape[1])
    return None if status != 0 else gain


def circle_bias_gain_reference(Jp: FloatArray, weights: FloatArray, radius_m: FloatArray) -> FloatArray | None:
    """The numpy reference of :func:`circle_bias_gain`."""
    radii, circle = np.unique(radius_m, return_inverse=True)
    weighted = Jp.T * weights  # (n, N)
    sums = np.zeros((Jp.shape[1], len(radii)))
    for c in range(len(radii)):  # Jp^T W 1_c: each circle's weighted Jacobian rows summed
        sums[:, c] = weighted[:, circle == c].sum(axis=1)
    try:
        return -np.linalg.solve(weighted @ Jp, sums)
    except np.linalg.LinAlgError:
        return None


@dataclass(frozen=True)
class AnisotropicBias:
    """What an exposure bias that depends on the edge's direction would change in a converged fit (see
    :func:`anisotropic_bias`).

    distance_shift: relative change of the distance (e.g. 0.03 = +3 %) when the bias is free to vary as
        ``delta + a cos 2 psi + b sin 2 psi`` (psi the edge normal's direction in the image).
    distance_shift_std: its standard deviation (relative), from the extended fit's covariance.
    rms_ratio: RMS of the residuals with that bias over the fit's RMS (1: it explains nothing; 0.3: the residuals
        were mostly that pattern).
    amplitude_px: sqrt(a^2 + b^2), pixels.
    fit: the fit moved by that step (pose, delta, the extended fit's covariance of the pose and delta; the
        residuals and their RMS stay the isotropic fit's, which tracking compares frame to frame).
    """

    distance_shift: float
    distance_shift_std: float
    rms_ratio: float
    amplitude_px: float
    fit: PoseFit


def anisotropic_bias(camera: CameraModel, obs: CircleEdgePoints, fit: PoseFit, *, estimate_delta: bool = True,
                     huber_px: float = 3.0, points_normalized: FloatArray | None = None) -> AnisotropicBias | None:
    """One Gauss-Newton step from a converged ``fit`` with two more parameters, an exposure bias that varies
    with the edge's direction in the image (``delta + a cos 2 psi + b sin 2 psi``): what a directional blur
    (motion, an elliptical PSF core) or charge spilling along the columns (blooming) does to over-exposed edges,
    and what the isotropic model turns into a wrong pose (``Tracker``'s ``_isotropic``). At the fit's optimum the
    step is what those two parameters pull the pose by (the iterated extended fit moves the distance by the same
    to ~10 % of the shift in the detection sweep's strongly affected targets). The weights are the fit's, Huber-
    reweighted at ``huber_px`` (in units of the residuals' robust scale when that exceeds ``HUBER_SCALE_MIN``, as
    ``fit_pose`` does). None when the step cannot be solved. Cost: one model evaluation with its Jacobian and an
    8 x 8 solve (~0.2 ms for 500 edge points)."""
    model = _LocalModel(camera, obs, points_normalized)
    r, J, valid = model.evaluate(fit.pose.R, fit.pose.t, fit.delta_px, jacobian=True)
    if not valid or J is None:
        return None
    # dr/dt (x, y) is -(n_bw^T A) / z: the edge normal's direction in the image, up to the lens's local scale
    psi2 = 2.0 * np.arctan2(J[:, 1], J[:, 0])
    weights0 = 1.0 / np.maximum(obs.std_px, 1e-3) ** 2
    scale = _residual_scale(r, weights0)
    threshold = huber_px * scale if scale > HUBER_SCALE_MIN else huber_px
    zs = np.abs(r) * np.sqrt(weights0)
    w = np.where(zs > threshold, weights0 * threshold / np.maximum(zs, 1e-12), weights0)
    Jx = np.column_stack([J[:, :6] if estimate_delta else J[:, :5], np.cos(psi2), np.sin(psi2)])
    normal = (Jx.T * w) @ Jx
    try:
        step = np.linalg.solve(normal, -(Jx.T * w) @ r)
        inverse = np.linalg.inv(normal)
    except np.linalg.LinAlgError:
        return None
    after = r + Jx @ step
    variance = float(np.sum(w * after * after)) / max(len(r) - Jx.shape[1], 1)
    R, t = fit.pose.R, fit.pose.t
    distance = float(np.linalg.norm(t))
    ray = t / distance
    n_params = Jx.shape[1] - 2
    yaw_std = float(np.sqrt(max(R[:, 2] @ fit.covariance[3:6, 3:6] @ R[:, 2], 0.0)))
    moved = PoseFit(pose=Pose(rotation_from_rotvec(step[3] * R[:, 0] + step[4] * R[:, 1]) @ R, t + step[:3]),
                    delta_px=fit.delta_px + (float(step[5]) if estimate_delta else 0.0),
                    covariance=_expand_covariance(inverse[:n_params, :n_params] * variance, R, yaw_std,
                                                  estimate_delta),
                    residuals_px=fit.residuals_px, residual_rms_px=fit.residual_rms_px, iterations=fit.iterations,
                    ok=fit.ok, reason=fit.reason)
    shift_std = float(np.sqrt(max(ray @ inverse[:3, :3] @ ray * variance, 0.0))) / distance
    return AnisotropicBias(distance_shift=float(ray @ step[:3]) / distance, distance_shift_std=shift_std,
                           rms_ratio=float(np.sqrt(np.mean(after * after) / max(np.mean(r * r), 1e-300))),
                           amplitude_px=float(np.hypot(step[-2], step[-1])), fit=moved)


def _gauss_newton(model: _LocalModel, R: FloatArray, t: FloatArray, delta: float, weights0: FloatArray,
                  huber_px: float | None, estimate_delta: bool, max_iterations: int):
    """The iterations, compiled (default) or the numpy reference: R, t, delta, r, J, iterations, converged,
    failure ("" when none)."""
    if kernels() == "numba":
        R, t, delta, r, J, iterations, converged, status = pose_kernels.gauss_newton(
            np.ascontiguousarray(R, dtype=np.float64), np.ascontiguousarray(t, dtype=np.float64), delta, model.px,
            model.py, model.a00, model.a01, model.a10, model.a11, np.ascontiguousarray(model.rho, dtype=np.float64),
            model.sign, model.bias, weights0, -1.0 if huber_px is None else float(huber_px), bool(estimate_delta),
            int(max_iterations), STEP_TOL)
        failure = {0: "", pose_kernels.FAILED_PLANE: "edge rays miss the target plane",
                   pose_kernels.FAILED_SINGULAR: "singular normal equations"}[status]
        return R, t, delta, r, J, iterations, converged, failure
    return _gauss_newton_numpy(model, R, t, delta, weights0, huber_px, estimate_delta, max_iterations)


def _residual_scale(r: FloatArray, weights0: FloatArray) -> float:
    """Robust standard deviation (1.4826 x median absolute value) of the residuals in units of their stated
    uncertainties: ~1 when the edge fits' uncertainties describe the residuals."""
    scaled = np.abs(r) * np.sqrt(weights0)
    return float(1.4826 * median_where(scaled, np.ones(len(scaled), dtype=bool)))  # np.median's number, compiled


def _next_step_sd(Jp: FloatArray, r: FloatArray, weights0: FloatArray, huber_px: float | None) -> float:
    """Length of the next Gauss-Newton step from (Jp (N, n), r (N,)) in standard deviations of the fit (its
    Mahalanobis length under the Huber-weighted covariance, a-posteriori variance factor included); inf when
    the normal equations are singular."""
    w = weights0
    if huber_px is not None:
        zs = np.abs(r) * np.sqrt(weights0)
        w = np.where(zs > huber_px, weights0 * huber_px / np.maximum(zs, 1e-12), weights0)
    JtW = Jp.T * w
    normal = JtW @ Jp
    try:
        dx = np.linalg.solve(normal, -JtW @ r)
    except np.linalg.LinAlgError:
        return float("inf")
    variance = float(np.sum(w * r * r)) / max(len(r) - Jp.shape[1], 1)
    return float(np.sqrt(max(dx @ normal @ dx, 0.0) / max(variance, 1e-300)))


def _gauss_newton_numpy(model: _LocalModel, R: FloatArray, t: FloatArray, delta: float, weights0: FloatArray,
                        huber_px: float | None, estimate_delta: bool, max_iterations: int):
    """The iterations of :func:`fit_pose` in numpy (the reference of
    :func:`~livetrack.estimator.pose_kernels.gauss_newton`): returns R, t, delta, residuals (N,), Jacobian (N, 6),
    iterations, converged and a failure reason ("" when none)."""
    n_params = 6 if estimate_delta else 5

    def apply(dx: FloatArray, Rm: FloatArray, tv: FloatArray, d: float):
        rot = rotation_from_rotvec(dx[3] * Rm[:, 0] + dx[4] * Rm[:, 1])
        return rot @ Rm, tv + dx[:3], d + (dx[5] if estimate_delta else 0.0)

    r, J, valid = model.evaluate(R, t, delta, jacobian=True)
    if not valid:
        return R, t, delta, None, None, 0, False, "edge rays miss the target plane"
    iterations = 0
    converged = False

    def negligible(d: FloatArray) -> bool:
        small_t = np.all(np.abs(d[:3]) < STEP_TOL * max(np.linalg.norm(t), 1.0))
        return bool(small_t and np.all(np.abs(d[3:5]) < STEP_TOL))

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
            return R, t, delta, r, J, iterations, False, "singular normal equations"
        if negligible(dx):
            converged = True  # the step is below the tolerance: taken, not worth an evaluation
            step = np.zeros(6)
            step[:n_params] = dx
            R, t, delta = apply(step, R, t, delta)
            break
        cost = np.sum(w * r * r)
        step = np.zeros(6)
        for _ in range(8):
            step[:n_params] = dx
            R_new, t_new, d_new = apply(step, R, t, delta)
            r_new, J_new, ok = model.evaluate(R_new, t_new, d_new, jacobian=True)
            if ok and np.sum(w * r_new * r_new) <= cost * (1 + 1e-12):
                break
            dx = 0.5 * dx
            if negligible(dx):
                break  # no decrease within the tolerance: at the optimum within numeric precision
        else:
            converged = True  # no decrease possible: at the optimum within numeric precision
            break
        if not (ok and np.sum(w * r_new * r_new) <= cost * (1 + 1e-12)):
            converged = True
            break
        R, t, delta, r, J = R_new, t_new, d_new, r_new, J_new
        if negligible(step):
            converged = True
            break
    return R, t, delta, r, J, iterations, converged, ""


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
