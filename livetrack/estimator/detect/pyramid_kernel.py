"""The detector's first pyramid level computed inside the 16-to-8-bit table look-up (``threshold._normalise_top``):
each 8-bit row is halved while it is in cache, instead of ``cv2.pyrDown`` reading the whole 8-bit image back
(the look-up then ``cv2.pyrDown`` 1.70-1.87 ms per fresh 1920x1200 frame on one core, the fused pass 1.54-1.60;
inside a detection ~0.16 ms saved: the README's speed section, session 14).

``pyr_down_row`` repeats OpenCV's ``pyrDown`` for 8-bit images: the 5x5 kernel [1 4 6 4 1]^T [1 4 6 4 1] / 256
in integers (every sum under 2^16), one rounding shift ``(s + 128) >> 8``, ``BORDER_REFLECT_101`` on every edge,
odd sizes included. ``tests/test_detect_pyramid.py`` holds it to ``cv2.pyrDown`` and the fused pass to
``lut_kernel.lut16`` + ``cv2.pyrDown``."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

try:  # numba is a dependency; without it (a broken install) numpy indexing and OpenCV run
    import numba
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None


def lut16_halved(src: npt.NDArray[np.uint16], table: npt.NDArray[np.uint8], dst: npt.NDArray[np.uint8],
                 half: npt.NDArray[np.uint8]) -> int:
    """``lut_kernel.lut16(src, table, dst)`` (its return value: the largest value of ``src``) and ``half`` =
    ``cv2.pyrDown(dst)`` ((H + 1) // 2, (W + 1) // 2), in one pass; H and W >= 3, ``dst`` and ``half``
    C-contiguous. Needs numba (``numba is not None``)."""
    h, w = dst.shape
    scratch = np.empty((w + 6) // 2 + 1, np.uint32)
    return int(_lut16_halved(src, table, dst, half, scratch.view(np.uint16), scratch))


def pyr_down(src: npt.NDArray[np.uint8], out: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """``cv2.pyrDown(src)`` into ``out`` (H and W >= 3), row by row from Python (for the tests)."""
    scratch = np.empty((src.shape[1] + 6) // 2 + 1, np.uint32)
    for yo in range(out.shape[0]):
        pyr_down_row(src, yo, out[yo], scratch.view(np.uint16), scratch)
    return out


if numba is not None:

    @numba.njit(cache=True, nogil=True)
    def pyr_down_row(src, yo, out, vv, vw):  # pragma: no cover - compiled
        """Row ``yo`` of ``cv2.pyrDown(src)`` into ``out`` ((W + 1) // 2,), reading rows 2 yo - 2 .. 2 yo + 2 of
        ``src`` (reflected at its edges). The vertical pass into ``vv[2 : 2 + W]`` (uint16, at most 16 x 255), its
        two values beyond each end reflected into ``vv``; ``vw`` is the same memory as uint32 words, each the pair
        (v[2k - 2], v[2k - 1]) from word k: the horizontal pass reads them contiguously (deinterleaving ``vv`` by
        stride-2 loops took 2.3x OpenCV's time)."""
        h, w = src.shape
        y = 2 * yo
        r0 = src[y - 2] if y >= 2 else src[2 - y]
        r1 = src[y - 1] if y >= 1 else src[1]
        r2 = src[y]
        r3 = src[y + 1] if y + 1 < h else src[2 * (h - 1) - (y + 1)]
        r4 = src[y + 2] if y + 2 < h else src[2 * (h - 1) - (y + 2)]
        four, six = np.uint16(4), np.uint16(6)
        v = vv[2 : 2 + w]
        for x in range(w):
            v[x] = (np.uint16(np.uint16(r0[x]) + np.uint16(r4[x])) + np.uint16(four * np.uint16(np.uint16(r1[x])
                    + np.uint16(r3[x]))) + np.uint16(six * np.uint16(r2[x])))
        vv[0], vv[1] = v[2], v[1]
        vv[2 + w], vv[3 + w] = v[w - 2], v[w - 3]
        wo = out.size
        low, shift = np.uint32(0xFFFF), np.uint32(16)
        f4, f6, half, eight = np.uint32(4), np.uint32(6), np.uint32(128), np.uint32(8)
        a, b, c = vw[:wo], vw[1 : wo + 1], vw[2 : wo + 2]
        for k in range(wo):
            e0, o0, e1, o1, e2 = a[k] & low, a[k] >> shift, b[k] & low, b[k] >> shift, c[k] & low
            out[k] = np.uint8((e0 + e2 + f4 * (o0 + o1) + f6 * e1 + half) >> eight)

    @numba.njit(cache=True, nogil=True)
    def _lut16_halved(src, table, dst, half, vv, vw):  # pragma: no cover - compiled
        """The table look-up row by row (``lut_kernel._lut16_compiled``'s loops), each row of ``half`` as soon
        as the rows it reads are mapped."""
        h, w = src.shape
        top = np.uint16(0)
        done = 0  # rows of ``half`` written
        for y in range(h):
            row, out = src[y], dst[y]
            for x in range(w):
                out[x] = table[row[x]]
            for x in range(w):  # the row's max in a loop of its own (vectorised)
                v = row[x]
                top = v if v > top else top
            # row yo reads up to 2 yo + 2 (reflected into the image at the bottom edge)
            while done < half.shape[0] and min(2 * done + 2, h - 1) <= y:
                pyr_down_row(dst, done, half[done], vv, vw)
                done += 1
        return top
