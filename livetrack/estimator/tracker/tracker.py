"""The core object: one call per frame, no I/O, no threads.

``Tracker.process(image, exposure_us) -> FrameResult``: detect every configured target, fit model-based sub-pixel
edges on both circles of each visible fractal level, start from the concentric-circle closed form, then fit the
pose jointly with the exposure bias ``delta_px``. In tracking mode most frames skip the detection and the closed
form: the edges are fitted where the last frame found them and the pose starts from the last one
(``TrackerOptions.tracking_verify_every``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.camera.encoding import LINEAR, LINEAR_BIT_DEPTH, linearise
from livetrack.estimator import surround_geometry
from livetrack.estimator.circle_pose import concentric_pose, fit_conic, projected_circle, rotation_from_normal
from livetrack.estimator.clip_level import frame_saturation_dn
from livetrack.estimator.detect import Candidate, Detector
from livetrack.estimator.edge_glue_kernels import median_where
from livetrack.estimator.edges import EdgeFits, fit_edges_two_pass
from livetrack.estimator.edges.two_pass import split_undecided
from livetrack.estimator.intrinsics_uncertainty import with_camera_uncertainty
from livetrack.estimator.pose_fit import (
    CircleEdgePoints,
    PoseFit,
    bias_weights,
    fit_pose,
    pixels_to_normalized,
    project,
    unproject,
)
from livetrack.estimator.residual_correlation import with_correlated_residuals
from livetrack.estimator.shared_edge_bias import with_circle_bias, with_outer_circle_bias
from livetrack.estimator.target_model import Halo
from livetrack.estimator.tracker.checks import (
    DOTS_CONFIRM_MAX_DEVIATION,
    FAR_FROM_START,
    _dots_agree,
    _dots_may_prefer_ground,
    _dots_prefer_edges,
    _dots_prefer_ground,
    _isotropic,
    _levels_agree,
    _mirrored,
    _plausible,
    _with_distance_sd,
    _with_dots_disagreement,
    _with_target_model,
)
from livetrack.estimator.tracker.contrast import (
    _clipped_contrast,
    _contrast_groups,
    _contrast_hint,
    _ground_split,
    _outer_bias_share,
    _outer_differs,
    _split_contrast,
)
from livetrack.estimator.tracker.delta_cache import _DeltaCache
from livetrack.estimator.tracker.options import (
    CLIP_MARGIN_FRACTION,
    DOTS_GUIDE_CLIPPED_DEVIATION,
    DOTS_GUIDE_CLIPPED_MIN_RADIUS_PX,
    DOTS_GUIDE_MIN_DEVIATION,
    DOTS_GUIDE_MIN_ROOM,
    DOTS_GUIDE_SHARES,
    DOTS_GUIDE_STEP,
    MIN_CLEAN_EDGES,
    RECENTRE_FRACTION,
    RECENTRE_MIN_KEPT,
    RECENTRE_OUTLIER_MIN_PX,
    RECENTRE_OUTLIER_SIGMAS,
    RECENTRE_PX,
    SURROUND_LEVELS,
    WIDE_HALF_WIDTH_PX,
    WIDE_RETRY_OK_FRACTION,
    TrackerOptions,
)
from livetrack.estimator.tracker.results import FrameResult, SearchOutcome, TargetFailure, TargetResult
from livetrack.estimator.tracker.target_model_pose import _ground_share_model, _refined_model, _target_model
from livetrack.estimator.tracker.tracks import (
    LOST_WINDOW_FRAMES,
    _Lost,
    _predicted,
    _Samples,
    _still_tracked,
    _Track,
    _with_motion,
)
from livetrack.estimator.tracker.windows import (
    _clearance_px,
    _half_width_px,
    _unique,
    _window,
    _window_min_radius_px,
    group_levels,
)
from livetrack.geometry import Pose
from livetrack.targets.spec import TargetSpec

FloatArray = npt.NDArray[np.float64]


LEVEL_AMBIGUOUS_REASON = ("its code is that of several fractal levels and the surroundings look like its parent's, "
                          "whose code cannot be read (clipped?): which level it is, hence its distance (x5), is "
                          "unknown")


_EDGE_FIELDS = tuple(f.name for f in dataclasses.fields(EdgeFits))
TARGET_CLIP_SAMPLES = 40_000
"""``Tracker._target_clip_level`` reads at most about this many pixels of a target's box (one row in
``rows * cols // TARGET_CLIP_SAMPLES``): ~0.03 ms; a box of up to 200 x 200 px is read whole."""
DARKER_GROUND_MIN_CONTRAST = 0.005
"""The least contrast of an ok edge fit (share of the clip level) for a target on darker ground
(``Candidate.darker_outside``), instead of the edge fits' 2 %: its outer edge is its ink against the ground, a
few percent of the white's reflectance (printed black at 4 % on black velvet at 2 %: 0.9 % of full scale at the
nominal exposure). Its profiles still need a contrast of 5 times their residuals' RMS (``edges.solver``)."""
DARKER_GROUND_MIN_CONTRAST_OF_WHITE = 0.01
"""... or this share of the target's own white (``Candidate.white_level``) where that is less: under-exposed, the
ink-to-ground step shrinks with the white (held-out seed 6's single-018, 12 bit, at x0.25: white 613 DN, the step
~13 DN, under the clip level's 0.5 % (20 DN): its outer circle fitted nowhere, the target lost; with 1 % of its white,
-0.17 %; at x0.5 and up as before)."""


class Tracker:
    """Estimator for a fixed camera and set of target specs."""

    def __init__(self, camera: CameraModel, targets: Sequence[TargetSpec], options: TrackerOptions | None = None):
        self.input_camera = camera
        """The camera as given; ``camera`` is the one the estimator works with: the same, or for a camera whose
        values are encoded (``CameraModel.encoding``: sRGB, a gamma) its 16-bit linear twin, whose frames each
        entry point makes from the given ones (``camera.encoding.linearise``)."""
        if camera.encoding != LINEAR:
            camera = dataclasses.replace(camera, bit_depth=LINEAR_BIT_DEPTH, encoding=LINEAR)
        self.camera = camera
        self.targets = list(targets)
        self.options = options or TrackerOptions()
        self._detector = Detector(self.targets)  # holds its work images from frame to frame
        self._delta_by_exposure = _DeltaCache()
        self._last_windows: list[tuple[tuple[int, int, int, int], float]] = []  # (window, min radius px)
        self._tracks: list[_Track] = []
        self._lost: list[_Lost] = []  # targets lost in tracking: their windows stay in the window searches
        self._lost_unsearched = False  # a target was lost in tracking since the last search: one is due
        self._frame_count = 0  # frames seen (tracked or searched)
        self._since_search = 0
        self._since_full_search = 0
        self._sigma_px = self._default_sigma_px  # blur of the last frame's edges: where the next frame's fits start
        self._clean_sigma_px: float | None = None  # blur measured on the last frame with clean (unclipped) edges
        # per target id, the last halo measured on its interior and that frame's exposure (``_target_model``'s stand-in
        # where a frame's interior shows none)
        self._halos: dict[int, tuple[Halo, float]] = {}
        self._frames_ahead = 1  # camera frames from the kept targets' frame to the one being tracked
        # where the camera's pixels clip (image units), as the last search measured it on its frame
        # (``clip_level.frame_saturation_dn``: below the top code for a full well read short of it)
        self._saturation_dn = float(self.camera.saturation_level)

    def process(self, image: np.ndarray, exposure_us: float | None = None, frames_ahead: int = 1) -> FrameResult:
        """One frame: ``track`` it when no search is due (``search_due``); when that gives nothing (every target
        lost) or a search is due, ``search`` it and ``adopt`` what it found. When ``track`` lost some targets but
        kept others, the lost ones are searched for in the same frame (``search(lost_only=True)``: their last
        windows, the whole frame if a window misses its target) and the frame's result holds the tracked targets
        and those found again. The live pipeline runs the same steps with the searches on a second thread
        (``livetrack.pipeline``). ``frames_ahead``: camera frames since the last frame given (more than 1 when a
        live pipeline dropped some): see ``track``."""
        t0 = time.perf_counter_ns()
        image = self._linear(image)
        if self.search_due:
            self._since_full_search += 1  # track() counts the frames it sees
            self._frame_count += 1
        else:
            tracked = self._track(image, exposure_us, frames_ahead=frames_ahead)
            if tracked is not None and self._lost_unsearched:  # some targets lost, others tracked
                found = self._search(image, exposure_us, lost_only=True)
                self.adopt(found)
                timings = {"detect_ms": found.result.timings_ms["detect_ms"],
                           "pose_ms": tracked.timings_ms["pose_ms"] + found.result.timings_ms["pose_ms"],
                           "total_ms": (time.perf_counter_ns() - t0) / 1e6}
                return FrameResult(tracked.targets + found.result.targets, timings, list(found.result.failures))
            if tracked is not None:
                return tracked
        found = self._search(image, exposure_us)
        self.adopt(found, motion_frames=frames_ahead)
        found.result.timings_ms["total_ms"] = (time.perf_counter_ns() - t0) / 1e6  # a failed track() included
        return found.result

    @property
    def search_due(self) -> bool:
        """The next frame needs a search: tracking is off, no target is kept, the verify interval
        (``tracking_verify_every``) is reached, or a target was lost in tracking since the last search
        (``lost_search_due``)."""
        opts = self.options
        return self._lost_unsearched or not (opts.tracking and self._tracks
                                             and self._since_search + 1 < max(opts.tracking_verify_every, 1))

    @property
    def lost_search_due(self) -> bool:
        """A search is due only because ``track`` lost some targets (others are tracked): ``search(lost_only=True)``
        is enough."""
        opts = self.options
        return bool(self._lost_unsearched and self._tracks
                    and self._since_search + 1 < max(opts.tracking_verify_every, 1))

    def track(self, image: np.ndarray, exposure_us: float | None = None, frames_ahead: int = 1
              ) -> FrameResult | None:
        """Fit every kept target from the last frame's edges and pose (no detection). The targets still tracked
        (``_still_tracked``) are kept and returned; the others are lost: dropped from tracking, their last windows
        kept for the window searches (``LOST_WINDOW_FRAMES``), and a search is due (``search_due``,
        ``lost_search_due``) that looks for them. None, with nothing changed, when tracking is off, no target is
        kept or every kept target is lost (the frame has no pose without a search). Counts the frame toward the
        periodic full-frame search (``tracking_full_search_every``). Ignores ``search_due``. ``frames_ahead``:
        camera frames from the kept targets' frame to this one (a live pipeline drops frames): the motion
        prediction (``predict_motion``) moves them on by that many frames' motion, and the motion kept is per
        camera frame."""
        return self._track(self._linear(image), exposure_us, frames_ahead)

    def _track(self, image: np.ndarray, exposure_us: float | None, frames_ahead: int) -> FrameResult | None:
        """``track`` of a frame already linear (``_linear``)."""
        t0 = time.perf_counter_ns()
        self._since_full_search += 1
        self._frame_count += 1
        if not (self.options.tracking and self._tracks):
            return None
        self._frames_ahead = max(int(frames_ahead), 1)
        kept = []
        for old in self._tracks:
            new = self._estimate(image, old.group, exposure_us, old)
            if not isinstance(new, TargetFailure) and _still_tracked(new[1], old):
                kept.append(new[1])
        if not kept:
            return None
        self._since_search += 1
        if len(kept) < len(self._tracks):
            self._lost_unsearched = True
        self._keep(kept, image.shape)
        elapsed_ms = (time.perf_counter_ns() - t0) / 1e6
        return FrameResult([t.result for t in kept], {"detect_ms": 0.0, "pose_ms": elapsed_ms,
                                                      "total_ms": elapsed_ms})

    def search(self, image: np.ndarray, exposure_us: float | None = None, *, lost_only: bool = False
               ) -> SearchOutcome:
        """Detect the targets (in the tracking windows and the lost targets' windows, or the whole frame when none
        or one is due, or when a target lost since the last search is not in its window) and estimate each from
        scratch. ``lost_only``: only the lost targets' windows (the whole frame if one misses its target), and
        only targets not tracked now are estimated. The kept targets stay as they are: ``adopt`` the outcome to
        track from it."""
        return self._search(self._linear(image), exposure_us, lost_only=lost_only)

    def _search(self, image: np.ndarray, exposure_us: float | None, *, lost_only: bool = False) -> SearchOutcome:
        """``search`` of a frame already linear (``_linear``)."""
        timings: dict[str, float] = {}
        t_detect = time.perf_counter_ns()
        tracked_ids = {t.result.target_id for t in self._tracks} if lost_only else set()
        self._saturation_dn = frame_saturation_dn(image, float(self.camera.saturation_level), self._clip_margin_dn)
        candidates = self._detect(image, lost_only=lost_only)
        timings["detect_ms"] = (time.perf_counter_ns() - t_detect) / 1e6
        estimated: list[tuple[TargetResult, _Track]] = []
        failures: list[TargetFailure] = []
        t1 = time.perf_counter_ns()
        for group in group_levels(candidates):
            if group[0].target_id in tracked_ids:
                continue
            if group[0].level_ambiguous:  # a pose from it may be off by the fractal scale (5x): reported instead
                failures.append(TargetFailure.from_candidate(group[0], "level", LEVEL_AMBIGUOUS_REASON))
                continue
            out = self._estimate(image, group, exposure_us)
            inner = [c for c in group[1:] if min(c.outer.semi_axes_px) >= self.options.min_level_radius_px]
            also = ""  # why the nested levels alone failed too, when they were tried
            if inner and (isinstance(out, TargetFailure) or not out[0].fit.ok):
                # The outer level's edges do not fit (blooming or a smudge across its ring, a ring cut by the
                # frame): the nested levels alone, which the same target's pose puts in the same frame.
                retry = self._estimate(image, inner, exposure_us)
                if not isinstance(retry, TargetFailure) and retry[0].fit.ok:
                    out = retry
                else:
                    why = retry.reason if isinstance(retry, TargetFailure) else retry[0].fit.reason
                    also = f"; its nested levels alone: {why or 'no pose'}"
            if not isinstance(out, TargetFailure) and (out[0].fit.reason or "").startswith("edge residuals"):
                # last: from the pose of its inlying edge points (``_recentred``)
                again = self._estimate(image, group, exposure_us, recentre=True)
                if not isinstance(again, TargetFailure) and again[0].fit.ok:
                    out, also = again, ""
            if isinstance(out, TargetFailure):
                failures.append(dataclasses.replace(out, reason=out.reason + also))
                continue
            estimated.append(out)
            if not out[0].fit.ok:
                failures.append(TargetFailure.from_candidate(group[0], "pose_fit", (out[0].fit.reason or "") + also))
        timings["pose_ms"] = (time.perf_counter_ns() - t1) / 1e6
        timings["total_ms"] = (time.perf_counter_ns() - t_detect) / 1e6
        return SearchOutcome(FrameResult([t.result for _, t in estimated], timings, failures),
                             [t for _, t in estimated], tuple(image.shape), lost_only=lost_only)

    def adopt(self, found: SearchOutcome, *, keep_current: bool = False, with_motion: bool = True,
              motion_frames: int = 1) -> None:
        """Track from now on from what ``search`` found (nothing to do with tracking off). By default its targets
        replace the kept ones, with their motion from the kept ones (``with_motion``: they are from the frame
        ``motion_frames`` camera frames before the searched one; False: no motion). ``keep_current``: the search
        is of an earlier frame and later frames were tracked since: targets kept now keep their newer tracks, the
        search adds the others (without a motion). A ``lost_only`` search is always added that way and does not
        count as the periodic verify search (the tracked targets were not searched)."""
        if not self.options.tracking:
            return
        self._lost_unsearched = False
        if found.lost_only:
            keep_current = True
        else:
            self._since_search = 0
        if keep_current:
            now = {t.result.target_id for t in self._tracks}
            tracks = self._tracks + [t for t in found.tracks if t.result.target_id not in now]
        else:
            before = {t.result.target_id: t for t in self._tracks}  # the last frame's, for the motion
            tracks = [_with_motion(t, before.get(t.result.target_id) if with_motion else None, motion_frames)
                      for t in found.tracks]
        self._keep(tracks, found.shape)

    def _linear(self, image: np.ndarray) -> np.ndarray:
        """``image`` as the estimator reads it: as given for a linear camera, else mapped to 16-bit linear values
        through the inverse of the camera's encoding (a new array; TypeError for a float image)."""
        if self.input_camera.encoding == LINEAR:
            return image
        return linearise(image, self.input_camera.encoding, self.input_camera.bit_depth)

    @property
    def _clip_margin_dn(self) -> float:
        level = float(self.camera.saturation_level)
        margin = self.options.clip_margin_dn
        return CLIP_MARGIN_FRACTION * level if margin is None else float(margin)

    def _target_clip_level(self, image: np.ndarray, points_px: FloatArray, half_width_px: float) -> float:
        """Where the edge fits of one target take a sample as clipped: its pixels' saturation level less the clip
        margin. The level is the camera's, or lower where the pixels clip lower (``clip_level``): as the box around
        the target's sample points (``points_px`` (N, 2), ``half_width_px`` of profile around them) shows it, every
        pixel read (a small target's clipped white is a few pixels, too few in the frame's subsample), else as the
        last search's frame showed it (``_saturation_dn``)."""
        nominal = float(self.camera.saturation_level)
        margin = self._clip_margin_dn
        level = nominal
        xs, ys = points_px[:, 0], points_px[:, 1]
        finite = np.isfinite(xs) & np.isfinite(ys)
        if not finite.all():  # (a search's points may hold NaN; a tracked target's do not)
            xs, ys = xs[finite], ys[finite]
        if len(xs):
            x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
            pad = half_width_px + 2.0
            h, w = image.shape[:2]
            box = image[max(int(y0 - pad), 0):min(int(math.ceil(y1 + pad)) + 1, h),
                        max(int(x0 - pad), 0):min(int(math.ceil(x1 + pad)) + 1, w)]
            if box.size:
                step = min(max(1, box.size // TARGET_CLIP_SAMPLES), box.shape[0])
                # read as a C-contiguous copy of the rows read: the compiled passes run ~3x faster on it
                level = frame_saturation_dn(np.ascontiguousarray(box[::step]), nominal, margin, row_step=1)
        if level >= nominal:
            level = self._saturation_dn
        return level - margin

    def _min_contrast(self, radius: FloatArray, white_outside: npt.NDArray[np.bool_], white_level: float,
                      clip_level: float) -> float | None:
        """The least black-to-white contrast of an ok edge fit of a target (image units), None for the edge fits'
        default (2 % of the clip level): for a target whose outermost circle has its white inside
        (``Candidate.darker_outside``), ``DARKER_GROUND_MIN_CONTRAST`` of the clip level or
        ``DARKER_GROUND_MIN_CONTRAST_OF_WHITE`` of its white (``white_level``: the detector's), the smaller."""
        if white_outside[radius >= radius.max()].all():
            return None
        return min(DARKER_GROUND_MIN_CONTRAST * clip_level,
                   DARKER_GROUND_MIN_CONTRAST_OF_WHITE * max(white_level, 0.0))

    @property
    def _clipped_sigma_px(self) -> float:
        """The blur of a frame whose edge profiles are all clipped: the known PSF core, else the blur measured on
        the last frame with clean edges, else 1.0 px."""
        if self.options.psf_sigma_px is None and self._clean_sigma_px is not None:
            return self._clean_sigma_px
        return self._default_sigma_px

    @property
    def _default_sigma_px(self) -> float:
        """The blur assumed where a frame gives none: the known PSF core, else 1.0 px."""
        return 1.0 if self.options.psf_sigma_px is None else float(self.options.psf_sigma_px)

    def reset(self) -> None:
        """Forget the previous frame (tracking windows and edges, kept exposure biases, blur)."""
        self._last_windows = []
        self._tracks = []
        self._lost = []
        self._lost_unsearched = False
        self._frame_count = 0
        self._since_search = 0
        self._since_full_search = 0
        self._delta_by_exposure = _DeltaCache()
        self._sigma_px = self._default_sigma_px
        self._clean_sigma_px = None
        self._halos = {}
        self._saturation_dn = float(self.camera.saturation_level)

    def _keep(self, tracks: list[_Track], shape: tuple[int, ...]) -> None:
        """Track ``tracks`` (those whose fit is ok) from now on; a target tracked until now and not among them is
        lost: its last window is kept (``_lost``) for ``LOST_WINDOW_FRAMES`` frames or until it is found again."""
        good = [t for t in tracks if t.result.fit.ok]
        ids = {t.result.target_id for t in good}
        lost = [_Lost(t.result.target_id, window, min_radius_px, self._frame_count)
                for t, (window, min_radius_px) in zip(self._tracks, self._last_windows, strict=False)
                if t.result.target_id not in ids]
        lost_ids = {entry.target_id for entry in lost}
        lost += [entry for entry in self._lost if entry.target_id not in ids | lost_ids
                 and self._frame_count - entry.since_frame <= LOST_WINDOW_FRAMES]
        self._tracks = good
        self._last_windows = [(_window(t.result, shape, self.options.tracking_margin), _window_min_radius_px(t.group))
                              for t in good]
        self._lost = lost

    def _detect(self, image: np.ndarray, lost_only: bool = False) -> list[Candidate]:
        """Candidates in the tracked targets' windows and the lost targets' (``lost_only``: those only); the
        whole frame's when there are no tracked windows, when a full-frame search is due, when the windows gave
        nothing, or when a target lost since the last search is not in its window."""
        saturation = self._saturation_dn
        full_due = self._since_full_search >= self.options.tracking_full_search_every
        # one read of each: the live pipeline's processing thread may replace them meanwhile
        tracked_windows, lost, fresh = self._last_windows, self._lost, self._lost_unsearched
        if self.options.tracking and (tracked_windows or lost_only) and not full_due:
            windows = [(entry.window, entry.min_radius_px) for entry in lost]
            if not lost_only:
                windows = tracked_windows + windows
            found: list[Candidate] = []
            for window, min_radius_px in windows:
                found.extend(self._detector.detect(image, saturation=saturation, roi=window,
                                                   min_outer_radius_px=min_radius_px))
            found_ids = {c.target_id for c in found}
            missed = fresh and any(entry.target_id not in found_ids for entry in lost)
            if (found or (lost_only and not fresh)) and not missed:
                return _unique(found)
        self._since_full_search = 0
        return self._detector.detect(image, saturation=saturation)

    # ------------------------------------------------------------------ per target
    def _wide_circles(self, image: np.ndarray, edges: EdgeFits, points: FloatArray, normals_bw: FloatArray,
                      radius: FloatArray, curvature: FloatArray, group: list[Candidate],
                      half_width_px: float, min_contrast: float | None, clip_level: float) -> EdgeFits:
        """``edges`` with the profiles of each circle that fit under ``WIDE_RETRY_OK_FRACTION`` fitted again up to
        ``WIDE_HALF_WIDTH_PX`` long within that circle's level's clearance; a profile's new fit replaces its old
        one where only the new is ok and at the offset most new fits share, when that is half the circle's."""
        opts = self.options
        for cand in group:
            wide_px = min(WIDE_HALF_WIDTH_PX, _clearance_px([cand]))
            if wide_px <= half_width_px + 2.0:
                continue
            for radius_m in (cand.spec.outer_radius_m, cand.spec.inner_radius_m):
                rows = np.flatnonzero(radius == radius_m)
                if rows.size == 0 or edges.ok[rows].mean() >= WIDE_RETRY_OK_FRACTION:
                    continue
                wide = fit_edges_two_pass(image, points[rows], normals_bw[rows], saturation=clip_level,
                                          min_contrast=min_contrast, curvature_per_px=curvature[rows],
                                          half_width_px=wide_px,
                                          noise_model=opts.noise_model, sigma_init_px=self._sigma_px,
                                          sigma_fallback_px=self._clipped_sigma_px, halo=opts.psf_halo,
                                          shared_contrast=opts.clipped_shared_contrast)
                # Kept where the circle's edge is: its new fits agree on one offset from where the detector put
                # it (within 1 px of their median), as a threshold's bias does; scattered offsets are other edges
                # reached (texture beside a target printed without a sheet).
                better = wide.ok & ~edges.ok[rows]
                if better.sum() < 0.5 * rows.size:
                    continue
                better &= np.abs(wide.offset_px - np.median(wide.offset_px[better])) <= 1.0
                if better.sum() >= 0.5 * rows.size:
                    fields = {}
                    for name in _EDGE_FIELDS:
                        merged = getattr(edges, name).copy()
                        merged[rows[better]] = getattr(wide, name)[better]
                        fields[name] = merged
                    edges = EdgeFits(**fields)
        return edges

    def _samples(self, usable: list[Candidate]) -> tuple[FloatArray, ...]:
        """Edge sample points (N, 2), black-to-white normals (N, 2), radius_m, white_outside, curvature (N,). The
        outer circle of a candidate on darker ground (``Candidate.darker_outside``) has its white (the ring) inside."""
        opts = self.options
        pts, normals, radii, white_out, curvature = [], [], [], [], []
        for cand in usable:
            for ellipse, radius_m, outside in ((cand.outer, cand.spec.outer_radius_m, not cand.darker_outside),
                                               (cand.inner, cand.spec.inner_radius_m, False)):
                a, b = ellipse.semi_axes_px
                perimeter = np.pi * (3 * (a + b) - np.sqrt((3 * a + b) * (a + 3 * b)))
                n = int(np.clip(perimeter / opts.edge_spacing_px, 24, opts.max_points_per_circle))
                angles = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
                outward = ellipse.normals(angles)
                pts.append(ellipse.points(angles))
                normals.append(outward if outside else -outward)
                # signed curvature 1/R of the ellipse, positive when its centre of curvature is on the white side
                kappa = a * b / (a * a * np.sin(angles) ** 2 + b * b * np.cos(angles) ** 2) ** 1.5
                curvature.append(-kappa if outside else kappa)
                radii.append(np.full(n, radius_m))
                white_out.append(np.full(n, outside))
        return (np.vstack(pts), np.vstack(normals), np.concatenate(radii), np.concatenate(white_out),
                np.concatenate(curvature))

    def _estimate(self, image: np.ndarray, group: list[Candidate], exposure_us: float | None,
                  track: _Track | None = None, recentre: bool = False) -> tuple[TargetResult, _Track] | TargetFailure:
        """Edges and pose of one target: from its detected levels, or (``track``) from the last frame's fit; a
        target whose pose cannot be started (too few edges, no closed form) is a ``TargetFailure``. ``recentre``: a
        search whose fit fails on its residuals is tried once more from its inliers' pose (``_recentred``)."""
        opts = self.options
        top = group[0]
        if track is None:
            usable = [c for c in group if min(c.outer.semi_axes_px) >= opts.min_level_radius_px] or [top]
            points, normals_bw, radius, outside, curvature = self._samples(usable)
            levels_used = tuple(c.level for c in usable)
            start, contrast_hint, predicted = None, None, None
        else:  # the last frame's ok sample points, moved to their fitted edge where it lies more than 0.5 px away
            keep = track.edges.ok
            if keep.all():  # the arrays themselves (never written to): the same values as copies, ~40 us less
                last, samples = track.edges, track
            else:
                last = EdgeFits(**{name: getattr(track.edges, name)[keep] for name in _EDGE_FIELDS})
                samples = _Samples(track.points_px[keep], track.normals[keep], track.radius_m[keep],
                                   track.white_outside[keep], track.curvature_per_px[keep])
            moved = np.abs(last.offset_px) > 0.5
            points = np.where(moved[:, None], last.points_px, samples.points_px)
            start = dataclasses.replace(last, offset_px=np.where(moved, 0.0, last.offset_px))
            normals_bw, radius, outside = samples.normals, samples.radius_m, samples.white_outside
            curvature, levels_used = samples.curvature_per_px, track.result.levels_used
            contrast_hint = _contrast_hint(track, exposure_us) if opts.clipped_shared_contrast else None
            predicted = self._predicted(track, points)
            if predicted is not None:
                points, predicted_pose = predicted

        # The levels whose edges are sampled: a nested level too small to use does not shorten its parent's
        # profiles (its own clearances, in its own small scale, would; the parent's clearance to it is its own).
        sampled = [c for c in (group if track is None else track.group) if c.level in levels_used]
        half_width_px = _half_width_px(sampled, opts.edge_half_width_px)
        contrast_groups = _contrast_groups(radius)
        white_step, black_step = surround_geometry.white_step_px(points, normals_bw, radius,
                                                                 group if track is None else track.group)
        reach = surround_geometry.reach_px(white_step)
        # The surround is modelled on the largest level used only (``SURROUND_LEVELS``)
        levels = sampled[:SURROUND_LEVELS]
        own_circles = np.zeros(len(radius), dtype=bool)  # np.isin's mask (a few radii: ~3 us less)
        for c in levels:
            own_circles |= (radius == c.spec.outer_radius_m) | (radius == c.spec.inner_radius_m)
        white_step = np.where(black_step & own_circles, white_step, np.inf)
        disks = None
        if track is not None:  # the code dots placed by the pose this frame is expected at, turned as last found
            disks = surround_geometry.white_disks(self.camera, track.result.pose if predicted is None else
                                                  predicted_pose, levels, half_width_px, self._sigma_px, image,
                                                  track.dots_turn_rad)
        if contrast_hint is not None:
            contrast_hint = contrast_hint[contrast_groups]

        memo: dict = {}  # a search's last edge fits with their clipped profiles' contrast sample (fit_edges_two_pass)

        clip_level = self._target_clip_level(image, points, half_width_px)
        min_contrast = self._min_contrast(radius, outside, top.white_level, clip_level)

        samples: list[dict] = []  # each search fit's clipped contrast sample (``memo``'s "state"), in order

        def fit_edges(points, start, contrast_hint, disks=None, start_fits_these=False):
            fits = fit_edges_two_pass(image, points, normals_bw, saturation=clip_level, min_contrast=min_contrast,
                                      contrast_hint=contrast_hint, contrast_groups=contrast_groups,
                                      reach_px=reach, white_step_px=white_step, white_disks=disks,
                                      start_fits_these=start_fits_these, memo=memo if track is None else None,
                                      curvature_per_px=curvature,
                                      half_width_px=half_width_px, noise_model=opts.noise_model,
                                      sigma_init_px=self._sigma_px, start=start,
                                      sigma_fallback_px=self._clipped_sigma_px,  # the blur of all-clipped frames
                                      halo=opts.psf_halo, shared_contrast=opts.clipped_shared_contrast)
            if track is None:
                samples.append(memo.get("state") or {})
            return fits

        edges = fit_edges(points, start, contrast_hint, disks)
        wide_px = min(WIDE_HALF_WIDTH_PX, _clearance_px(sampled)) if track is None else 0.0  # searches only
        if track is None and wide_px > half_width_px + 2.0 and edges.ok.mean() < WIDE_RETRY_OK_FRACTION:
            # the detector's ellipses miss the edges by more than a profile reaches (a large target across a
            # distorted lens is no ellipse in the image): longer profiles find them, the re-centring below
            # then samples them again at the usual length
            wide = fit_edges_two_pass(image, points, normals_bw, saturation=clip_level,
                                      min_contrast=min_contrast, curvature_per_px=curvature, half_width_px=wide_px,
                                      noise_model=opts.noise_model, sigma_init_px=self._sigma_px,
                                      sigma_fallback_px=self._clipped_sigma_px, halo=opts.psf_halo,
                                      shared_contrast=opts.clipped_shared_contrast, contrast_groups=contrast_groups)
            if wide.ok.sum() > edges.ok.sum():
                edges = wide
        elif track is None:
            # One circle missed where the rest fit (a target printed without a sheet: a threshold between its black
            # and white puts its outer edge, black against grey ground, pixels off): that circle's profiles again,
            # as long as its own level's clearance allows (the group's least is often the nested level's).
            edges = self._wide_circles(image, edges, points, normals_bw, radius, curvature, group, half_width_px,
                                       min_contrast, clip_level)
        off_centre = None if track is not None else edges.ok & (np.abs(edges.offset_px) > RECENTRE_PX)
        if track is None and off_centre.sum() > RECENTRE_FRACTION * max(edges.ok.sum(), 1):
            # the detector's ellipses (a threshold: biased by the exposure) put the profiles off the edges: sample
            # them again centred on the fitted edges, as the next frame of a track would
            points = np.where(off_centre[:, None], edges.points_px, points)
            start = dataclasses.replace(edges, offset_px=np.where(off_centre, 0.0, edges.offset_px))
            edges = fit_edges(points, start, _split_contrast(edges, contrast_groups))
        # a tracked frame at the exposure of its last search keeps the outer circle's bias share its dots set
        outer_share = (track.outer_share if track is not None and track.exposure_us == exposure_us else None)
        posed = self._pose(edges, radius, outside, top, exposure_us, track,
                           None if track is None or predicted is None else predicted_pose, outer_share,
                           clip_level=clip_level)
        if isinstance(posed, TargetFailure):
            return posed
        fit, obs, ok = posed
        if track is None and not fit and (fit.reason or "").startswith(FAR_FROM_START):
            # far from the closed form: started again from its own pose where the code dots confirm its scale
            confirmed = surround_geometry.dots_scale(self.camera, fit.pose, levels, image, self._sigma_px)
            if confirmed is not None and abs(confirmed - 1.0) <= DOTS_CONFIRM_MAX_DEVIATION:
                posed = self._pose(edges, radius, outside, top, exposure_us, None, fit.pose, clip_level=clip_level)
                if isinstance(posed, TargetFailure):
                    return posed
                fit, obs, ok = posed
        if track is None and recentre and not fit and fit.reason.startswith("edge residuals"):
            again = self._recentred(image, group, exposure_us, fit, obs)
            if again is not None:
                return again
        if track is None and fit:  # a search: the code dots placed by this pose, then the edges and the pose again
            disks = surround_geometry.white_disks(self.camera, fit.pose, levels, half_width_px, self._sigma_px, image)
            if disks is not None:  # (only the profiles the dots or the next edge reach are fitted again; the ground's
                # contrast kept apart from the white's where the pose took the ground apart)
                hint = _ground_split(edges, contrast_groups, obs.bias_share is not None)
                edges = fit_edges(points, edges, hint, disks, start_fits_these=True)
                posed = self._pose(edges, radius, outside, top, exposure_us, None, fit.pose, clip_level=clip_level)
                if isinstance(posed, TargetFailure):
                    return posed
                fit, obs, ok = posed
        if track is None and fit:  # the outer circle's share of the exposure bias from the code dots, where they ask
            guided = self._dots_guided(fit, obs, edges, radius, outside, top, exposure_us, levels, image, clip_level)
            if guided is not None:
                (fit, obs, ok), outer_share = guided
            else:
                fit = self._with_undecided_split(fit, samples, memo, contrast_groups, clip_level, points, edges,
                                                 fit_edges, radius, outside, top, exposure_us)
        model, edges_dots = None, None
        if track is None and fit and opts.fit_target_model is not False:  # a search: the whole target in 2-D
            model, halo = _target_model(self.camera, edges, fit, levels or group, image, clip_level,
                                        self._clipped_sigma_px, self._halos.get(top.target_id), exposure_us)
            if halo is not None and exposure_us is not None and exposure_us > 0:
                self._halos[top.target_id] = (halo, float(exposure_us))
            if model is not None:
                edges_dots, model_dots = (surround_geometry.dots_scale(self.camera, pose, levels, image,
                                                                       self._sigma_px)
                                          for pose in (fit.pose, model.pose))
                ground = (_ground_share_model(self.camera, model, levels or group, image, clip_level,
                                              self._clipped_sigma_px)
                          if _dots_may_prefer_ground(edges_dots, model_dots) else None)
                ground_dots = None if ground is None else surround_geometry.dots_scale(
                    self.camera, ground.pose, levels, image, self._sigma_px)
                if _dots_prefer_ground(edges_dots, model_dots, ground_dots):
                    model = ground
                elif _dots_prefer_edges(edges_dots, model_dots) and not _mirrored(fit.pose, model.pose):
                    model = None
            if model is not None:
                fit = _with_target_model(fit, model)
        elif (track is not None and fit and track.result.target_model is not None
              and opts.track_target_model):  # a tracked frame after a 2-D model's pose: the model again
            model = _refined_model(self.camera, track, fit, levels, image, exposure_us,
                                   track.result.pose if predicted is None else predicted_pose, clip_level,
                                   self._clipped_sigma_px)
            if model is not None:
                fit = _with_target_model(fit, model)
        scale = None
        if track is None and fit:  # a search: the pose's scale checked on the code dots' centres
            scale = surround_geometry.dots_scale(self.camera, fit.pose, levels, image, self._sigma_px)
            fit = _dots_agree(fit, scale)
        # the dots' disagreement (this search's, else the last search's) in the distance's variance, for a pose of the
        # 2-D model too (its covariance, from every pixel, knows nothing of ground it takes for white: the detection
        # sweep's x32 targets printed without a sheet were 0.3-0.7 % off at a distance sd of 0.003-0.05 %, their dots
        # 0.4-0.9 % off the same way); the tracked frames that keep their edges' pose after a model's take the edges'
        # pose's dots, those that fit the model again the model's
        dots_seen = scale if track is None else track.dots_scale
        model_dots = None if track is None else track.model_dots_scale
        if model is None:
            fit = _with_dots_disagreement(fit, dots_seen)
        elif track is None:
            fit = _with_dots_disagreement(fit, scale)
            dots_seen, model_dots = edges_dots, scale
        else:
            fit = _with_dots_disagreement(fit, model_dots)
        result = TargetResult(target_id=top.target_id, levels_used=levels_used, fit=fit,
                              heading_known=top.heading_rad is not None, n_edge_points=int(ok.sum()),
                              edge_points_px=obs.points_px, candidate=top, dots_scale=scale, target_model=model,
                              outer_share=_outer_share_of(obs))
        contrast, measured_at = _clipped_contrast(edges, contrast_groups), exposure_us
        if contrast is None:  # kept from the last clipped frame (e.g. exposures cycling under, nominal, over)
            contrast, measured_at = (None, None) if track is None else (track.clipped_contrast,
                                                                         track.contrast_exposure_us)
        new = _Track(group, points, normals_bw, radius, outside, curvature, edges, result, contrast, measured_at,
                     dots_turn_rad=None if disks is None else disks.turn_rad, dots_scale=dots_seen,
                     exposure_us=exposure_us, outer_share=outer_share, model_dots_scale=model_dots)
        return result, _with_motion(new, track, self._frames_ahead if track is not None else 1)

    def _recentred(self, image: np.ndarray, group: list[Candidate], exposure_us: float | None, fit: PoseFit,
                   obs: CircleEdgePoints) -> tuple[TargetResult, _Track] | None:
        """A search whose pose fit failed on its residuals' RMS (``fit``, of the edge points ``obs``), estimated once
        more from the ellipses that the pose of its inlying edge points projects, or None when there is no such
        pose or the second estimate fails too.

        The detector's ellipses come from a threshold: a ring joined by the threshold to dark texture beside it
        (flecks of foliage touching a ring printed without a sheet, x16-x32) gets an outline pixels off and too
        big, its edge profiles then straddle the flecks' edges and a sixth of them fit 7-24 px off: the robust
        fit converged 6 % short at 7.7 px RMS. The points within ``RECENTRE_OUTLIER_SIGMAS`` robust standard
        deviations (1.4826 x the median absolute residual; at least ``RECENTRE_OUTLIER_MIN_PX``) give a pose (the
        closed form and the fit again, on them alone) when they are at least ``RECENTRE_MIN_KEPT`` of the points
        and of each circle's; its projected circles are the candidates' ellipses of a second search estimate,
        whose profiles are centred on the edges as a tracked frame's are. Only a fit that then passes every check
        is kept (the same checks: residuals, distance, levels, dots' scale)."""
        top = group[0]
        r = np.abs(fit.residuals_px)
        if len(r) != len(obs) or not np.all(np.isfinite(r)):
            return None
        keep = r <= max(RECENTRE_OUTLIER_SIGMAS * 1.4826 * float(np.median(r)), RECENTRE_OUTLIER_MIN_PX)
        if keep.all() or keep.mean() < RECENTRE_MIN_KEPT:
            return None
        for radius in (top.spec.outer_radius_m, top.spec.inner_radius_m):
            on = obs.radius_m == radius
            if keep[on].sum() < RECENTRE_MIN_KEPT * on.sum():
                return None
        inlying = obs.subset(keep)
        norm = pixels_to_normalized(self.camera, inlying.points_px)
        initial = self._closed_form(inlying, norm, top)
        if isinstance(initial, TargetFailure):
            return None
        pose = fit_pose(self.camera, inlying, initial, estimate_delta=self.options.compensate_exposure,
                        points_normalized=norm)
        if not _plausible(pose, initial):
            return None
        moved = []
        for c in group:
            outer = projected_circle(self.camera, pose.pose, c.spec.outer_radius_m)
            inner = projected_circle(self.camera, pose.pose, c.spec.inner_radius_m)
            if outer is None or inner is None:
                return None
            moved.append(dataclasses.replace(c, outer=outer, inner=inner))
        again = self._estimate(image, moved, exposure_us)
        return None if isinstance(again, TargetFailure) or not again[0].fit else again

    def _pose(self, edges: EdgeFits, radius: FloatArray, outside: npt.NDArray[np.bool_], top: Candidate,
              exposure_us: float | None, track: _Track | None, start_pose: Pose | None,
              outer_share: float | None = None, *, clip_level: float, record: bool = True
              ) -> tuple[PoseFit, CircleEdgePoints, npt.NDArray[np.bool_]] | TargetFailure:
        """The pose fit of one target's edge fits (and the frame's blur, measured on them), from ``start_pose``, else
        from the closed form (a search) or the last frame's pose (``track``): the fit, its observations and which
        edge points are in them; a search whose closed form fails is a ``TargetFailure``. ``outer_share``: the
        outermost circle's share of the exposure bias (``_dots_guided``); None: ``_outer_bias_share``'s. ``record``:
        False for a fit only compared with another (the frame's blur and the exposure's delta are not kept)."""
        opts = self.options
        ok = edges.ok & np.isfinite(edges.points_px[:, 0]) & np.isfinite(edges.points_px[:, 1])
        if ok.sum() >= 5 and record:
            self._sigma_px = median_where(edges.sigma_px, ok)
        clean = ok & (edges.n_clipped == 0)
        if record and clean.sum() >= MIN_CLEAN_EDGES and not (track is not None
                                                             and track.result.target_model is not None):
            # (a target posed by the 2-D model gives none: its unclipped profiles lie beside the halo-lifted black,
            # paper-lab optics at x32 and 2 m: 28 of 263 at a blur of 2.6 px for 0.8; the model, given that core,
            # found no halo narrower than 2.5 cores and the pose stayed 0.33 % off)
            self._clean_sigma_px = median_where(edges.sigma_px, clean)
        share = (_outer_bias_share(edges, radius, ok, clip_level) if outer_share is None or not ok.any()
                 else np.where(radius[ok] >= radius[ok].max(), outer_share, 1.0))
        obs = CircleEdgePoints(edges.points_px[ok], radius[ok], outside[ok],
                               np.maximum(edges.position_std_px[ok], 0.01), share)
        points_norm = pixels_to_normalized(self.camera, obs.points_px)
        if start_pose is not None:
            initial = start_pose
        elif track is None:
            initial = self._closed_form(obs, points_norm, top)
            if isinstance(initial, TargetFailure):
                return initial
        else:
            initial = track.result.pose
        delta0, estimate = 0.0, opts.compensate_exposure
        if estimate and track is not None:
            delta0 = track.result.delta_px
        kept = self._delta_by_exposure.get(exposure_us) if opts.keep_delta_across_frames else None
        if kept is not None:
            delta0, estimate = kept, False
        slot_rad = 2.0 * np.pi / max(top.spec.code.slots if top.spec.code else 8, 1)
        yaw_std = slot_rad / np.sqrt(12.0) if top.heading_rad is not None else np.pi
        fit = fit_pose(self.camera, obs, initial, estimate_delta=estimate, delta_px=delta0, yaw_std_rad=yaw_std,
                       points_normalized=points_norm)
        fit = _plausible(fit, initial)
        if fit:
            fit = _levels_agree(fit, self.camera, obs, points_norm, estimate)
        if fit:
            fit = _isotropic(fit, self.camera, obs, points_norm, estimate)
        # the edge residuals' correlation along the circles in the covariance: after the checks above, which were
        # set on the fit's own covariance (``_tight``), so that it changes what is reported, not what is found
        fit = with_correlated_residuals(fit, obs)
        fit = with_circle_bias(fit, opts.edge_bias_floor_px)  # (a floor under it: a bias the residuals cannot show)
        if share is not None:  # the outermost circle's share of the white's bias, modelled: its uncertainty, times
            # the white's bias, a bias of that circle alone
            fit = with_outer_circle_bias(fit, opts.outer_share_sd * abs(fit.delta_px))
        if opts.camera_std is not None:  # the camera's calibration uncertainty, to first order
            fit = with_camera_uncertainty(fit, self.camera, obs, opts.camera_std, estimate)
        if record and fit and estimate and opts.keep_delta_across_frames and exposure_us is not None:
            self._delta_by_exposure.put(exposure_us, fit.delta_px)
        return fit, obs, ok

    def _with_undecided_split(self, fit: PoseFit, samples: list[dict], memo: dict, groups: npt.NDArray[np.int64],
                              clip_level: float, points: FloatArray, edges: EdgeFits, fit_edges, radius: FloatArray,
                              outside: npt.NDArray[np.bool_], top: Candidate, exposure_us: float | None) -> PoseFit:
        """A search's ``fit`` with the distance it would have had with the white's and the ground's clipped contrasts
        apart in its variance, where the edge fits shared one between them only because the split fell short of its
        standard errors (``two_pass.split_undecided``): a small target printed without a sheet, deep in the clip,
        whose white shows few unclipped samples (a 13.5 px target on grey ground at x16: the white's contrast
        283 k +- 58 k, the ground's 98 k +- 3 k, shared at 103 k; its distance -3.9 % at a reported sd of 0.08 %).
        The ambiguity is real (a sheet's outer circle reads 0.4-1.8 of its white's contrast at up to 5.5 standard
        errors): the pose stands, its uncertainty says so. ``samples``: the search's fits' clipped contrast samples,
        the first undecided one taken (the re-centred and the surround's fits sample fewer white profiles: at x16 the
        13.5 px target's last kept 8 of its white's, under the 10 a group needs); ``memo``: the search's
        (``fit_edges_two_pass``), left as it was. Only where ``edges`` shared one contrast."""
        shared = _clipped_contrast(edges, groups)
        if shared is None or not np.all(np.isfinite(shared)) or shared[0] != shared[1]:
            return fit
        split = next((s for s in (split_undecided(state, groups, clip_level) for state in samples) if s is not None),
                     None)
        if split is None:
            return fit
        kept = dict(memo)
        try:
            again = self._pose(fit_edges(points, edges, split), radius, outside, top, exposure_us, None, fit.pose,
                               clip_level=clip_level, record=False)
        finally:
            memo.clear()
            memo.update(kept)
        if isinstance(again, TargetFailure) or not again[0]:
            return fit
        moved = abs(float(np.linalg.norm(again[0].pose.t)) / float(np.linalg.norm(fit.pose.t)) - 1.0)
        return _with_distance_sd(fit, moved)

    def _dots_guided(self, fit: PoseFit, obs: CircleEdgePoints, edges: EdgeFits, radius: FloatArray,
                     outside: npt.NDArray[np.bool_], top: Candidate, exposure_us: float | None,
                     levels: list[Candidate], image: np.ndarray, clip_level: float
                     ) -> tuple[tuple[PoseFit, CircleEdgePoints, npt.NDArray[np.bool_]], float] | None:
        """A search's pose fitted again with the outermost circle's share of the exposure bias set by the code dots,
        and that share (the track keeps it for its frames at this exposure), or None (``fit`` stands). See
        ``DOTS_GUIDE_MIN_DEVIATION``.

        One delta moves every edge by the white's bias; the outer circle of a target printed without a sheet has
        ground on its bright side, clipped less deeply or not at all, whose bias is another (``_outer_bias_share``
        models it from the fitted levels, which a clipped frame measures poorly). The dots' centres do not move
        with the exposure (``surround_geometry.dots_scale``): where they put the pose's scale off, the share that
        brings them to 1 is found from two fits (the pose's scale is linear in it over the range) and kept if the
        dots then agree better. Only where most of the white's profiles are clipped (unclipped, the white has no
        clipping bias for the outer circle to share, and its share, then barely moving the pose, was driven to its
        limits by the dots' scatter: a 17 px target on carpet at x0.25-x1 went from 0.38 to 0.64 %), and the edge
        fits show the outer circle's bright side darker than the white (``contrast._outer_differs``), or, on a
        target of at least ``DOTS_GUIDE_CLIPPED_MIN_RADIUS_PX`` (a clipped frame shares one contrast between the
        white and the ground and cannot tell them apart), the dots disagree by more than
        ``DOTS_GUIDE_CLIPPED_DEVIATION``: on a sheet the dots' own scatter (0.1 %) exceeds the edges' (0.01 %). Not
        where the ink itself is lifted near the clip (``DOTS_GUIDE_MIN_ROOM``): at x32 a halo moves clipped dots'
        centroids too (a 200 px target on a sheet: its dots 0.5 % off an edges' pose within 0.002 %)."""
        ok = edges.ok & np.isfinite(edges.points_px[:, 0]) & np.isfinite(edges.points_px[:, 1])
        if not ok.any() or not clip_level - median_where(edges.black_level, ok) >= DOTS_GUIDE_MIN_ROOM * clip_level:
            return None
        white_side = radius[ok] < radius[ok].max()
        if not (edges.n_clipped[ok][white_side] > 0).mean() > 0.5:
            return None  # the white not clipped: no clipping bias to share (before the dots are measured: ~0.08 ms)
        differs = _outer_differs(edges, radius, ok)
        if not differs and not min(top.outer.semi_axes_px) >= DOTS_GUIDE_CLIPPED_MIN_RADIUS_PX:
            return None
        scale0 = surround_geometry.dots_scale(self.camera, fit.pose, levels, image, self._sigma_px)
        if scale0 is None or not abs(scale0 - 1.0) > (DOTS_GUIDE_MIN_DEVIATION if differs
                                                       else DOTS_GUIDE_CLIPPED_DEVIATION):
            return None
        outer = obs.radius_m >= obs.radius_m.max()
        s0 = float(np.median(bias_weights(obs)[outer]))
        s1 = s0 - DOTS_GUIDE_STEP if s0 >= 0.5 else s0 + DOTS_GUIDE_STEP
        scale1, _ = self._scale_at_share(s1, fit, edges, radius, outside, top, exposure_us, levels, image,
                                        clip_level)
        if scale1 is None or scale1 == scale0:
            return None
        share = min(max(s0 + (1.0 - scale0) * (s1 - s0) / (scale1 - scale0), DOTS_GUIDE_SHARES[0]),
                    DOTS_GUIDE_SHARES[1])
        scale, posed = self._scale_at_share(share, fit, edges, radius, outside, top, exposure_us, levels,
                                                image, clip_level)
        if scale is None or posed is None or not abs(scale - 1.0) < abs(scale0 - 1.0):
            return None
        # the scale is now the dots': their scatter (up to the least disagreement acted on) in the distance's variance
        return (_with_distance_sd(posed[0], DOTS_GUIDE_MIN_DEVIATION), posed[1], posed[2]), share

    def _scale_at_share(self, share: float, fit: PoseFit, edges: EdgeFits, radius: FloatArray,
                        outside: npt.NDArray[np.bool_], top: Candidate, exposure_us: float | None,
                        levels: list[Candidate], image: np.ndarray, clip_level: float
                        ) -> tuple[float | None, tuple[PoseFit, CircleEdgePoints, npt.NDArray[np.bool_]] | None]:
        """The code dots' scale at the pose fitted with the outer circle's bias share ``share`` (from ``fit``'s
        pose), and that fit; (None, None) when it fails."""
        posed = self._pose(edges, radius, outside, top, exposure_us, None, fit.pose, outer_share=share,
                           clip_level=clip_level)
        if isinstance(posed, TargetFailure) or not posed[0]:
            return None, None
        return surround_geometry.dots_scale(self.camera, posed[0].pose, levels, image, self._sigma_px), posed

    def _predicted(self, track: _Track, points: FloatArray) -> tuple[FloatArray, Pose] | None:
        """``tracks._predicted`` over the camera frames since the kept targets' frame, or None with
        ``predict_motion`` off."""
        if not self.options.predict_motion:
            return None
        return _predicted(self.camera, track, points, self._frames_ahead)

    def _closed_form(self, obs: CircleEdgePoints, points_norm: FloatArray, top: Candidate) -> Pose | TargetFailure:
        """The concentric-circle pose of the outermost level, or why there is none."""
        outer = obs.radius_m == top.spec.outer_radius_m
        inner = obs.radius_m == top.spec.inner_radius_m
        if outer.sum() < 6 or inner.sum() < 6:
            return TargetFailure.from_candidate(
                top, "edges", f"too few edge points fitted for the closed form ({int(outer.sum())} on the outer "
                f"circle, {int(inner.sum())} on the inner; 6 each needed)")
        norm_outer, norm_inner = points_norm[outer], points_norm[inner]
        sol = concentric_pose(fit_conic(norm_outer), fit_conic(norm_inner), top.spec.outer_radius_m,
                              top.spec.inner_radius_m)
        if not np.all(np.isfinite(sol.t_m)):
            return TargetFailure.from_candidate(top, "closed_form", "the two circles give no finite pose")
        if sol.t_m[2] <= 0:
            return TargetFailure.from_candidate(top, "closed_form", "the closed-form pose is behind the camera")
        hint = self._x_axis_hint(sol.t_m, sol.normal_cam, top)
        return Pose(rotation_from_normal(sol.normal_cam, hint), sol.t_m)

    def _x_axis_hint(self, t_m: FloatArray, normal: FloatArray, cand: Candidate) -> FloatArray:
        """Target +x in the camera frame from the code's image-plane heading (camera +x if unknown)."""
        if cand.heading_rad is None:
            return np.array([1.0, 0.0, 0.0])
        centre_px = project(self.camera, t_m[None, :])[0]
        step = 5.0 * np.array([np.cos(cand.heading_rad), np.sin(cand.heading_rad)])
        ray = unproject(self.camera, (centre_px + step)[None, :])[0]
        point = ray * (normal @ t_m) / (normal @ ray)
        return point - t_m


def _outer_share_of(obs: CircleEdgePoints) -> float | None:
    """The median share of the exposure bias of ``obs``' outermost circle's points, None when every point takes it
    whole (``TargetResult.outer_share``)."""
    if obs.bias_share is None or len(obs) == 0:
        return None
    return float(np.median(obs.bias_share[obs.radius_m >= obs.radius_m.max()]))
