"""Exact edge points of a target's circles seen at a pose, for the pose-fit tests (not a test module)."""

from __future__ import annotations

import numpy as np

from livetrack.camera import CameraModel
from livetrack.estimator.pose_fit import CircleEdgePoints, _model
from livetrack.geometry import Pose


def circle_edge_points(camera: CameraModel, pose: Pose, radii_m, white_outside, per_circle: int, std_px: float
                       ) -> tuple[CircleEdgePoints, np.ndarray]:
    """The points of each circle (``radii_m``, white outside where ``white_outside``) at ``per_circle`` evenly spaced
    angles, in the tracker's order (by angle around each circle, circle after circle), stated with ``std_px``, and
    their black-to-white normals (N, 2): moving a point along its normal by b adds b to its residual."""
    pts, rad, wo = [], [], []
    ang = np.linspace(0.0, 2.0 * np.pi, per_circle, endpoint=False)
    for r, o in zip(radii_m, white_outside, strict=True):
        X = pose.apply(np.column_stack([r * np.cos(ang), r * np.sin(ang), np.zeros(per_circle)]))
        pts.append(camera.project(X))
        rad += [r] * per_circle
        wo += [o] * per_circle
    obs = CircleEdgePoints(np.vstack(pts), np.array(rad), np.array(wo), np.full(len(rad), std_px))
    _, n_bw, _ = _model(camera, camera.unproject(obs.points_px), obs, pose.R, pose.t)
    return obs, n_bw
