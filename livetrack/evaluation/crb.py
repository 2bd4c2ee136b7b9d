"""Cramér-Rao bound on the pose from the image-formation model itself.

The Fisher information of the pixel intensities with respect to the six pose parameters is
F = sum_k (d mu_k / d theta)(d mu_k / d theta)^T / var_k, with mu_k the noise-free DN of pixel k (the simulator's
``expected_dn``: clipped pixels carry no information, their derivative is 0) and var_k the Poisson-Gaussian
variance in DN^2: g^2 (mu_e + read_noise_e^2) + 1/12 (quantisation). Derivatives are central differences of
rendered images (steps chosen to move edges by about 0.2 px, large against the renderer's sub-pixel area
quantisation and small against the PSF). Rendering is done on a crop of the camera around the target (the
principal point shifted: the same geometry, far fewer pixels).

Parameters theta: (tx, ty, tz) in metres, then a small rotation (rx, ry, rz) in the camera frame.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.geometry import Pose, rotation_from_rotvec
from livetrack.sim.coverage import Placement, sheet_roi
from livetrack.sim.formation import ImageFormation

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class PoseBound:
    """Cramér-Rao bound of one view. ``covariance`` (6, 6) in the order above; ``distance_std_m`` the bound on
    the standard deviation of the distance |t| of any unbiased estimator."""

    covariance: FloatArray
    distance_std_m: float
    exposure_us: float


def crop_formation(formation: ImageFormation, placements: list[Placement], margin_px: int = 20
                   ) -> tuple[ImageFormation, tuple[int, int, int, int]]:
    """The same image formation on a camera cropped to the placements' sheets (plus a margin)."""
    cam = formation.camera
    rois = [sheet_roi(cam, p.pose, p.texture.bounds_m, margin_px=margin_px) for p in placements]
    rois = [r for r in rois if r is not None]
    if not rois:
        raise ValueError("no placement is visible")
    i0, i1 = min(r[0] for r in rois), max(r[1] for r in rois)
    j0, j1 = min(r[2] for r in rois), max(r[3] for r in rois)
    crop = CameraModel(width=j1 - j0, height=i1 - i0, fx=cam.fx, fy=cam.fy, cx=cam.cx - j0, cy=cam.cy - i0,
                       dist=cam.dist, bit_depth=cam.bit_depth)
    return replace(formation, camera=crop), (i0, i1, j0, j1)


def perturbed(pose: Pose, theta: FloatArray) -> Pose:
    return Pose(rotation_from_rotvec(theta[3:]) @ pose.R, pose.t + theta[:3])


def pose_bounds(formation: ImageFormation, placement: Placement, exposures_us: list[float],
                gain_db: float = 0.0, edge_step_px: float = 0.2) -> list[PoseBound]:
    """Bounds for one target placement at each exposure (optical derivatives computed once, reused)."""
    crop, _ = crop_formation(formation, [placement])
    pose = placement.pose
    distance = pose.distance_m
    radius_px = formation.camera.fx * _texture_radius_m(placement) / distance
    # Steps that move the outer edge by ~edge_step_px: translation along the ray scales the image, across it
    # shifts it; a rotation tilts it.
    h_t = np.array([1.0, 1.0, 1.0]) * edge_step_px * distance / formation.camera.fx
    h_t[2] = edge_step_px / radius_px * distance
    h_r = np.full(3, edge_step_px / radius_px)
    steps = np.concatenate([h_t, h_r])
    derivatives = []
    for k in range(6):
        theta = np.zeros(6)
        theta[k] = steps[k]
        plus = crop.optical_image([Placement(perturbed(pose, theta), placement.texture)])
        minus = crop.optical_image([Placement(perturbed(pose, -theta), placement.texture)])
        derivatives.append((plus.astype(np.float64), minus.astype(np.float64), steps[k]))
    centre = crop.optical_image([placement])
    sensor = crop.sensor_in_use
    gain = sensor.dn_per_e_at(gain_db)
    out = []
    for exposure_us in exposures_us:
        mu_dn = crop.expected_dn_from_optical(centre, exposure_us, gain_db)
        mu_e = crop.electrons_from_optical(centre, exposure_us).astype(np.float64)
        var = gain**2 * (np.maximum(mu_e, 0.0) + sensor.read_noise_e**2) + 1.0 / 12.0
        J = np.empty((mu_dn.size, 6))
        for k, (plus, minus, h) in enumerate(derivatives):
            dp = crop.expected_dn_from_optical(plus, exposure_us, gain_db)
            dm = crop.expected_dn_from_optical(minus, exposure_us, gain_db)
            J[:, k] = ((dp - dm) / (2.0 * h)).ravel()
        fisher = (J.T / var.ravel()) @ J
        cov = np.linalg.pinv(fisher)
        g = np.concatenate([pose.t / distance, np.zeros(3)])
        out.append(PoseBound(covariance=cov, distance_std_m=float(np.sqrt(max(g @ cov @ g, 0.0))),
                             exposure_us=float(exposure_us)))
    return out


def _texture_radius_m(placement: Placement) -> float:
    spec = getattr(placement.texture, "spec", None)
    if spec is not None:
        return float(spec.outer_radius_m)
    xmin, xmax, ymin, ymax = placement.texture.bounds_m
    return 0.5 * min(xmax - xmin, ymax - ymin)
