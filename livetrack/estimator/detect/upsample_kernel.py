"""The full-resolution end of the local threshold in one compiled pass: a threshold image computed on the pyramid
level two steps down, upsampled 4x by bilinear interpolation and compared with the image, without writing the
upsampled threshold out (``cv2.resize`` then ``cv2.compare`` cost ~0.8 ms per 1920x1200 frame on one core, this
~0.35 ms; 0.6 before its horizontal pass ran in packed 64-bit words, ``_columns_4x``).

The upsampling repeats the arithmetic of OpenCV's ``resize(..., INTER_LINEAR)`` for 8-bit images (its SIMD
path), so the binary image is bit for bit the same: coefficients in 11-bit fixed point (for an exact 4x scale
they are 7/8, 5/8, 3/8 and 1/8 of 2048, every column clamped at the borders, rows not), a horizontal pass into
integers, then per output pixel ``((((D0 >> 4) * b0) >> 16) + (((D1 >> 4) * b1) >> 16) + 2) >> 2``.
``tests/test_detect_equivalents.py`` holds it to ``cv2.resize`` + ``cv2.compare``. Only exact 4x scales take
this path (``is_exact_4x``); others, and installs without numba, go through OpenCV."""

from __future__ import annotations

import functools

import cv2
import numpy as np
import numpy.typing as npt

try:  # numba is a dependency; without it (a broken install) OpenCV runs
    import numba
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None

IntArray = npt.NDArray[np.int32]
_NO_SCRATCH = np.empty(0, np.uint16)


def is_exact_4x(coarse_shape: tuple[int, ...], shape: tuple[int, ...]) -> bool:
    """True when ``shape`` is exactly 4x ``coarse_shape`` in both directions (the compiled path applies)."""
    return numba is not None and shape[0] == 4 * coarse_shape[0] and shape[1] == 4 * coarse_shape[1]


@functools.lru_cache(maxsize=32)
def _row_taps(n_coarse: int) -> tuple[IntArray, IntArray, npt.NDArray[np.uint16], npt.NDArray[np.uint16]]:
    """For each of the 4 n_coarse output rows: the two coarse rows (clamped to the image) and their weights in
    eighths (OpenCV's 11-bit weights over 256; rows beyond the outer coarse centres keep their fractional weights
    on the clamped rows, as OpenCV's do). Read-only, cached."""
    f = (np.arange(4 * n_coarse) + 0.5) * 0.25 - 0.5  # exact in binary
    first = np.floor(f).astype(np.int64)
    w1 = np.rint((f - first) * 8.0).astype(np.uint16)
    taps = (np.clip(first, 0, n_coarse - 1).astype(np.int32), np.clip(first + 1, 0, n_coarse - 1).astype(np.int32),
            (8 - w1).astype(np.uint16), w1)
    for a in taps:
        a.flags.writeable = False
    return taps


if numba is not None:
    from livetrack.estimator.detect.blur_kernel import blur_row

    @numba.njit(cache=True, nogil=True)
    def _columns_4x(coarse_row, words):  # pragma: no cover - compiled
        """OpenCV's horizontal pass of one coarse row, over 256 (in eighths: columns beyond the outer coarse
        centres take the border value, 8 eighths), into ``words`` (w + 1 uint64) whose uint16 view from its
        third element on is the pass. The four outputs between coarse columns j and j + 1
        (7, 5, 3 and 1 eighths of c0, the rest of c1) are one word, ``c0 * 0x0001_0003_0005_0007 + c1 *
        0x0007_0005_0003_0001``: each 16-bit field stays under 8 x 255, so no carry crosses into the next, and
        the loop runs in vector lanes (interleaved 16-bit stores did not: ~4x the time)."""
        w = coarse_row.size
        k0, k1 = np.uint64(0x0001_0003_0005_0007), np.uint64(0x0007_0005_0003_0001)
        a, b, out = coarse_row[: w - 1], coarse_row[1:], words[1:w]
        for j in range(out.size):
            out[j] = np.uint64(a[j]) * k0 + np.uint64(b[j]) * k1
        first, last = np.uint64(8) * np.uint64(coarse_row[0]), np.uint64(8) * np.uint64(coarse_row[w - 1])
        # outputs 0 and 1: the upper half of word 0; outputs 4w - 2 and 4w - 1: the lower half of word w
        words[0] = (first << np.uint64(32)) | (first << np.uint64(48))
        words[w] = last | (last << np.uint64(16))

    @numba.njit(cache=True, nogil=True)
    def _dark_row(row0, row1, m0, m1, img_row, out, start, stop):  # pragma: no cover - compiled
        """Columns ``start:stop`` of one output row: OpenCV's vertical pass in 16-bit lanes (its ``(x * b) >> 16``
        on the pass's values over 16, i.e. ``(k * m) >> 4`` on ours over 256), its rounding shift, and the
        comparison. Returns the OR of the pixels written (non-zero when one is dark)."""
        four, two = np.uint16(4), np.uint16(2)
        seen = np.uint8(0)
        # over slices from 0: an index from ``range(start, stop)`` may be negative to numba, whose wrap-around
        # test then keeps the loop from vectorising (~10x slower)
        r0, r1, img, dark = row0[start:stop], row1[start:stop], img_row[start:stop], out[start:stop]
        for x in range(dark.size):
            t = np.uint16(np.uint16(np.uint16(r0[x] * m0) >> four) + np.uint16(np.uint16(r1[x] * m1) >> four)
                          + two) >> two
            v = np.uint8(255) if np.uint16(img[x]) <= t else np.uint8(0)
            dark[x] = v
            seen = np.uint8(seen | v)
        return seen

    @numba.njit(cache=True, nogil=True)
    def _any(row, start, stop):  # pragma: no cover - compiled
        """The OR of ``row[start:stop]`` (0 for an empty span), vectorised (a loop over a slice from 0)."""
        seen = np.uint8(0)
        span = row[start:stop]
        for x in range(span.size):
            seen = np.uint8(seen | span[x])
        return seen

    @numba.njit(cache=True, nogil=True)
    def _fill_slot(coarse, words, held, slot, want):  # pragma: no cover - compiled
        """Makes slot ``slot`` of ``words`` hold coarse row ``want``'s horizontal pass (``_columns_4x``), unless
        it holds it already (``held``: the row each slot holds, updated)."""
        if held[slot] != want:
            _columns_4x(coarse[want], words[slot])
            held[slot] = want

    @numba.njit(cache=True, nogil=True)
    def _dark_by_upsampled_threshold(img8, coarse, yi0, yi1, ym0, ym1, out, words, blur_src, side, centre,
                                     v, blurred_step):  # pragma: no cover
        """Fills ``out``; with ``centre`` > 0, first each row of ``img8`` as the 3x3 blur of ``blur_src`` with
        taps (``side``, ``centre``, ``side``) / 256 (``blur_kernel.blur_row``; ``v`` its (W,) uint16 scratch), the
        row then compared while it is in cache (but for rows 0, ``blurred_step``, 2 ``blurred_step``, ... when
        ``blurred_step`` > 0: blurred already). Returns the bounding box (x0, y0, x1, y1; exclusive ends) of its
        non-zero pixels, (0, 0, 0, 0) when there are none. ``words`` (2, w + 1) uint64 hold two coarse rows'
        horizontal passes (each row's uint16 view from its third element on: ``_columns_4x``); a row held in either
        slot is not computed again (the slots swap roles). Each row's comparison ORs its pixels (no branch per
        pixel); a row with a dark pixel ORs the spans left and right of the box found so far, and only a span that
        widens the box is searched for its outermost dark pixel. ~0.1 ms per 1920x1200 image (``cv2.boundingRect``
        ~0.17)."""
        held = np.full(2, -1, np.int64)  # the coarse rows whose horizontal pass slots 0 and 1 hold
        w = out.shape[1]
        bx0, by0, bx1, by1 = w, -1, 0, -1
        for y in range(out.shape[0]):
            want0, want1 = yi0[y], yi1[y]
            s0 = 0 if held[0] == want0 else (1 if held[1] == want0 else (1 if held[0] == want1 else 0))
            _fill_slot(coarse, words, held, s0, want0)
            _fill_slot(coarse, words, held, 1 - s0, want1)
            r0, r1 = words[s0].view(np.uint16)[2 : 2 + w], words[1 - s0].view(np.uint16)[2 : 2 + w]
            row = out[y]
            if centre and (blurred_step <= 0 or y % blurred_step):
                blur_row(blur_src, y, img8[y], side, centre, v)
            if _dark_row(r0, r1, ym0[y], ym1[y], img8[y], row, 0, w):
                if by0 < 0:
                    by0 = y
                by1 = y
                if _any(row, 0, bx0):  # a dark pixel left of the box found so far
                    for x in range(bx0):
                        if row[x]:
                            bx0 = x
                            break
                if _any(row, bx1, w):  # right of it
                    for x in range(w - 1, max(bx1, bx0) - 1, -1):
                        if row[x]:
                            bx1 = x + 1
                            break
        if by0 < 0:
            return 0, 0, 0, 0
        return bx0, by0, bx1, by1 + 1


def dark_by_upsampled_threshold(img8: npt.NDArray[np.uint8], coarse_threshold: npt.NDArray[np.uint8],
                                out: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """``out`` = 255 where ``img8`` (H, W) is at or below ``coarse_threshold`` (h, w) upsampled to (H, W) by
    ``cv2.resize(..., INTER_LINEAR)``, else 0; compiled when the scale is exactly 4x (``is_exact_4x``). ``out``
    (H, W) uint8 must not share memory with ``img8``."""
    if not is_exact_4x(coarse_threshold.shape, out.shape):
        cv2.resize(coarse_threshold, out.shape[::-1], dst=out, interpolation=cv2.INTER_LINEAR)
        return cv2.compare(img8, out, cv2.CMP_LE, dst=out)
    return dark_and_box(img8, coarse_threshold, out)[0]


def dark_and_box(img8: npt.NDArray[np.uint8], coarse_threshold: npt.NDArray[np.uint8],
                 out: npt.NDArray[np.uint8], blur: tuple[npt.NDArray[np.uint8], int, int] | None = None,
                 blurred_step: int = 0) -> tuple[npt.NDArray[np.uint8], tuple[int, int, int, int]]:
    """``dark_by_upsampled_threshold`` and the bounding box (x0, y0, x1, y1; exclusive ends) of the dark pixels,
    (0, 0, 0, 0) when there are none: the box ``cv2.boundingRect`` gives (~0.17 ms per 1920x1200 image), found by
    the compiled pass on the way.

    blur: (src, side, centre): ``img8`` (C-contiguous, not sharing memory with ``src``) is first filled with the
        3x3 blur of ``src`` (the same shape) by the taps (side, centre, side) / 256, row by row inside the pass
        (``blur_kernel``: ``kernel_taps`` must have given them); only where the scale is exactly 4x
        (``is_exact_4x``), which the caller checks. Default None (``img8`` is read as it is).
    blurred_step: with ``blur``, > 0 when rows 0, blurred_step, 2 blurred_step, ... of ``img8`` hold their blur
        already (``blur_kernel.blur_rows``): they are not blurred again. Default 0."""
    h, w = out.shape
    if not is_exact_4x(coarse_threshold.shape, out.shape):
        if blur is not None:
            raise ValueError("the fused blur needs an exact 4x scale")
        cv2.resize(coarse_threshold, (w, h), dst=out, interpolation=cv2.INTER_LINEAR)
        cv2.compare(img8, out, cv2.CMP_LE, dst=out)
        return out, box_of(out)
    yi0, yi1, ym0, ym1 = _row_taps(coarse_threshold.shape[0])
    words = np.empty((2, coarse_threshold.shape[1] + 1), np.uint64)
    if blur is None:
        src, side, centre, v = img8, 0, 0, _NO_SCRATCH
    else:
        (src, side, centre), v = blur, np.empty(w, np.uint16)
    box = _dark_by_upsampled_threshold(img8, coarse_threshold, yi0, yi1, ym0, ym1, out, words, src,
                                       np.uint16(side), np.uint16(centre), v, blurred_step if blur is not None else 0)
    return out, (int(box[0]), int(box[1]), int(box[2]), int(box[3]))


def box_of(binary: npt.NDArray[np.uint8]) -> tuple[int, int, int, int]:
    """The bounding box (x0, y0, x1, y1; exclusive ends) of the non-zero pixels of ``binary``, (0, 0, 0, 0) when
    there are none (``cv2.boundingRect``'s, as corners)."""
    x, y, bw, bh = cv2.boundingRect(binary)
    return (x, y, x + bw, y + bh) if bw else (0, 0, 0, 0)
