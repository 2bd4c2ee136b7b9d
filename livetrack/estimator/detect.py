"""Coarse detection of ring targets: concentric ellipse pairs, verified and identified by their code.

Pipeline (``detect``):

1. Map the image to 8 bits for the coarse stage with a fixed map, ``255 sqrt(v / full scale)``: no image
   statistics, so whatever else the frame holds (a saturated sky, a black night, one dark patch) a target keeps
   its levels; the square root keeps about as many levels of contrast for an underexposed target as for an
   overexposed one, and makes shot noise about level-independent.
2. A Gaussian pyramid; on each level a local threshold (mean or mid-range of a window, minus an offset from the
   local range and the camera noise; in saturated windows anything clearly below the top) marks dark pixels, and
   OpenCV's contours with two-level hierarchy give, for each dark blob, its outer boundary and its holes; on
   coarser levels also after closing 1-2 px white gaps (a small over-exposed ring cut by its grown dots). Level
   ``s`` looks for targets whose outer semi-minor axis is 8..48 pixels *of that level* (the full-resolution
   level: ``min_outer_radius_px``..24), so the window always spans the black ring, whatever the target's size.
   The full-resolution level is slightly blurred first (texture), and the local statistics come from two levels
   down (cheap).
3. Cheap tests (size, a hole near the middle with about (r/R)^2 of the blob's area, solidity), then ellipses
   fitted to the outer boundary and to the holes (filtered by fit residual, area and aspect); a pair is kept
   when the hole is concentric with the blob and both semi-axis ratios match some configured r/R (with room for
   an exposure bias of a few pixels on each edge).
4. Each pair is refined on a crop of the finest pyramid level on which the target is at most
   ``refine_max_radius_px`` big, with a global threshold halfway between its own black and white levels.
5. Verification and identification on the original image: the homography implied by the two concentric ellipses
   (up to the in-plane rotation) maps target-plane sample points to the image; the black annulus must be dark
   (between the inner disk and the code dots, between the dots and the outer edge, and in every gap between two
   slots; where the pair's seen ring thickness puts them: over-exposure thins the bands and grows the dots), the
   inner disk bright, with a contrast relative to the target's own white. The slot grid's phase comes from
   the N-th circular harmonic of the code circle;
   each slot's value is normalised between the black and white levels and decoded against the configured codes
   (only those of the geometry that matched). No code match: no candidate.
6. Fractal levels: a nested target is found as its own pair; when its code does not tell the level (the default
   design repeats the code), a detected parent around it decides, else the parent's own code read around it
   (in the same frame, on whatever part of the parent's code circle is in the image).

Limits: the code needs an outer radius of about 9 px or more (8 px blurred targets fail); at 4x overexposure
the white dots swell into the inner disk for outer radii below ~25 px, and such targets are missed.

Cost: mostly the full-resolution passes of steps 1-2 (16-to-8-bit conversion, blur, first pyramid step, the
upsampled local threshold and its comparison) and the ellipse fits. The full-size work images (8-bit image,
pyramid, blurred level 0, threshold image: about 3.5 bytes per pixel of the largest image seen) are kept by the
``Detector`` from one call to the next and overwritten: a fresh multi-megabyte array costs its page faults, more
than a pass over it. Contours are traced over the bounding box of a level's dark pixels only; the homography of
step 5 is computed in scalar arithmetic.

Pixel convention: (x, y), (0, 0) the centre of the top-left pixel; ``image[y, x]``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.lut_kernel import lut16
from livetrack.estimator.target_map import (
    affine_homography,
    apply_homography,
    centre_homography,
    rotation3,
    sample_target,
)
from livetrack.targets import codebook
from livetrack.targets.spec import TargetSpec

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Candidate:
    """One detected target level.

    target_id: the configured target's id; level: 0 = outermost, 1 = the nested target, ...; spec: that level's
    spec. outer / inner: image ellipses (pixels) of the black disk's outer edge and of the white inner disk's
    edge, from a mid-level threshold (biased by exposure like any threshold; the sub-pixel edge fit removes it).
    rotation_slots: ``codebook.decode``'s rotation, relative to the image +x direction from the centre (the
    target's +x axis lies about ``rotation_slots * 2 pi / N`` from it); None if the code is symmetric.
    heading_rad: image-plane angle (from +x toward +y) of the target's +x axis at the centre, from the slot grid
    (a few degrees); None if unknown. code_margin: soft-distance gap (slots) to the next best code or rotation.
    code_values: (N,) soft slot values in [0, 1] as read on the slot grid nearest the image +x direction from
    the centre: ``code_values[j]`` ~ bit ``(j - rotation_slots) mod N`` of the code.
    black_level, white_level: median image values (input units) seen in the black annulus / white inner disk.
    level_ambiguous: the code is that of several levels and the pair's surroundings look like its parent's
    without its code being readable (e.g. clipped): ``level`` is the outermost, which may be wrong by the
    fractal scale; the tracker reports such a candidate as a failure (stage "level"), not a pose.
    """

    target_id: int
    level: int
    spec: TargetSpec
    outer: Ellipse
    inner: Ellipse
    rotation_slots: int | None
    heading_rad: float | None
    code_margin: float
    code_values: FloatArray
    black_level: float
    white_level: float
    level_ambiguous: bool = False


@dataclass(frozen=True)
class TraceEvent:
    """One step of the detector on one blob or pair, recorded when ``detect`` is given a ``trace`` list (a
    diagnostic: which stage lost a target). Stages, in the order a target passes them:

    - "blob": a dark blob of a pyramid level that gave no pair; ``detail`` says why ("no hole", "short contour",
      "size", "hole area/centre", "outer fit", "outer size", "inner fit/ratio").
    - "pair": a concentric pair kept after de-duplication (``detail``: "plain", "closed", "wide", "crop").
    - "border": a pair too close to the image border.
    - "code": a pair whose verification or code failed for one geometry (``detail``: the reason).
    - "candidate": a pair identified (``detail``: "id N level L", with " ambiguous" when the level is).

    ``level``: the pyramid level (0 = full resolution) of the blob or pair, -1 after the pyramid stage;
    ``centre_px`` and ``semi_major_px`` in full-image pixels."""

    stage: str
    level: int
    centre_px: tuple[float, float]
    semi_major_px: float
    detail: str


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


# ---------------------------------------------------------------------- target geometry groups
@dataclass(frozen=True)
class _Geometry:
    """The shape of a level in units of its outer radius (what the sampling needs)."""

    ratio: float  # r / R
    ring: float  # code ring radius / R
    dot: float  # code dot radius / R
    slots: int


@dataclass(frozen=True)
class _Entry:
    """One configured level: the top-level id, the level, its spec and its parent's spec (None at level 0)."""

    target_id: int
    level: int
    spec: TargetSpec
    parent: TargetSpec | None


def _geometry_groups(targets: list[TargetSpec]) -> dict[_Geometry, list[_Entry]]:
    groups: dict[_Geometry, list[_Entry]] = {}
    for top in targets:
        parent = None
        for level, spec in top.levels():
            if spec.code is not None:
                R = spec.outer_radius_m
                geom = _Geometry(round(spec.radius_ratio, 6), round(spec.code.ring_radius_m / R, 6),
                                 round(spec.code.dot_radius_m / R, 6), spec.code.slots)
                groups.setdefault(geom, []).append(_Entry(top.id, level, spec, parent))
            parent = spec
    return groups


def _hole(entries: list[_Entry]) -> float:
    """Radius (units of R) inside the inner disk that may hold something dark (child, centre dot, its text)."""
    worst = 0.0
    for e in entries:
        s = e.spec
        dark = max(3.0 * s.centre_dot_radius_m, s.child.outer_radius_m if s.child else 0.0, 0.3 * s.inner_radius_m)
        worst = max(worst, dark / s.outer_radius_m)
    return worst


# ---------------------------------------------------------------------- entry point
class Detector:
    """The coarse detector for one set of targets: their geometry groups, the options and the full-size work
    images, kept from one call to the next and overwritten (a fresh multi-megabyte array costs its page faults,
    more than a pass over it). Not thread-safe: one Detector per thread.

    ``Detector(targets, options).detect(image, ...) -> list[Candidate]``; ``detect(image, targets, ...)`` is the
    same with a Detector made for the call."""

    def __init__(self, targets: list[TargetSpec], options: DetectOptions | None = None) -> None:
        self.targets = list(targets)
        self.options = options or DetectOptions()
        self._groups = _geometry_groups(self.targets)
        self._ratios = sorted({g.ratio for g in self._groups})
        # pairs from a hole alone (``_hole_pairs``): a code within half a slot of its match, a full slot ahead of
        # the next (dark ground with a few bright flecks around a round hole can read as a sparse code otherwise)
        self._hole_opts = dataclasses.replace(self.options, max_code_distance=HOLE_PAIR_MAX_CODE_DISTANCE,
                                              min_code_margin=HOLE_PAIR_MIN_CODE_MARGIN)
        self._work = _WorkImages()

    def detect(
        self,
        image: npt.ArrayLike,
        saturation: float | None = None,
        min_outer_radius_px: float = 8.0,
        border_margin_px: float = 3.0,
        roi: tuple[int, int, int, int] | None = None,
        trace: list[TraceEvent] | None = None,
    ) -> list[Candidate]:
        """Find the configured targets (every fractal level big enough) in one image.

        image: (H, W) uint8, uint16 or float (any scale); other dtypes are converted to float32.
        saturation: the sensor's clip level in image units (e.g. 4095), or None (then the full scale of the
            data: see ``full_scale``); pixels at or above it count as white. Default None.
        min_outer_radius_px: smallest outer radius found (the code needs about 9 px or more). Above
            ``DetectOptions.level0_max_radius_px`` (32 px) the full-resolution pass is skipped (about 1.7x
            faster). Default 8.
        border_margin_px: a target whose outer ellipse comes closer than this to the image (or ``roi``) border
            is rejected (it may be cut). Default 3.
        roi: (x0, y0, x1, y1) pixel bounds (x1, y1 exclusive, clipped to the image) to search, e.g. around a
            tracked target: cost scales with its area. Results are in full-image pixels. Default None (all).
        trace: a list to which every blob, pair and verification step is appended as a ``TraceEvent`` (a
            diagnostic, slower: every dark blob is examined). Default None.

        Returns candidates sorted by (target_id, level); an empty list when nothing is found (never raises for
        image content: blank, saturated, tiny or odd-sized images give ``[]``).
        """
        opts, work = self.options, self._work
        img = np.asarray(image)
        if img.ndim != 2:
            raise ValueError(f"image must be 2-D (H, W), got shape {img.shape}")
        if img.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
            img = img.astype(np.float32)
        if not self._groups:
            return []
        x0, y0 = 0, 0
        if roi is not None:
            x0, y0 = max(int(roi[0]), 0), max(int(roi[1]), 0)
            x1, y1 = min(int(roi[2]), img.shape[1]), min(int(roi[3]), img.shape[0])
            if x1 <= x0 or y1 <= y0:
                return []
            img = img[y0:y1, x0:x1]
        min_r = max(float(min_outer_radius_px), 3.0)
        if min(img.shape) < 2 * min_r + 2:
            return []
        norm = _normalise(img, saturation, work)
        if norm is None:
            return []
        img8, full = norm
        clipped = cv2.minMaxLoc(img8)[1] >= SATURATED_LEVEL  # a cost gate only: no decision on what is dark
        pyramid = [img8]
        while (2 * opts.min_level_radius_px * 2 ** len(pyramid) <= min(img.shape) / 2
               and min(pyramid[-1].shape) > 32):
            h, w = pyramid[-1].shape
            level = work.image(f"level{len(pyramid)}", ((h + 1) // 2, (w + 1) // 2))
            pyramid.append(cv2.pyrDown(pyramid[-1], dst=level))
        coarse: list[tuple[int, Ellipse, Ellipse, str]] = []
        noise = 0.0
        for s, level_img in enumerate(pyramid):
            scale = 2.0**s
            note = None if trace is None else _level_note(trace, s, scale, x0, y0)
            a_lo = min_r / scale if s == 0 else max(min_r / scale, opts.min_level_radius_px)
            a_hi = opts.level0_max_radius_px if s == 0 else opts.max_level_radius_px
            if a_lo > a_hi:
                continue
            smooth = level_img
            if s == 0 and opts.level0_blur_px > 0:
                ksize = 3 if opts.level0_blur_px <= 1.0 else 0  # 3x3 holds a sigma <= 1 px well enough, and is fast
                smooth = cv2.GaussianBlur(level_img, (ksize, ksize), opts.level0_blur_px,
                                          dst=work.image("smooth", level_img.shape))
            if s == 0 or (s == 1 and noise == 0.0):
                noise = _noise(smooth)
            elif s == 1:
                # Level 1 is a smoothed subsample of level 0: never noisier. An estimate that says it is measured
                # edges, not noise (most of an over-exposed frame clipped, its cleanest unclipped tile a textured
                # one): at x32 it doubled the offset and left a light-grey ring of 200 px undetected.
                noise = min(noise, _noise(smooth))
            # Coarser levels: level 1's estimate (measuring each costs more than it changes).
            binary = _dark(smooth, pyramid[s + 2] if s + 2 < len(pyramid) else None, _offset(noise, opts),
                           opts, work)
            bias = opts.exposure_bias_px / scale + 0.5
            retried: list[tuple[Ellipse, Ellipse]] = []
            holes: list[tuple[Ellipse, Ellipse]] = []
            found = [(o, i, "plain") for o, i in _pairs(binary, a_lo, a_hi, self._ratios, bias, opts, retried, note,
                                                        from_holes=holes)]
            # Also with white gaps of 1-2 level pixels closed: a small target's black ring cut by its own white dots
            # (grown by over-exposure, or thinned by tilt) is one ring again. Only added: the same closing fills the
            # thin white gap between a ring and its nested child, so it cannot replace the plain binary.
            closed = cv2.morphologyEx(binary, cv2.MORPH_CLOSE, _KERNEL3, dst=work.image("closed", binary.shape))
            found += [(o, i, "closed") for o, i in _pairs(closed, a_lo, a_hi, self._ratios, bias, opts, retried, note)]
            if s >= 1 and clipped:
                # Over-exposure grows the dots of a small target into its inner disk and past its outer edge:
                # its ring is arcs. Closing white gaps up to ~6 level pixels makes it one ring again (its inner
                # disk, wider, stays open). Only in frames with clipped pixels (a pass costs ~20 % of detect).
                wide = cv2.morphologyEx(binary, cv2.MORPH_CLOSE, _DISK7, dst=work.image("closed7", binary.shape))
                found += [(o, i, "wide") for o, i in _pairs(wide, max(a_lo, 12.0), a_hi, self._ratios, bias, opts,
                                                            note=note)]
            found += [(o, i, "crop") for o, i in retried]
            # small ones only: the hole's ellipse scaled is the outer one without the perspective, pixels off on a
            # large tilted target (a 235 px one at 50 deg: its pose fit then failed where its nested level alone
            # gave it)
            found += [(o, i, "hole") for o, i in holes if o.a * scale <= HOLE_PAIR_MAX_RADIUS_PX]
            for outer, inner, how in found:
                if s > 0:
                    outer = Ellipse(outer.centre_px * scale, outer.semi_axes_px * scale, outer.angle_rad)
                    inner = Ellipse(inner.centre_px * scale, inner.semi_axes_px * scale, inner.angle_rad)
                coarse.append((s, outer, inner, how))
        # pairs from a hole alone (``_hole_pairs``) only where no pair of the usual kind lies, on any level
        usual = _dedupe_pairs([p for p in coarse if p[3] != "hole"])
        coarse = usual + [p for p in _dedupe_pairs([p for p in coarse if p[3] == "hole"])
                          if not any(_same_place(p[1], q[1]) for q in usual)]
        height, width = img.shape
        candidates: list[Candidate] = []
        from_hole: list[Candidate] = []
        shift = np.array([x0, y0], dtype=np.float64)
        for s, outer, inner, how in coarse:
            if trace is not None:
                trace.append(_event("pair", s, outer, shift, how))
            refined = _refine(pyramid, outer, inner, self._ratios, opts)
            if refined is not None:
                outer, inner = refined
            half = outer.half_extent_px()
            c = outer.centre_px
            if (c[0] - half[0] < border_margin_px or c[1] - half[1] < border_margin_px
                    or c[0] + half[0] > width - 1 - border_margin_px
                    or c[1] + half[1] > height - 1 - border_margin_px):
                if trace is not None:
                    trace.append(_event("border", -1, outer, shift, ""))
                continue
            reasons: list[str] | None = None if trace is None else []
            strict = how == "hole"  # only a hole behind it: its code must read cleanly
            found_here = _identify(img, outer, inner, self._groups, full, self._hole_opts if strict else opts,
                                   reasons)
            if strict:
                sparse = [c for c in found_here if c.spec.code is None
                          or c.spec.code.bits.count("1") < HOLE_PAIR_MIN_DOTS]
                if reasons is not None and sparse:
                    reasons.append(f"code of under {HOLE_PAIR_MIN_DOTS} dots read from a hole alone")
                found_here = [c for c in found_here if c not in sparse]
            if trace is not None:
                trace.extend(_event("code", -1, outer, shift, r) for r in reasons or [])
                trace.extend(_event("candidate", -1, outer, shift, f"id {c.target_id} level {c.level}"
                                    + (" ambiguous" if c.level_ambiguous else "")) for c in found_here)
            (from_hole if strict else candidates).extend(found_here)
        # a pair from a hole alone only where no pair of the usual kind gave a candidate there or inside it (its
        # outer ellipse is the hole's scaled, without the perspective: beside a nested level found alone, an 80 px
        # target's pose fit started 140 % off and failed, where the nested level alone gave the pose)
        candidates += [c for c in from_hole
                       if not any(c.outer.sampson_distance(k.outer.centre_px[None, :])[0] <= 0 for k in candidates)]
        candidates = _nest(_dedupe_candidates(candidates))
        if x0 or y0:
            candidates = [_shifted(c, shift) for c in candidates]
        return sorted(candidates, key=lambda c: (c.target_id, c.level, c.outer.centre_px[0]))


def detect(
    image: npt.ArrayLike,
    targets: list[TargetSpec],
    saturation: float | None = None,
    min_outer_radius_px: float = 8.0,
    border_margin_px: float = 3.0,
    roi: tuple[int, int, int, int] | None = None,
    options: DetectOptions | None = None,
) -> list[Candidate]:
    """``Detector(targets, options).detect(image, ...)`` with a Detector for this call only (its work images
    are allocated anew: a caller that detects frame after frame keeps a Detector)."""
    return Detector(targets, options).detect(image, saturation, min_outer_radius_px, border_margin_px, roi)


def _event(stage: str, level: int, ellipse: Ellipse, shift: FloatArray, detail: str) -> TraceEvent:
    c = ellipse.centre_px + shift
    return TraceEvent(stage, level, (float(c[0]), float(c[1])), float(ellipse.a), detail)


def _level_note(trace: list[TraceEvent], level: int, scale: float, x0: int, y0: int):
    """A recorder for ``_pairs`` on pyramid level ``level``: (centre x, y and half size in level pixels, reason)
    -> a "blob" event in full-image pixels."""
    def note(cx: float, cy: float, half: float, detail: str) -> None:
        trace.append(TraceEvent("blob", level, (cx * scale + x0, cy * scale + y0), half * scale, detail))
    return note


# ---------------------------------------------------------------------- work images
class _WorkImages:
    """Full-size work images of one Detector, kept from one call to the next: a fresh multi-megabyte array
    costs its page faults on first write, about 0.5 ms per 2 Mpx, more than most passes over it. Each name
    holds a grow-only byte store; ``image`` hands out a C-contiguous view of its start (contents undefined)."""

    def __init__(self) -> None:
        self.stores: dict[str, np.ndarray] = {}

    def image(self, name: str, shape: tuple[int, ...], dtype: npt.DTypeLike = np.uint8) -> np.ndarray:
        dtype = np.dtype(dtype)
        size = math.prod(shape) * dtype.itemsize
        store = self.stores.get(name)
        if store is None or store.size < size:
            store = self.stores[name] = np.empty(size, np.uint8)
        return store[:size].view(dtype).reshape(shape)


# ---------------------------------------------------------------------- local threshold
def _dark(img8: np.ndarray, coarse: np.ndarray | None, offset: float, opts: DetectOptions,
          work: _WorkImages) -> np.ndarray:
    """Local threshold: 255 where ``img8`` is at or below its threshold, else 0. Every decision is local (a
    ``threshold_window_px`` square around each pixel): a dark ring is dark against its own surroundings, whatever
    the rest of the frame holds.

    - Where the window holds saturated pixels (its max at the top level): anything ``offset`` below the top is
      dark. Saturation is noise-free, so a black ring that over-exposure has cut into pieces (white dots grown
      into the inner disk, 1-2 px bands left at 80 % of white) stays one dark ring.
    - Elsewhere: max(mean, (max + min) / 2) - max(offset, ``relative_offset`` x range), range = max - min. The
      half-range keeps a window that the black ring fills nearly whole (a strongly tilted target, along its
      major axis) dark where the mean alone would call its ring bright; the part relative to the range keeps
      texture and noise beside a high-contrast edge out, the absolute part (from the noise) keeps flat regions
      out.

    With ``coarse`` (the pyramid level two steps down) the statistics come from it, upsampled: the same up to
    their smoothness, at a fraction of the cost. The result is a work image, overwritten by the next call."""
    window = opts.threshold_window_px
    if coarse is None:
        src, k = img8, window | 1
    else:
        src, k = coarse, max(window // 4, 1) | 1
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    top = cv2.dilate(src, kernel, borderType=cv2.BORDER_REPLICATE)
    bottom = cv2.erode(src, kernel, borderType=cv2.BORDER_REPLICATE)
    span = cv2.subtract(top, bottom)
    spread = cv2.max(cv2.convertScaleAbs(span, alpha=opts.relative_offset), int(round(offset)))
    middle = cv2.addWeighted(top, 0.5, bottom, 0.5, 0.0)
    threshold = cv2.subtract(cv2.max(cv2.blur(src, (k, k), borderType=cv2.BORDER_REPLICATE), middle), spread)
    saturated = cv2.compare(top, SATURATED_LEVEL, cv2.CMP_GE)
    if cv2.countNonZero(saturated):
        spread = cv2.max(cv2.convertScaleAbs(span, alpha=SATURATED_RELATIVE_OFFSET), int(round(offset)))
        np.copyto(threshold, cv2.max(threshold, cv2.subtract(top, spread)), where=saturated.view(bool))
    if coarse is not None:
        threshold = cv2.resize(threshold, (img8.shape[1], img8.shape[0]), dst=work.image("dark", img8.shape),
                               interpolation=cv2.INTER_LINEAR)
    return cv2.compare(img8, threshold, cv2.CMP_LE, dst=threshold)  # in place: element by element


_KERNEL3 = np.ones((3, 3), np.uint8)
_DISK5 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
_DISK7 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))
SATURATED_RELATIVE_OFFSET = 0.25

SATURATED_LEVEL = 254
"""8-bit level (of the coarse stage's square-root image) from which a window counts as saturated: 0.992 of full
scale and up."""


# ---------------------------------------------------------------------- normalisation
def _quantile(values: np.ndarray, q: float) -> float:
    """The q-th percentile (nearest rank) of a non-empty 1-D array, by partial sort (much cheaper than
    ``np.percentile`` on the few dozen samples used here)."""
    v = np.asarray(values).ravel()
    k = min(int(round(q / 100.0 * (v.size - 1))), v.size - 1)
    return float(np.partition(v, k)[k])


def _noise(img8: np.ndarray) -> float:
    """Pixel noise (standard deviation, 8-bit levels): the median absolute difference of pixels two apart
    horizontally (sqrt(2) x 0.6745 = 0.954 sd for Gaussian noise), in each of 8 x 8 tiles of the frame, and the
    least of those medians (pairs with a clipped pixel, saturated or black, left out). Texture (carpet, foliage, text)
    raises a tile's figure, so the cleanest tile (a sheet of paper, a wall, the sky) tells the camera's noise
    even when texture fills most of the frame. On the square-root image shot noise is about the same at every
    level, so one figure holds for the frame. Two apart so that a slight blur does not hide it; ~20k
    differences in all."""
    step = max(1, int(math.sqrt(img8.size / 20_000)))
    w = img8.shape[1] - 2
    left, right = img8[::step, 0:w:step], img8[::step, 2 : w + 2 : step]
    diff = np.maximum(left, right)
    diff -= np.minimum(left, right)  # |right - left| in uint8
    # Clipped pairs (either pixel saturated or black) carry no noise: they count as unusable (255).
    clipped = (np.maximum(left, right) >= SATURATED_LEVEL) | (np.minimum(left, right) == 0)
    diff[clipped] = 255
    rows, cols = diff.shape
    th, tw = max(rows // NOISE_TILES, 1), max(cols // NOISE_TILES, 1)
    ny, nx = rows // th, cols // tw
    tiles = diff[: ny * th, : nx * tw].reshape(ny, th, nx, tw).swapaxes(1, 2).reshape(ny * nx, th * tw)
    k = (th * tw - 1) // 2
    least = int(np.partition(tiles, k, axis=1)[:, k].min())
    return 0.0 if least == 255 else least / 0.954


NOISE_TILES = 8


def _offset(noise: float, opts: DetectOptions) -> float:
    """Least depth (8-bit levels) below the local threshold's reference: 4x the pixel noise, within [1, 3] x
    ``threshold_offset``."""
    return float(min(max(4.0 * noise, opts.threshold_offset), 3.0 * opts.threshold_offset))  # np.clip: 10 us


def full_scale(img: np.ndarray, saturation: float | None) -> float | None:
    """The input value that maps to white in the coarse stage: ``saturation`` when given; else, for integer
    data, the top code of the smallest bit depth (8 or more bits) that holds the image's largest value (a 12-bit
    camera's frames in 16-bit words map as 12-bit); for float data 1.0 when the values lie in [0, 1], else the
    largest finite value. None when the image holds nothing above 0 (blank)."""
    if saturation is not None:
        return float(saturation) if saturation > 0 else None
    if img.dtype.kind == "f":
        finite = img[np.isfinite(img)]
        top = float(finite.max()) if finite.size else 0.0
        return None if not top > 0 else (1.0 if top <= 1.0 else top)
    top = int(cv2.minMaxLoc(img)[1]) if img.dtype in (np.uint8, np.uint16) else int(img.max())
    if top <= 0:
        return None
    return float((1 << max(8, top.bit_length())) - 1)


def _normalise(img: np.ndarray, saturation: float | None, work: _WorkImages) -> tuple[np.ndarray, float] | None:
    """8-bit image for the coarse stage (a work image) and the input value mapped to 255, or None when the image
    is blank.

    A fixed map, the same for every scene: ``255 * sqrt(v / full)``, clipped, with ``full`` from
    ``full_scale``. No image statistics decide what is dark: a small target in a frame saturated everywhere
    else keeps its black ring (a stretch between global percentiles left it nothing when its dark pixels were
    fewer than the lower percentile). The square root compresses the range like shot noise grows (photon noise
    becomes about constant in 8-bit levels), so an underexposed target keeps as many levels of contrast as an
    overexposed one: at 12 bits, paper at 1/32 of full scale still spans ~45 levels."""
    full = full_scale(img, saturation)
    if full is None:
        return None
    out = work.image("level0", img.shape)
    if img.dtype == np.uint8:
        return cv2.LUT(img, _sqrt_table(full, 256), dst=out), full
    if img.dtype == np.uint16:
        lut16(img, _sqrt_table(full, 65536), out)
        return out, full
    # Float data: by bands of rows through a small float32 scratch (stays in cache): sqrt, scale, round, saturate.
    rows = max(1, (1 << 17) // img.shape[1])
    scratch = work.image("band32", (rows, img.shape[1]), np.float32)
    alpha = 255.0 / math.sqrt(full)
    for y in range(0, img.shape[0], rows):
        band = scratch[: min(rows, img.shape[0] - y)]
        np.copyto(band, np.nan_to_num(img[y : y + rows], nan=0.0, posinf=full, neginf=0.0), casting="unsafe")
        cv2.max(band, 0.0, dst=band)
        cv2.sqrt(band, dst=band)
        cv2.convertScaleAbs(band, dst=out[y : y + rows], alpha=alpha)
    return out, full


@functools.lru_cache(maxsize=8)
def _sqrt_table(full: float, size: int) -> npt.NDArray[np.uint8]:
    """round(255 sqrt(v / full)) for v = 0 .. size - 1, clipped to [0, 255] (read-only, cached)."""
    table = np.clip(np.round(255.0 * np.sqrt(np.arange(size) / full)), 0, 255).astype(np.uint8)
    table.flags.writeable = False
    return table


# ---------------------------------------------------------------------- ellipse pairs in a binary image
def _fit(contour: np.ndarray, offset_px: float, min_aspect: float, area_px: float | None = None) -> Ellipse | None:
    """Ellipse through a contour of pixel centres, its semi-axes moved by ``offset_px`` to the pixel edge
    (+0.5 for the outer boundary of a dark blob, -0.5 for a hole), or None if it is not an ellipse: first-order
    (Sampson) residual RMS above 0.5 px + 3 % of sqrt(ab) or largest above 2 px + 12 % of sqrt(ab), or area off
    by more than 6 % + 1.5 px / b (the contour's own area, or ``area_px``)."""
    if len(contour) < 6:
        return None
    try:
        (cx, cy), (w, h), angle_deg = cv2.fitEllipse(contour)
    except cv2.error:
        return None
    a, b = 0.5 * max(w, h), 0.5 * min(w, h)
    if not (math.isfinite(a) and math.isfinite(b)) or b < 1.0 or b / a < min_aspect or b + offset_px <= 0.5:
        return None
    theta = math.radians(angle_deg) + (0.0 if w >= h else 0.5 * math.pi)
    c, s = math.cos(theta), math.sin(theta)
    # (u, v): the points in the ellipse's frame, in units of its semi-axes; few numpy calls (a few dozen fits per
    # frame, each a few hundred points).
    uv = (contour.reshape(-1, 2) - (cx, cy)) @ np.array([[c / a, -s / b], [s / a, c / b]])
    uv *= uv
    sq = uv @ np.array([[1.0, 1.0 / (a * a)], [1.0, 1.0 / (b * b)]])  # u^2 + v^2, (u/a)^2 + (v/b)^2
    dist = (sq[:, 0] - 1.0) / np.maximum(2.0 * np.sqrt(sq[:, 1]), 1e-12)
    size = math.sqrt(a * b)  # a tilted target's outline strays with its length too (distortion, blur, JPEG)
    if (math.sqrt(float(dist @ dist) / len(dist)) > 0.5 + 0.03 * size
            or max(float(dist.max()), -float(dist.min())) > 2.0 + 0.12 * size):
        return None
    area = abs(cv2.contourArea(contour)) if area_px is None else area_px
    if abs(area / (math.pi * a * b) - 1.0) > 0.06 + 1.5 / b:
        return None
    return Ellipse(np.array([cx, cy]), np.array([a + offset_px, b + offset_px]), theta)


def _fit_without_notches(contour: np.ndarray, offset_px: float, min_aspect: float) -> Ellipse | None:
    """``_fit`` of a dark blob's outer boundary with its notches left out: a small or over-exposed target's
    white code dots, grown into the black ring's outer edge, cut notches into it (a blob that fails the solidity
    test). The points along each convexity defect deeper than 1.5 px are dropped; at least 60 % of the boundary
    must remain and fit an ellipse, and the convex hull's area must match it as ``_fit`` asks of a clean
    boundary."""
    if len(contour) < 12:
        return None
    try:
        hull = cv2.convexHull(contour, returnPoints=False)
        defects = cv2.convexityDefects(contour, hull)
    except cv2.error:  # a self-touching contour (OpenCV refuses non-monotonic hull indices)
        return None
    if defects is None:
        return None
    n = len(contour)
    keep = np.ones(n, bool)
    for start, end, _, depth in defects.reshape(-1, 4):
        if depth / 256.0 > 1.5:
            if start <= end:
                keep[start + 1 : end] = False
            else:  # the defect wraps around the contour's start
                keep[start + 1 :] = False
                keep[:end] = False
    if keep.sum() < 0.6 * n or keep.all():
        return None
    fitted = _fit(contour[keep], offset_px, min_aspect, area_px=abs(cv2.contourArea(contour[hull.ravel()])))
    return fitted


def _convex(contour: np.ndarray, area: float) -> bool:
    """Solidity test: an ellipse's pixel boundary fills nearly all of its convex hull (texture blobs do not)."""
    hull = abs(cv2.contourArea(cv2.convexHull(contour)))
    return area >= 0.9 * hull - 2.0


def _ratio_bounds(x: float, ratio: float, bias_px: float, tol: float) -> tuple[float, float]:
    """Range of (inner / outer) semi-axis ratios accepted for an outer semi-axis of x pixels: each edge may
    move by ``bias_px`` toward either side, plus a relative tolerance ``tol``."""
    lo = (ratio * x - bias_px) / (x + bias_px) * (1.0 - tol)
    hi = (ratio * x + bias_px) / max(x - bias_px, 1e-9) * (1.0 + tol)
    return lo, hi


def _ratio_ok(outer: Ellipse, inner: Ellipse, ratio: float, bias_px: float, tol: float) -> bool:
    for xo, xi in ((outer.a, inner.a), (outer.b, inner.b)):
        lo, hi = _ratio_bounds(xo, ratio, bias_px, tol)
        if not lo <= xi / xo <= hi:
            return False
    return True


def _contours(binary: np.ndarray) -> tuple[tuple[np.ndarray, ...], np.ndarray | None]:
    """``cv2.findContours`` (two-level hierarchy, all points) of a binary image. On a large image, only over the
    bounding box of its non-zero pixels with a 1 px margin (points shifted back): the same contours in the same
    order, without the scan of (and copy of) the empty rest, which costs more than the box (two max-reductions)
    when the dark pixels are clustered."""
    if binary.size < 100_000:
        return cv2.findContours(binary, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    rows = np.flatnonzero(binary.max(axis=1))
    if rows.size == 0:
        return (), None
    y0, y1 = max(int(rows[0]) - 1, 0), min(int(rows[-1]) + 2, binary.shape[0])
    cols = np.flatnonzero(binary[y0:y1].max(axis=0))
    x0, x1 = max(int(cols[0]) - 1, 0), min(int(cols[-1]) + 2, binary.shape[1])
    return cv2.findContours(binary[y0:y1, x0:x1], cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE, offset=(x0, y0))


def _pairs(binary: np.ndarray, a_lo: float, a_hi: float, ratios: list[float], bias_px: float,
           opts: DetectOptions, closed_retry: list[tuple[Ellipse, Ellipse]] | None = None,
           note: Callable[[float, float, float, str], None] | None = None,
           from_holes: list[tuple[Ellipse, Ellipse]] | None = None) -> list[tuple[Ellipse, Ellipse]]:
    """Concentric (outer boundary, hole) ellipse pairs of the dark blobs in ``binary`` (255 = dark) whose outer
    semi-axes a >= b have a >= a_lo, b <= a_hi, a <= 3 a_hi (pixels; an oblique target is searched where its
    minor axis fits), and whose semi-axis ratios match one of ``ratios``.

    ``closed_retry`` (a list): a blob with a hole that gives no pair is tried once more on its own crop with white
    gaps up to ~4 px closed (a disk of 5 px), and what that finds is appended to ``closed_retry`` (the caller
    ranks it after the plain pairs): on a small target the thin black band between the inner disk and a code dot
    gives way (blur, over-exposure) and the hole is the disk with a dot attached; closing cuts the neck and fills
    the dot. Only such blobs pay for it (a closing pass over the whole level cost half as much again).

    ``note`` (a diagnostic): called with (centre x, y, half size, reason) for every dark blob of about the
    searched size that gives no pair (``TraceEvent``).

    ``from_holes`` (a list): a blob too big for a pair, or whose outline is no ellipse, or whose holes are off its
    middle (a ring merged with dark ground, a target printed without a sheet), is also tried from each of its
    holes alone (``_hole_pairs``); what that finds is appended to ``from_holes`` (the caller reads their codes
    more strictly)."""
    contours, hierarchy = _contours(binary)
    if hierarchy is None or not contours:
        return []
    hier = hierarchy.reshape(-1, 4)
    lengths = np.fromiter(map(len, contours), dtype=np.int64, count=len(contours))
    min_len = max(12, int(3.5 * a_lo))
    tops = np.flatnonzero((hier[:, 3] < 0) & (hier[:, 2] >= 0) & (lengths >= min_len))
    if note is not None:
        _note_skipped(contours, hier, lengths, min_len, a_lo, a_hi, note)
    pairs = []
    for i in tops:
        x, y, w, h = cv2.boundingRect(contours[i])
        if 0.5 * max(w, h) < 0.8 * a_lo:
            continue
        if 0.5 * min(w, h) > 1.25 * a_hi + 1 or 0.5 * max(w, h) > 3.2 * a_hi:
            if note is not None:
                note(x + 0.5 * w, y + 0.5 * h, 0.5 * max(w, h), "size")
            if from_holes is not None:
                from_holes.extend(_hole_pairs(binary, contours, hier, lengths, i, a_lo, a_hi, ratios, opts))
            continue
        pair = _pair_of(contours, hier, lengths, i, (x, y, w, h), a_lo, a_hi, ratios, bias_px, opts)
        if not isinstance(pair, str):
            pairs.append(pair)
            continue
        if from_holes is not None and pair in ("hole area/centre", "outer fit"):
            from_holes.extend(_hole_pairs(binary, contours, hier, lengths, i, a_lo, a_hi, ratios, opts))
        if note is not None:
            note(x + 0.5 * w, y + 0.5 * h, 0.5 * max(w, h), pair)
        if closed_retry is not None and min(w, h) >= 2 * a_lo - 2:
            closed_retry.extend(_pairs_closed(binary, (x, y, w, h), a_lo, a_hi, ratios, bias_px, opts))
    return pairs


HOLE_PAIR_DARK_FRACTION = 0.8
HOLE_PAIR_MAX_CODE_DISTANCE = 0.5
HOLE_PAIR_MIN_CODE_MARGIN = 1.0
HOLE_PAIR_MIN_DOTS = 3
HOLE_PAIR_MAX_RADIUS_PX = 128.0
"""Codes read from a pair found from a hole alone (``_hole_pairs``) must match within
``HOLE_PAIR_MAX_CODE_DISTANCE`` slots, ``HOLE_PAIR_MIN_CODE_MARGIN`` ahead of the next code, and have at least
``HOLE_PAIR_MIN_DOTS`` dots: around round holes in dark foliage, two bright flecks at the right angles read as the
two-dot code of id 1 (seed-0 sweep: 7 false positives on frames without targets and 11 beside targets with the
usual code rules; 2 and 3 with the stricter match alone; 0 with both)."""
HOLE_PAIR_OUTSIDE = 1.2
HOLE_PAIR_OUTSIDE_BRIGHT_FRACTION = 0.35
HOLE_PAIR_ANGLES = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
HOLE_PAIR_ANGLES.flags.writeable = False


def _hole_pairs(binary: np.ndarray, contours, hier: np.ndarray, lengths: np.ndarray, i: int, a_lo: float,
                a_hi: float, ratios: list[float], opts: DetectOptions) -> list[tuple[Ellipse, Ellipse]]:
    """Pairs of the blob ``i`` from its holes alone: each convex elliptical hole whose size, over a design's
    radius ratio r/R, is that of a searched outer ellipse gives the outer ellipse of that shape (concentric,
    scaled by R/r) when the binary image is dark on ``HOLE_PAIR_DARK_FRACTION`` of the samples of the black ring
    around it (between the hole and the code dots, and between the dots and the outer edge), and bright on
    ``HOLE_PAIR_OUTSIDE_BRIGHT_FRACTION`` of those at ``HOLE_PAIR_OUTSIDE`` R (a merged ring still shows part of
    its outer edge; a round hole deep in dark foliage with one bright fleck read as a one-dot code otherwise). The
    code read next decides."""
    out: list[tuple[Ellipse, Ellipse]] = []
    h, w = binary.shape
    j = hier[i, 2]
    while j >= 0:
        hole, j = j, hier[j, 0]
        if lengths[hole] < 6:
            continue
        area = abs(cv2.contourArea(contours[hole]))
        r_px = math.sqrt(area / math.pi)
        fits = [rho for rho in ratios if 0.8 * a_lo <= r_px / rho <= 1.25 * a_hi]
        if not fits or not _convex(contours[hole], area):
            continue
        inner = _fit(contours[hole], -0.5, opts.min_aspect)
        if inner is None:
            continue
        for rho in fits:
            outer = inner.scaled(1.0 / rho)
            if outer.a < a_lo - 0.5 or outer.b > a_hi or outer.a > 3.0 * a_hi:
                continue
            dark = []
            for band in (rho + 0.2 * (1.0 - rho), 0.95, HOLE_PAIR_OUTSIDE):
                p = np.rint(outer.scaled(band).points(HOLE_PAIR_ANGLES)).astype(np.int64)
                inside = (p[:, 0] >= 0) & (p[:, 0] < w) & (p[:, 1] >= 0) & (p[:, 1] < h)
                dark.append(int(np.count_nonzero(binary[p[inside, 1], p[inside, 0]])) / len(HOLE_PAIR_ANGLES))
            if (dark[0] + dark[1] >= 2 * HOLE_PAIR_DARK_FRACTION
                    and 1.0 - dark[2] >= HOLE_PAIR_OUTSIDE_BRIGHT_FRACTION):
                out.append((outer, inner))
                break
    return out


def _note_skipped(contours, hier: np.ndarray, lengths: np.ndarray, min_len: int, a_lo: float, a_hi: float,
                  note: Callable[[float, float, float, str], None]) -> None:
    """For ``_pairs``' diagnostic: the top-level blobs of about the searched size that its first filter drops
    (no hole, or a boundary too short)."""
    for i in np.flatnonzero((hier[:, 3] < 0) & ((hier[:, 2] < 0) | (lengths < min_len)) & (lengths >= 8)):
        x, y, w, h = cv2.boundingRect(contours[i])
        if 0.5 * a_lo <= 0.5 * max(w, h) <= 3.2 * a_hi:
            note(x + 0.5 * w, y + 0.5 * h, 0.5 * max(w, h), "no hole" if hier[i, 2] < 0 else "short contour")


def _pairs_closed(binary: np.ndarray, rect: tuple[int, int, int, int], a_lo: float, a_hi: float,
                  ratios: list[float], bias_px: float, opts: DetectOptions) -> list[tuple[Ellipse, Ellipse]]:
    """``_pairs`` on the crop ``rect`` (x, y, w, h) of ``binary`` grown by 3 px, after closing its white gaps
    with a 5 px disk; ellipses in ``binary``'s pixels."""
    x, y, w, h = rect
    x0, y0 = max(x - 3, 0), max(y - 3, 0)
    crop = binary[y0 : y + h + 3, x0 : x + w + 3]
    closed = cv2.morphologyEx(crop, cv2.MORPH_CLOSE, _DISK5, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return _shift_pairs(_pairs(closed, a_lo, a_hi, ratios, bias_px, opts), np.array([x0, y0], dtype=np.float64))


def _shift_pairs(pairs: list[tuple[Ellipse, Ellipse]], shift: FloatArray) -> list[tuple[Ellipse, Ellipse]]:
    return [(Ellipse(o.centre_px + shift, o.semi_axes_px, o.angle_rad),
             Ellipse(i.centre_px + shift, i.semi_axes_px, i.angle_rad)) for o, i in pairs]


def _pair_of(contours, hier: np.ndarray, lengths: np.ndarray, i: int, rect: tuple[int, int, int, int],
             a_lo: float, a_hi: float, ratios: list[float], bias_px: float,
             opts: DetectOptions) -> tuple[Ellipse, Ellipse] | str:
    """For ``_pairs``: the pair of the top-level contour ``i`` (bounding ``rect``) and its best hole, or why
    there is none."""
    x, y, w, h = rect
    # Cheap tests before any fit: a hole near the blob's middle whose area is about (r/R)^2 of the blob's
    # (pixel-centre contours sit half a pixel inside the dark blob, hence the +-1 px).
    area = abs(cv2.contourArea(contours[i]))
    radius = math.sqrt(area / math.pi)
    lo2 = min(_ratio_bounds(radius, r, bias_px + 1.0, opts.ratio_tolerance)[0] for r in ratios) ** 2
    hi2 = max(_ratio_bounds(radius, r, bias_px + 1.0, opts.ratio_tolerance)[1] for r in ratios) ** 2
    mid_x, mid_y, tol = x + 0.5 * w, y + 0.5 * h, opts.centre_tolerance * 0.5 * max(w, h) + 2.0
    holes = []
    j = hier[i, 2]
    while j >= 0:
        if lengths[j] >= 6 and lo2 <= abs(cv2.contourArea(contours[j])) / max(area, 1.0) <= hi2:
            hx, hy, hw, hh = cv2.boundingRect(contours[j])
            if abs(hx + 0.5 * hw - mid_x) <= tol and abs(hy + 0.5 * hh - mid_y) <= tol:
                holes.append(j)
        j = hier[j, 0]
    if not holes:
        return "hole area/centre"
    if _convex(contours[i], area):
        outer = _fit(contours[i], 0.5, opts.min_aspect)
    else:  # notched (white dots grown into the outer edge, or a cut ring closed by the closing pass)
        outer = _fit_without_notches(contours[i], 0.5, opts.min_aspect)
    if outer is None:
        return "outer fit"
    if outer.a < a_lo - 0.5 or outer.b > a_hi or outer.a > 3.0 * a_hi:
        return "outer size"
    best: Ellipse | None = None
    for j in holes:
        if not _convex(contours[j], abs(cv2.contourArea(contours[j]))):
            continue
        inner = _fit(contours[j], -0.5, opts.min_aspect)
        if (inner is not None
                and np.hypot(inner.centre_px[0] - outer.centre_px[0], inner.centre_px[1] - outer.centre_px[1])
                <= opts.centre_tolerance * outer.a + 1.0
                and any(_ratio_ok(outer, inner, r, bias_px, opts.ratio_tolerance) for r in ratios)
                and (best is None or inner.a > best.a)):
            best = inner
    return "inner fit/ratio" if best is None else (outer, best)


def _same_place(e1: Ellipse, e2: Ellipse, size_ratio: float = 1.4) -> bool:
    c1, c2 = e1.centre_px, e2.centre_px
    d = np.hypot(c1[0] - c2[0], c1[1] - c2[1])
    return d <= 0.25 * min(e1.b, e2.b) + 1.0 and 1.0 / size_ratio <= e1.a / e2.a <= size_ratio


def _dedupe_pairs(pairs: list[tuple[int, Ellipse, Ellipse, str]]) -> list[tuple[int, Ellipse, Ellipse, str]]:
    kept: list[tuple[int, Ellipse, Ellipse, str]] = []
    for pair in sorted(pairs, key=lambda p: p[0]):
        if not any(_same_place(pair[1], k[1]) for k in kept):
            kept.append(pair)
    return kept


# ---------------------------------------------------------------------- refinement
_ANGLES_64X3 = np.tile(np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False), 3)
_ANGLES_64X3.flags.writeable = False


def _refine(pyramid: list[np.ndarray], outer: Ellipse, inner: Ellipse, ratios: list[float],
            opts: DetectOptions) -> tuple[Ellipse, Ellipse] | None:
    """Re-fit the pair on a crop with a global threshold halfway between its black and white levels (in input
    units)."""
    s = max(0, math.ceil(math.log2(max(outer.a / opts.refine_max_radius_px, 1e-9))))
    s = min(s, len(pyramid) - 1)
    scale = 2.0**s
    level_img = pyramid[s]
    o, i = outer, inner
    if s > 0:
        o = Ellipse(outer.centre_px / scale, outer.semi_axes_px / scale, outer.angle_rad)
        i = Ellipse(inner.centre_px / scale, inner.semi_axes_px / scale, inner.angle_rad)
    H0 = affine_homography(o)
    rho = i.a / o.a
    vals = sample_target(level_img, H0, np.repeat([rho + 0.2 * (1 - rho), 0.93, 0.8 * rho], 64), _ANGLES_64X3)
    dark, bright = vals[:128], vals[128:]
    dark, bright = dark[np.isfinite(dark)], bright[np.isfinite(bright)]
    if dark.size < 16 or bright.size < 8:
        return None
    black, white = _quantile(dark, 25), _quantile(bright, 75)
    if white - black < 6:  # 8-bit levels: too little contrast for a clean global threshold on the crop
        return None
    half = o.half_extent_px()
    margin = 0.25 * o.a + 4
    cx0 = max(int(o.centre_px[0] - half[0] - margin), 0)
    cy0 = max(int(o.centre_px[1] - half[1] - margin), 0)
    cx1 = min(int(o.centre_px[0] + half[0] + margin) + 2, level_img.shape[1])
    cy1 = min(int(o.centre_px[1] + half[1] + margin) + 2, level_img.shape[0])
    crop = level_img[cy0:cy1, cx0:cx1]
    # Halfway between black and white. Full resolution: in input units (the level holds their square roots, and
    # the lens blurred the input). Coarser levels: in level units (pyrDown's blur, wider there than the lens's,
    # acted on the square roots).
    middle = math.sqrt(0.5 * (black * black + white * white)) if s == 0 else 0.5 * (black + white)
    _, binary = cv2.threshold(crop, middle, 255, cv2.THRESH_BINARY_INV)
    binary = np.ascontiguousarray(binary)
    found = _pairs(binary, 0.7 * o.a, 1.3 * o.a + 2, ratios, opts.exposure_bias_px / scale + 0.5, opts)
    offset = np.array([cx0, cy0], dtype=np.float64)
    best, best_d = None, np.inf
    for fo, fi in found:
        d = np.hypot(fo.centre_px[0] + cx0 - o.centre_px[0], fo.centre_px[1] + cy0 - o.centre_px[1])
        if d < best_d and d <= 0.2 * o.b + 1.5:
            best, best_d = (fo, fi), d
    if best is None:
        return None
    fo, fi = best
    return (Ellipse((fo.centre_px + offset) * scale, fo.semi_axes_px * scale, fo.angle_rad),
            Ellipse((fi.centre_px + offset) * scale, fi.semi_axes_px * scale, fi.angle_rad))


# ---------------------------------------------------------------------- verification and code
def _identify(img: np.ndarray, outer: Ellipse, inner: Ellipse, groups: dict[_Geometry, list[_Entry]],
              full: float, opts: DetectOptions, reasons: list[str] | None = None) -> list[Candidate]:
    """The candidates the pair reads as, one per geometry at most; ``reasons`` (a list): why each geometry
    whose ratio matches gave none is appended."""
    out: list[Candidate] = []
    H0 = centre_homography(outer, inner)
    for geom, entries in groups.items():
        if not _ratio_ok(outer, inner, geom.ratio, opts.exposure_bias_px + 0.5, opts.ratio_tolerance):
            continue
        cand = _read_code(img, outer, inner, H0, geom, entries, full, opts)
        if isinstance(cand, Candidate):
            out.append(cand)
        elif reasons is not None:
            reasons.append(cand)
    return out


def _read_code(img: np.ndarray, outer: Ellipse, inner: Ellipse, H0: FloatArray, g: _Geometry,
               entries: list[_Entry], full: float, opts: DetectOptions) -> Candidate | str:
    """The candidate the pair reads as with geometry ``g``, or why it reads as none."""
    n = g.slots
    g = _as_seen(g, outer, inner)
    radius, angle, harmonic_kernel = _code_pattern(g, _hole(entries))
    k = 8 * n
    vals = sample_target(img, H0, radius, angle)
    black_vals, white_vals, ring_vals = vals[:k], vals[k : 2 * k], vals[2 * k :]
    outside = np.isnan(vals)
    if outside.any():
        if (np.count_nonzero(outside[:k]) / k > 0.1 or np.count_nonzero(outside[k : 2 * k]) / k > 0.1
                or outside[2 * k :].any()):
            return "outside the image"
        black_vals, white_vals = black_vals[np.isfinite(black_vals)], white_vals[np.isfinite(white_vals)]
    # Small targets: blur lifts the narrow black bands; the code circle between the dots is darker (every code
    # leaves at least a fifth of that circle black).
    black = min(_quantile(black_vals, 50), _quantile(ring_vals, 20))
    white = _quantile(white_vals, 50)
    contrast = white - black
    # Contrast relative to the target's own white (its surroundings, not the frame, decide), and at least a
    # thousandth of full scale (quantisation and noise).
    if not (contrast > opts.min_contrast * min(max(white, 0.0), full) and contrast > 1e-3 * full):
        return "contrast"

    def norm(v: FloatArray) -> FloatArray:
        return (v - black) / contrast

    # (norm is increasing: the quantile of the normalised values is the normalised quantile). Three fifths of
    # the black-band samples dark: at x16-x32 the bands of a small or tilted target (its pair often found on a
    # coarse level) are thin and partly white (four fifths lost 2 of 405 visible targets in the sweep, 0 FP).
    clipped = white >= 0.98 * full
    if not clipped and (_quantile(black_vals, 60) - black) / contrast > 0.5:
        return "black bands not dark"
    if (_quantile(white_vals, 20) - black) / contrast < 0.5:
        return "inner disk not white"
    # Slot grid phase from the N-th harmonic of the code circle.
    harmonic = np.sum(norm(ring_vals) * harmonic_kernel)
    phase = float(-np.angle(harmonic) / n)
    slot_vals, gaps = _slots(img, H0, g.ring, g.dot, n, phase)
    slot_vals, gaps = norm(slot_vals), norm(gaps)
    if np.max(gaps) > 0.5 or np.mean(gaps) > 0.3:
        return f"gaps between slots white (max {np.max(gaps):.2f}, mean {np.mean(gaps):.2f})"
    peak = float(slot_vals.max())
    if peak < 0.35:
        return f"no dot brighter than {peak:.2f}"
    soft = np.clip(slot_vals / max(peak, 0.5), 0.0, 1.0)  # small blurred dots never reach the white level
    codes = _shortlist(soft, entries)
    decoded = codebook.decode(soft, codes, max_distance=opts.max_code_distance)
    if not decoded or decoded.margin < opts.min_code_margin:
        return "no code match" if not decoded else f"code margin {decoded.margin:.2f}"
    bits = codes[decoded.index]
    matching = [e for e in entries if e.spec.code is not None and e.spec.code.bits == bits]
    entry, ambiguous = _choose_level(img, H0, matching, phase, decoded.rotation_slots, black, contrast, outer)
    heading = None
    rotation = decoded.rotation_slots
    if rotation is not None:
        H = H0 @ rotation3(phase + 2.0 * np.pi * rotation / n)
        c = apply_homography(H, np.array([[0.0, 0.0], [0.5, 0.0]]))
        heading = float(math.atan2(c[1, 1] - c[0, 1], c[1, 0] - c[0, 0]))
        # Phase is in [-pi/n, pi/n]: a phase beyond half a slot belongs to the neighbouring slot.
        rotation = int(round(phase / (2.0 * np.pi / n))) + rotation
        rotation %= n
    return Candidate(target_id=entry.target_id, level=entry.level, spec=entry.spec, outer=outer, inner=inner,
                     rotation_slots=rotation, heading_rad=heading, code_margin=float(decoded.margin),
                     code_values=soft, black_level=black, white_level=white, level_ambiguous=ambiguous)


def _as_seen(g: _Geometry, outer: Ellipse, inner: Ellipse) -> _Geometry:
    """The geometry as the pair shows it, in units of the seen outer radius. Over-exposure moves every
    black/white edge by some d (units of R) into the black: the outer edge in to 1 - d, the inner disk out to
    r + d, the white dots grow by d; under-exposure the other way. The seen ratio of the pair's ellipses gives d,
    (r + d) / (1 - d) = seen ratio; the code is then read where the bands and dots are in this image (a 4x
    over-exposed target of 20 px keeps a 2 px black band between its inner disk and its dots, where the design's
    band centre is already white). d is kept within +-0.12 (and above half the dot radius below zero: under-exposed
    dots shrink, they do not vanish) and rounded to 1/200 (cached patterns)."""
    seen = 0.5 * (inner.a / outer.a + inner.b / outer.b)
    d = (seen - g.ratio) / (1.0 + seen)
    d = round(min(max(d, -0.12, -0.5 * g.dot), 0.12) * 200.0) / 200.0
    if d == 0.0:
        return g
    k = 1.0 / (1.0 - d)
    return _Geometry(round((g.ratio + d) * k, 6), round(g.ring * k, 6), round((g.dot + d) * k, 6), g.slots)


@functools.lru_cache(maxsize=256)
def _code_pattern(g: _Geometry, hole: float) -> tuple[FloatArray, FloatArray, npt.NDArray[np.complex128]]:
    """The sample points of ``_read_code`` (radius in units of R, angle; read-only, cached): 4N angles on each
    of two circles in the black annulus (between the inner disk and the dots, between the dots and the outer
    edge), then on two circles in the white inner disk outside whatever may sit at its centre (``hole``), then
    16N angles on the code circle; and exp(-i N angle) on the code circle (its N-th harmonic)."""
    n = g.slots
    t4 = np.linspace(0.0, 2.0 * np.pi, 4 * n, endpoint=False)
    r_black = np.array([0.5 * (g.ratio + g.ring - g.dot), 0.5 * (g.ring + g.dot + 1.0)])
    r_white = hole + (g.ratio - hole) * np.array([0.45, 0.75])
    m = 16 * n
    tm = np.linspace(0.0, 2.0 * np.pi, m, endpoint=False)
    radius = np.concatenate([np.repeat(r_black, t4.size), np.repeat(r_white, t4.size), np.full(m, g.ring)])
    angle = np.concatenate([t4, t4, t4, t4, tm])
    kernel = np.exp(-1j * n * tm)
    for a in (radius, angle, kernel):
        a.flags.writeable = False
    return radius, angle, kernel


def _shortlist(soft: FloatArray, entries: list[_Entry]) -> list[str]:
    """The two configured codes nearest to ``soft`` (N,) at their best rotation. ``codebook.decode`` on them
    gives the same winner, distance and margin as on all codes (the runner-up code is the only other code
    that can set the margin), at a fraction of the cost for a large book."""
    codes = sorted({e.spec.code.bits for e in entries if e.spec.code is not None and len(e.spec.code.bits)
                    == soft.size})
    if len(codes) <= 2:
        return codes
    bits = np.array([[b == "1" for b in c] for c in codes], dtype=np.float64)  # (C, N)
    n = soft.size
    rolled = soft[(np.arange(n)[None, :] + np.arange(n)[:, None]) % n]  # (N rotations, N)
    dist = np.abs(rolled[None, :, :] - bits[:, None, :]).sum(axis=2).min(axis=1)  # (C,)
    best = np.argsort(dist, kind="stable")[:2]
    return [codes[i] for i in sorted(best)]


def _slots(img: np.ndarray, H0: FloatArray, ring: float, dot: float, n: int,
           phase: float, brightest: bool = False) -> tuple[FloatArray, FloatArray]:
    """Image values (N,) at the N slots (angle ``phase + 2 pi j / N`` on the circle of radius ``ring``, units
    of R, through ``H0``: the mean of a cluster with radial and tangential offsets of 0.4 dot radius, or its
    brightest value with ``brightest``) and at the N gaps half-way between them. NaN where outside the image."""
    radius, cluster_t, grid_t = _slot_pattern(ring, dot, n)
    slot_t = phase + grid_t
    vals = sample_target(img, H0, radius, np.concatenate([(slot_t[:, None] + cluster_t).ravel(), slot_t + np.pi / n]))
    cluster = vals[: 5 * n].reshape(n, 5)
    return (np.max(cluster, axis=1) if brightest else cluster.sum(axis=1) / 5), vals[5 * n :]


@functools.lru_cache(maxsize=256)
def _slot_pattern(ring: float, dot: float, n: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """For ``_slots`` (read-only, cached): the radii of the N 5-point clusters then of the N gaps, the angular
    offsets (5,) within a cluster, and the slot angles 2 pi j / N."""
    dr = 0.4 * dot
    dt = dr / ring
    cluster_r = ring + np.array([0.0, dr, -dr, 0.0, 0.0])
    radius = np.concatenate([np.tile(cluster_r, n), np.full(n, ring)])
    cluster_t = np.array([0.0, 0.0, 0.0, dt, -dt])
    grid_t = 2.0 * np.pi * np.arange(n) / n
    for a in (radius, cluster_t, grid_t):
        a.flags.writeable = False
    return radius, cluster_t, grid_t


def _choose_level(img: np.ndarray, H0: FloatArray, entries: list[_Entry], phase: float, rotation: int | None,
                  black: float, contrast: float, outer: Ellipse | None = None) -> tuple[_Entry, bool]:
    """Among levels sharing the code, the deepest whose parent is seen around the pair, and whether the choice
    is ambiguous. A pair taken for the wrong level gives a distance off by the fractal scale (5x), so the parent
    is judged slot by slot against its own surroundings (an illumination gradient or clipping on one side must
    not decide): at each slot angle, the parent's two dark bands there are its local black, the middle of its
    white disk there its local white; slots whose local contrast is under a third of the pair's are not read.

    - *confirmed*: the parent's code reads right on the readable slots (at least 3, a blank among them, and at
      least half of the readable dots seen; mean error under a quarter, no more contradictions than below): that
      level.
    - *refuted*: readable slots where the parent has a dot read under half-way (at their brightest sample), or
      ones where it has none (or gaps between slots) read white, more than once among 4 or more readable slots
      (at all with fewer, or once when the code does not otherwise read right), or no parent-like surroundings
      (a white disk as white as the pair's all round, a dark band beside it at most angles): the next level out
      is tried, the outermost at last.
    - otherwise (parent-like surroundings whose code cannot be read, e.g. its ring clipped on most of its
      slots) the choice is ambiguous: the outermost level is returned with ``True``; the caller reports it
      rather than a pose that may be off 5x.
    When too little of the surroundings is in the image to judge (under half of the slot angles), the outermost
    (not ambiguous: a target at the border would be lost otherwise).

    ``outer``: the pair's outer ellipse. Given, a parent not confirmed through the pair's own map is read again
    through a map anchored on the parent's white disk edge, where that is found around the pair
    (``_parent_homography``), and confirmed if its code reads right there: the pair's map, extrapolated to 3-5
    of its radii, is a fraction of a dot off for a small pair (a 7 px child on dark foliage read its parent's
    dots dark, was refuted, and came out as the outer level: 5x the distance). Only a confirmation is taken from
    the second reading: a refutation through a map fitted to a clipped or smudged parent is no evidence."""
    entries = sorted(entries, key=lambda e: e.level)
    if len(entries) == 1:
        return entries[0], False
    ambiguous = False
    for e in reversed(entries):
        p = e.parent
        if p is None or p.code is None:
            continue
        verdict = _parent_verdict(img, H0, e, p, phase, rotation, black, contrast)
        if verdict != "confirmed" and outer is not None:
            H = _parent_homography(img, H0, outer, p.inner_radius_m / e.spec.outer_radius_m, black)
            if H is not H0 and _parent_verdict(img, H, e, p, phase, rotation, black, contrast) == "confirmed":
                verdict = "confirmed"
        if verdict == "confirmed":
            return e, False
        ambiguous = ambiguous or verdict == "ambiguous"
    return entries[0], ambiguous


def _parent_verdict(img: np.ndarray, H0: FloatArray, e: _Entry, p: TargetSpec, phase: float,
                    rotation: int | None, black: float, contrast: float) -> str:
    """For ``_choose_level``: "confirmed", "refuted", "ambiguous" or "unseen" for the parent ``p`` of level
    ``e`` around the pair of homography ``H0`` whose black level and contrast are ``black``, ``contrast``."""
    assert p.code is not None
    k = 1.0 / e.spec.outer_radius_m
    n = p.code.slots
    ring, dot = k * p.code.ring_radius_m, k * p.code.dot_radius_m
    radii, angles = _parent_pattern(k * p.inner_radius_m, ring, dot, k * p.outer_radius_m, n)
    vals = sample_target(img, H0, radii, angles + phase).reshape(3, n)  # inner band, outer band, white disk
    # A parent's dots are 5x its child's: a slot's brightest sample is on the dot even where the pair's
    # homography, extrapolated to the parent's ring, is a fraction of a dot off; a blank slot stays dark.
    slot_vals, gaps = _slots(img, H0, ring, dot, n, phase, brightest=True)
    # The darker band: over-exposed dots grow into one band (both, at steep tilt), rarely into both.
    local_black = np.where(np.isfinite(vals[0]) & np.isfinite(vals[1]), np.fmin(vals[0], vals[1]), np.nan)
    local_contrast = vals[2] - local_black
    finite = np.isfinite(local_contrast) & np.isfinite(slot_vals)
    if finite.sum() < max(3, n // 2):
        return "unseen"
    # A parent's white disk is as white as the pair's own white all around (a sheet's square or the ground
    # beyond it are not), with a dark band beside it at most angles where no gradient or clipping hides it.
    white_all_round = np.mean((vals[2][np.isfinite(vals[2])] - black) >= 0.6 * contrast) >= 0.75
    dark_beside = np.mean(local_contrast[finite] >= 0.33 * contrast) >= 0.5
    if not (white_all_round and dark_beside):
        return "refuted"  # a sheet, the ground: not a parent
    readable = finite & (local_contrast >= 0.33 * contrast)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = (slot_vals - local_black) / local_contrast
        g = (gaps - local_black) / local_contrast  # gap j lies between slots j and j+1
    gap_ok = np.isfinite(g) & readable & np.roll(readable, -1)
    ref = np.array([b == "1" for b in p.code.bits], dtype=np.float64)
    contradicted = True
    seen = int(readable.sum())
    for r in range(n) if rotation is None else [rotation]:
        bits = np.roll(ref, r)
        ones, zeros = readable & (bits > 0.5), readable & (bits < 0.5)
        # A dot of the parent missing, or white where it has none. One is forgiven among 4 or more readable slots:
        # the pair's homography, extrapolated 3-5 radii out from a small or tilted pair, can put a slot's samples
        # beside its dot.
        against = (int(np.count_nonzero(s[ones] < 0.5)) + int(np.count_nonzero(s[zeros] > 0.75))
                   + int(np.count_nonzero(g[gap_ok] > 0.75)))
        if against > (1 if seen >= 4 else 0):
            continue  # not this rotation
        error = float(np.mean(np.abs(np.clip(s[readable], 0.0, 1.0) - bits[readable])))
        dots_seen = int(np.count_nonzero(s[ones] >= 0.5))  # a code of one dot read as all dark must not confirm
        if dots_seen >= max(1, (int(ones.sum()) + 1) // 2) and zeros.any() and seen >= 3 and error < 0.25:
            return "confirmed"
        contradicted = contradicted and against > 0  # a forgiven contradiction stands when the rest reads poorly
    return "refuted" if contradicted else "ambiguous"


PARENT_RAYS = 48
PARENT_MIN_RAYS = 0.6


def _parent_homography(img: np.ndarray, H0: FloatArray, outer: Ellipse, disk_ratio: float,
                       black: float) -> FloatArray:
    """``H0`` (the pair's map, target units of its own outer radius) re-anchored on the edge of the white disk a
    parent would put around the pair, ``disk_ratio`` of its radii out (the parent's inner radius over the pair's
    outer one: 2 in the default design): on ``PARENT_RAYS`` rays from the centre, the first fall below halfway
    from that ray's white (between the pair and the edge) to the pair's ``black``, between 0.65 and 1.5
    ``disk_ratio``; an ellipse through them (one pass without the points off it by over a tenth of its size);
    then the map taking the unit circle to it and the centre to the pair's, scaled to the pair's units. ``H0``
    unchanged when under ``PARENT_MIN_RAYS`` of the rays find an edge or the ellipse is not about
    ``disk_ratio`` times the pair, round the same centre."""
    r = disk_ratio * np.linspace(0.5, 1.5, 41)
    t = np.linspace(0.0, 2.0 * np.pi, PARENT_RAYS, endpoint=False)
    vals = sample_target(img, H0, np.tile(r, len(t)), np.repeat(t, len(r))).reshape(len(t), len(r))
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # rays leaving the image: all-NaN slices
        white = np.nanmedian(vals[:, r <= 0.75 * disk_ratio], axis=1)
    level = black + 0.5 * (white - black)
    below = (vals < level[:, None]) & (r >= 0.65 * disk_ratio)[None, :]
    first = np.argmax(below, axis=1)
    found = below.any(axis=1) & (first > 0) & np.isfinite(white) & (white > black)
    if found.sum() < PARENT_MIN_RAYS * len(t):
        return H0
    rows = np.flatnonzero(found)
    j = first[rows]
    v0, v1 = vals[rows, j - 1], vals[rows, j]
    frac = np.clip((v0 - level[rows]) / np.maximum(v0 - v1, 1e-12), 0.0, 1.0)
    rho = r[j - 1] + frac * (r[1] - r[0])
    tx, ty = rho * np.cos(t[rows]), rho * np.sin(t[rows])
    w = H0[2, 0] * tx + H0[2, 1] * ty + H0[2, 2]
    pts = np.column_stack([(H0[0, 0] * tx + H0[0, 1] * ty + H0[0, 2]) / w,
                           (H0[1, 0] * tx + H0[1, 1] * ty + H0[1, 2]) / w])
    try:
        disk = Ellipse.from_cv(cv2.fitEllipse(pts.astype(np.float32)))
        keep = np.abs(disk.sampson_distance(pts)) <= 0.1 * disk.b
        if keep.sum() < PARENT_MIN_RAYS * len(t):
            return H0
        disk = Ellipse.from_cv(cv2.fitEllipse(pts[keep].astype(np.float32)))
    except (cv2.error, ValueError):
        return H0
    size = math.sqrt(disk.a * disk.b) / math.sqrt(outer.a * outer.b)
    if not (0.8 * disk_ratio <= size <= 1.25 * disk_ratio
            and np.hypot(*(disk.centre_px - outer.centre_px)) <= 0.25 * outer.b):
        return H0
    H = centre_homography(disk, outer)
    return H @ np.diag([1.0 / disk_ratio, 1.0 / disk_ratio, 1.0])


@functools.lru_cache(maxsize=16)
def _parent_pattern(inner: float, ring: float, dot: float, outer: float, n: int) -> tuple[FloatArray, FloatArray]:
    """For ``_parent_verdict`` (read-only, cached): radii and angles (before the slot grid's phase) of the n
    slot angles on each of the parent's two dark bands (between its inner disk and its dots, between its dots
    and its outer edge), then on the middle of its white disk; radii in units of the child's R."""
    t = 2.0 * np.pi * np.arange(n) / n
    radii = np.repeat(np.array([0.5 * (inner + ring - dot), 0.5 * (ring + dot + outer), 0.5 * (1.0 + inner)]), n)
    angles = np.tile(t, 3)
    for a in (radii, angles):
        a.flags.writeable = False
    return radii, angles


def _nest(cands: list[Candidate]) -> list[Candidate]:
    """A candidate inside another's inner disk, of the size and code of its child, is that child (and the other,
    if it is the outermost of two levels, is no longer ambiguous)."""
    out = sorted(cands, key=lambda c: -c.outer.a)
    for i, x in enumerate(out):
        for j, y in enumerate(out[:i]):
            child = y.spec.child
            if (child is None or child.code is None or x.spec.code is None or child.code.bits != x.spec.code.bits
                    or y.inner.sampson_distance(x.outer.centre_px[None, :])[0] >= 0 or x.outer.a >= y.inner.a):
                continue
            expected = child.outer_radius_m / y.spec.outer_radius_m
            if 0.7 * expected <= x.outer.a / y.outer.a <= 1.4 * expected:
                out[i] = dataclasses.replace(x, target_id=y.target_id, level=y.level + 1, spec=child)
                if y.level_ambiguous and y.level == 0 and child.child is None:
                    # a level with a level inside it is not the deepest: of two levels, the outermost
                    out[j] = dataclasses.replace(y, level_ambiguous=False)
                break
    return out


def _dedupe_candidates(cands: list[Candidate]) -> list[Candidate]:
    kept: list[Candidate] = []
    for c in sorted(cands, key=lambda c: -c.code_margin):
        if not any(_same_place(c.outer, k.outer, 1.25) for k in kept):
            kept.append(c)
    return kept


def _shifted(c: Candidate, shift: FloatArray) -> Candidate:
    return dataclasses.replace(c, outer=Ellipse(c.outer.centre_px + shift, c.outer.semi_axes_px, c.outer.angle_rad),
                               inner=Ellipse(c.inner.centre_px + shift, c.inner.semi_axes_px, c.inner.angle_rad))
