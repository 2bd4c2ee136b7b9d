"""Edge residuals correlated along a circle, and the pose covariance that allows for them.

``fit_pose``'s covariance counts every edge point as an independent measurement. Neighbouring points are not: their
profiles overlap (a point every 1-3 px, each profile as wide as the blur) and whatever the edge model misses (a
halo, an anisotropic or motion blur, ground beside the ring, the ink's own edge) moves a run of neighbours alike.
N residuals correlated so carry the information of about N / tau independent ones, where tau, the integrated
autocorrelation time of the residuals along each circle, is ``1 + 2 sum_k rho_k`` over the lags k (in points) until
the correlation has died out (Sokal's estimator of the effective sample size, with a fixed cutoff); the pose
covariance is multiplied by tau (never divided).

Measured before this (the detection sweep, seeds 0-4): the distance errors of found targets lay within 3 sd of
their own covariance in 84 % of the cases, their median |error| / sd ~1.0-1.3 where a Gaussian gives 0.67; see
the README (Estimator, "what a pose claims") for the figures with tau.

The residuals are read in the order the tracker samples them (by angle around each circle; a circle is the run of
points sharing one ``radius_m``) and whitened by each point's standard deviation, as the fit weighs them.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt

from livetrack.estimator import pose_kernels
from livetrack.estimator.edge_glue_kernels import kernel_array
from livetrack.estimator.edge_kernels import kernels
from livetrack.estimator.pose_fit import CircleEdgePoints, PoseFit

FloatArray = npt.NDArray[np.float64]

MAX_LAG = 50
"""The longest lag (in points along a circle) whose correlation is summed: a run of ~50-150 px at the tracker's edge
spacing. A correlation that lasts longer (a misfit of the whole circle) is counted only that far: tau comes out
too small then, not too large."""
RHO_CUTOFF = 0.05
"""The sum stops at the first lag whose correlation falls below this (the noise of a correlation estimated from a
few hundred points is ~0.05)."""


def circle_starts(radius_m: FloatArray) -> npt.NDArray[np.int64]:
    """The index of each circle's first point and, last, the number of points: runs of equal ``radius_m``."""
    n = len(radius_m)
    if n == 0:
        return np.zeros(1, dtype=np.int64)
    change = np.nonzero(np.diff(radius_m) != 0.0)[0] + 1
    return np.concatenate(([0], change, [n])).astype(np.int64)


def _lagged_sums_numpy(r: FloatArray, starts: npt.NDArray[np.int64], max_lag: int) -> tuple[FloatArray, FloatArray]:
    """The reference of ``pose_kernels.lagged_sums``: for each lag k in 0..max_lag, the sum of ``r[i] * r[i + k]``
    over the pairs of points of one circle, and how many pairs there are."""
    sums, counts = np.zeros(max_lag + 1), np.zeros(max_lag + 1)
    for a, b in zip(starts[:-1], starts[1:], strict=True):
        run = r[a:b]
        for k in range(min(max_lag, len(run) - 1) + 1):
            sums[k] += float(np.dot(run[: len(run) - k], run[k:]))
            counts[k] += len(run) - k
    return sums, counts


def correlation_time(residuals: FloatArray, radius_m: FloatArray, max_lag: int = MAX_LAG,
                     cutoff: float = RHO_CUTOFF) -> float:
    """The integrated autocorrelation time (>= 1) of the residuals along their circles: ``1 + 2 sum rho_k`` over the
    lags k = 1, 2, ... up to the first whose correlation ``rho_k`` (pooled over the circles) is below ``cutoff``, at
    most ``max_lag``. 1 when there are too few points or the residuals are all zero or not finite."""
    r = np.asarray(residuals, dtype=np.float64)
    if len(r) < 8 or not np.all(np.isfinite(r)):
        return 1.0
    starts = circle_starts(np.asarray(radius_m, dtype=np.float64))
    if kernels() == "numba":
        sums, counts = pose_kernels.lagged_sums(kernel_array(r, np.float64), starts, int(max_lag))
    else:
        sums, counts = _lagged_sums_numpy(r, starts, int(max_lag))
    if not sums[0] > 0.0:
        return 1.0
    variance = sums[0] / counts[0]
    tau = 1.0
    for k in range(1, max_lag + 1):
        if counts[k] < 4:
            break
        rho = (sums[k] / counts[k]) / variance
        if not rho >= cutoff:
            break
        tau += 2.0 * rho
    return tau


def with_correlated_residuals(fit: PoseFit, obs: CircleEdgePoints) -> PoseFit:
    """``fit`` with its covariance multiplied by the correlation time of its whitened residuals along the circles
    (:func:`correlation_time`); unchanged when the fit failed or its residuals do not match ``obs``."""
    if not fit or len(fit.residuals_px) != len(obs):
        return fit
    tau = correlation_time(fit.residuals_px / obs.std_px, obs.radius_m)
    if tau <= 1.0:
        return fit
    return dataclasses.replace(fit, covariance=fit.covariance * tau)
