"""What tracking mode keeps of a target from frame to frame (``_Track``, ``_Lost``), its frame-to-frame motion
and the prediction from it, and whether a tracked target is still tracked."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.estimator import pose_kernels
from livetrack.estimator.detect import Candidate
from livetrack.estimator.edge_glue_kernels import kernel_array
from livetrack.estimator.edge_kernels import kernels
from livetrack.estimator.edges import EdgeFits
from livetrack.estimator.pose_fit import UNDISTORT_ITERATIONS, UNDISTORT_TOL, project, unproject
from livetrack.geometry import Pose

if TYPE_CHECKING:
    from livetrack.estimator.tracker.results import TargetResult

FloatArray = npt.NDArray[np.float64]


PREDICT_MIN_PX = 0.25
PREDICT_MAX_PX = 64.0
"""Tracking moves the last frame's edge samples on by the target's last motion when that moves them by a median of
at least ``PREDICT_MIN_PX`` (below, the edges stay where they were fitted: a static target keeps its exact start)
and at most ``PREDICT_MAX_PX`` (beyond, the motion is not trusted; the window search takes over if needed)."""


MAX_FRAMES_AHEAD = 30
"""The motion prediction extrapolates over at most this many camera frames (beyond, ``PREDICT_MAX_PX`` usually
refuses it anyway)."""


LOST_WINDOW_FRAMES = 60
"""A target lost in tracking while others stay tracked keeps its last window in the window searches (the verify
searches, every ``tracking_verify_every`` frames) for this many frames: an occluded target that comes back where it
was is found at the next one; elsewhere, by the periodic full-frame search."""


@dataclass(frozen=True)
class _Track:
    """What tracking mode keeps of one target for the next frame: its detected levels, the edge samples (N,)
    (sample points (N, 2), normals (N, 2), circle radius, white outside, curvature) and their fits; the contrast
    shared by its clipped edge profiles in the last frame that had enough of them (None: none yet) and that
    frame's exposure (None: not given); the camera-frame rigid motion (R_m, t_m) from the frame before to this
    one, X' = R_m X + t_m (None after a search); the turn (rad) about the target's normal that put its code dots
    where the image has them, relative to its pose (``surround_geometry.white_disks``; None: not measured)."""

    group: list[Candidate]
    points_px: FloatArray
    normals: FloatArray
    radius_m: FloatArray
    white_outside: npt.NDArray[np.bool_]
    curvature_per_px: FloatArray
    edges: EdgeFits
    result: TargetResult
    clipped_contrast: FloatArray | None  # per contrast group (``_contrast_groups``), NaN where unmeasured
    contrast_exposure_us: float | None
    motion: tuple[FloatArray, FloatArray] | None = None
    dots_turn_rad: float | None = None
    dots_scale: float | None = None  # the last search's ``TargetResult.dots_scale`` (``_with_dots_disagreement``)
    exposure_us: float | None = None  # the frame's (None: not given)
    # the outer circle's share of the exposure bias the last search's code dots set (``Tracker._dots_guided``), for
    # the tracked frames at its exposure; None: modelled (``contrast._outer_bias_share``)
    outer_share: float | None = None
    # where the code dots lay relative to the last search's 2-D model's pose (``TargetResult.dots_scale`` then), for
    # the tracked frames that fit the model again (``_with_dots_disagreement``)
    model_dots_scale: float | None = None


class _Samples(NamedTuple):
    """A track's edge samples (``_Track``'s fields of the same names), e.g. those of its ok fits."""

    points_px: FloatArray
    normals: FloatArray
    radius_m: FloatArray
    white_outside: npt.NDArray[np.bool_]
    curvature_per_px: FloatArray


@dataclass(frozen=True)
class _Lost:
    """A target lost in tracking while others stayed tracked: its last search window (and the least outer radius
    to look for there) and the frame count (``Tracker._frame_count``) when it was lost."""

    target_id: int
    window: tuple[int, int, int, int]
    min_radius_px: float
    since_frame: int


def _with_motion(track: _Track, before: _Track | None, frames: int = 1) -> _Track:
    """``track`` with the camera-frame rigid motion per camera frame from ``before`` (the same target ``frames``
    camera frames before) to it, X' = R_m X + t_m (over several frames: the rotation's angle and the translation
    divided by ``frames``, exact for a translation, close for small rotations); unchanged when there is no
    earlier track or either pose fit failed."""
    if before is None or not (track.result.fit.ok and before.result.fit.ok):
        return track
    then, now = before.result.pose, track.result.pose
    r_m = now.R @ then.R.T
    t_m = now.t - r_m @ then.t
    if frames > 1:
        r_m = cv2.Rodrigues(cv2.Rodrigues(r_m)[0] / frames)[0]
        t_m = t_m / frames
    return dataclasses.replace(track, motion=(r_m, t_m))


def _still_tracked(new: _Track, old: _Track) -> bool:
    """A target fitted from the last frame's edges is kept when its pose fit is ok, at least 80 % of the last
    frame's edge points are still ok and the residual RMS has not more than doubled; or, its pose from the 2-D model
    (``TrackerOptions.track_target_model``), when its pose fit is ok: there the edges are the halo's tails, and their
    count moves with the exposure (paper-lab pose 3 from x32 to x31: 144 -> 78 ok edge points, the model's pose within
    0.01 %)."""
    fit, last = new.result.fit, old.result.fit
    if fit.ok and new.result.target_model is not None:
        return True
    return bool(fit.ok and new.result.n_edge_points >= 0.8 * old.result.n_edge_points
                and fit.residual_rms_px <= 2.0 * last.residual_rms_px + 0.01)


def _predicted(camera: CameraModel, track: _Track, points: FloatArray, frames_ahead: int
               ) -> tuple[FloatArray, Pose] | None:
    """The sample points (N, 2) and the pose moved on by the track's last motion over ``frames_ahead`` camera frames
    (constant velocity per processed frame), or None when there is no motion yet or it moves the points by less than
    ``PREDICT_MIN_PX`` (median; a static target keeps its exact start) or by more than ``PREDICT_MAX_PX``."""
    if track.motion is None:
        return None
    r_m, t_m = track.motion
    for _ in range(min(frames_ahead, MAX_FRAMES_AHEAD) - 1):  # the motion of each camera frame since
        r_m, t_m = track.motion[0] @ r_m, track.motion[0] @ t_m + track.motion[1]
    pose = track.result.pose
    if kernels() == "numba":  # the same steps compiled (one call instead of ~20 numpy operations)
        cam = camera
        new_points, shift, status = pose_kernels.predict_points(
            kernel_array(points, np.float64), float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy),
            *(float(d) for d in cam.dist), UNDISTORT_ITERATIONS, UNDISTORT_TOL, kernel_array(pose.R, np.float64),
            kernel_array(pose.t, np.float64), kernel_array(r_m, np.float64), kernel_array(t_m, np.float64))
        if status != 0 or not (PREDICT_MIN_PX <= shift <= PREDICT_MAX_PX):
            return None
        return new_points, Pose(r_m @ pose.R, r_m @ pose.t + t_m)
    rays = unproject(camera, points)
    normal = pose.R[:, 2]
    along = rays @ normal
    if np.any(along <= 1e-9):
        return None
    on_plane = rays * ((normal @ pose.t) / along)[:, None]  # the points on the target plane, camera frame
    moved = on_plane @ r_m.T + t_m
    if np.any(moved[:, 2] <= 1e-9):
        return None
    new_points = project(camera, moved)
    shift = np.median(np.linalg.norm(new_points - points, axis=1))
    if not (PREDICT_MIN_PX <= shift <= PREDICT_MAX_PX):
        return None
    return new_points, Pose(r_m @ pose.R, r_m @ pose.t + t_m)
