"""Where a frame's pixels clip, read off the frame: a sensor whose full well (or whose ADC gain) stops below the top
code clips there, not at ``2^bits - 1``.

The estimator takes a sample as clipped when it lies within the clip margin of the camera's saturation level
(``Tracker._clip_level``), and the detector's coarse stage runs its over-exposure passes only in frames with pixels
at that level. A camera whose pixels saturate at 90 % of the top code (a full well read below full scale, a gain
that maps it there, a renderer that clips at its own white) gives neither: its clipped white reads as a plain white
level to the edge model, whose blurred-step fit is then biased outward, and a small over-exposed target whose ring
the clipped white cut through was missed (seed 0's single-000 at x32, full well at 0.9 of the top code: lost; at x8
and x16 the distance 0.006-0.009 % off against 0.0003 %).

:func:`frame_saturation_dn` finds such a clip from the frame's own values: the largest value of a row-subsampled
frame is a clip when

- at least ``MIN_CLIPPED_SAMPLES`` samples hold exactly that value (a clipped patch; the brightest pixels of an
  unclipped frame are the tail of its noise, a few samples),
- they outnumber ``SPIKE_RATIO`` times the samples within ``NEAR_FRACTION`` of it below (a clip piles values up at
  one code; noise spreads an unclipped white over many), and
- the frame is noisy: of the pairs of neighbouring samples strictly between its least and largest values, at most
  ``MAX_EQUAL_SHARE`` are equal (a noiseless render's flat white is also one code over many pixels: without noise
  nothing tells it from a clip, and it is left at the camera's level).

A frame whose largest value lies within the clip margin of the camera's level keeps that level (the usual case,
decided by the first pass alone). Pure: no state, no I/O; the tracker calls it once per frame
(``Tracker.process``). ``frame_saturation_dn_reference`` is the numpy version of the compiled pass
(``tests/test_clip_level.py`` holds them together)."""

from __future__ import annotations

import math

import numpy as np

try:  # numba is a dependency; without it (a broken install) numpy runs
    import numba
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None

ROW_STEP = 8
"""Rows sampled: one in this many (every column of each). A 1920x1200 frame: 150 rows, ~0.03 ms for a frame whose
largest value is the camera's, ~0.25 ms compiled for one below it (both passes)."""
PEAK_FRACTION = 0.01
"""The clip's peak: the samples within this fraction of the largest value (at least 2 codes) below it. Pixels
clipped by their well still carry the read noise added after it (a 12-bit camera, 5 e read noise: +-2 codes about
the clip), so a clip is a narrow peak, not always one code."""
MIN_CLIPPED_SAMPLES = 16
"""Least samples in the peak for it to be a clip (with ``ROW_STEP`` 8: ~128 pixels of the frame)."""
SPIKE_RATIO = 2.0
"""The peak's samples must be at least this many times those in the two peak widths below it: a clip piles values
up there; the brightest values of an unclipped white are its noise's tail, thinning towards the largest."""
MAX_EQUAL_SHARE = 0.6
"""Most share of equal neighbouring samples (both strictly between the frame's least value and the peak) of a noisy
frame: noise of sigma 0.5 codes leaves ~0.5 of such pairs equal, a noiseless render's flat regions ~1."""
MIN_PAIRS = 100
"""Least neighbouring pairs for the noise test; with fewer (a frame of two values, all clipped or black) nothing
shows noise, and no clip is read."""


def frame_saturation_dn(image: np.ndarray, saturation_dn: float, margin_dn: float, row_step: int = ROW_STEP
                        ) -> float:
    """The level (image units) at which ``image`` (H, W; uint8 or uint16 compiled, other integer types in numpy, a
    float image never) clips: its largest value where the module's tests say the values piled up just under it are a
    clip below the camera's ``saturation_dn`` less ``margin_dn``, else ``saturation_dn``. (The estimator takes
    samples within its clip margin of this level as clipped: the peak's width, ``PEAK_FRACTION`` of it, lies within
    the default margin, 1 % of the camera's level.)
    ``row_step``: one row in this many is read (a target's small box: every row, 1)."""
    if image.dtype.kind not in "ui":  # float frames (values as given, NaN and all): no code to pile up at
        return float(saturation_dn)
    if image.ndim != 2 or image.size == 0 or image.dtype not in (np.uint8, np.uint16) or numba is None:
        return frame_saturation_dn_reference(image, saturation_dn, margin_dn, row_step)
    least, top = _subsampled_range(image, row_step)
    if top >= saturation_dn - margin_dn:
        return float(saturation_dn)
    peak_lo, below_lo = _bands(float(top))
    counts = _top_counts(image, row_step, least, peak_lo, below_lo)
    return float(top) if _is_clip(*counts) else float(saturation_dn)


def _bands(top: float) -> tuple[int, int]:
    """The lowest values (integers) of the peak band and of the band below it."""
    width = max(PEAK_FRACTION * top, 2.0)
    return math.ceil(top - width), math.ceil(top - 3.0 * width)


def _is_clip(peak: int, below: int, pairs: int, equal: int) -> bool:
    noisy = pairs >= MIN_PAIRS and equal <= MAX_EQUAL_SHARE * pairs
    return peak >= MIN_CLIPPED_SAMPLES and peak >= SPIKE_RATIO * below and noisy


def frame_saturation_dn_reference(image: np.ndarray, saturation_dn: float, margin_dn: float,
                                  row_step: int = ROW_STEP) -> float:
    """:func:`frame_saturation_dn` in numpy (any integer dtype; a float image keeps ``saturation_dn``)."""
    rows = np.asarray(image)[::row_step]
    if rows.size == 0 or rows.dtype.kind not in "ui":
        return float(saturation_dn)
    top = rows.max()
    if top >= saturation_dn - margin_dn:
        return float(saturation_dn)
    least = rows.min()
    peak_lo, below_lo = _bands(float(top))
    values = rows.astype(np.float64)
    peak = int(np.count_nonzero(values >= peak_lo))
    below = int(np.count_nonzero((values < peak_lo) & (values >= below_lo)))
    a, b = values[:, :-1], values[:, 1:]
    inside = (a > least) & (a < peak_lo) & (b > least) & (b < peak_lo)
    pairs = int(np.count_nonzero(inside))
    equal = int(np.count_nonzero(inside & (a == b)))
    return float(top) if _is_clip(peak, below, pairs, equal) else float(saturation_dn)


if numba is not None:

    @numba.njit(cache=True, nogil=True)
    def _subsampled_range(image, step):  # pragma: no cover - compiled
        """(least, largest) value of rows 0, step, 2 step, ... of ``image``."""
        least = top = image[0, 0]
        for i in range(0, image.shape[0], step):
            row = image[i]
            for j in range(image.shape[1]):
                least = min(least, row[j])
                top = max(top, row[j])
        return least, top

    @numba.njit(cache=True, nogil=True)
    def _top_counts(image, step, least, peak_lo, below_lo):  # pragma: no cover - compiled
        """Over rows 0, step, ...: (samples at ``peak_lo`` and up, samples in [below_lo, peak_lo), neighbouring pairs
        with both samples strictly between ``least`` and ``peak_lo``, and how many of those are equal)."""
        peak = 0
        below = 0
        pairs = 0
        equal = 0
        for i in range(0, image.shape[0], step):
            row = image[i]
            for j in range(image.shape[1]):
                v = row[j]
                if v >= peak_lo:
                    peak += 1
                elif v >= below_lo:
                    below += 1
            for j in range(image.shape[1] - 1):
                v = row[j]
                w = row[j + 1]
                if least < v < peak_lo and least < w < peak_lo:
                    pairs += 1
                    if v == w:
                        equal += 1
        return peak, below, pairs, equal
