"""Tunables of the coarse detector."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DetectOptions:
    """Tunables of the coarse detector (the defaults suit 8-16 bit cameras and phone photos).

    threshold_window_px: window of the adaptive threshold on every pyramid level (odd, level pixels); must span
        the black ring of the largest target a level looks for (``max_level_radius_px``). Cost independent of it.
        Default 51.
    threshold_offset: a pixel is dark when it is this much below its window's mean (levels of the normalised
        8-bit image); raised to 8x the estimated noise (texture included) of each pyramid level, up to 3x this
        value. Higher: fewer texture blobs (faster), misses low-contrast targets. Default 10.
    level0_blur_px: Gaussian blur (sigma, pixels) of the full-resolution level before its threshold (coarser
        levels are smoothed by the pyramid): removes pixel noise and fine texture, i.e. most of the blobs (cost
        ~1 ms per 2 Mpx, saves far more in contour tracing). Default 0.8.
    level0_max_radius_px: the same for the full-resolution level, the costliest: targets bigger than this are
        left to level 1 (where they are at least 16 px). With ``min_outer_radius_px`` above it, the full-resolution
        level is skipped altogether (about 40 % of the cost of a frame). Default 32 (with 24, targets of 24-32 px
        met only level 1, where grown dots cut their bands).
    max_level_radius_px: largest outer semi-minor axis searched on each coarser pyramid level (level pixels; the
        semi-major axis may reach 3x this); larger targets are found on coarser levels. Default 48.
    min_level_radius_px: smallest outer semi-major axis searched on levels 1 and up (level pixels); level 0 uses
        ``min_outer_radius_px``. Default 8.
    exposure_bias_px: edge displacement (pixels, each edge) the r/R test tolerates, from over-/underexposure and
        blur. Larger: accepts thinner/thicker rings, more chance pairings. Default 2.5.
    ratio_tolerance: relative slack on each semi-axis ratio beyond the bias (perspective, fit noise). Default 0.1.
    centre_tolerance: largest distance between the two ellipse centres, as a fraction of the outer semi-major
        axis (plus 1 px). Default 0.12.
    min_aspect: smallest b/a accepted for an ellipse (0.2 = about 78 degrees of tilt). Default 0.2.
    refine_max_radius_px: pairs are refined on the finest pyramid level where the outer radius is at most this
        (level pixels): full resolution up to it, coarser (cheaper, ~0.1 level px of accuracy) beyond. Default 256.
    max_code_distance: largest soft Hamming distance (slots) of a code match. Default 1.0.
    min_code_margin: smallest gap (slots) between the best code (at its best rotation) and the next best code or
        rotation: a read one slot off two codes is ambiguous (the code book's codes differ in two or more slots),
        and a wrong id is worse than a miss. Default 0.5.
    min_contrast: smallest (white - black) level difference of a target, as a fraction of its own white level
        (in input units, clipped at full scale). Default 0.05.
    relative_offset: the local threshold also needs a pixel this fraction of its window's range (max - min,
        8-bit levels) below the window's mean: keeps texture and noise beside a high-contrast edge out.
        Default 0.15.
    """

    threshold_window_px: int = 51
    threshold_offset: float = 8.0
    level0_blur_px: float = 0.8
    level0_max_radius_px: float = 32.0
    max_level_radius_px: float = 48.0
    min_level_radius_px: float = 8.0
    exposure_bias_px: float = 2.5
    ratio_tolerance: float = 0.1
    centre_tolerance: float = 0.12
    min_aspect: float = 0.2
    refine_max_radius_px: float = 256.0
    max_code_distance: float = 1.0
    min_code_margin: float = 0.5
    min_contrast: float = 0.05
    relative_offset: float = 0.05
