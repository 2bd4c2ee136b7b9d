"""The tracker's tunables (``TrackerOptions``) and the constants that tune its steps: where a search's edge
profiles are sampled again (re-centred, longer), which frames measure the blur, the clip margin's default, the
inliers of a re-centred estimate and how many levels have their surround modelled."""

from __future__ import annotations

from dataclasses import dataclass

CLIP_MARGIN_FRACTION = 0.01
"""Default ``TrackerOptions.clip_margin_dn``, as a fraction of the camera's saturation level."""


@dataclass(frozen=True)
class TrackerOptions:
    """Tunables of the estimator.

    compensate_exposure: estimate delta jointly with the pose (livetrack's method). False gives the baseline
        "rigorous fit, delta fixed at 0".
    keep_delta_across_frames: reuse the delta estimated at the same exposure time for later frames at that exposure
        (fixed, not re-estimated): more precise when the exposure rarely changes; wrong if the lighting changes.
        "The same" is within 1 % (``DELTA_CACHE_REL_TOL``); the last 16 exposures are kept (``DELTA_CACHE_SIZE``).
        Frames of unknown exposure (None) estimate delta.
    edge_spacing_px: spacing of edge samples along each circle; smaller = more points, slower, slightly more
        precise. Default 1.5 px.
    max_points_per_circle: cap on edge samples per circle (cost bound for near targets). Default 360.
    min_level_radius_px: a fractal level is used only if its outer circle is at least this big in the image.
    edge_half_width_px: half length of each edge profile along the normal (pixels). Default 4.
    noise_model: (read variance DN^2, DN per electron) of the sensor, for absolute edge uncertainties; None
        estimates them from the fit residuals.
    tracking: search only around the targets of the previous frame (a window of the last outer ellipse grown by
        ``tracking_margin`` x its size on each side); a full-frame search runs when the window finds nothing, and
        every frame when the previous one had no target. Much faster; a new target entering the image is found by
        the periodic full-frame search (``tracking_full_search_every``) or once the tracked ones are lost.
    tracking_verify_every: in tracking mode, the window search (and the code read, which confirms id and
        heading) runs on one frame in this many; on the frames between, each target's edges are fitted where the
        last frame found them ok (the others wait for the next search), starting from their offsets, blur and
        levels, and its pose from the last pose (a static target: 1 edge-model evaluation instead of ~4, no
        detection, no closed form). A target whose edges stop
        fitting (pose fit failed, fewer than 80 % of the last frame's edge points ok, or residual RMS more than
        doubled) is lost: when every target is, the frame goes to the window search at once; otherwise the others
        stay tracked and the lost ones are searched for (their last windows, the whole frame if they are not
        there; ``Tracker.process`` in the same frame, the live pipeline on its search thread), their windows
        staying in the later window searches (``LOST_WINDOW_FRAMES``). 1 searches every frame. Default 10.
    tracking_full_search_every: in tracking mode, a search runs over the whole frame (not only the windows) once
        at least this many frames have passed since the last full-frame search, so that targets entering the
        image are picked up. Default 30.
    psf_sigma_px: None (default) or the known width of the lens's Gaussian PSF core (px), e.g. a camera file's
        ``optics.psf_sigma_px``: the blur of the edge fits in a frame whose edge profiles are all clipped (no
        clean edge to measure it from; otherwise the blur measured on the last frame with clean edges, else
        1.0 px; a wrong blur moves clipped edges outward into the white for a blur too wide: by ~0.2 px at 2x
        and ~0.5 px at 4x over-exposure for 1.0 instead of 0.8 px, which delta absorbs but the uncompensated fit
        does not), and where the first frame's free-blur fits start. Cost: none.
    psf_halo: None (default: Gaussian PSF) or the known wide halo of the lens, ``(fraction, sigma_px)``: the PSF
        is ``(1 - fraction) G(core) + fraction G(sigma_px)`` with the core fitted per edge as before (e.g. from
        a camera file's ``optics``, written by ``livetrack model --camera-out``). The edge fits then model the
        halo's tail, which otherwise pulls over-exposed edges into the black by an amount growing with the
        exposure. Cost: each edge-model evaluation takes about twice as long (paper-lab: 0.053 -> 0.055 s per
        frame).
    fit_target_model: a search's target whose edges are mostly clipped and on whose ring's interior a wide halo is
        measured that alone lifts the black to the clip at its edges (``target_model.halo_clips_the_edges``), or pulls
        them by 0.75 % of the target's size or more (``target_model.halo_scale_bias_pct``: a small target; the model's
        pose then kept within 5 % of the edges', ``target_model_pose.PULLED_MAX_MOVE``), gets its
        pose from the whole target modelled in 2-D, the halo included (``target_model.fit_target_model``), instead of
        from its edges: paper-lab at x32 (3 % halo of 6 px), 0.6-3.3 % off from the edges, -0.04 to +0.06 % after;
        a target printed without a sheet can come out worse (clipped ground is taken for its white: 3 of 5 on the
        detection sweep's seeds 0-1), so the model's pose is kept only where the code dots lie no further from it
        than from the edges' (``_dots_prefer_edges``: it turned away exactly those 3), unless the model's normal is
        the mirror image of the edges' (``_mirrored``: then the dots do not judge). The dots check and
        ``TargetResult.target_model`` follow. Searches only; the tracked frames after: ``track_target_model``.
        Cost: 0.8-5.4 s per such target on paper-lab (x32,
        20-130 px; one core at a load of 5-6; two starts, the edges' pose and its mirror image: ``target_model``);
        with the live pipeline's search worker it holds up no tracked frame.
        True, False, or None (default: auto): on, except where ``pipeline.build_pipeline`` turns it off because a
        search holds up the frames behind it (a live source without a search worker, e.g. ``tracking`` off: every
        frame a search). ``--no-fit-target-model``; run config ``tracker.fit_target_model: true | false | null``.
    track_target_model: in tracking mode, a target whose last pose came from the 2-D model (``fit_target_model``, or
        this) gets the model fitted again in each tracked frame while its halo, its levels scaled by the exposure,
        still clips its edges (``target_model.refine_target_model``: stage 2 alone from the predicted pose and the
        last frame's levels), and stays tracked while that fit holds (its edges, the halo's tails, may lose half
        their points when the exposure moves); else the tracked frames give their edges' pose, as biased as the
        search's would have been (paper-lab optics at x32, a target moving at ~3 m: the searches -0.03 to +0.05 %,
        the tracked frames between them +0.75 to +1.54 % without, -0.05 to +0.06 % with it). Cost: ~35-60 ms per
        tracked frame of a 75 px target (~3 m), growing with the target's area (one core; BLAS on one thread: with
        OpenBLAS's own threads on a loaded machine ~150 ms). Default True.
    clip_margin_dn: edge samples at or above the top code minus this (DN) count as clipped, and the edge model
        clips there. A pixel at full well reads the top code plus read noise, rounded and clipped, so about half
        of the saturated pixels read a little less; at 0 the edge fits take those as unclipped white and locate
        an over-exposed edge near the mid-level as a threshold would (~1 px into the black at 4x in paper-lab; the
        joint delta absorbs most of it, not all), and the fits of such profiles converge slowly (their residuals
        are large: ~3x as many model evaluations). None (default): ``CLIP_MARGIN_FRACTION`` (1 %) of the
        camera's saturation level (41 DN at 12 bits), which also covers a full-well non-uniformity of that size;
        a camera file's ``response.read_noise_dn`` gives 3 read-noise sd instead. Samples within the margin carry
        little information, so a generous margin costs little. Cost: none. In DN of the frames the estimator
        reads: for a camera whose values are encoded (``CameraModel.encoding``), its 16-bit linear values.
    clipped_shared_contrast: fit the clipped edge profiles of a target with one shared black-to-white contrast
        (``fit_edges_two_pass(shared_contrast=True)``). Over-exposed profiles show only the tail of the edge,
        where position and contrast trade off; one contrast per target turns the per-point scatter of ~0.2 px
        at 16x into ~0.02 px, and an error of that contrast moves all edges alike (absorbed by delta). In
        paper-lab it divides the mean |distance error| by ~2.5 (default optics) to ~3 (known optics). Assumes
        the target evenly lit (a 40 % vignetting across the image did not hurt). Default True. Cost: one more
        short fit of the clipped points (paper-lab: 0.055 -> 0.066 s per frame).
    predict_motion: in tracking mode, move the last frame's edge samples and pose on by the target's last
        frame-to-frame motion (constant velocity per processed frame) before fitting, so that a target moving
        more than the edge profiles' half length (``edge_half_width_px``) per frame is still followed without a
        search, and the fits start nearer. Default True. Cost: one back-projection of the edge samples.
    edge_bias_floor_px: the standard deviation (px) of a bias shared by all the edge points of one circle, which
        their residuals cannot show and more points do not average away (the ground beside a ring, the code dots,
        the pixel response, a PSF other than the model's): each circle's taken as independent, its effect on the
        pose (``PoseFit.circle_bias_gain``) is added to every pose's covariance
        (``livetrack.estimator.shared_edge_bias``), a floor under the distance's standard deviation of about this
        over the outer radius in px. Changes what is reported, not the pose. Default 0.002 px: on the detection
        sweep's seeds 0-1 (1129 found targets) the floor at which the median |distance error| / sd is a Gaussian's
        0.674 (0.82 without): targets on a sheet want 0.001-0.002, printed without one 0.009, at x32 0.015 (those
        are not covered: a bias that grows with the clip depth and the ground's, not a floor). Cost: ~10 us a pose.
    outer_share_sd: the standard deviation of the outermost circle's share of the exposure bias ``delta`` (the
        white's) where the fit gives that circle a share of its own (``contrast._outer_bias_share``: its bright side
        ground clearly darker than the white, a target printed without a sheet; or the code dots' share,
        ``Tracker._dots_guided``): the share is modelled, not measured, and ``outer_share_sd * |delta|`` is added as
        a bias of that circle alone to the pose's covariance (``shared_edge_bias.outer_circle_bias_covariance``).
        Changes what is reported, not the pose. Default 0.17: on the detection sweep's seeds 0-4, the value at which
        the median |distance error| / sd of the 87 found targets whose outer circle took a share of its own is a
        Gaussian's 0.674 (0.82 without; within 3 sd 86 -> 97 %). Cost: ~10 us a pose, where it applies.
    camera_std: None (default) or the 1-sigma of the camera's (fx, fy, cx, cy, k1, k2, p1, p2, k3), e.g. a camera
        file's ``uncertainty`` section (``livetrack calibrate``; config ``tracker.propagate_camera_uncertainty``):
        each pose's covariance then includes, to first order, what that uncertainty adds
        (``livetrack.estimator.intrinsics_uncertainty``). Cost: ~1-2 ms per target.
    """

    compensate_exposure: bool = True
    keep_delta_across_frames: bool = False
    edge_spacing_px: float = 1.5
    max_points_per_circle: int = 360
    min_level_radius_px: float = 10.0
    edge_half_width_px: float = 4.0
    fit_target_model: bool | None = None
    track_target_model: bool = True
    noise_model: tuple[float, float] | None = None
    tracking: bool = False
    tracking_margin: float = 0.5
    tracking_verify_every: int = 10
    tracking_full_search_every: int = 30
    psf_sigma_px: float | None = None
    psf_halo: tuple[float, float] | None = None
    clip_margin_dn: float | None = None
    clipped_shared_contrast: bool = True
    predict_motion: bool = True
    edge_bias_floor_px: float = 0.002
    outer_share_sd: float = 0.17
    camera_std: tuple[float, ...] | None = None


RECENTRE_PX = 0.5
RECENTRE_FRACTION = 0.2
"""After a search, when more than ``RECENTRE_FRACTION`` of the ok edge points were fitted more than ``RECENTRE_PX``
from where the detector's ellipse put them (an over- or underexposed frame: the ellipses come from a threshold),
their profiles are sampled again centred on the fitted edges and fitted again (paper-lab: the fitted edges of an
x16 frame lie ~1.7 px outside the threshold ellipses, and off-centre profiles lose the tail the fit reads)."""


MIN_CLEAN_EDGES = 20
"""Clean (unclipped, ok) edge points a frame needs for its median blur to become the blur of later all-clipped
frames."""


RECENTRE_OUTLIER_SIGMAS = 4.0
RECENTRE_OUTLIER_MIN_PX = 1.0
RECENTRE_MIN_KEPT = 0.6
"""``Tracker._recentred``: edge points within this many robust standard deviations of a failed search's pose
(at least this many pixels) are its inliers, which must be at least this share of its points and of each
circle's."""


SURROUND_LEVELS = 1
"""How many of a target's levels (the largest used first) have their surround (the next edge on the white side, the
code dots: :mod:`livetrack.estimator.edges.surround`) modelled in their edge profiles. A nested level used beside
its parent is a small target whose surround is within reach, but its edges weigh little in the pose next to its
parent's: modelling it too moved paper-lab's distances by <0.0003 % and cost 2-3 ms per search and ~0.35 ms per
tracked frame (`livetrack bench`, model off/on, load ~1)."""


WIDE_HALF_WIDTH_PX = 16.0
WIDE_RETRY_OK_FRACTION = 0.5
"""After a search, when fewer than ``WIDE_RETRY_OK_FRACTION`` of a target's edge profiles fit, they are fitted
again up to ``WIDE_HALF_WIDTH_PX`` long (within the design's clearance) and the better fit kept."""


DOTS_GUIDE_MIN_DEVIATION = 0.002
DOTS_GUIDE_CLIPPED_DEVIATION = 0.003
DOTS_GUIDE_CLIPPED_MIN_RADIUS_PX = 30.0
DOTS_GUIDE_MIN_ROOM = 0.5
DOTS_GUIDE_STEP = 0.5
DOTS_GUIDE_SHARES = (-0.5, 1.5)
"""``Tracker._dots_guided``: a search of a target whose white is clipped (most of its profiles) and whose outer
circle's bright side is darker than its white (printed without a sheet) has that circle's share of the exposure bias
set by the code dots when they put the pose's scale more than ``DOTS_GUIDE_MIN_DEVIATION`` off (twice their own
scatter about a good pose, ``checks.DOTS_SCALE_NOISE``), or, where the fits do not tell the ground from the white
(clipped white and ground share one contrast: a sheet cannot be told from grey ground), by more than
``DOTS_GUIDE_CLIPPED_DEVIATION`` on a target of at least ``DOTS_GUIDE_CLIPPED_MIN_RADIUS_PX``
(outer semi-minor axis; the dots of a 19 px target on a sheet in an sRGB frame scattered 0.3 % about its pose's
scale from x2 to x8, and taken at their word put it 0.25 % off); and only with the white's black at least
``DOTS_GUIDE_MIN_ROOM`` of the clip level under it (deeper, a halo moves the dots too): from the fits at the
modelled share and ``DOTS_GUIDE_STEP`` from it, the share where the dots' scale is 1, within ``DOTS_GUIDE_SHARES``.

Measured (simulator, one search per frame, 4 grounds x 4 seeds x 3 sizes of 0.2-5 % of the frame, x4-x32): over
sheetless targets on grey ground at x16, the dots' scale minus 1 followed the distance's error (-1.4 to 0 %) to 0.09 %
in median. Over the whole set without a sheet (179 found), mean |distance error| at x4 / x8 / x16 went from 0.124 /
0.255 / 0.375 % to 0.070 / 0.121 / 0.281 % (median 0.037 / 0.110 / 0.269 -> 0.028 / 0.051 / 0.141 %; 39 better by
over 0.1 %, 3 worse) with ``contrast._outer_bias_share`` and this (x32 unchanged at 0.62 %: no room under the clip;
0.118 / 0.189 / 0.357 % with the modelled share alone; 0.051 / 0.111 / 0.221 % without the size limit, which cost
targets on a sheet in the detection sweep). The same targets on a sheet: 0.016 / 0.016 / 0.018 / 0.039 % before,
0.016 / 0.016 / 0.017 / 0.038 % after."""
