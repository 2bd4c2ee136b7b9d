"""Fractal levels: which level a pair whose code several levels share is, and nesting of candidates."""

from __future__ import annotations

import dataclasses
import functools
import math

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect.geometry import _Entry, _slots
from livetrack.estimator.detect.levels_kernel import _row_nanmedian, disk_edges, verdict  # noqa: F401 (the tests)
from livetrack.estimator.detect.places import _same_place
from livetrack.estimator.detect.results import Candidate
from livetrack.estimator.target_map import (
    centre_homography,
    sample_target,
    sample_target_points,
)
from livetrack.targets.spec import TargetSpec

FloatArray = npt.NDArray[np.float64]


def _choose_level(img: np.ndarray, H0: FloatArray, entries: list[_Entry], phase: float, rotation: int | None,
                  black: float, contrast: float, outer: Ellipse | None = None, inner: Ellipse | None = None
                  ) -> tuple[_Entry, bool]:
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
    When too little of the surroundings is in the image to judge (under half of the slot angles), the deepest
    level where that is seen otherwise (``_deepest_level_seen``: a camera close to the target, its outer ring
    beyond the frame; the pair's inner disk plain white where its parent would hold that level's ring, or, that
    ring washed out, the parent's white disk and black band around the pair), else the outermost (not ambiguous:
    a target at the border would be lost otherwise).

    In a design of three levels or more (``alike``: two levels or more with a parent, which a parent verdict may
    read alike), a level is never taken by default: the outermost is taken for a parent out of the image only
    where the pair's surroundings show no parent's white disk and black band (``_parent_disk_state``), the deepest
    for a confirmed parent only where its inner disk or its grandparent tells (``_deepest_or_middle``), a middle
    level for a parent out of the image where its parent's disk lies around it and the next level's ring in it
    (``_middle_level_seen``); otherwise the choice is ambiguous, unless a level found inside or around the pair
    tells (``_nest``). A camera descending onto a three-level target of 0.5 m saw its middle level as the outermost
    (+400 %) or the deepest (-80 %), and its deepest as the outermost (+2400 %), fit ok.

    ``outer``: the pair's outer ellipse. Given, a parent not confirmed through the pair's own map is read again
    through a map anchored on the parent's white disk edge, where that is found around the pair
    (``_parent_homography``), and confirmed if its code reads right there: the pair's map, extrapolated to 3-5
    of its radii, is a fraction of a dot off for a small pair (a 7 px child on dark foliage read its parent's
    dots dark, was refuted, and came out as the outer level: 5x the distance). Only a confirmation is taken from
    the second reading: a refutation through a map fitted to a clipped or smudged parent is no evidence. Only for
    pairs under ``PARENT_REREAD_MAX_PX``."""
    entries = sorted(entries, key=lambda e: e.level)
    if len(entries) == 1:
        return entries[0], False
    ambiguous = unseen = False
    # two levels or more with a parent (three levels or more): a parent verdict may read them alike
    alike = sum(1 for e in entries if e.parent is not None and e.parent.code is not None) >= 2
    for e in reversed(entries):
        p = e.parent
        if p is None or p.code is None:
            continue
        verdict = _parent_verdict(img, H0, e, p, phase, rotation, black, contrast)
        if verdict != "confirmed" and outer is not None and min(outer.semi_axes_px) < PARENT_REREAD_MAX_PX:
            H = _parent_homography(img, H0, outer, p.inner_radius_m / e.spec.outer_radius_m, black)
            if H is not H0 and _parent_verdict(img, H, e, p, phase, rotation, black, contrast) == "confirmed":
                verdict = "confirmed"
        if (verdict == "ambiguous" and e.spec.child is None and e.spec.centre_dot_radius_m == 0.0
                and _child_seen(img, H0, e, p, black, contrast)):
            verdict = "refuted"  # the deepest level's inner disk is plain white: this pair's holds a ring
        if (verdict == "unseen" and e.spec.child is None and e.spec.centre_dot_radius_m == 0.0 and outer is not None
                and _deepest_level_seen(img, H0, e, p, black, contrast, outer, inner, p is entries[0].spec)):
            verdict = "confirmed"  # its parent's code out of the image, the deepest level seen otherwise
        if (verdict == "unseen" and alike and e.spec.child is not None and p is entries[0].spec
                and outer is not None and inner is not None
                and _middle_level_seen(img, H0, e, entries, black, contrast, outer, inner)):
            verdict = "confirmed"  # its parent's code out of the image, its parent's disk round it, a ring in it
        if verdict == "confirmed" and alike and e.spec.child is None and e.spec.centre_dot_radius_m == 0.0:
            verdict = _deepest_or_middle(img, H0, e, p, entries, phase, rotation, black, contrast, outer)
            if verdict == "ambiguous":
                return e, True
        if verdict == "confirmed":
            return e, False
        ambiguous = ambiguous or verdict == "ambiguous"
        unseen = unseen or verdict == "unseen"
    if alike and unseen and not ambiguous:
        # the outermost level only where no parent's disk lies around the pair
        below = entries[1]
        ambiguous = (outer is None or inner is None or below.parent is None
                     or _parent_disk_state(img, H0, below, below.parent, black, contrast, outer, inner) != "absent")
    return entries[0], ambiguous


def _deepest_or_middle(img: np.ndarray, H0: FloatArray, e: _Entry, p: TargetSpec, entries: list[_Entry],
                       phase: float, rotation: int | None, black: float, contrast: float, outer: Ellipse | None
                       ) -> str:
    """For ``_choose_level``, in a design of three levels or more: whether a pair whose parent ``p`` reads right
    around it is the deepest level ``e`` ("confirmed"), the level above it ("refuted": its parent reads the same,
    the same code and proportions) or either ("ambiguous"). Its inner disk tells where the pair's contrast is at
    least ``CHILD_PLAIN_MIN_CONTRAST`` of its white: the ring a level above would hold there seen
    (``_child_seen``; at least ``CHILD_SEEN_MIN_PX``), the level above; plain white where that ring would be at
    least ``CHILD_PLAIN_MIN_PX`` (``_inner_disk_plain``), the deepest. Else its grandparent around its parent:
    confirmed, the deepest; refuted, the level above."""
    if outer is not None and contrast >= CHILD_PLAIN_MIN_CONTRAST * (black + contrast):
        semi_minor_px = float(min(outer.semi_axes_px))
        ring_px = semi_minor_px * e.spec.outer_radius_m / p.outer_radius_m
        if ring_px >= CHILD_SEEN_MIN_PX and _child_seen(img, H0, e, p, black, contrast):
            return "refuted"
        if ring_px >= CHILD_PLAIN_MIN_PX and _inner_disk_plain(img, H0, e, p, black, contrast, semi_minor_px):
            return "confirmed"
    grandparent = next((x.parent for x in entries if x.spec is p), None)
    if grandparent is not None and grandparent.code is not None:
        said = _parent_verdict(img, H0, e, grandparent, phase, rotation, black, contrast)
        if said in ("confirmed", "refuted"):
            return said
    return "ambiguous"


CHILD_SEEN_MIN_PX = 4.0
"""``_deepest_or_middle``: least semi-minor axis (pixels) of a nested ring looked for in a pair's inner disk (a
ring seen is evidence from a smaller size than a plain disk, ``CHILD_PLAIN_MIN_PX``: a 5.8 px ring shows at x1)."""


PARENT_REREAD_MAX_PX = 20.0
"""``_choose_level`` reads a parent again through ``_parent_homography`` only for a pair whose outer semi-minor axis
is under this (pixels): a larger pair's own map holds its parent's dots (its ellipses fitted to ~0.1 px, a fifth of
a pixel or so at the parent's 3-5 radii, against dots of half its radius). Every level-0 pair of an ordinary frame
was read again so (27-110 px in the bench's frames: 0.12 ms of the full frame's ~6.7)."""


CHILD_RAYS = 16
CHILD_DEPTH = 0.3
CHILD_WHITE = 0.5
CHILD_SEEN_SHARE = 0.75
"""``_child_seen``: a nested ring is seen in a pair's inner disk when, on at least ``CHILD_SEEN_SHARE`` of the
``CHILD_RAYS`` rays inside the image, the darkest sample across where its black ring would lie is ``CHILD_DEPTH``
of the pair's contrast below the white between it and the pair's inner edge, itself over ``CHILD_WHITE`` of the
contrast above the pair's black. A 5 x 8 px nested ring on a chessboard (seed 8's multi-004): its darkest at 0.1-0.5
at x1, 0.1-0.7 at x4 (its white clipped at 1.0), mostly over 0.85 at x8 (unseen there)."""


def _child_seen(img: np.ndarray, H0: FloatArray, e: _Entry, p: TargetSpec, black: float, contrast: float) -> bool:
    """Whether the pair of homography ``H0`` (units of its outer radius), read as the level ``e`` of parent ``p``,
    holds a nested level's black ring in its inner disk, where ``e`` would be were the pair ``p``: a ring of
    ``e.outer / p.outer`` of the pair's radius, its inner disk ``e.inner / e.outer`` of that. The deepest level of
    a design has none (its inner disk is printed white), so a pair that holds one is not that level.

    For ``_choose_level``, where a pair's surroundings look like its parent's but its code cannot be read: a 26 x
    41 px target on a 2.8 R sheet on a chessboard, the squares beyond the sheet where its parent's ring would be
    (held-out seed 8's multi-004, six exposures reported as of unknown level); its own nested ring, 5 x 8 px,
    shows in its inner disk."""
    darkest, white = _child_band(img, H0, e, p, black, contrast)
    if darkest is None:
        return False
    dark = (darkest < white - CHILD_DEPTH) & (white > CHILD_WHITE)
    return bool(np.count_nonzero(dark) >= CHILD_SEEN_SHARE * darkest.size)


def _child_band(img: np.ndarray, H0: FloatArray, e: _Entry, p: TargetSpec, black: float, contrast: float
                ) -> tuple[FloatArray, FloatArray] | tuple[None, None]:
    """For ``_child_seen`` and ``_inner_disk_plain``: along each of ``CHILD_RAYS`` rays inside the image, the
    darkest sample across where the nested ring would lie in the pair's inner disk were the pair ``p`` (``e``'s
    ring, from just outside its inner disk to just inside its outer edge: its dots, on the ring's middle circle,
    leave its two bands dark along every ray) and the white between that ring and the pair's inner edge, both in
    units of the pair's contrast above its black; (None, None) when under half of the rays are inside."""
    s = e.spec.outer_radius_m / p.outer_radius_m
    rho = e.spec.inner_radius_m / e.spec.outer_radius_m
    band = s * np.linspace(rho + 0.15 * (1.0 - rho), 0.9, 6)
    white_r = 0.5 * (s + p.inner_radius_m / p.outer_radius_m)
    angles = np.linspace(0.0, 2.0 * np.pi, CHILD_RAYS, endpoint=False)
    radii = np.concatenate([np.repeat(band, CHILD_RAYS), np.full(CHILD_RAYS, white_r)])
    vals = (sample_target(img, H0, radii, np.tile(angles, band.size + 1)) - black) / contrast
    darkest = np.min(vals[:-CHILD_RAYS].reshape(band.size, CHILD_RAYS), axis=0)
    white = vals[-CHILD_RAYS:]
    inside = np.isfinite(darkest) & np.isfinite(white)
    if np.count_nonzero(inside) < CHILD_RAYS // 2:
        return None, None
    return darkest[inside], white[inside]


CHILD_PLAIN_MIN_PX = 6.0
CHILD_PLAIN_DEPTH = 0.15
CHILD_PLAIN_SHARE = 0.9
CHILD_PLAIN_MIN_CONTRAST = 0.5
"""``_inner_disk_plain``: a pair's inner disk is plain white (no nested ring in it) when the nested ring it would
hold were it its parent would be at least ``CHILD_PLAIN_MIN_PX`` (semi-minor axis, pixels) and, on at least
``CHILD_PLAIN_SHARE`` of the ``CHILD_RAYS`` rays inside the image, the darkest sample across that ring lies within
``CHILD_PLAIN_DEPTH`` of the pair's contrast of the white between it and the pair's inner edge, itself over
``CHILD_WHITE`` of the contrast above the pair's black. A nested ring there reads 0.1-0.7 (``CHILD_DEPTH``).
``_deepest_level_seen`` asks only of a pair whose contrast is at least ``CHILD_PLAIN_MIN_CONTRAST`` of its white:
at x32 (contrast 0.10 of the white) the nested rings of two 51-64 px targets at the image's border read white, and
each came out as its own nested level (-80 %, held-out seeds 6 and 8); at x16 (0.55) they showed."""


def _deepest_level_seen(img: np.ndarray, H0: FloatArray, e: _Entry, p: TargetSpec, black: float, contrast: float,
                        outer: Ellipse, inner: Ellipse | None, parent_outermost: bool) -> bool:
    """For ``_choose_level``: positive evidence that a pair whose parent's code is out of the image (a camera close
    to the target) is the deepest level ``e`` of parent ``p``. Where the nested ring that ``p`` holds would show in
    the pair's inner disk (at least ``CHILD_PLAIN_MIN_PX``, the pair's contrast at least ``CHILD_PLAIN_MIN_CONTRAST``
    of its white), the inner disk decides: plain white (``_inner_disk_plain``), the deepest level; else not. Where
    it may not show, and ``p`` is the outermost level (``parent_outermost``): its parent's white disk and black band
    around the pair (``_parent_disk_seen``, which tells a level with a parent from the outermost level, not which
    of several nested levels a pair is).

    At low contrast (over-exposure: the ink near the clip) a nested ring is no evidence either way: a 3 % lens halo
    lifts a small ring inside a white disk over the clip, blur thins it. A sunlit landing (x32, contrast 0.17 of the
    white) came out at 5x its distance (+400 %, fit ok) until the parent's disk was read; taking the plain inner
    disk there instead, with the ring's width left by the exposure growth its own ring shows (3.3 px predicted),
    read a 45 deg level-0 target at x32 on clipped bright ground (its nested ring under a halo) as its own nested
    level (-80 %)."""
    semi_minor_px = float(min(outer.semi_axes_px))
    ring_shows = (semi_minor_px * e.spec.outer_radius_m / p.outer_radius_m >= CHILD_PLAIN_MIN_PX
                  and contrast >= CHILD_PLAIN_MIN_CONTRAST * (black + contrast))
    if ring_shows:  # a nested ring would show: the inner disk decides, either way
        return _inner_disk_plain(img, H0, e, p, black, contrast, semi_minor_px)
    if not parent_outermost or inner is None:
        return False
    return _parent_disk_seen(img, H0, e, p, black, contrast, outer, inner)


def _middle_level_seen(img: np.ndarray, H0: FloatArray, e: _Entry, entries: list[_Entry], black: float,
                       contrast: float, outer: Ellipse, inner: Ellipse) -> bool:
    """For ``_choose_level``, in a design of three levels or more: positive evidence that a pair whose parent's
    code is out of the image is the level ``e`` below the outermost, neither the outermost nor deeper: its inner
    disk holds the next level's ring (``_child_seen``), and the parent's white disk and black band lie around it
    (``_parent_disk_seen``). A camera 0.55-1.0 m from a three-level target of 0.5 m sees its middle level whole
    and the outer one's code beyond the frame; that level came out as the outermost (+400 %, fit ok)."""
    p = e.parent
    below = next((x for x in entries if x.parent is e.spec), None)
    return (p is not None and below is not None and _child_seen(img, H0, below, e.spec, black, contrast)
            and _parent_disk_seen(img, H0, e, p, black, contrast, outer, inner))


def _parent_disk_seen(img: np.ndarray, H0: FloatArray, e: _Entry, p: TargetSpec, black: float, contrast: float,
                      outer: Ellipse, inner: Ellipse) -> bool:
    """Whether ``_parent_disk_state`` is "seen"."""
    return _parent_disk_state(img, H0, e, p, black, contrast, outer, inner) == "seen"


def _parent_disk_state(img: np.ndarray, H0: FloatArray, e: _Entry, p: TargetSpec, black: float, contrast: float,
                       outer: Ellipse, inner: Ellipse) -> str:
    """Whether the pair of homography ``H0`` (units of its seen outer radius), read as the level ``e`` of parent
    ``p``, lies in its parent's white disk with the parent's black band beyond it (``_parent_disk_around``): "seen"
    through the pair's own map, else through a map anchored on the parent's white disk edge where one is found;
    "absent" where, through the pair's own map, at most ``PARENT_DISK_ABSENT_SHARE`` of the rays (at least
    ``PARENT_DISK_MIN_INSIDE``) are parent-like next to the pair and next to the parent's edge (the
    samples farther out are misplaced by a wide lens's distortion: a three-level target's middle level, 300 px 0.2
    m from a wide lens, read no parent's disk all round through them and came out as the outer level, +400 %),
    the white disk asked only where the pair's contrast is at least ``CHILD_PLAIN_MIN_CONTRAST`` of its white (at
    x32 under vignetting a parent's white disk read under 0.7 of the contrast: +400 %); else "unknown"."""
    if p.code is None:
        return "unknown"
    # where the parent's edge and dots lie through the pair's map, moved by the exposure growth d: (q + d) / (1 - d)
    # and (m - d) / (1 - d) of the pair's seen radius
    d = _seen_growth(outer, inner, e.spec)
    q = p.inner_radius_m / e.spec.outer_radius_m
    m = (p.code.ring_radius_m - p.code.dot_radius_m) / e.spec.outer_radius_m
    edge, dots = (q + d) / (1.0 - d), (m - d) / (1.0 - d)
    share = _parent_disk_share(img, H0, black, contrast, edge, dots)
    if share is not None and share >= PARENT_DISK_SHARE:
        return "seen"
    # through a map anchored on the parent's white disk edge where one is found round the pair: the pair's own map,
    # extrapolated to 2-3 radii of a close, tilted target, misplaces it by up to a third of a radius
    H = _parent_homography(img, H0, outer, q, black)
    if H is not H0:
        again = _parent_disk_share(img, H, black, contrast, q, q * (m - d) / (q + d))
        if again is not None and again >= PARENT_DISK_SHARE:
            return "seen"
    if share is None:
        return "unknown"
    # over-exposed, the pair's own black and white are no measure of a parent's: under vignetting or a gradient at
    # x32 a parent's white read under 0.7 of the pair's contrast and its ink from clipped to darker than the pair's
    white_too = contrast >= CHILD_PLAIN_MIN_CONTRAST * (black + contrast)
    near = _parent_disk_share(img, H0, black, contrast, edge, dots, near=True, white_too=white_too)
    at_most = PARENT_DISK_ABSENT_SHARE if white_too else PARENT_DISK_ABSENT_SHARE_CLIPPED
    return "absent" if near is not None and near <= at_most else "unknown"


PARENT_NEAR_BAND_LIFT = 0.12
"""``_parent_disk_share(..., near=True)``: most a parent's band next to its edge lies above the pair's black, a share
of the pair's contrast (printed ink: ~0; grey ground of reflectance 0.2 beside a level-0 target's sheet, 0.2)."""
PARENT_NEAR_STEP = 0.2
"""``_parent_disk_share(..., white_too=False)``: least step (share of the pair's contrast) from a parent's white disk
down to its band on one ray."""
PARENT_DISK_ABSENT_SHARE = 0.5
PARENT_DISK_ABSENT_SHARE_CLIPPED = 0.25
"""``_parent_disk_state``: a parent's disk is absent around a pair where at most this share of the rays whose
samples next to the pair and next to the parent's edge are in the image are parent-like there (a parent's are on
at least ``PARENT_DISK_SHARE`` of the whole rays); ``..._CLIPPED`` where the pair's contrast is under
``CHILD_PLAIN_MIN_CONTRAST`` of its white (the band then asked only to step down from the white disk). A level-0
target on a sheet of 2.2 R on grey ground reads parent-like on its sheet's sides (white at 1.2 R, grey as dark as
ink at 2.2 R) and not towards its corners; at x32 under an illumination gradient a parent's ink stepped down from
its white disk on 6 of 17 rays, clipped white on the others (+400 % with half)."""


def _seen_growth(outer: Ellipse, inner: Ellipse, spec: TargetSpec) -> float:
    """The exposure growth d (units of the outer radius) that the pair's ellipses show for the design ``spec``:
    (r + d) / (1 - d) = their seen ratio (``code._as_seen``), kept within [0, 0.15] (over-exposure)."""
    seen = 0.5 * (inner.a / outer.a + inner.b / outer.b)
    rho = spec.inner_radius_m / spec.outer_radius_m
    return min(max((seen - rho) / (1.0 + seen), 0.0), 0.15)


PARENT_DISK_RAYS = 32
PARENT_DISK_MIN_INSIDE = 8
PARENT_DISK_SHARE = 0.9
PARENT_DISK_WHITE = 0.7
"""``_parent_disk_share``, ``_parent_disk_state``: on at least ``PARENT_DISK_SHARE`` of the ``PARENT_DISK_RAYS`` rays
inside the image (at least ``PARENT_DISK_MIN_INSIDE`` of them: a quarter turn), the parent's white disk around the
pair reads at least ``PARENT_DISK_WHITE`` of the pair's contrast above its black and the parent's black band beyond
it at most ``PARENT_MAX_BAND_LIFT``. Half of them was too many: a camera 0.16 m from a target tilted 60 deg sees 14
of the 32 rays whole (all 14 parent-like), and the pair came out as the outer level (+400 %)."""


def _parent_disk_share(img: np.ndarray, H: FloatArray, black: float, contrast: float, edge: float,
                       dots: float, near: bool = False, white_too: bool = True) -> float | None:
    """The share of rays on which the pair seen through the homography ``H`` (target-plane units of the pair's outer
    radius) lies in its parent's white disk with the parent's black band beyond it: white from the pair out to the
    parent's inner edge, dark from there to the parent's code dots, that edge at ``edge`` on every ray and the dots'
    inner edge at ``dots`` (same units). Through the pair's own map (its seen outer radius 1) the caller puts them where
    the design and the exposure put them: the parent's inner radius over the pair's outer one, q (2 in the default
    design), moved out by the growth d the pair's own ring shows, (q + d) / (1 - d), and the dots' edge at (m - d) /
    (1 - d). White is asked up to 0.15 inside that edge, dark from 0.2 beyond it to 0.2 short of the dots: blur (2 px on
    a 70 px pair at x32) and the pair's map extrapolated to 3 radii move it by less, but for a close, tilted target,
    whose own map the caller replaces by one anchored on the parent's edge (``_parent_homography``). The parent's ring
    and code can be beyond the frame while its inner edge is in it (a camera descending onto it).

    Ground round an outermost-level target does not show it: plain or textured ground is not white next to the
    pair, a larger sheet is white at 2-3 radii, and a sheet is square: its edge lies within that 0.35 window on
    at most ~75 % of the rays (a side of 3.7 R), never 90 %. Without the window (dark anywhere at 2.4-2.6 radii) a
    level-0 target on a sheet of 3.4 R on black ground at x32, its parent's code out of the frame, came out as its
    own nested level (-80 %). None where fewer than ``PARENT_DISK_MIN_INSIDE`` rays lie whole in the image.

    near: only the white disk's sample nearest the pair (1.2 radii) and the band's nearest the edge are asked, on
    every ray where both are in the image (``_parent_disk_state``'s "absent"). Default False.
    white_too: False to ask only that the band be ``PARENT_NEAR_STEP`` of the pair's contrast darker than the
        white disk on the same ray, not that they be as white and as dark as the pair. Default True."""
    white_r = np.linspace(1.2, edge - 0.15, 4)
    band_r = np.linspace(edge + 0.2, dots - 0.2, 3)
    radii = np.concatenate([white_r, band_r])
    angles = np.linspace(0.0, 2.0 * np.pi, PARENT_DISK_RAYS, endpoint=False)
    vals = (sample_target(img, H, np.repeat(radii, PARENT_DISK_RAYS), np.tile(angles, radii.size))
            - black) / contrast
    vals = vals.reshape(radii.size, PARENT_DISK_RAYS)
    if near:  # the white disk's first two samples and the band's first, on the rays where they are in the image
        white, band = np.fmin(vals[0], vals[1]), vals[white_r.size]
        inside = np.isfinite(white) & np.isfinite(band)
        white, band = white[inside], band[inside]
    else:
        inside = np.all(np.isfinite(vals), axis=0)
    if np.count_nonzero(inside) < PARENT_DISK_MIN_INSIDE:
        return None
    if not near:
        white = np.min(vals[: white_r.size, inside], axis=0)
        band = np.max(vals[white_r.size:, inside], axis=0)
    if white_too:
        parent_like = (white >= PARENT_DISK_WHITE) & (band <= (PARENT_NEAR_BAND_LIFT if near else PARENT_MAX_BAND_LIFT))
    else:  # the band darker than the white disk on the same ray (an illumination gradient moves both)
        parent_like = band <= white - PARENT_NEAR_STEP
    return float(np.count_nonzero(parent_like)) / band.size


def _inner_disk_plain(img: np.ndarray, H0: FloatArray, e: _Entry, p: TargetSpec, black: float, contrast: float,
                      semi_minor_px: float) -> bool:
    """Whether the pair of homography ``H0`` (outer semi-minor axis ``semi_minor_px``), read as the deepest level
    ``e`` of parent ``p``, has a plain white inner disk, as ``e`` has and ``p`` has not (``p`` holds ``e``'s ring
    there, ``_child_seen``): positive evidence that the pair is ``e`` where ``p``'s ring is out of the image.

    For ``_choose_level``'s parents that are "unseen" (under half of their slot angles in the image): the
    outermost level was taken then, for a target at the image's border; but a camera close to a target sees its
    nested level whole and its parent's ring beyond the frame: a 0.25 m target from 0.25 m on a 640 x 480 camera
    (800 px focal length), its nested ring 78 px, came out as the outer level at 5x its distance (+400 %, fit ok).
    A pair too small to show a nested ring (``CHILD_PLAIN_MIN_PX``) keeps the outermost level."""
    s = e.spec.outer_radius_m / p.outer_radius_m
    if semi_minor_px * s < CHILD_PLAIN_MIN_PX:
        return False
    darkest, white = _child_band(img, H0, e, p, black, contrast)
    if darkest is None:
        return False
    plain = (darkest >= white - CHILD_PLAIN_DEPTH) & (white > CHILD_WHITE)
    return bool(np.count_nonzero(plain) >= CHILD_PLAIN_SHARE * darkest.size)


def _parent_verdict(img: np.ndarray, H0: FloatArray, e: _Entry, p: TargetSpec, phase: float,
                    rotation: int | None, black: float, contrast: float) -> str:
    """For ``_choose_level``: "confirmed", "refuted", "ambiguous" or "unseen" for the parent ``p`` of level
    ``e`` around the pair of homography ``H0`` whose black level and contrast are ``black``, ``contrast``: its
    samples here, their reading in ``levels_kernel.verdict`` (compiled; the numpy reading, with the reasons for
    each rule, is ``levels_kernel.verdict_reference``)."""
    assert p.code is not None
    k = 1.0 / e.spec.outer_radius_m
    n = p.code.slots
    ring, dot = k * p.code.ring_radius_m, k * p.code.dot_radius_m
    radii, angles = _parent_pattern(k * p.inner_radius_m, ring, dot, k * p.outer_radius_m, n)
    t = angles + phase  # (``sample_target(img, H0, radii, t)``'s arithmetic without its wrapper)
    vals = sample_target_points(img, H0, radii * np.cos(t), radii * np.sin(t)).reshape(3, n)  # bands, white disk
    # A parent's dots are 5x its child's: a slot's brightest sample is on the dot even where the pair's
    # homography, extrapolated to the parent's ring, is a fraction of a dot off; a blank slot stays dark.
    slot_vals, gaps = _slots(img, H0, ring, dot, n, phase, brightest=True)
    said = verdict(vals, slot_vals, gaps, _code_values(p.code.bits), rotation, black, contrast, PARENT_MIN_CONTRAST)
    if said == "confirmed" and (np.any(vals[2] < black + PARENT_WHITE_DISK * contrast)  # (NaN: outside, not dark)
                                or _blank_slot_white(vals, p.code.bits, rotation, black, contrast)):
        said = "ambiguous"  # a parent's white disk is white all round, its ink dark where it has no dot
    if said == "ambiguous":
        bands = np.fmin(vals[0], vals[1])
        bands = bands[np.isfinite(bands)]
        if bands.size and float(np.median(bands)) > black + PARENT_MAX_BAND_LIFT * contrast:
            return "refuted"  # its dark bands are not ink: ground beyond a sheet
    return said


def _blank_slot_white(vals: FloatArray, bits: str, rotation: int | None, black: float, contrast: float) -> bool:
    """Whether both of the parent's dark bands are white (``PARENT_BLANK_BANDS``) at a slot where its code, at the
    confirmed ``rotation``, has no dot; False when the rotation is not known (a symmetric code)."""
    if rotation is None:
        return False
    bands = np.minimum(vals[0], vals[1])[_blank_slots(bits, rotation)]  # (NaN, outside the image: not white)
    return bool(np.any(bands > black + PARENT_BLANK_BANDS * contrast))


@functools.lru_cache(maxsize=256)
def _blank_slots(bits: str, rotation: int) -> npt.NDArray[np.bool_]:
    """The slots without a dot of a code turned by ``rotation`` slots, ``np.roll(code values, rotation) < 0.5``
    (read-only, cached: np.roll cost ~10 us a call)."""
    blank = np.roll(_code_values(bits), rotation) < 0.5
    blank.flags.writeable = False
    return blank


@functools.lru_cache(maxsize=64)
def _code_values(bits: str) -> FloatArray:
    """A code's slots as floats, 1.0 for a dot (read-only, cached)."""
    ref = np.array([b == "1" for b in bits], dtype=np.float64)
    ref.flags.writeable = False
    return ref


PARENT_MIN_CONTRAST = 0.6
"""``_parent_verdict``: a parent is confirmed only where its readable slots' median local contrast is at least this
share of the pair's."""
PARENT_WHITE_DISK = 0.6
"""``_parent_verdict``: a parent confirmed by its code reading is taken as ambiguous instead when its white disk
(sampled at each slot angle) is darker than this share of the pair's contrast above its black anywhere in the image:
a chessboard around a 26 x 41 px target on a small sheet read as a six-dot parent code, one square where the parent's
disk would be, and the target came out as its own nested level (-80 %, held-out seed 8, six frames). Over seeds 0-4
and 8, none of the 1509 other confirmed parents has a sample under it; five of that target's six have one."""
PARENT_BLANK_BANDS = 0.85
"""``_parent_verdict``: a parent confirmed by its code reading is taken as ambiguous instead when both its dark bands
lie more than this share of the pair's contrast above its black at a slot where the code (at the rotation read) has
no dot. Its dots grown by over-exposure or a halo whiten the bands beside them, and its white disk or outer edge
one band, never both at a blank slot; ground does: a chessboard square around a 22 x 41 px target at x8 (held-out
seed 8's multi-004) covered a blank slot's two bands (1.0 and 1.0) while the squares elsewhere read as its parent's
six-dot code, and the target came out as its own nested level (-80 %; its white disk was white there, the rule
above missed it). Over 1268 confirmed parents of detector-only runs on seeds 0-2 and 8 and part of 3 and 4 (session
16), the darker band at a blank slot reached 1.00 there and at most 0.61 elsewhere (seed 0's single-008 at x32: its
grown dots), under 0.1 but for three."""
PARENT_MAX_BAND_LIFT = 0.3
"""``_parent_verdict``: parent-like surroundings whose code cannot be read ("ambiguous") are refuted when the median
of their darker band (at the slot angles) lies more than this share of the pair's contrast above the pair's own
black: a parent's bands, printed with the pair and wider than its ring, are as dark as it (detection sweep seeds
0-1, 499 confirmed parents: -0.19 to +0.13, 99 % under 0.02), while textured ground beyond a small sheet, as dark
as a band only next to white, stands at +0.50 and +0.54 (a 17 px target on carpet at x2 and a 30 px one at 70
deg, each refused as of unknown level before)."""
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
    r, t, tx, ty, white_cols, far = _ray_pattern(disk_ratio)
    vals = _sample_points(img, H0, tx, ty).reshape(len(t), len(r))
    rows, rho = disk_edges(vals, r, white_cols, far, black)
    if len(rows) < PARENT_MIN_RAYS * len(t):
        return H0
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
def _ray_pattern(disk_ratio: float) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, int,
                                               npt.NDArray[np.bool_]]:
    """For ``_parent_homography`` (read-only, cached): the radii r (41, units of the pair's R, 0.5-1.5
    ``disk_ratio``) and angles t (``PARENT_RAYS``) of its rays; the target points (x, y) of every ray's radii
    (ray after ray) as ``sample_target`` computes them from the radii and angles; how many of the first radii
    give a ray's white (up to 0.75 ``disk_ratio``); the radii where an edge may lie (0.65 ``disk_ratio`` on)."""
    r = disk_ratio * np.linspace(0.5, 1.5, 41)
    t = np.linspace(0.0, 2.0 * np.pi, PARENT_RAYS, endpoint=False)
    radius, angle = np.tile(r, len(t)), np.repeat(t, len(r))
    tx, ty = radius * np.cos(angle), radius * np.sin(angle)
    white_cols = int(np.count_nonzero(r <= 0.75 * disk_ratio))  # a prefix: r increases
    far = r >= 0.65 * disk_ratio
    for a in (r, t, tx, ty, far):
        a.flags.writeable = False
    return r, t, tx, ty, white_cols, far


def _sample_points(img: np.ndarray, H: FloatArray, tx: FloatArray, ty: FloatArray) -> FloatArray:
    """``sample_target(img, H, radius, angle)`` from the target points ``tx = radius cos(angle)``, ``ty = radius
    sin(angle)`` (M,) instead of their radii and angles (cached by the caller): the same arithmetic on them, the
    same values (``tests/test_detect_levels.py``)."""
    return sample_target_points(img, H, tx, ty)


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


def _nest(cands: list[Candidate], targets: dict[int, TargetSpec]) -> list[Candidate]:
    """A candidate inside another's inner disk, of the size and code of its child, is that child (and the other,
    if it is the outermost of two levels, is no longer ambiguous). In a design of three levels or more
    (``targets``: the configured ones by id), a level that ``_choose_level`` left ambiguous is told by one nested
    with it whose level is not: the one inside takes the level below the other's, and first, the other way round,
    the one around takes the level above that of the one inside, where the one inside has its child's code and
    size at that level. A camera 0.48 m from a three-level target of 0.5 m sees its middle level whole (168 px)
    and the deepest inside it (33 px, its parent's code read on the middle level, its plain inner disk), but not
    the outer level's code."""
    out = sorted(cands, key=lambda c: -c.outer.a)
    alike = {i for i, t in targets.items() if sum(1 for _ in t.levels()) >= 3}
    for i, x in enumerate(out):
        if x.level_ambiguous or x.level == 0 or x.target_id not in alike:
            continue
        for j, y in enumerate(out[:i]):
            if not y.level_ambiguous or y.target_id != x.target_id:
                continue
            spec = dict(targets[y.target_id].levels()).get(x.level - 1)
            if spec is not None and _holds(y, x, spec):
                out[j] = dataclasses.replace(y, level=x.level - 1, spec=spec, level_ambiguous=False)
    for i, x in enumerate(out):
        for j, y in enumerate(out[:i]):
            if _holds(y, x, y.spec):
                child = y.spec.child
                assert child is not None
                told = x.level_ambiguous and not y.level_ambiguous and y.target_id in alike
                out[i] = dataclasses.replace(x, target_id=y.target_id, level=y.level + 1, spec=child,
                                             level_ambiguous=False if told else x.level_ambiguous)
                if y.level_ambiguous and y.level == 0 and child.child is None:
                    # a level with a level inside it is not the deepest: of two levels, the outermost
                    out[j] = dataclasses.replace(y, level_ambiguous=False)
                break
    return out


def _holds(y: Candidate, x: Candidate, spec: TargetSpec) -> bool:
    """Whether ``x`` lies in ``y``'s inner disk with the code and the size (0.7-1.4 times) of the child of
    ``spec``, ``y`` read as the level ``spec``."""
    child = spec.child
    if (child is None or child.code is None or x.spec.code is None or child.code.bits != x.spec.code.bits
            or y.inner.sampson_distance(x.outer.centre_px[None, :])[0] >= 0 or x.outer.a >= y.inner.a):
        return False
    expected = child.outer_radius_m / spec.outer_radius_m
    return 0.7 * expected <= x.outer.a / y.outer.a <= 1.4 * expected


def _dedupe_candidates(cands: list[Candidate]) -> list[Candidate]:
    kept: list[Candidate] = []
    for c in sorted(cands, key=lambda c: -c.code_margin):
        if not any(_same_place(c.outer, k.outer, 1.25) for k in kept):
            kept.append(c)
    return kept


def _shifted(c: Candidate, shift: FloatArray) -> Candidate:
    return dataclasses.replace(c, outer=Ellipse(c.outer.centre_px + shift, c.outer.semi_axes_px, c.outer.angle_rad),
                               inner=Ellipse(c.inner.centre_px + shift, c.inner.semi_axes_px, c.inner.angle_rad))
