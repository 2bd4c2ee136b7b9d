"""Baseline pose estimators livetrack is compared with, behind one small protocol (``PoseMethod``).

* ``NaiveEllipseMethod`` (``naive``): Canny contours + ``cv2.fitEllipse`` + concentric-circle pose, distance from
  the outer circle, no exposure model;
* ``ArucoMethod`` (``square_markers``): OpenCV ArUco markers, sub-pixel corners, ``SOLVEPNP_IPPE_SQUARE``;
* ``AprilTagMethod`` (``square_markers``): AprilTag 36h11 corners from ``pupil_apriltags``, the same PnP and
  camera model as ArUco.

All report poses in livetrack's target frame (origin at the centre, x right and y down seen from the front,
z away from the viewer) and are compared at the same physical outer size: a square marker's black square side
equals the ring target's outer diameter 2R.
"""

from livetrack.baselines.common import PoseEstimate, PoseMethod
from livetrack.baselines.naive import NaiveEllipseMethod, NaiveOptions
from livetrack.baselines.square_markers import (
    AprilTagMethod,
    ArucoMethod,
    apriltag_marker_image,
    aruco_marker_image,
    texture_side_m,
)

__all__ = [
    "AprilTagMethod",
    "ArucoMethod",
    "NaiveEllipseMethod",
    "NaiveOptions",
    "PoseEstimate",
    "PoseMethod",
    "apriltag_marker_image",
    "aruco_marker_image",
    "texture_side_m",
]
