"""Verification and identification of a pair: its black and white levels, the slot grid and the code."""

from __future__ import annotations

import functools
import math

import numpy as np
import numpy.typing as npt

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect import blurred as blurred_code
from livetrack.estimator.detect.geometry import _Entry, _Geometry, _hole, _slots
from livetrack.estimator.detect.levels import _choose_level
from livetrack.estimator.detect.options import DetectOptions
from livetrack.estimator.detect.pairs import _ratio_ok
from livetrack.estimator.detect.results import Candidate
from livetrack.estimator.detect.threshold import _quantile
from livetrack.estimator.target_map import (
    centre_homography,
    rotation3,
    sample_target,
    sample_target_points,
)
from livetrack.targets import codebook

FloatArray = npt.NDArray[np.float64]


# ---------------------------------------------------------------------- verification and code
CLIPPED_MAX_GAP = 0.65
"""Largest normalised value of a gap between two slots of a pair whose white is clipped (0.5 otherwise)."""
MAX_EXPOSURE_SHIFT = 0.1
"""Largest exposure shift of each edge (units of the outer radius) of a pair whose code is read: its seen radius
ratio may lie anywhere ``(r/R + d) / (1 - d)`` gives for ``|d|`` up to this, beyond the pixel bias of
``DetectOptions.exposure_bias_px``. At x32 with a 3 % halo a 58 px target read 0.53 for 0.4 (d = 0.085 R,
4.5 px: its edges move with the halo's width, not the lens's); ``_as_seen`` reads codes up to d = 0.12."""


def _identify(img: np.ndarray, outer: Ellipse, inner: Ellipse, groups: dict[_Geometry, list[_Entry]],
              full: float, opts: DetectOptions, reasons: list[str] | None = None) -> list[Candidate]:
    """The candidates the pair reads as, one per geometry at most; ``reasons`` (a list): why each geometry
    whose ratio matches gave none is appended."""
    out: list[Candidate] = []
    H0 = centre_homography(outer, inner)
    for geom, entries in groups.items():
        if not _ratio_ok(outer, inner, geom.ratio, opts.exposure_bias_px + 0.5, opts.ratio_tolerance,
                         MAX_EXPOSURE_SHIFT):
            continue
        cand = _read_code(img, outer, inner, H0, geom, entries, full, opts)
        if isinstance(cand, Candidate):
            out.append(cand)
        elif reasons is not None:
            reasons.append(cand)
    return out


OFF_CENTRE_SHIFTS = (0.05, 0.1)
"""``identify_off_centre``: the shifts tried (units of the outer semi-minor axis), nearer first."""
OFF_CENTRE_MAX_ASPECT = 0.8
"""``identify_off_centre``: only pairs at least this tilted (outer b / a at most this); perspective moves the
circles' images apart by the sine of the tilt."""
OFF_CENTRE_REASONS = ("no code match", "code margin", "gaps between slots white")


def identify_off_centre(img: np.ndarray, outer: Ellipse, inner: Ellipse, groups: dict[_Geometry, list[_Entry]],
                        full: float, opts: DetectOptions, reasons: list[str], centre_first: bool = False
                        ) -> tuple[Ellipse, list[Candidate]]:
    """A pair whose outer ellipse is its inner disk's hole scaled (concentric: a pair from a hole alone) read
    again with that ellipse moved along its minor axis by ``OFF_CENTRE_SHIFTS`` of its semi-minor axis, to either
    side; (outer, candidates), none when no shift reads.

    Under perspective the centre of a circle's image lies off the image of the circle's centre, along the tilt
    (the ellipses' minor axis), by about the square of its radius: the outer circle's image is off the inner
    disk's by a few percent of its minor axis, towards the side nearer the camera. The hole scaled about its own
    centre leaves the code slots of a strongly tilted target off its dots: seed 6's single-018 at x0.25 (29 x 89
    px at 70 deg, on black ground without a sheet, found from its hole) read one of its seven dots dark, no code
    within half a slot; its outer ellipse moved by 0.03-0.15 b to one side read id 12 (margin 1.6-1.7), to the
    other none. Which side is nearer needs the camera: both sides are tried, each at every shift, and a side is
    kept only when all its shifts read the same target and the other side's read none (one shift on one side,
    kept alone, read id 5 in foliage at x32: seed 7's no-sheet-005). Only after a reading that found the dots off
    their slots (``OFF_CENTRE_REASONS``) and on pairs tilted past ``OFF_CENTRE_MAX_ASPECT``. ``centre_first``: the
    pair as given is read first (it was not yet: a large one's was read placed on the grey image's edges instead,
    ``detector.LARGE_HOLE_PAIR_EDGE_SEEN``)."""
    if outer.b > OFF_CENTRE_MAX_ASPECT * outer.a or not any(r.startswith(OFF_CENTRE_REASONS) for r in reasons):
        return outer, []
    if centre_first:
        found = _identify(img, outer, inner, groups, full, opts)
        if found:
            return outer, found
    t = outer.angle_rad + 0.5 * math.pi
    across = np.array([math.cos(t), math.sin(t)])
    sides = []
    for side in (1.0, -1.0):
        read = []
        for k in OFF_CENTRE_SHIFTS:
            moved = Ellipse(outer.centre_px + side * k * outer.b * across, outer.semi_axes_px, outer.angle_rad)
            read.append((moved, _identify(img, moved, inner, groups, full, opts)))
        sides.append(read)
    ids = [[{(c.target_id, c.level) for c in found} for _, found in read] for read in sides]
    agreed = [bool(side[0]) and all(i == side[0] for i in side) for side in ids]
    if agreed[0] == agreed[1] or any(any(i) for i in ids[int(agreed[0])]):
        return outer, []  # both sides, or neither, or the other side reads too: nothing trusted
    moved, found = sides[0 if agreed[0] else 1][0]
    return moved, found


def _read_code(img: np.ndarray, outer: Ellipse, inner: Ellipse, H0: FloatArray, g: _Geometry,
               entries: list[_Entry], full: float, opts: DetectOptions) -> Candidate | str:
    """The candidate the pair reads as with geometry ``g``, or why it reads as none."""
    n = g.slots
    g_design = g
    g = _as_seen(g, outer, inner)
    tx, ty, harmonic_kernel = _code_pattern(g, _hole(entries))
    k = 8 * n
    vals = sample_target_points(img, H0, tx, ty)
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

    if _darker_than_its_clipped_surroundings(img, H0, g_design, outer, inner, white, full, n):
        return "inner disk darker than its clipped surroundings"

    def norm(v: FloatArray) -> FloatArray:
        return (v - black) / contrast

    # (norm is increasing: the quantile of the normalised values is the normalised quantile). Three fifths of
    # the black-band samples dark: at x16-x32 the bands of a small or tilted target (its pair often found on a
    # coarse level) are thin and partly white (four fifths lost 2 of 405 visible targets in the sweep, 0 FP).
    clipped = white >= 0.98 * full
    blurred = False
    if not clipped and (_quantile(black_vals, 60) - black) / contrast > 0.5:
        # a small pair: its bands may be lifted by blur; read on, its code against the blurred hypotheses
        # (``blurred``) where the thresholds below refuse it
        if not blurred_code.MIN_SEMI_MINOR_PX <= float(np.min(outer.semi_axes_px)) <= blurred_code.MAX_SEMI_MINOR_PX:
            return "black bands not dark"
        blurred = True

    def refused(reason: str) -> str:  # a blurred reading refused is refused as before (no re-reading on edges)
        return "black bands not dark" if blurred else reason

    if (_quantile(white_vals, 20) - black) / contrast < 0.5:
        return refused("inner disk not white")
    # Slot grid phase from the N-th harmonic of the code circle.
    harmonic = (norm(ring_vals) * harmonic_kernel).sum()  # (np.sum's reduction, without its wrapper)
    phase = float(-np.angle(harmonic) / n)
    slot_vals, gaps = _slots(img, H0, g.ring, g.dot, n, phase)
    slot_vals, gaps = norm(slot_vals), norm(gaps)
    # clipped white: a small target's grown dots reach half-way into the gaps between slots (x16, 13 px: the
    # one gap between id 1's two dots read 0.50), and a gap between two grown dots closes (``_gaps_to_test``)
    white_gap = gaps.max() > (CLIPPED_MAX_GAP if clipped else 0.5)
    if white_gap and clipped:  # one gap between two dots may have closed; the others then dark, on its ink
        others = _gaps_to_test(slot_vals, gaps)
        white_gap = not (others.size < gaps.size and others.max() <= 0.5 and others.min() >= MERGED_MIN_GAP)
    if white_gap or gaps.mean() > 0.3:
        return refused(f"gaps between slots white (max {np.max(gaps):.2f}, mean {np.mean(gaps):.2f})")
    peak = float(slot_vals.max())
    if peak < 0.35:
        return refused(f"no dot brighter than {peak:.2f}")
    soft = (slot_vals / max(peak, 0.5)).clip(0.0, 1.0)  # small blurred dots never reach the white level
    codes = _shortlist(soft, entries)
    decoded = codebook.decode(soft, codes, max_distance=opts.max_code_distance)
    if (not decoded or decoded.margin < opts.min_code_margin) and clipped and not blurred:
        local = _against_the_gaps(slot_vals, gaps)
        if local is not None:
            local_codes = _shortlist(local, entries)
            again = codebook.decode(local, local_codes, max_distance=min(opts.max_code_distance,
                                                                          LOCAL_MAX_CODE_DISTANCE))
            if again and again.margin >= max(opts.min_code_margin, LOCAL_MIN_CODE_MARGIN):
                soft, codes, decoded = local, local_codes, again
    if not decoded or decoded.margin < opts.min_code_margin:
        if not blurred:
            return "no code match" if not decoded else f"code margin {decoded.margin:.2f}"
        read = blurred_code.read_blurred_code(img, H0, g_design, entries, phase, full)
        if isinstance(read, str):
            return "black bands not dark"
        bits, rotation_slots = read
        # ranked below every clean reading of the same place (``_dedupe_candidates``)
        decoded = codebook.Decoded(index=0, rotation_slots=rotation_slots, distance=0.0, margin=0.0,
                                   heading_known=True)
        codes = [bits]
    bits = codes[decoded.index]
    matching = [e for e in entries if e.spec.code is not None and e.spec.code.bits == bits]
    entry, ambiguous = _choose_level(img, H0, matching, phase, decoded.rotation_slots, black, contrast, outer,
                                     inner)
    heading = None
    rotation = decoded.rotation_slots
    if rotation is not None:
        H = H0 @ rotation3(phase + 2.0 * np.pi * rotation / n)
        heading = _heading(H.tolist())
        # Phase is in [-pi/n, pi/n]: a phase beyond half a slot belongs to the neighbouring slot.
        rotation = int(round(phase / (2.0 * np.pi / n))) + rotation
        rotation %= n
    return Candidate(target_id=entry.target_id, level=entry.level, spec=entry.spec, outer=outer, inner=inner,
                     rotation_slots=rotation, heading_rad=heading, code_margin=float(decoded.margin),
                     code_values=soft, black_level=black, white_level=white, level_ambiguous=ambiguous,
                     darker_outside=entry.level == 0 and darker_outside(img, H0, black, contrast))


BLOOM_MIN_SLOT = 0.75
"""``_gaps_to_test``: least normalised value of the two slots beside a gap that may close."""
MERGED_MIN_GAP = -0.15
"""A pair read with one gap between dots left out (``_gaps_to_test``) needs its other gaps on its ink: none
darker than its black by more than this (normalised). Texture is not ink: foliage read as id 5 with gaps at -0.28
and -0.2 (seed 3's border-001 at x8); the over-exposed targets so read had their other gaps within -0.01..0.42."""


def _gaps_to_test(slot_vals: FloatArray, gaps: FloatArray) -> FloatArray:
    """The gaps (normalised, (N,)) of a pair whose white is clipped that must stay dark: all but those between
    two bright slots (both at least ``BLOOM_MIN_SLOT``). Over-exposure grows each dot by the same d; a gap beside
    one dot turns white when the dot's edge, blurred, reaches it, a gap between two dots gets light from both
    and closes first: at x8-x16 the adjacent dots of a small target merge. Seed 9's no-sheet-005 at x16 (id 3,
    four dots in a row, 8 px, 50 deg) read its slots 1, 0, 0, 0, 0, 1, 1, 1 and its gaps 0.03, 0, 0.02, 0.03,
    0.05, 0.42, 0.75, 0.23: the 0.75 lies between two dots. Only the whitest such gap is left out: two closed
    gaps or more are a white arc along the code circle (texture seen through a thin uncoded ring's band: a
    decoy on carpet at x4 read as id 12, six dots, with every gap between them left out), and a gap beside a dark
    slot still refuses (an arc stays white past its last slot). The caller holds the gaps left to an unclipped
    pair's limit then (0.5, not ``CLIPPED_MAX_GAP``), and above ``MERGED_MIN_GAP``."""
    bright = slot_vals >= BLOOM_MIN_SLOT
    between = bright & np.roll(bright, -1)  # gap j lies between slots j and j + 1
    if not between.any() or between.all():
        return gaps
    # only the whitest gap between dots is left out: one pair of dots merged
    return np.delete(gaps, int(np.flatnonzero(between)[np.argmax(gaps[between])]))


LOCAL_MIN_CONTRAST = 0.25
"""``_against_the_gaps``: least (white - local black), normalised, for a slot to be read against its gaps."""
LOCAL_MAX_CODE_DISTANCE = 0.5
LOCAL_MIN_CODE_MARGIN = 1.0
"""A code read against the gaps must match within this many slots, this far ahead of the next code (a pair
found from a hole alone's rule): the second reading of a pair whose first read as none. Seed 2's no-sheet-004 at
x32 (a ring merged with the chessboard's dark squares, its blob's outline 14 px off-centre and 30 % too big) read
0, 0.01, 0.01, 0, 0.02, 0.55, 0.41, 1 against its gaps: id 1 at 0.91 slots, a wrong id with the pair's usual
1.0."""


def _against_the_gaps(slot_vals: FloatArray, gaps: FloatArray) -> FloatArray | None:
    """The slots (N,) read against their own neighbourhood: each one's black is the mean of the two gaps beside
    it (normalised values: 0 the pair's black, 1 its white), so ``(slot - black) / (1 - black)``, clipped to
    [0, 1]; None when a slot's neighbourhood is within ``LOCAL_MIN_CONTRAST`` of the white (or not finite).

    For a pair whose white is clipped: there the black ring is lifted by the halo of the white around it, by
    more where more white lies near (beside the grown dots, along the inner disk's side facing more of the
    sheet), and by the illumination's gradient; one black level for the whole ring reads the lifted side's bare
    slots as dots. A 124 px target at 70 deg at x32 with a 3 % halo and a 0.6 light gradient (seed 7's
    single-008, id 5: "00011011") read 1, 1, 0.56, 1, 1, -0.14, 0.03, 0.35 (no code within one slot); its gaps
    0.61, 0.55, 0.52, 0.16, -0.04, -0.05, 0.17, 0.46 put its slots at 1, 1, 0.05, 1, 1, 0, 0, 0.05."""
    black = 0.5 * (gaps + np.roll(gaps, 1))  # slot j lies between gaps j - 1 and j
    span = 1.0 - black
    if not np.all(np.isfinite(span)) or np.any(span < LOCAL_MIN_CONTRAST) or not np.all(np.isfinite(slot_vals)):
        return None
    return np.clip((slot_vals - black) / span, 0.0, 1.0)


DARKER_OUTSIDE_RADIUS = 1.15
DARKER_OUTSIDE_SHARE = 0.8
DARKER_OUTSIDE_MIN_STEP = 0.01
"""``darker_outside``: the ground is sampled at ``DARKER_OUTSIDE_RADIUS`` of the outer radius (clear of the edge's
blur) in 32 directions; darker outside means at least ``DARKER_OUTSIDE_SHARE`` of them below the pair's black by
``DARKER_OUTSIDE_MIN_STEP`` of its contrast or more."""


def darker_outside(img: np.ndarray, H0: FloatArray, black: float, contrast: float) -> bool:
    """Whether the ground around a pair (``H0``: its centre homography) is darker than its black ring (``black``:
    its level as ``_read_code`` reads it; ``contrast``: white minus black): a target printed without a sheet on
    darker ground. Ink is not black: the 4 % of a printed ring against black velvet at 2 % gives an outer edge
    whose bright side is the ring (seed 6's single-018, 12 bit: ring 89-104, ground 53 at x1; ~2200 against 1100 at
    x8 where the white clips), and an edge fit with a black-to-white normal pointing out of the ring finds none of
    it. (Asked of level 0 only: a nested level's outside is its parent's white disk.)"""
    ground = sample_target(img, H0, _OUTSIDE_RADII, _OUTSIDE_ANGLES)
    ground = ground[np.isfinite(ground)]
    if ground.size < _OUTSIDE_ANGLES.size // 2:
        return False
    below = black - DARKER_OUTSIDE_MIN_STEP * contrast
    return bool(np.count_nonzero(ground < below) >= DARKER_OUTSIDE_SHARE * ground.size)


_OUTSIDE_ANGLES = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
_OUTSIDE_RADII = np.full(32, DARKER_OUTSIDE_RADIUS)
for _a in (_OUTSIDE_ANGLES, _OUTSIDE_RADII):
    _a.flags.writeable = False


UNCLIPPED_WHITE = 0.9
"""``_darker_than_its_clipped_surroundings``: a white level below this share of full scale is not clipped."""
UNDER_EXPOSED_SHIFT = -0.05
"""... and a pair whose radius ratio puts its edges' exposure shift below this (units of R) reads under-exposed."""
CLIPPED_SURROUNDINGS = 0.75
"""... with its surroundings (``SURROUNDINGS_RADII`` of its outer radius) clipped in this share of the directions."""
SURROUNDINGS_RADII = (1.2, 1.3)


def _darker_than_its_clipped_surroundings(img: np.ndarray, H0: FloatArray, g: _Geometry, outer: Ellipse,
                                          inner: Ellipse, white: float, full: float, n: int) -> bool:
    """True for a pair that no target shows: its white unclipped and its ring thicker than the design's (the
    radius ratio of an under-exposed target, the black grown by more than ``-UNDER_EXPOSED_SHIFT`` R), while
    the ground just outside it is clipped all round. Ground clipped around a target means light enough to clip
    at this exposure; its own white paper, as bright or nearly, then clips or nearly, and over-exposure grows
    the white (the ratio rises); a paper darker than clipped ground (a target without a sheet against the sky)
    keeps its inner edge and loses its outer one inward (the ratio rises too). A dark fleck of foliage around a
    lighter spot in a frame clipped at x16 read as id 1's two dots at (1866, 619) of seed 9's single-004 (its
    "white" 2151 of 4095, the ratio 0.27 for 0.4: d = -0.10; the ground clipped all round)."""
    if white >= UNCLIPPED_WHITE * full:
        return False
    seen = 0.5 * (inner.a / outer.a + inner.b / outer.b)
    if (seen - g.ratio) / (1.0 + seen) >= UNDER_EXPOSED_SHIFT:
        return False
    angle = np.linspace(0.0, 2.0 * np.pi, 4 * n, endpoint=False)
    around = np.concatenate([sample_target(img, H0, np.full_like(angle, r), angle) for r in SURROUNDINGS_RADII])
    around = around[np.isfinite(around)]
    return around.size > 0 and np.count_nonzero(around >= 0.98 * full) >= CLIPPED_SURROUNDINGS * around.size


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


def _heading(H: list[list[float]]) -> float:
    """The image direction (radians) of the target's +x axis at its centre through ``H`` (3x3 nested lists): from
    the image of (0, 0) to that of (0.5, 0). ``apply_homography(H, [[0, 0], [0.5, 0]])`` in scalars: the same
    numbers (each coordinate there is one product with 0.5, exact, and one rounded sum, the zero terms adding
    nothing), without its four numpy calls (~12 us)."""
    (h00, _, h02), (h10, _, h12), (h20, _, h22) = H
    w = 0.5 * h20 + h22
    return float(math.atan2((0.5 * h10 + h12) / w - h12 / h22, (0.5 * h00 + h02) / w - h02 / h22))


@functools.lru_cache(maxsize=256)
def _code_pattern(g: _Geometry, hole: float) -> tuple[FloatArray, FloatArray, npt.NDArray[np.complex128]]:
    """The sample points of ``_read_code`` as target points (x, y) in units of R (read-only, cached), from their
    radii and angles as ``sample_target`` computes them: 4N angles on each of two circles in the black annulus
    (between the inner disk and the dots, between the dots and the outer edge), then on two circles in the white
    inner disk outside whatever may sit at its centre (``hole``), then 16N angles on the code circle; and
    exp(-i N angle) on the code circle (its N-th harmonic)."""
    n = g.slots
    t4 = np.linspace(0.0, 2.0 * np.pi, 4 * n, endpoint=False)
    r_black = np.array([0.5 * (g.ratio + g.ring - g.dot), 0.5 * (g.ring + g.dot + 1.0)])
    r_white = hole + (g.ratio - hole) * np.array([0.45, 0.75])
    m = 16 * n
    tm = np.linspace(0.0, 2.0 * np.pi, m, endpoint=False)
    radius = np.concatenate([np.repeat(r_black, t4.size), np.repeat(r_white, t4.size), np.full(m, g.ring)])
    angle = np.concatenate([t4, t4, t4, t4, tm])
    kernel = np.exp(-1j * n * tm)
    tx, ty = radius * np.cos(angle), radius * np.sin(angle)
    for a in (tx, ty, kernel):
        a.flags.writeable = False
    return tx, ty, kernel


def _shortlist(soft: FloatArray, entries: list[_Entry]) -> list[str]:
    """The two configured codes nearest to ``soft`` (N,) at their best rotation. ``codebook.decode`` on them
    gives the same winner, distance and margin as on all codes (the runner-up code is the only other code
    that can set the margin), at a fraction of the cost for a large book."""
    codes = sorted({e.spec.code.bits for e in entries if e.spec.code is not None and len(e.spec.code.bits)
                    == soft.size})
    if len(codes) <= 2:
        return codes
    bits, rotations = _shortlist_pattern(tuple(codes))
    rolled = soft[rotations]  # (N rotations, N)
    dist = np.abs(rolled[None, :, :] - bits[:, None, :]).sum(axis=2).min(axis=1)  # (C,)
    best = np.argsort(dist, kind="stable")[:2]
    return [codes[i] for i in sorted(best)]


@functools.lru_cache(maxsize=64)
def _shortlist_pattern(codes: tuple[str, ...]) -> tuple[FloatArray, npt.NDArray[np.int64]]:
    """For ``_shortlist`` (read-only, cached per code set): the codes' slots as floats (C, N), 1.0 for a dot, and
    the index (N, N) whose row k takes slots k, k + 1, ... (mod N) of a reading."""
    bits = np.array([[b == "1" for b in c] for c in codes], dtype=np.float64)
    n = len(codes[0])
    rotations = (np.arange(n)[None, :] + np.arange(n)[:, None]) % n
    for a in (bits, rotations):
        a.flags.writeable = False
    return bits, rotations
