"""A bias shared by all the edges of one circle, in the pose covariance.

``fit_pose``'s covariance comes from the edge points' scatter (with :mod:`residual_correlation`'s allowance for
residuals correlated along a run of neighbours). Whatever the edge model misses alike all round a circle (the
ground beside a ring's outer edge, the code dots beside its inner one, the pixel response, a PSF a little other
than Gaussian) moves every point of that circle by the same fraction of a pixel: the residuals cannot show it, and
averaging ~500 points does not shrink it. Shared by every circle, such a bias is a change of the exposure bias
``delta``, which the fit estimates; the circles' differences move the scale, hence the distance, by about
``b / R_px`` (b the bias, R_px the outer radius in px; the exact figure from the fit's Jacobian:
``pose_fit.circle_bias_gain``).

This module adds ``b^2 G G^T`` to a fit's covariance, each circle's bias taken as independent with standard
deviation ``b`` (``TrackerOptions.edge_bias_floor_px``), G the fit's ``circle_bias_gain``: a floor under the
distance's standard deviation that does not shrink with more edge points.

The outermost circle has a bias of its own on top (:func:`outer_circle_bias_covariance`): its bright side is the
ground or the sheet, not the white inside the ring, and over-exposed it takes a share of the white's bias that the
fit can only model (``tracker.contrast._outer_bias_share``: a ground clipped less deeply than the paper moves its
edge less; a sheet, the same paper, as much). That share's uncertainty times the white's bias ``|delta|`` is a
bias of the outermost circle alone (``TrackerOptions.outer_share_sd``). Pure, no I/O.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import numpy.typing as npt

from livetrack.estimator.pose_fit import PoseFit, _expand_covariance

FloatArray = npt.NDArray[np.float64]


def circle_bias_covariance(fit: PoseFit, bias_px: float) -> FloatArray | None:
    """(7, 7) covariance (t m, rotation vector rad, delta px) that independent biases of sd ``bias_px`` px shared by
    the edge points of each of ``fit``'s circles add to it; None when the fit has no ``circle_bias_gain``."""
    gain = fit.circle_bias_gain
    if gain is None or not np.all(np.isfinite(gain)):
        return None
    small = float(bias_px) ** 2 * (gain @ gain.T)
    return _expand_covariance(small, fit.pose.R, 0.0, gain.shape[0] == 6)


def with_circle_bias(fit: PoseFit, bias_px: float) -> PoseFit:
    """``fit`` with :func:`circle_bias_covariance` added to its covariance; unchanged when the fit failed, has no
    gain, or ``bias_px`` is 0."""
    if not fit or not bias_px > 0.0:
        return fit
    added = circle_bias_covariance(fit, bias_px)
    if added is None:
        return fit
    return dataclasses.replace(fit, covariance=fit.covariance + added)



def outer_circle_bias_covariance(fit: PoseFit, bias_px: float) -> FloatArray | None:
    """(7, 7) covariance that a bias of sd ``bias_px`` px shared by the edge points of ``fit``'s outermost circle
    alone (the last column of its ``circle_bias_gain``: circles by ascending radius) adds to it; None when the fit
    has no gain."""
    gain = fit.circle_bias_gain
    if gain is None or gain.shape[1] == 0 or not np.all(np.isfinite(gain[:, -1])):
        return None
    outer = gain[:, -1:]
    small = float(bias_px) ** 2 * (outer @ outer.T)
    return _expand_covariance(small, fit.pose.R, 0.0, gain.shape[0] == 6)


def with_outer_circle_bias(fit: PoseFit, bias_px: float) -> PoseFit:
    """``fit`` with :func:`outer_circle_bias_covariance` added to its covariance; unchanged when the fit failed, has
    no gain, or ``bias_px`` is 0 (or not finite)."""
    if not fit or not (math.isfinite(bias_px) and bias_px > 0.0):
        return fit
    added = outer_circle_bias_covariance(fit, bias_px)
    if added is None:
        return fit
    return dataclasses.replace(fit, covariance=fit.covariance + added)
