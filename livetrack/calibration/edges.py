"""The calibration's own edge points: every circle of a target sampled where the current camera and pose put it,
only where a profile stays clear of the design's other edges.

Why: the tracker's edge profiles have one half length per target (4 px, shortened to 0.2 x the outer ellipse's
semi-minor axis, the design's clearance there). A profile that comes closer than ~3 blur widths to another edge of
the design (the nested level inside the inner disk, the white code dots in the black band) reads that edge too,
and its fitted position moves by up to 0.2-0.5 px. Under perspective the far side of a tilted target is
compressed, so those errors are larger on the far side than on the near side: a near/far asymmetry of a few
thousandths of a pixel, which is exactly what separates the focal length from the distance in a calibration
(in the 16-view simulation of docs/calibration.md the fitted fx and each target's distance correlate at
0.95-0.99; an inner-circle near/far asymmetry of 0.003 px moved fx by +0.25 %).

Here the circles are sampled where the current camera and pose project them (the lens's distortion included:
the normals and curvatures are those of the projected circle, not of an ellipse), and a point is kept only when
every sample of its profile, on both sides, stays ``margin_px`` away from every other edge of the design in the
image (2-D distance; the code dots and the nested levels included). The estimator's edge fit
(``fit_edges_two_pass``, curvature model, one shared contrast per target) is used unchanged. Pure: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.estimator.edges import fit_edges_two_pass
from livetrack.estimator.pose_fit import CircleEdgePoints, _model
from livetrack.geometry import Pose
from livetrack.targets.spec import TargetSpec

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class EdgeOptions:
    """margin_px : least image distance (px) between any sample of a profile and another edge of the design
        (default 2.0: 2.5 blur widths of 0.8 px; in the 16-view simulation 2.0 and 2.8 px both left the edges
        within 0.001-0.005 px of the truth at x1-x16).
    clipped_white_margin_px : the margin on the white side of a target whose white reads clipped (more than half
        of the samples 2 px into the white; default 0.75 px): its samples there are clipped, as the model has
        them, unless a darker feature comes within about a blur width. Keeps the inner circles of small targets
        under over-exposure (their white side faces the nested level at 0.2 R).
    half_width_px : profile half length on each side (default 4, the tracker's). Only points whose profile
        stays clear on both sides are used: shortened profiles (an asymmetric window fitted as a symmetric one
        around a moved point) were measured too, and under over-exposure a profile with less than ~3.5 px on
        its dark side is biased by 0.03-0.14 px (the clipped fit sees too little of the edge's tail).
    spacing_px : spacing of the sample points along each circle (default 1.5 px, the tracker's).
    min_radius_px : circles whose smallest image radius is below this are not sampled (default 6).
    sigma_px : blur for profiles clipped everywhere on one side (None: the median of the frame's unclipped fits,
        else 1.0 px).
    step_px : resolution of the reach search along the normal (default 0.25 px).
    """

    margin_px: float = 2.0
    clipped_white_margin_px: float = 0.75
    half_width_px: float = 4.0
    spacing_px: float = 1.5
    min_radius_px: float = 6.0
    sigma_px: float | None = None
    step_px: float = 0.25


def _levels(spec: TargetSpec) -> list[TargetSpec]:
    out, level = [], spec
    while level is not None:
        out.append(level)
        level = level.child
    return out


def design_features(spec: TargetSpec) -> tuple[FloatArray, FloatArray]:
    """Every edge of a design: radii (M,) of its concentric circles (all levels) and (D, 3) white code dots
    (centre x, y, radius; metres, target frame)."""
    radii, dots = [], []
    for level in _levels(spec):
        radii += [level.outer_radius_m, level.inner_radius_m]
        if level.centre_dot_radius_m > 0:
            radii.append(level.centre_dot_radius_m)
        if level.code is not None:
            for c in level.code.white_dot_centres_m():
                dots.append((float(c[0]), float(c[1]), level.code.dot_radius_m))
    return np.array(radii, dtype=np.float64), np.array(dots, dtype=np.float64).reshape(-1, 3)


def _plane_points(camera: CameraModel, pose: Pose, pixels: FloatArray) -> FloatArray:
    """(..., 2) pixels -> (..., 2) target-plane coordinates (m); NaN where the ray misses the plane."""
    rays = camera.unproject(pixels.reshape(-1, 2))
    n = pose.R[:, 2]
    along = rays @ n
    ok = along > 1e-9
    X = rays * ((n @ pose.t) / np.where(ok, along, 1.0))[:, None]
    q = (X - pose.t) @ pose.R
    q[~ok] = np.nan
    return q[:, :2].reshape(pixels.shape)


def _min_scale_px_per_m(camera: CameraModel, pose: Pose, q: FloatArray, h_m: float = 1e-4) -> FloatArray:
    """(N,) smallest singular value of d(pixel)/d(plane point) at plane points q (N, 2): image distance per
    metre on the plane in its most compressed direction."""
    def px(offset: FloatArray) -> FloatArray:
        Q = np.column_stack([q + offset, np.zeros(len(q))])
        return camera.project(Q @ pose.R.T + pose.t)
    jx = (px(np.array([h_m, 0.0])) - px(np.array([-h_m, 0.0]))) / (2 * h_m)
    jy = (px(np.array([0.0, h_m])) - px(np.array([0.0, -h_m]))) / (2 * h_m)
    J = np.stack([jx, jy], axis=-1)  # (N, 2, 2)
    return np.linalg.svd(J, compute_uv=False)[:, -1]


def reach_px(camera: CameraModel, pose: Pose, spec: TargetSpec, points_px: FloatArray, normals_bw: FloatArray,
             own_radius_m: FloatArray, options: EdgeOptions, white_margin_px: float | None = None
             ) -> tuple[FloatArray, FloatArray]:
    """How far (px) each profile may reach on its white side and on its black side: up to the last sample
    (along the normal, and 0.5 px to either side of it: the sampled strip) that stays ``margin_px`` (on the white
    side ``white_margin_px``, default the same) from every other edge of the design. Each (N,), between 0 and
    ``half_width_px``."""
    radii, dots = design_features(spec)
    s = np.arange(options.step_px, options.half_width_px + 1e-9, options.step_px)
    tangent = np.column_stack([-normals_bw[:, 1], normals_bw[:, 0]])
    q0 = _plane_points(camera, pose, points_px)
    scale = _min_scale_px_per_m(camera, pose, np.nan_to_num(q0))
    out = []
    for sign in (1.0, -1.0):
        clear = np.ones((len(points_px), len(s)), dtype=bool)
        for t in (-0.5, 0.0, 0.5):
            line = (points_px[:, None, :] + sign * s[None, :, None] * normals_bw[:, None, :]
                    + t * tangent[:, None, :])
            q = _plane_points(camera, pose, line)
            rho = np.hypot(q[..., 0], q[..., 1])
            # plane distance to every other concentric circle, then to every white dot
            other = np.abs(radii[None, None, :] - own_radius_m[:, None, None]) > 1e-9
            d = np.where(other, np.abs(rho[..., None] - radii[None, None, :]), np.inf).min(axis=-1)
            if len(dots):
                to_dot = np.hypot(q[..., 0:1] - dots[:, 0], q[..., 1:2] - dots[:, 1]) - dots[:, 2]
                d = np.minimum(d, np.abs(to_dot).min(axis=-1))
            margin = options.margin_px if sign < 0 or white_margin_px is None else white_margin_px
            clear &= np.nan_to_num(d, nan=0.0) * scale[:, None] >= margin
        blocked = ~clear
        first = np.where(blocked.any(axis=1), np.argmax(blocked, axis=1), len(s))  # index of the first blocked
        out.append(np.where(first > 0, s[np.maximum(first - 1, 0)], 0.0))
    return out[0], out[1]


def _circle_px(camera: CameraModel, pose: Pose, radius_m: float, phi: FloatArray) -> FloatArray:
    """(N, 2) image points of a circle of the target plane at polar angles phi (N,)."""
    circle = np.column_stack([radius_m * np.cos(phi), radius_m * np.sin(phi), np.zeros(len(phi))])
    return camera.project(circle @ pose.R.T + pose.t)


def sample_circles(camera: CameraModel, pose: Pose, spec: TargetSpec, options: EdgeOptions
                   ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, npt.NDArray[np.bool_]]:
    """Points (N, 2) on every circle of the design large enough in the image (``min_radius_px``), every
    ``spacing_px``, their black-to-white normals (N, 2), signed curvatures (N,) (1/px, positive when the centre of
    curvature lies on the white side), radii (N,) and white_outside (N,)."""
    pts, nrm, kap, rad, out = [], [], [], [], []
    for level in _levels(spec):
        for radius, outside in ((level.outer_radius_m, True), (level.inner_radius_m, False)):
            ring = _circle_px(camera, pose, radius, np.linspace(0.0, 2 * np.pi, 16, endpoint=False))
            centre = camera.project(pose.t[None, :])[0]
            r_px = np.linalg.norm(ring - centre, axis=1)
            if r_px.min() < options.min_radius_px:
                continue
            perimeter = float(np.sum(np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1)))
            n = max(int(perimeter / options.spacing_px), 24)
            phi = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
            eps = 1e-3

            p, pa, pb = (_circle_px(camera, pose, radius, a) for a in (phi, phi - eps, phi + eps))
            d1, d2 = (pb - pa) / (2 * eps), (pb - 2 * p + pa) / eps ** 2
            curvature = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.hypot(d1[:, 0], d1[:, 1]) ** 3
            edges = CircleEdgePoints(p, np.full(n, radius), np.full(n, outside), np.ones(n))
            _, normal_bw, valid = _model(camera, camera.unproject(p), edges, pose.R, pose.t)
            keep = valid & camera.contains(p, 2.0)
            pts.append(p[keep])
            nrm.append(normal_bw[keep])
            kap.append((-curvature if outside else curvature)[keep])
            rad.append(np.full(int(keep.sum()), radius))
            out.append(np.full(int(keep.sum()), outside))
    if not pts:
        empty = np.zeros((0, 2))
        return empty, empty, np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool)
    return (np.vstack(pts), np.vstack(nrm), np.concatenate(kap), np.concatenate(rad),
            np.concatenate(out).astype(bool))


@dataclass(frozen=True)
class MeasuredEdges:
    """The edge points of one target in one view (the ok fits) and the fit's quality: ``residual_rms`` (M,) the
    profile residual RMS (image units) of every point sampled, NaN where its fit is not ok (the same M points for
    the same camera, pose, delta and options, whatever the blur), ``clipped`` how many ok profiles had clipped
    samples."""

    edges: CircleEdgePoints
    residual_rms: FloatArray
    clipped: int


def measure_edges(image: npt.NDArray, camera: CameraModel, pose: Pose, spec: TargetSpec, saturation: float,
                  delta_px: float = 0.0, options: EdgeOptions | None = None) -> MeasuredEdges:
    """The edge points of one target in one view, sampled on its circles as ``camera`` and ``pose`` project them,
    moved by the exposure bias (the measured edge lies ``-delta_px`` along the black-to-white normal from the
    model); only the points whose profile (``half_width_px`` on each side) stays clear of the design's other
    edges (see the module docstring). Uniform weights."""
    options = options or EdgeOptions()
    pts, nrm, kap, rad, outside = sample_circles(camera, pose, spec, options)
    if len(pts):
        pts = pts - delta_px * nrm
        kap = kap / (1.0 + kap * delta_px)  # the curvature of the parallel curve through the moved point
        # white side clipped (over-exposure): a darker feature there leaves its samples clipped, as the model
        # has them, unless it comes within about a blur width; only the black side needs the full margin
        probe = np.rint(pts + 2.0 * nrm).astype(np.int64)
        inside = (probe[:, 0] >= 0) & (probe[:, 1] >= 0) & (probe[:, 0] < image.shape[1]) & (
            probe[:, 1] < image.shape[0])
        values = image[probe[inside, 1], probe[inside, 0]]
        white_clipped = values.size > 0 and float(np.mean(values >= saturation)) > 0.5
        white, black = reach_px(camera, pose, spec, pts, nrm, rad, options,
                                options.clipped_white_margin_px if white_clipped else None)
        keep = np.minimum(white, black) >= options.half_width_px - 1e-9
        pts, nrm, kap, rad, outside = pts[keep], nrm[keep], kap[keep], rad[keep], outside[keep]
    if len(pts) == 0:
        return MeasuredEdges(CircleEdgePoints(np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=bool), np.ones(0)),
                             np.zeros(0), 0)
    sigma = 1.0 if options.sigma_px is None else options.sigma_px
    fits = fit_edges_two_pass(image, pts, nrm, saturation=saturation, curvature_per_px=kap,
                              half_width_px=options.half_width_px, sigma_init_px=sigma, sigma_fallback_px=sigma,
                              shared_contrast=True)
    ok = fits.ok & np.isfinite(fits.points_px).all(axis=1)
    return MeasuredEdges(CircleEdgePoints(fits.points_px[ok], rad[ok], outside[ok], np.ones(int(ok.sum()))),
                         np.where(ok, fits.residual_rms, np.nan), int(np.sum(fits.n_clipped[ok] > 0)))
