"""The level choice's arithmetic on its samples, compiled (numba): ``levels._parent_verdict``'s reading of a parent
from its samples, and ``levels._parent_homography``'s search for the parent's white disk edge on its rays. Each
repeats the numpy computation it replaced (kept here as ``*_reference``) operation for operation, in the same
order and in float64, so the results are the same to the last bit: numpy's means of up to 128 values are its
pairwise sums (eight running sums from eight values up, a plain sum below), its medians the mean of the middle
one or two values. The numpy versions cost ~40 us per verdict and ~45 us per ray search in a few dozen small
array operations (a paper-lab search runs about two verdicts and one search per frame); these ~8 and ~6 us with
their calls (a ray's white values sorted in place as they come: ``np.sort`` per ray made it 19 us).
``tests/test_detect_levels.py`` holds each to its reference. Without numba the references run."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

try:  # numba is a dependency; without it (a broken install) the numpy references run
    import numba
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None

FloatArray = npt.NDArray[np.float64]

VERDICTS = ("unseen", "refuted", "ambiguous", "confirmed")
"""``verdict``'s results by index."""
PAIRWISE_MAX = 128
"""Largest count whose mean the compiled verdict sums as numpy does (one block of its pairwise sum); more slots
than this go to the reference."""


# ---------------------------------------------------------------------- the parent's verdict
def verdict_reference(vals: FloatArray, slot_vals: FloatArray, gaps: FloatArray, ref: FloatArray,
                      rotation: int | None, black: float, contrast: float, min_contrast: float) -> str:
    """``levels._parent_verdict`` from its samples: ``vals`` (3, N) on the parent's inner and outer dark bands
    and its white disk at the N slot angles, ``slot_vals`` (N,) the slots' brightest values, ``gaps`` (N,) the
    values between slots, ``ref`` (N,) the parent's code (1.0 for a dot), ``rotation`` (slots) or None for any;
    the pair's ``black`` and ``contrast``; ``min_contrast`` is ``levels.PARENT_MIN_CONTRAST``."""
    n = slot_vals.size
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
    # A parent printed with the pair has the pair's contrast where it is readable (a gradient or clipping lowers
    # some slots, not most): text at reflectance 0.85 around a 18 px target read as its parent's code on 4 of 8
    # slots at 0.43-0.57 of the pair's contrast, and the target came out as its own nested level (-80 %).
    strong = bool(readable.any()) and float(np.median(local_contrast[readable])) >= min_contrast * contrast
    contradicted = True
    # The outer band bright where the inner one is dark: something bright across the ring from outside (a bloom
    # streak, glare, an object in front), or a dot grown into that band. Streaks across the top of a 42 px
    # target's parent ring read as two dots where it has none, the parent was refuted and the nested level came
    # out as the outer one (5x the distance). Such blank slots left unread, a reading may still confirm, with
    # ``EXCUSED_MIN_DOTS`` dots and ``EXCUSED_MIN_SLOTS`` slots read (a two-dot code around a small pair in a
    # clipped frame confirmed from one dot and three slots so: -80 %); it never refutes.
    with np.errstate(invalid="ignore"):
        outer_bright = (vals[1] - local_black) >= 0.5 * local_contrast
        inner_bright = (vals[0] - local_black) >= 0.5 * local_contrast
    # (only around a parent-like ring: its white disk white at every angle, its inner band dark at every slot
    # read: checkered ground around a 19 px target confirmed a parent so, -80 %)
    ringed = bool(np.all((vals[2][np.isfinite(vals[2])] - black) >= 0.6 * contrast))
    for r in range(n) if rotation is None else [rotation]:
        bits = np.roll(ref, r)
        against, reads, dots_seen, _ = _reading(s, g, gap_ok, readable, bits, strong)
        # A dot of the parent missing, or white where it has none. One is forgiven among 4 or more readable slots:
        # the pair's homography, extrapolated 3-5 radii out from a small or tilted pair, can put a slot's samples
        # beside its dot.
        if against <= (1 if int(readable.sum()) >= 4 else 0):
            # A forgiven contradiction confirms only with two dots seen besides it: a 61 px target on a sheet at
            # the top of the frame, its parent's ring mostly outside, had one slot on the sheet's corner read as a
            # dot and one dot missed, and came out as its own nested level (-80 %). Otherwise ambiguous.
            if reads and (against == 0 or dots_seen >= FORGIVEN_MIN_DOTS):
                return "confirmed"
            contradicted = contradicted and against > 0 and not reads  # a forgiven contradiction stands when
            # the rest reads poorly
        use = readable & ~((bits < 0.5) & outer_bright & (s > 0.75))
        if (use != readable).any() and ringed and not (use & inner_bright).any():
            against, reads, dots_seen, seen = _reading(s, g, gap_ok, use, bits, strong)
            if against <= 1 and reads and dots_seen >= EXCUSED_MIN_DOTS and seen >= EXCUSED_MIN_SLOTS:
                return "confirmed"
    return "refuted" if contradicted else "ambiguous"


def _reading(s: FloatArray, g: FloatArray, gap_ok: npt.NDArray[np.bool_], use: npt.NDArray[np.bool_],
             bits: FloatArray, strong: bool) -> tuple[int, bool, int, int]:
    """For ``verdict_reference``: one rotation's reading of the slots ``use``: (contradictions, whether the rest
    reads as the code, dots seen, slots read)."""
    seen = int(use.sum())
    ones, zeros = use & (bits > 0.5), use & (bits < 0.5)
    against = (int(np.count_nonzero(s[ones] < 0.5)) + int(np.count_nonzero(s[zeros] > 0.75))
               + int(np.count_nonzero(g[gap_ok] > 0.75)))
    error = float(np.mean(np.abs(np.clip(s[use], 0.0, 1.0) - bits[use]))) if seen else 1.0
    dots_seen = int(np.count_nonzero(s[ones] >= 0.5))  # a code of one dot read as all dark must not confirm
    reads = (dots_seen >= max(1, (int(ones.sum()) + 1) // 2) and bool(zeros.any()) and seen >= 3 and error < 0.25
             and strong)
    return against, reads, dots_seen, seen


FORGIVEN_MIN_DOTS = 2
"""``verdict``: a parent whose reading has one forgiven contradiction is confirmed only with this many dots seen."""
EXCUSED_MIN_DOTS = 2
EXCUSED_MIN_SLOTS = 4
"""``verdict``: a parent read without the blank slots under something bright from outside is confirmed only with
this many dots seen and slots read (one contradiction forgiven, as in the full reading)."""


def verdict(vals: FloatArray, slot_vals: FloatArray, gaps: FloatArray, ref: FloatArray, rotation: int | None,
            black: float, contrast: float, min_contrast: float) -> str:
    """``verdict_reference``, compiled when numba is there and the code has at most ``PAIRWISE_MAX`` slots."""
    if numba is None or slot_vals.size > PAIRWISE_MAX:
        return verdict_reference(vals, slot_vals, gaps, ref, rotation, black, contrast, min_contrast)
    return VERDICTS[_verdict(vals, slot_vals, gaps, ref, -1 if rotation is None else int(rotation), float(black),
                             float(contrast), float(min_contrast))]


# ---------------------------------------------------------------------- the parent's white disk edge
def disk_edges_reference(vals: FloatArray, r: FloatArray, white_cols: int, far: npt.NDArray[np.bool_],
                         black: float) -> tuple[npt.NDArray[np.intp], FloatArray]:
    """``levels._parent_homography``'s edge search on its rays: ``vals`` (rays, radii) sampled at the radii ``r``
    (increasing, evenly spaced); each ray's white is the median of its finite values on the first ``white_cols``
    radii, its edge the first radius where ``far`` holds (a mask over ``r``) with a value under half-way from that
    white to ``black``, interpolated from the radius before. Returns the rays with an edge (not on the first
    radius, a finite white above ``black``) and the edge's radius on each."""
    white = _row_nanmedian(vals[:, :white_cols])
    level = black + 0.5 * (white - black)
    below = (vals < level[:, None]) & far[None, :]
    first = np.argmax(below, axis=1)
    found = below.any(axis=1) & (first > 0) & np.isfinite(white) & (white > black)
    rows = np.flatnonzero(found)
    j = first[rows]
    v0, v1 = vals[rows, j - 1], vals[rows, j]
    frac = np.clip((v0 - level[rows]) / np.maximum(v0 - v1, 1e-12), 0.0, 1.0)
    return rows, r[j - 1] + frac * (r[1] - r[0])


def disk_edges(vals: FloatArray, r: FloatArray, white_cols: int, far: npt.NDArray[np.bool_],
               black: float) -> tuple[npt.NDArray[np.intp], FloatArray]:
    """``disk_edges_reference``, compiled when numba is there."""
    if numba is None:
        return disk_edges_reference(vals, r, white_cols, far, black)
    rows, rho, count = _disk_edges(vals, r, white_cols, far, float(black))
    return rows[:count], rho[:count]


def _row_nanmedian(values: FloatArray) -> FloatArray:
    """``np.nanmedian(values, axis=1)`` of a (rows, k) array, bit for bit (the mean of the two middle finite values
    of each row's sort, NaN for a row without one), without its warnings and ~8x faster on the few dozen rows used
    here (its masked-array path costs ~0.1 ms)."""
    ordered = np.sort(values, axis=1)  # NaN sorts last
    count = np.count_nonzero(~np.isnan(values), axis=1)
    rows = np.arange(values.shape[0])
    high = np.minimum(count // 2, values.shape[1] - 1)
    low = np.maximum(np.where(count % 2 == 1, high, count // 2 - 1), 0)
    median = (ordered[rows, low] + ordered[rows, high]) / 2.0
    median[count == 0] = np.nan
    return median


if numba is not None:

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def _mean_of(values, count):  # pragma: no cover - compiled
        """numpy's mean of ``values[:count]`` (float64, count <= 128): its pairwise sum's one block (eight running
        sums from eight values on, combined as a tree, then the rest in order; a plain sum from 0.0 below
        eight), over the count."""
        if count < 8:
            total = 0.0
            for i in range(count):
                total += values[i]
            return total / count
        r0, r1, r2, r3 = values[0], values[1], values[2], values[3]
        r4, r5, r6, r7 = values[4], values[5], values[6], values[7]
        i = 8
        while i < count - count % 8:
            r0 += values[i]
            r1 += values[i + 1]
            r2 += values[i + 2]
            r3 += values[i + 3]
            r4 += values[i + 4]
            r5 += values[i + 5]
            r6 += values[i + 6]
            r7 += values[i + 7]
            i += 8
        total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < count:
            total += values[i]
            i += 1
        return total / count

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def _verdict(vals, slot_vals, gaps, ref, rotation, black, contrast, min_contrast):  # pragma: no cover
        """``verdict_reference``'s index in ``VERDICTS`` (``rotation`` -1 for any)."""
        n = slot_vals.size
        local_black = np.empty(n)
        local_contrast = np.empty(n)
        finite = np.zeros(n, np.bool_)
        n_finite = 0
        for j in range(n):
            a, b = vals[0, j], vals[1, j]
            if np.isfinite(a) and np.isfinite(b):
                local_black[j] = a if a <= b else b
            else:
                local_black[j] = np.nan
            local_contrast[j] = vals[2, j] - local_black[j]
            finite[j] = np.isfinite(local_contrast[j]) and np.isfinite(slot_vals[j])
            n_finite += finite[j]
        if n_finite < max(3, n // 2):
            return 0
        white_count, white_seen, dark_count = 0, 0, 0
        for j in range(n):
            if np.isfinite(vals[2, j]):
                white_seen += 1
                white_count += (vals[2, j] - black) >= 0.6 * contrast
            if finite[j]:
                dark_count += local_contrast[j] >= 0.33 * contrast
        if not (white_count / white_seen >= 0.75 and dark_count / n_finite >= 0.5):
            return 1
        readable = np.zeros(n, np.bool_)
        s = np.empty(n)
        g = np.empty(n)
        kept = np.empty(n)  # the readable slots' contrasts, then their errors
        seen = 0
        for j in range(n):
            readable[j] = finite[j] and local_contrast[j] >= 0.33 * contrast
            s[j] = (slot_vals[j] - local_black[j]) / local_contrast[j]
            g[j] = (gaps[j] - local_black[j]) / local_contrast[j]
            if readable[j]:
                kept[seen] = local_contrast[j]
                seen += 1
        strong = False
        if seen > 0:
            ordered = np.sort(kept[:seen])
            half = seen // 2
            median = ordered[half] if seen % 2 == 1 else (ordered[half - 1] + ordered[half]) / 2.0
            strong = median >= min_contrast * contrast
        gap_against = 0
        for j in range(n):
            if np.isfinite(g[j]) and readable[j] and readable[(j + 1) % n] and g[j] > 0.75:
                gap_against += 1
        outer_bright = np.zeros(n, np.bool_)
        inner_bright = np.zeros(n, np.bool_)
        ringed = True
        for j in range(n):  # NaN compares False, as numpy's
            outer_bright[j] = (vals[1, j] - local_black[j]) >= 0.5 * local_contrast[j]
            inner_bright[j] = (vals[0, j] - local_black[j]) >= 0.5 * local_contrast[j]
            if np.isfinite(vals[2, j]) and not (vals[2, j] - black) >= 0.6 * contrast:
                ringed = False
        use = np.zeros(n, np.bool_)
        n_readable = 0
        for j in range(n):
            n_readable += readable[j]
        contradicted = True
        first, last = (0, n) if rotation < 0 else (rotation, rotation + 1)
        for r in range(first, last):
            against, reads, dots_seen, seen = _reading_c(s, readable, ref, r, gap_against, strong, kept)
            if against <= (1 if n_readable >= 4 else 0):
                if reads and (against == 0 or dots_seen >= FORGIVEN_MIN_DOTS):
                    return 3
                contradicted = contradicted and against > 0 and not reads
            excused, inner_lit = False, False
            for j in range(n):
                use[j] = readable[j] and not (ref[(j - r) % n] < 0.5 and outer_bright[j] and s[j] > 0.75)
                excused = excused or (readable[j] and not use[j])
                inner_lit = inner_lit or (use[j] and inner_bright[j])
            if excused and ringed and not inner_lit:
                against, reads, dots_seen, seen = _reading_c(s, use, ref, r, gap_against, strong, kept)
                if against <= 1 and reads and dots_seen >= EXCUSED_MIN_DOTS and seen >= EXCUSED_MIN_SLOTS:
                    return 3
        return 1 if contradicted else 2

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def _reading_c(s, use, ref, r, gap_against, strong, kept):  # pragma: no cover - compiled
        """``_reading`` of rotation ``r`` (``kept``: scratch of N values)."""
        n = s.size
        against, ones, dots_seen, any_zero, seen = gap_against, 0, 0, False, 0
        for j in range(n):
            if not use[j]:
                continue
            seen += 1
            bit = ref[(j - r) % n]  # np.roll(ref, r)[j]
            if bit > 0.5:
                ones += 1
                against += s[j] < 0.5
                dots_seen += s[j] >= 0.5
            elif bit < 0.5:
                any_zero = True
                against += s[j] > 0.75
        m = 0
        for j in range(n):
            if use[j]:
                v = s[j]
                v = 0.0 if v < 0.0 else (1.0 if v > 1.0 else v)
                kept[m] = abs(v - ref[(j - r) % n])
                m += 1
        error = _mean_of(kept, m) if m else 1.0
        reads = dots_seen >= max(1, (ones + 1) // 2) and any_zero and seen >= 3 and error < 0.25 and strong
        return against, reads, dots_seen, seen

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def _disk_edges(vals, r, white_cols, far, black):  # pragma: no cover - compiled
        """``disk_edges_reference``: the rays with an edge and their radii in the first ``count`` entries."""
        n_rays, n_r = vals.shape
        rows = np.empty(n_rays, np.intp)
        rho = np.empty(n_rays)
        buffer = np.empty(max(white_cols, 1))
        step = r[1] - r[0]
        count = 0
        for i in range(n_rays):
            k = 0
            for c in range(white_cols):  # the finite values, sorted as they come (a few per ray)
                v = vals[i, c]
                if not np.isnan(v):
                    m = k
                    while m > 0 and buffer[m - 1] > v:
                        buffer[m] = buffer[m - 1]
                        m -= 1
                    buffer[m] = v
                    k += 1
            if k == 0:
                continue  # no white: np.isfinite(white) fails
            ordered = buffer
            high = min(k // 2, white_cols - 1)
            low = max(high if k % 2 == 1 else k // 2 - 1, 0)
            white = (ordered[low] + ordered[high]) / 2.0
            if not (np.isfinite(white) and white > black):
                continue
            level = black + 0.5 * (white - black)
            j = -1
            for c in range(n_r):
                if vals[i, c] < level and far[c]:
                    j = c
                    break
            if j <= 0:
                continue
            v0, v1 = vals[i, j - 1], vals[i, j]
            d = v0 - v1
            d = d if (d >= 1e-12 or np.isnan(d)) else 1e-12  # np.maximum(d, 1e-12): NaN stays
            frac = (v0 - level) / d
            if not np.isnan(frac):
                frac = 0.0 if frac < 0.0 else (1.0 if frac > 1.0 else frac)
            rows[count] = i
            rho[count] = r[j - 1] + frac * step
            count += 1
        return rows, rho, count
