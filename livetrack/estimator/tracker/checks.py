"""Checks of a converged pose fit (``PoseFit``) that refuse it (``ok`` False, with the reason) or correct it: its
residuals and distance change, the code dots' scale, the fractal levels' agreement, a directional exposure
bias; the 2-D target model's pose taken into a fit and the dots' disagreement added to its covariance. Each
threshold's docstring gives what it was measured on."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.estimator.pose_fit import CircleEdgePoints, PoseFit, anisotropic_bias, fit_pose
from livetrack.estimator.target_model import TargetModelFit
from livetrack.geometry import Pose

FloatArray = npt.NDArray[np.float64]


MAX_RESIDUAL_RMS_PX = 3.0
MAX_DISTANCE_CHANGE = 0.5
TIGHT_FIT_RMS_PX = 1.0
TIGHT_FIT_DISTANCE_SD = 0.01
"""A converged pose fit is still refused (``ok`` False, with the reason) when its edge residuals' RMS exceeds
``MAX_RESIDUAL_RMS_PX`` (real phone photos with JPEG and an uncalibrated lens reach ~2.3 px) or its distance
is more than ``MAX_DISTANCE_CHANGE`` (relative) from the start's (the closed form, or the last frame's pose):
a tiny target's edges once drove the robust fit to 7.7 km (9.5 px RMS) from a 6.3 m start, and a vehicle must
not be handed that. A fit that moved that far is kept when it is tight: residuals within ``TIGHT_FIT_RMS_PX``
RMS and a distance standard deviation within ``TIGHT_FIT_DISTANCE_SD`` (relative, from its covariance). The
closed form is what is off then: at 70 deg, on a ring 7-9 px across its minor axis, it started 2.07-2.27x too far
(detection sweep seeds 3 and 5: three such fits, 0.09-0.30 px RMS, sd 0.05-0.35 %, within -0.12 .. +0.30 % of
the true distance, were refused)."""


FAR_FROM_START = "distance"
"""How ``_plausible``'s reason for a fit too far from its start begins."""
DOTS_CONFIRM_MAX_DEVIATION = 0.01
"""A search's fit refused only for its distance's change from the closed form (``MAX_DISTANCE_CHANGE``, not tight)
is started again from its own pose when the code dots put its scale within this of 1 (``surround_geometry.
dots_scale``: a measurement of the distance independent of the circles' edges; p99 0.011 over the sweeps' found
targets): the closed form was off, not the fit. Seed 7's no-sheet-005 at x8 (42 x 124 px at 70 deg on foliage
without a sheet, its pair from its hole scaled, 6-13 % too large) started at 2.40 m and converged at 1.125 m, the
truth; refused before."""


def _plausible(fit: PoseFit, initial: Pose) -> PoseFit:
    """``fit`` unchanged, or not ok with why (see ``MAX_RESIDUAL_RMS_PX``)."""
    if not fit:
        return fit
    if not fit.residual_rms_px <= MAX_RESIDUAL_RMS_PX:
        return dataclasses.replace(fit, ok=False, reason=f"edge residuals {fit.residual_rms_px:.2f} px RMS (more "
                                                         f"than {MAX_RESIDUAL_RMS_PX} px): the model does not fit")
    change = fit.pose.distance_m / initial.distance_m - 1.0
    if not abs(change) <= MAX_DISTANCE_CHANGE and not _tight(fit):
        return dataclasses.replace(fit, ok=False, reason=f"{FAR_FROM_START} {fit.pose.distance_m:.3f} m is "
                                                         f"{100 * change:+.0f} % from the start's "
                                                         f"{initial.distance_m:.3f} m")
    return fit


MAX_DOTS_SCALE_DEVIATION = 0.03
"""A search's fit is refused when the image puts the target's white code dots at a scale (about its centre) off
the pose's projection by more than this (``surround_geometry.dots_scale``). The circles' edges move with the
exposure and with whatever touches them (a chessboard's squares widening a ring printed without a sheet, a halo),
the dots' centres do not: their scale is a third measurement of the distance, beside the two circles' that the
exposure bias is estimated from. Measured (session 16, detection sweep seeds 0-9): over the 4279 found targets whose
dots are measured, |scale - 1| has median 0.0002, p99 0.011, max 0.029; the 46 whose pose is off by over 1 % lean the
same way as their error (0.4-1.8 times it); refused: a ring at x32 on a chessboard without a sheet at -9.5 % (dots at
0.88) and a blurred one at +4.5 % (1.056)."""


def _dots_agree(fit: PoseFit, scale: float | None) -> PoseFit:
    """``fit`` unchanged, or not ok with why (see ``MAX_DOTS_SCALE_DEVIATION``)."""
    if scale is None or abs(scale - 1.0) <= MAX_DOTS_SCALE_DEVIATION:
        return fit
    return dataclasses.replace(fit, ok=False, reason=(
        f"the code dots lie at {scale:.3f} of the pose's scale (more than {MAX_DOTS_SCALE_DEVIATION:.0%} off): the "
        f"edges put the distance about {100.0 * (scale - 1.0):+.0f} % off"))


def _dots_prefer_edges(at_edges: float | None, at_model: float | None) -> bool:
    """Whether the code dots (``surround_geometry.dots_scale`` at the edges' pose and at the 2-D model's: an
    exposure-free measurement of the scale) lie further from the model's pose than from the edges': then the model is
    not taken (it counts clipped ground around a target printed without a sheet as the target's white). False when
    the dots are not measured."""
    return at_edges is not None and at_model is not None and abs(at_model - 1.0) > abs(at_edges - 1.0)


def _dots_prefer_ground(at_edges: float | None, at_model: float | None, at_ground: float | None) -> bool:
    """Whether the code dots (``surround_geometry.dots_scale`` at the edges' pose, the 2-D model's, and the model's
    with the ground's share fitted: ``target_model.fit_ground_share``) lie nearer to the pose with the ground's share
    than to the model's by more than their own scatter (``DOTS_SCALE_NOISE``), and no further from it than from the
    edges'. False when any is not measured. The detection sweep's x32 targets printed without a sheet whose model's
    pose was taken (seeds 2-9, 11 targets): 7 moved by it (-0.67 -> -0.04 %, -0.59 -> -0.03 %, -0.55 -> -0.09 %,
    -0.64 -> -0.20 %, -0.62 -> +0.55 %, +0.28 -> +0.06 %), 4 kept (two on chessboards whose share overshot to +0.77
    and +1.16 %; one on text that it would have taken from -0.83 to -0.23 %, the dots 0.04 % off the model's)."""
    if not _dots_may_prefer_ground(at_edges, at_model) or at_ground is None:
        return False
    return (abs(at_ground - 1.0) + DOTS_SCALE_NOISE < abs(at_model - 1.0)
            and abs(at_ground - 1.0) <= abs(at_edges - 1.0))


def _dots_may_prefer_ground(at_edges: float | None, at_model: float | None) -> bool:
    """Whether ``_dots_prefer_ground`` can hold for any pose with the ground's share: both measured, the model's dots
    off by more than their scatter. Otherwise that fit (seconds on a large target) is not run: of paper-lab's 20 poses
    at x32, on a sheet, 10 have their model's dots within 0.1 %, 2 none measured."""
    return at_edges is not None and at_model is not None and abs(at_model - 1.0) > DOTS_SCALE_NOISE


MIRRORED_MIN_DEG = 20.0
"""A 2-D model's pose whose normal is at least this far from the edges' pose's is the other of the two poses one
circle's image allows (``target_model.mirrored_about_line_of_sight``), chosen on every pixel's residual: the code dots'
scale (``_dots_prefer_edges``) does not judge between the two (paper-lab's pose 19 at x32: the edges' pose +2.27 %,
normal 87 deg off, dots at 1.0024 of its scale; the model's -0.062 %, 0.0 deg off, dots at 1.0046)."""


def _mirrored(edges_pose: Pose, model_pose: Pose) -> bool:
    """Whether the model's normal is at least ``MIRRORED_MIN_DEG`` from the edges' pose's."""
    cosine = float(np.clip(edges_pose.R[:, 2] @ model_pose.R[:, 2], -1.0, 1.0))
    return math.degrees(math.acos(cosine)) >= MIRRORED_MIN_DEG


def _with_target_model(fit: PoseFit, model: TargetModelFit) -> PoseFit:
    """``fit`` with the pose and the pose covariance of the 2-D fit (its delta and residuals, the edges', kept)."""
    covariance = fit.covariance.copy()
    covariance[:6, :] = 0.0
    covariance[:, :6] = 0.0
    covariance[:6, :6] = model.covariance
    return dataclasses.replace(fit, pose=model.pose, covariance=covariance)


DOTS_SCALE_NOISE = 0.001
"""The code dots' own scatter about a good pose's scale (relative): beyond it, their disagreement with the pose is
added to the distance's variance (``_with_dots_disagreement``). Measured (session 16's detection sweep, seeds 0-9):
of the 3580 found targets within 0.05 % of the true distance whose dots were measured, 93 % had |scale - 1| <= 0.001
(98 % <= 0.002)."""


def _with_dots_disagreement(fit: PoseFit, scale: float | None) -> PoseFit:
    """``fit`` with the code dots' disagreement about its scale, beyond ``DOTS_SCALE_NOISE``, added to the variance of
    its distance (along the line of sight to the target: ``((|scale - 1| - noise) d)^2``); unchanged when the dots
    agree, were not measured, or the fit failed. The fit's covariance comes from its edge residuals and knows nothing
    of a bias all the edges share: over-exposure with a halo (paper-lab at x32, the ring's black at 85 % of full scale
    and the halo lifting it to the clip near every edge) moves both circles' edges by amounts the edge model does not
    follow, and the pose came out 0.3-3.3 % too far with a distance sd of a few thousandths of a percent, while its
    dots said 0.2-2.4 %. Over the detection sweep (seeds 0-9, the 4280 found targets whose dots were measured) the
    share of distance errors beyond 3 sd goes from 22 % to 15 %, and among the 186 off by more than 0.3 % from 91 %
    to 4 % (the rest of the 15 %: small errors, 0.01-0.3 %, under-covered by the edges' own covariance)."""
    if not fit or scale is None:
        return fit
    excess = abs(scale - 1.0) - DOTS_SCALE_NOISE
    if not excess > 0.0:
        return fit
    return _with_distance_sd(fit, excess)


def _with_distance_sd(fit: PoseFit, relative_sd: float) -> PoseFit:
    """``fit`` with ``(relative_sd d)^2`` added to the variance of its distance ``d`` (along the line of sight)."""
    t = fit.pose.t
    distance_m = float(np.linalg.norm(t))
    along = t / distance_m
    covariance = fit.covariance.copy()
    covariance[:3, :3] += (relative_sd * distance_m) ** 2 * np.outer(along, along)
    return dataclasses.replace(fit, covariance=covariance)


def _tight(fit: PoseFit) -> bool:
    """Whether ``fit``'s residuals and distance uncertainty are small (see ``TIGHT_FIT_RMS_PX``)."""
    t = fit.pose.t
    distance_m = float(np.linalg.norm(t))
    variance = float(t @ fit.covariance[:3, :3] @ t) / max(distance_m, 1e-12) ** 2
    return bool(fit.residual_rms_px <= TIGHT_FIT_RMS_PX and np.isfinite(variance)
                and 0.0 <= variance <= (TIGHT_FIT_DISTANCE_SD * distance_m) ** 2)


LEVELS_MIN_RMS_PX = 1.0
MAX_LEVEL_DISAGREEMENT = 0.05
"""A converged fit of several fractal levels whose edge residuals reach ``LEVELS_MIN_RMS_PX`` RMS is refused when
its levels, each fitted alone from it (both circles, with their own ``delta``), disagree about the distance by
more than ``MAX_LEVEL_DISAGREEMENT`` (relative): two measurements of one distance that far apart leave the joint one
uncertain by as much, whatever its covariance says. Measured (detection sweep, session 14): the levels of 1186
multi-level targets found on seeds 0, 1, 3, 4, 5 and 7 disagree by at most 3.4 % (seed 1's single-007 at x32,
2.5 px RMS, joint error +0.23 %; the next 2.9 %, 0.44 px RMS); seed 7's optics-003 at x4 (strong blooming across
a 117 px target: charge spilling 21 %, 2.5 px defocus, motion blur, a halo) by 5.4-5.8 % with 2.4-3.0 px RMS,
+3.9 to +5.9 % off as both levels fitted jointly (which of these depends on the blur the tracker carried from
earlier frames). A level whose edges alone fit worse than ``MAX_RESIDUAL_RMS_PX`` is refused as a whole fit would
be (the same frame at x4 after other frames: 2.96 px RMS jointly, its outer level alone 3.37 px, +5.9 %); a search
then fits the nested levels alone (``Tracker.search``). Cost: two more pose fits, only for fits of several levels
with residuals over 1 px RMS (3 of the ~1190 multi-level targets found on those seeds)."""


def _levels_agree(fit: PoseFit, camera: CameraModel, obs: CircleEdgePoints, points_norm: FloatArray,
                  estimate_delta: bool) -> PoseFit:
    """``fit`` unchanged, or not ok with why (see ``MAX_LEVEL_DISAGREEMENT``)."""
    if not fit.residual_rms_px >= LEVELS_MIN_RMS_PX:  # (the cheap test first: most fits stop here)
        return fit
    radii = np.unique(obs.radius_m)[::-1]
    if len(radii) < 4:
        return fit
    distances = []
    for k in range(0, len(radii) - 1, 2):  # (outer, inner) of each level, the largest first
        mine = np.isin(obs.radius_m, radii[k:k + 2])
        alone = fit_pose(camera, obs.subset(mine), fit.pose, estimate_delta=estimate_delta, delta_px=fit.delta_px,
                         points_normalized=points_norm[mine])
        if alone and not alone.residual_rms_px <= MAX_RESIDUAL_RMS_PX:
            return dataclasses.replace(fit, ok=False, reason=(
                f"the edge residuals of its level {k // 2} alone are {alone.residual_rms_px:.2f} px RMS (more than "
                f"{MAX_RESIDUAL_RMS_PX} px; {fit.residual_rms_px:.2f} px with the others): the model does not fit"))
        if alone:
            distances.append(alone.pose.distance_m)
    if len(distances) < 2:
        return fit
    spread = (max(distances) - min(distances)) / fit.pose.distance_m
    if spread <= MAX_LEVEL_DISAGREEMENT:
        return fit
    return dataclasses.replace(fit, ok=False, reason=(
        f"its fractal levels, each fitted alone, put it {100 * spread:.1f} % apart ("
        + ", ".join(f"{d:.3f} m" for d in distances) + f"; {fit.residual_rms_px:.2f} px RMS): the edge model "
        "does not hold"))


ANISOTROPY_MIN_RMS_PX = 0.1
ANISOTROPY_MAX_RMS_RATIO = 0.5
ANISOTROPY_MAX_SHIFT = 0.02
ANISOTROPY_MIN_SHIFT_SD = 3.0
"""A converged, plausible fit whose residuals are mostly an exposure bias that depends on the edge's direction is
corrected for it, or refused when that bias moves its distance by more than ``ANISOTROPY_MAX_SHIFT``: the edge
model and ``delta`` are isotropic (one blur, one bias for every edge), while motion blur, an elliptical PSF core or
blooming (charge spilling along the columns) grow an over-exposed white more along one image direction than across
it. The outer and inner circles then disagree about the ellipse they are (the white outside the ring and the
white inside it grow towards each other along that direction), and the fit turns the disagreement into a tilt and
a distance. ``pose_fit.anisotropic_bias`` adds ``a cos 2 psi + b sin 2 psi`` to the bias for one Gauss-Newton
step from the fit. When that explains most of the residuals (their RMS falls to at most
``ANISOTROPY_MAX_RMS_RATIO`` of the fit's: the pattern is at least 3/4 of their variance), the step is taken (the
pose, delta and covariance of the extended fit; the residuals stay the fit's) if it moves the distance by at most
``ANISOTROPY_MAX_SHIFT`` (relative); beyond, and by more than ``ANISOTROPY_MIN_SHIFT_SD`` standard deviations, the
pose depends on what the model does not hold and is refused (``ok`` False, with the figures). Fits with residuals
under ``ANISOTROPY_MIN_RMS_PX`` RMS are not checked (cost: none for them, ~0.2 ms otherwise).

Measured (session 14) on the final fits of the 2925 targets found on the detection sweep's seeds 0, 1, 3, 4, 5
and 7: 20 pass the ratio, all in the optics family at x8-x32, their errors going from -1.21 / -1.05 % (seed 7's
optics-001 at x16 / x8) -> +0.15 / +0.11 %, -1.09 / -1.08 % (seed 4's optics-005) -> +0.12 / -0.04 %, the
others from 0.03-0.42 % to 0.00-0.07 % (but seed 4's optics-004 at x32, -0.058 -> -0.052 %); one is refused, seed
7's optics-003 at x4 (below). The next ratios, 0.52-0.59, include a fit whose inner circle Huber had discarded
(seed 1's optics-000 at x4, +0.04 %: a step would have made it -1.4 %), hence 0.5. Of the 14 phone photos, 4 pass
the ratio (sharpening and the uncalibrated lens also bend edges by direction) and move by -0.6, +0.1, -0.15 and
+1.0 % (no truth there). The paper-lab exposure sweep's 140 distances are unchanged. Seed 7's
optics-003 at x4, a 117 px target under strong blooming, posed from its nested level after its outer level's edges
fit 3.05 px RMS: +8.3 % with 1.23 px RMS; the directional bias explains 87 % of their variance (amplitude 1.19 px)
and moves the distance by -3.7 % (8 sd): refused. The detection sweep re-run on seeds 0-7: 19 found targets moved by
more than 0.02 %, 17 towards the truth, 2 away (seed 6's optics-006 at x16 -0.01 -> +0.08 %, seed 7's optics-004
at x8 -0.17 -> -0.20 %)."""


def _isotropic(fit: PoseFit, camera: CameraModel, obs: CircleEdgePoints, points_norm: FloatArray,
               estimate_delta: bool) -> PoseFit:
    """``fit``, or ``fit`` with a directional exposure bias taken out, or not ok with why (see
    ``ANISOTROPY_MAX_SHIFT``)."""
    if not fit.residual_rms_px >= ANISOTROPY_MIN_RMS_PX:
        return fit
    bias = anisotropic_bias(camera, obs, fit, estimate_delta=estimate_delta, points_normalized=points_norm)
    if bias is None or not bias.rms_ratio <= ANISOTROPY_MAX_RMS_RATIO:
        return fit
    if abs(bias.distance_shift) <= ANISOTROPY_MAX_SHIFT:
        return bias.fit
    if not abs(bias.distance_shift) > ANISOTROPY_MIN_SHIFT_SD * bias.distance_shift_std:
        return fit
    return dataclasses.replace(fit, ok=False, reason=(
        f"edge residuals ({fit.residual_rms_px:.2f} px RMS) mostly an exposure bias that depends on the edge's "
        f"direction ({bias.amplitude_px:.2f} px; motion blur, an elliptical blur or blooming), which moves the "
        f"distance by {100 * bias.distance_shift:+.1f} %: the isotropic edge model does not hold"))
