"""Where the design around each edge point lies, for the edge fits of one target: the design's next edge on each
profile's white side, how far the profile may reach, and the white code dots placed in the image by a pose (the
geometry; the model is :mod:`livetrack.estimator.edges.surround`)."""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.estimator import surround_kernels
from livetrack.estimator.detect import Candidate
from livetrack.estimator.edge_glue_kernels import kernel_array
from livetrack.estimator.edge_kernels import kernels
from livetrack.estimator.edges.surround import DISK_REACH_SIGMA, WhiteDisks
from livetrack.estimator.pose_fit import project
from livetrack.geometry import Pose

FloatArray = npt.NDArray[np.float64]


REACH_MARGIN_PX = 1.5
MIN_REACH_PX = 1.5
"""On its white side, an edge profile stops ``REACH_MARGIN_PX`` short of the next edge of the design (its blur,
sigma ~1 px, still darkens a sample 1.5 px from it by ~7 %), but reaches at least ``MIN_REACH_PX``."""


def white_room_m(group: Sequence[Candidate]) -> dict[float, tuple[float, bool]]:
    """For each circle of the group's levels (by its radius, metres): the room on its white side to the next edge
    of the design (metres; inf outside the top level: a sheet or the ground, unknown), and whether the white ends
    there in black (a nested level's ring, a centre dot, a parent's ring) rather than at the centre of a plain
    white disk. A level on darker ground (``Candidate.darker_outside``): its outer circle's white is the ring,
    which ends at the code dots (a step up, not down)."""
    room: dict[float, tuple[float, bool]] = {}
    for cand in group:
        spec = cand.spec
        inside = spec.child.outer_radius_m if spec.child is not None else spec.centre_dot_radius_m
        if cand.darker_outside and spec.code is not None:  # the ring is the outer edge's white, up to the dots
            room[spec.outer_radius_m] = (spec.outer_radius_m - spec.code.ring_radius_m - spec.code.dot_radius_m,
                                         False)
        room.setdefault(spec.outer_radius_m, (math.inf, False))
        room[spec.inner_radius_m] = (spec.inner_radius_m - inside, inside > 0)
        if spec.child is not None:  # a nested level's outside is its parent's white disk
            room[spec.child.outer_radius_m] = (spec.inner_radius_m - spec.child.outer_radius_m, True)
    return room


def white_step_px(points: FloatArray, normals_bw: FloatArray, radius_m: FloatArray,
                   group: Sequence[Candidate]) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """(N,) the distance (pixels, along the normal) from each edge point to the design's next edge on its white
    side (``white_room_m``: the nested level's black ring inside an inner circle, the parent's inner circle outside
    a nested level, the centre of a plain white disk), scaled at each point by the circle's distance from its
    centre along the normal (exact for an affine view of concentric circles), inf where there is none (outside
    the top level: a sheet or the ground); and (N,) whether the white ends there in a step down to black.
    Compiled (``surround_kernels.white_step``; this numpy is its reference, ``LIVETRACK_KERNELS=numpy``: the same to
    rounding, tested): ~0.12 ms of numpy per tracked frame."""
    room = white_room_m(group)
    if kernels() == "numba":
        finite = [(r_m, room_m / r_m, black) for r_m, (room_m, black) in room.items() if math.isfinite(room_m)]
        return surround_kernels.white_step(
            kernel_array(points, np.float64), kernel_array(normals_bw, np.float64), kernel_array(radius_m, np.float64),
            np.array([f[0] for f in finite], dtype=np.float64), np.array([f[1] for f in finite], dtype=np.float64),
            np.array([f[2] for f in finite], dtype=np.bool_))
    step = np.full(len(points), np.inf)
    black = np.zeros(len(points), dtype=bool)
    for r_m in np.unique(radius_m):
        rows = radius_m == r_m
        room_m, black_beyond = room.get(r_m, (math.inf, False))
        if not math.isfinite(room_m) or rows.sum() < 3:
            continue
        centre = points[rows].mean(axis=0)
        support_px = np.abs(np.einsum("ij,ij->i", points[rows] - centre, normals_bw[rows]))
        step[rows] = room_m / r_m * support_px
        black[rows] = black_beyond
    return step, black


def reach_px(white_step_px: FloatArray) -> FloatArray:
    """(N, 2) how far each edge profile may reach toward its black and its white side (pixels). The white side:
    up to ``REACH_MARGIN_PX`` short of the design's next edge (``white_step_px``; its blurred step is modelled, see
    :mod:`livetrack.estimator.edges.surround`, but beyond it lie the nested level's code dots), at least
    ``MIN_REACH_PX``. The black side is not limited: over-exposed, the edge is seen 1-2 px into the black, and
    profiles held short of the code dots there lost their black level (16x, 20 px target: 6 of 88 outer points
    fitted)."""
    reach = np.full((len(white_step_px), 2), np.inf)
    reach[:, 1] = np.maximum(white_step_px - REACH_MARGIN_PX, MIN_REACH_PX)
    return reach



def white_disks(camera: CameraModel, pose: Pose, levels: Sequence[Candidate], half_width_px: float,
                sigma_px: float, image: npt.NDArray | None = None, turn_rad: float | None = None
                ) -> WhiteDisks | None:
    """The white code dots of the levels whose dots come within a profile's reach of their circles (``half_width_px``
    plus ``DISK_REACH_SIGMA`` blurs ``sigma_px``, along the level's outer semi-minor axis: small targets), placed by
    ``pose`` (the target's frame in the camera's); None when there are none (large targets, codes without a heading:
    the dots' places are then unknown). Each dot's local Jacobian comes from projecting points one dot radius away
    along the target's x and y axes.

    image: None, or the frame: the circles fix a pose's rotation about the target's normal only to the code's
    slot (an 11 px target's dots came out ~1 px from their place), so the dots are turned about the centre to
    where the image is brightest at their centres (``_dots_turn_rad``) before they are placed; ``turn_rad`` (rad), if
    given, is that turn found before (a tracked target: its pose keeps its rotation about the normal from frame to
    frame) and no search is made. The disks carry the turn used (``WhiteDisks.turn_rad``)."""
    centres, radii, slots = [], [], []
    for cand in levels:
        spec, code = cand.spec, cand.spec.code
        if code is None or cand.heading_rad is None:  # (a code without a heading reads as none)
            continue
        gap_m = min(code.ring_radius_m - code.dot_radius_m - spec.inner_radius_m,
                    spec.outer_radius_m - code.ring_radius_m - code.dot_radius_m)
        if gap_m / spec.outer_radius_m * min(cand.outer.semi_axes_px) > half_width_px + DISK_REACH_SIGMA * sigma_px:
            continue
        dots = code.white_dot_centres_m()
        centres.append(dots)
        radii.append(np.full(len(dots), code.dot_radius_m))
        slots.append(code.slots)
    if not centres:
        return None
    c_m, r_m = np.vstack(centres), np.concatenate(radii)

    if turn_rad is None:
        turn_rad = 0.0 if image is None else _dots_turn_rad(image, c_m, camera, pose, np.pi / max(slots))
    c_m = _turned(c_m, turn_rad)
    m = len(c_m)
    px = _image_of(camera, pose, np.vstack([c_m, c_m + np.column_stack([r_m, 0.0 * r_m]),
                                            c_m + np.column_stack([0.0 * r_m, r_m])]))
    c_px = px[:m]
    jacobian = np.stack([(px[m:2 * m] - c_px) / r_m[:, None], (px[2 * m:] - c_px) / r_m[:, None]], axis=-1)
    det = jacobian[:, 0, 0] * jacobian[:, 1, 1] - jacobian[:, 0, 1] * jacobian[:, 1, 0]
    if not np.all(np.isfinite(c_px)) or not np.all(np.abs(det) > 0):
        return None
    return WhiteDisks(c_px, np.linalg.inv(jacobian), r_m, np.sqrt(np.abs(det)), turn_rad)


TURN_STEP_RAD = np.deg2rad(0.5)
"""The grid on which ``_dots_turn_rad`` scores the dots' rotation about the target's normal."""


def _image_of(camera: CameraModel, pose: Pose, xy_m: FloatArray) -> FloatArray:
    """(M, 2) pixels of points (M, 2) in the target's plane (metres), placed by ``pose``."""
    return project(camera, np.column_stack([xy_m, np.zeros(len(xy_m))]) @ pose.R.T + pose.t)


def _pose_and_camera(camera: CameraModel, pose: Pose) -> tuple:
    """The compiled kernels' arguments for ``_image_of``: R, t (fresh C arrays), fx, fy, cx, cy and the lens's
    distortion."""
    return (np.array(pose.R, dtype=np.float64, order="C"), np.array(pose.t, dtype=np.float64), float(camera.fx),
            float(camera.fy), float(camera.cx), float(camera.cy), *(float(d) for d in camera.dist))


def _turned(xy_m: FloatArray, angle_rad: float) -> FloatArray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return xy_m @ np.array([[c, s], [-s, c]])


def _dots_turn_rad(image: npt.NDArray, centres_m: FloatArray, camera: CameraModel, pose: Pose,
                   half_range_rad: float) -> float:
    """The rotation (rad, about the target's normal, within +-``half_range_rad``) that puts the dots' projected
    centres where the image is brightest: the sum of the image (bilinear) at the centres on a grid of
    ``TURN_STEP_RAD``, and the centre of its top quarter (weights: the excess over 3/4 of the way from its least to
    its greatest), which also finds the middle of a flat top (clipped dots). (A coarse grid first, then a fine one
    around its best, placed an 11 px target's dots 0.09 px off instead of 0.04: the top quarter is wider than the
    fine window. Searches only: a tracked target keeps its turn.)"""
    angles = np.arange(-half_range_rad, half_range_rad + 0.5 * TURN_STEP_RAD, TURN_STEP_RAD)
    score = _dots_brightness(image, centres_m, camera, pose, angles)
    top, least = float(score.max()), float(score.min())
    weight = np.maximum(score - (least + 0.75 * (top - least)), 0.0)
    if not np.isfinite(top) or weight.sum() <= 0:
        return 0.0
    return float((weight * angles).sum() / weight.sum())


def _turned_by_each(xy_m: FloatArray, angles_rad: FloatArray) -> FloatArray:
    """(A * M, 2) the points (M, 2) turned by each angle (A,): ``_turned`` of each, stacked (one array operation
    instead of A small products: ~0.14 of the turn search's ~0.26 ms)."""
    c, s = np.cos(angles_rad)[:, None], np.sin(angles_rad)[:, None]
    x, y = xy_m[:, 0], xy_m[:, 1]
    return np.stack([x * c - y * s, x * s + y * c], axis=-1).reshape(-1, 2)


def _dots_brightness(image: npt.NDArray, centres_m: FloatArray, camera: CameraModel, pose: Pose,
                     angles_rad: FloatArray) -> FloatArray:
    """(A,) the sum of the image (bilinear, clamped to the frame) at the dots' centres turned by each angle.
    Compiled (``surround_kernels.dots_brightness``; this numpy is its reference, ``LIVETRACK_KERNELS=numpy``)."""
    if kernels() == "numba":
        return surround_kernels.dots_brightness(image, centres_m, np.cos(angles_rad), np.sin(angles_rad),
                                                *_pose_and_camera(camera, pose))
    px = _image_of(camera, pose, _turned_by_each(centres_m, angles_rad))
    h, w = image.shape[:2]
    clamped = np.column_stack([np.clip(px[:, 0], 0.0, w - 1.001), np.clip(px[:, 1], 0.0, h - 1.001)])
    return _bilinear(image, clamped).reshape(len(angles_rad), len(centres_m)).sum(axis=1)


DOTS_WINDOW = 1.6
DOTS_GRID = 13
DOTS_MIN_CONTRAST = 0.3
DOTS_MIN_RADIUS_PX = 1.5
DOTS_MIN_RADIUS_SIGMAS = 1.5
"""``dots_scale``: each white dot's centroid is taken over a window of ``DOTS_WINDOW`` dot radii about where it is
expected, sampled on a ``DOTS_GRID`` x ``DOTS_GRID`` grid in the target's plane, twice (the second window centred on the
first centroid); a dot counts when its window's brightest and darkest samples differ by at least ``DOTS_MIN_CONTRAST``
of the level's black-to-white contrast, and a level only when its dots' radius, along its outer semi-minor axis, is at
least ``DOTS_MIN_RADIUS_PX`` and ``DOTS_MIN_RADIUS_SIGMAS`` times the blur measured on the target's edges (smaller dots,
blurred, place a scale no better than the edges do: a 1.6 px dot under a 2.2 px blur with 7 px of motion blur, its
window reaching the nested level's white disk, read 1.17 for a pose 0.15 % off). The window (0.7 R +- 0.16 R) stays
inside the black annulus (0.4 R to R)."""


def dots_scale(camera: CameraModel, pose: Pose, levels: Sequence[Candidate], image: npt.NDArray,
               sigma_px: float = 0.0) -> float | None:
    """Where the image puts the white code dots relative to ``pose``: the median, over the dots of the detected
    ``levels`` (those whose circles the pose was fitted to: dots between the circles a pose fits are placed by it even
    when its tilt is a little off, while a nested level's pose extrapolated to its parent's dots, 5x out, put them 2-3 %
    off) whose dots are large enough (``DOTS_MIN_RADIUS_PX``, ``DOTS_MIN_RADIUS_SIGMAS`` times ``sigma_px``), of the
    distance of a dot's centroid from the target's centre over the design's (1.0: the dots lie where the pose projects
    them). Each level's dots are first turned about the normal to where the image is brightest (``_dots_turn_rad``).
    Blur and clipping grow a dot or shrink it about its centre: its centre, unlike the circles' edges, does not move
    with the exposure, so this measures the pose's distance apart from the edges' exposure bias (a pose 9.7 % too near,
    its outer circle widened by a chessboard's squares, put the dots at ~0.88). A dot's centroid: the samples of its
    window (in the target's plane, through ``pose``) above halfway from the window's darkest to its brightest, weighted
    by their excess. None when no detected level has a heading (the dots' places are unknown), or fewer than two dots
    count (too small, too faint, or their windows leave the frame).

    The windows and the turn search are compiled (``surround_kernels.dots_centroids``, ``dots_brightness``; this numpy
    is their reference, ``LIVETRACK_KERNELS=numpy``: the same scale to ~1e-15, tests/test_dots_scale_kernel.py): 0.082
    ms a call instead of 0.463 (5.6x; the 81 calls of the searches of every 6th scene of the sweep's seed 3, in-process,
    alternated, medians of 15 repeats, load ~0.8-1.5)."""
    h, w = image.shape[:2]
    known = [c for c in levels if c.heading_rad is not None]
    if not known:
        return None
    ref = max(known, key=lambda c: c.spec.outer_radius_m)
    px_per_m = float(min(ref.outer.semi_axes_px)) / ref.spec.outer_radius_m
    contrast = float(ref.white_level - ref.black_level)
    if not contrast > 0:
        return None

    centres, dots = [], []
    for spec in {c.spec.outer_radius_m: c.spec for c in levels}.values():
        code = spec.code
        if code is None or code.dot_radius_m * px_per_m < max(DOTS_MIN_RADIUS_PX, DOTS_MIN_RADIUS_SIGMAS * sigma_px):
            continue
        c_m = code.white_dot_centres_m()
        if len(c_m) == 0:
            continue
        centres.append(_turned(c_m, _dots_turn_rad(image, c_m, camera, pose, np.pi / code.slots)))
        dots.append(np.full(len(c_m), code.dot_radius_m))
    if not centres:
        return None
    c_m, dot_m = np.vstack(centres), np.concatenate(dots)
    gx, gy = _dots_window()
    if kernels() == "numba":
        scale = surround_kernels.dots_centroids(image, c_m, dot_m, gx, gy, *_pose_and_camera(camera, pose),
                                                DOTS_MIN_CONTRAST * contrast)
        return None if math.isnan(scale) else float(scale)
    found = c_m.copy()
    counted = np.ones(len(c_m), dtype=bool)
    for _ in range(2):
        pts = np.stack([found[:, 0, None] + dot_m[:, None] * gx, found[:, 1, None] + dot_m[:, None] * gy], axis=-1)
        px = _image_of(camera, pose, pts.reshape(-1, 2)).reshape(len(c_m), -1, 2)
        in_frame = np.all(np.isfinite(px), axis=(1, 2)) & np.all(px >= 0.0, axis=(1, 2)) & \
            np.all(px[:, :, 0] <= w - 1.001, axis=1) & np.all(px[:, :, 1] <= h - 1.001, axis=1)
        counted &= in_frame
        if counted.sum() < 2:
            return None
        vals = np.zeros(pts.shape[:2])
        vals[counted] = _bilinear(image, px[counted].reshape(-1, 2)).reshape(int(counted.sum()), -1)
        lo, hi = vals.min(axis=1), vals.max(axis=1)
        weight = np.maximum(vals - 0.5 * (lo + hi)[:, None], 0.0)
        total = weight.sum(axis=1)
        counted &= (hi - lo >= DOTS_MIN_CONTRAST * contrast) & (total > 0)
        safe = np.where(total > 0, total, 1.0)
        centroid = np.stack([(weight * pts[:, :, 0]).sum(axis=1), (weight * pts[:, :, 1]).sum(axis=1)], axis=-1)
        found = np.where(counted[:, None], centroid / safe[:, None], found)
    if counted.sum() < 2:
        return None
    ratio = np.hypot(found[:, 0], found[:, 1]) / np.hypot(c_m[:, 0], c_m[:, 1])
    return float(np.median(ratio[counted]))


@functools.cache
def _dots_window() -> tuple[FloatArray, FloatArray]:
    """``dots_scale``'s window: (K,) x and y offsets (dot radii) of the ``DOTS_GRID`` x ``DOTS_GRID`` grid's points
    within ``DOTS_WINDOW``, built once (read-only)."""
    grid = np.linspace(-DOTS_WINDOW, DOTS_WINDOW, DOTS_GRID)
    gx, gy = (a.ravel() for a in np.meshgrid(grid, grid))
    inside = gx**2 + gy**2 <= DOTS_WINDOW**2
    gx, gy = gx[inside], gy[inside]
    gx.flags.writeable = gy.flags.writeable = False
    return gx, gy


def _bilinear(image: npt.NDArray, px: FloatArray) -> FloatArray:
    """(M,) the image at the points (M, 2), bilinear; the points lie inside the frame."""
    x, y = px[:, 0], px[:, 1]
    x0, y0 = np.floor(x).astype(np.intp), np.floor(y).astype(np.intp)
    fx, fy = x - x0, y - y0
    return ((1 - fx) * (1 - fy) * image[y0, x0] + fx * (1 - fy) * image[y0, x0 + 1]
            + (1 - fx) * fy * image[y0 + 1, x0] + fx * fy * image[y0 + 1, x0 + 1])
