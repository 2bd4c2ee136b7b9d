"""The coarse stage's 8-bit image (a fixed square-root map), its noise and its local threshold; the Detector's
work images."""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.estimator.detect import blur_kernel, noise_kernel, pyramid_kernel, sqrt_kernel, window_kernel
from livetrack.estimator.detect.options import DetectOptions
from livetrack.estimator.detect.upsample_kernel import box_of, dark_and_box, is_exact_4x
from livetrack.estimator.lut_kernel import lut16


# ---------------------------------------------------------------------- work images
class _WorkImages:
    """Full-size work images of one Detector, kept from one call to the next: a fresh multi-megabyte array
    costs its page faults on first write, about 0.5 ms per 2 Mpx, more than most passes over it. Each name
    holds a grow-only byte store; ``image`` hands out a C-contiguous view of its start (contents undefined)."""

    def __init__(self) -> None:
        self.stores: dict[str, np.ndarray] = {}
        self.written: dict[str, tuple[np.ndarray, tuple[int, ...], tuple[int, int, int, int]]] = {}
        self.window: tuple[np.ndarray, int, np.ndarray, np.ndarray] | None = None  # ``top_and_mean``'s last
        # ``_blurred_for_noise``'s last (out, blur, step), read once by ``_rows_blurred``
        self.noise_rows: tuple[np.ndarray, tuple[np.ndarray, int, int], int] | None = None

    def top_and_mean(self, src: np.ndarray, k: int, kernel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The window's max and mean over ``src`` (``cv2.dilate`` by ``kernel`` and ``cv2.blur`` by (k, k), borders
        replicated): remembered with a copy of ``src`` and given again for an equal image (the ``_dark_box`` then
        ``_clipped_dark_box`` of one level read the same coarse level: ~0.1 ms of 480x300 saved for a compare
        and a copy of ~0.01). The caller must not write into them."""
        last = self.window
        if last is not None and last[1] == k and last[0].shape == src.shape and np.array_equal(last[0], src):
            return last[2], last[3]
        top = cv2.dilate(src, kernel, borderType=cv2.BORDER_REPLICATE)
        mean = cv2.blur(src, (k, k), borderType=cv2.BORDER_REPLICATE)
        self.window = (src.copy(), k, top, mean)
        return top, mean

    def image(self, name: str, shape: tuple[int, ...], dtype: npt.DTypeLike = np.uint8) -> np.ndarray:
        dtype = np.dtype(dtype)
        size = math.prod(shape) * dtype.itemsize
        store = self.stores.get(name)
        if store is None or store.size < size:
            store = self.stores[name] = np.empty(size, np.uint8)
        return store[:size].view(dtype).reshape(shape)

    def zero_outside(self, name: str, shape: tuple[int, int], box: tuple[int, int, int, int]) -> np.ndarray:
        """The uint8 work image ``name`` of ``shape``, zero outside ``box`` (x0, y0, x1, y1; exclusive ends; its
        contents inside undefined), for a caller that writes only ``box``. Only what the last call's box may have
        left non-zero is cleared (all of the image when its store or shape changed since)."""
        out = self.image(name, shape)
        store, last = self.stores[name], self.written.get(name)
        if last is None or last[0] is not store or last[1] != shape:
            out.fill(0)
        else:
            lx0, ly0, lx1, ly1 = last[2]
            x0, y0, x1, y1 = box
            if lx1 > lx0 and not (x0 <= lx0 and y0 <= ly0 and lx1 <= x1 and ly1 <= y1):
                out[ly0:ly1, lx0:lx1] = 0
        self.written[name] = (store, shape, box)
        return out

    def written_box(self, name: str) -> tuple[int, int, int, int]:
        """The box (x0, y0, x1, y1; exclusive ends) outside which the work image ``name`` is zero, as the last
        ``zero_outside`` for it set it (``_closed``'s crop): for ``pairs._contours``, which then scans nothing
        for it."""
        return self.written[name][2]


def _closed(binary: np.ndarray, box: tuple[int, int, int, int], kernel: np.ndarray, name: str,
            work: _WorkImages) -> np.ndarray:
    """``cv2.morphologyEx(binary, cv2.MORPH_CLOSE, kernel)`` (a work image ``name``) where ``box`` (x0, y0, x1,
    y1; exclusive ends) bounds the non-zero pixels of ``binary``: computed on the box grown by twice the kernel's
    reach only, zero elsewhere. The same image bit for bit: outside that crop the dilation and then the erosion
    are 0; inside it, OpenCV's default border (which never wins a max or min) stands for the binary's zeros
    beyond it, since a crop pixel whose erosion reads beyond the crop is itself more than one reach from the box
    (its dilation 0); on the image's edges crop and image share the border. A frame's dark pixels cluster around
    its targets (the bench's frames: boxes of ~5 % of the frame): ~0.05 against ~0.4 ms at 1920x1200."""
    h, w = binary.shape
    x0, y0, x1, y1 = box
    m = max(kernel.shape) - 1  # twice the reach (an odd kernel, centred)
    crop = (max(x0 - m, 0), max(y0 - m, 0), min(x1 + m, w), min(y1 + m, h)) if x1 > x0 else (0, 0, 0, 0)
    out = work.zero_outside(name, binary.shape, crop)
    cx0, cy0, cx1, cy1 = crop
    if cx1 > cx0:
        view = out[cy0:cy1, cx0:cx1]
        got = cv2.morphologyEx(binary[cy0:cy1, cx0:cx1], cv2.MORPH_CLOSE, kernel, dst=view)
        if not np.shares_memory(got, view):  # OpenCV wrote a new array (it does not for these views)
            np.copyto(view, got)
    return out


# ---------------------------------------------------------------------- local threshold
def _dark(img8: np.ndarray, coarse: np.ndarray | None, offset: float, opts: DetectOptions,
          work: _WorkImages, saturated_offset: float | None = None) -> np.ndarray:
    """``_dark_box``'s binary image alone."""
    return _dark_box(img8, coarse, offset, opts, work, saturated_offset)[0]


def _dark_box(img8: np.ndarray, coarse: np.ndarray | None, offset: float, opts: DetectOptions,
              work: _WorkImages, saturated_offset: float | None = None,
              blur: tuple[np.ndarray, int, int] | None = None) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """Local threshold: 255 where ``img8`` is at or below its threshold, else 0. Every decision is local (a
    ``threshold_window_px`` square around each pixel): a dark ring is dark against its own surroundings, whatever
    the rest of the frame holds.

    - Where the window holds saturated pixels (its max at the top level): anything ``saturated_offset`` (default
      ``offset``) and ``SATURATED_RELATIVE_OFFSET`` of the window's range below the top is dark. Saturation is
      noise-free, so a black ring that over-exposure has cut into pieces (white dots grown into the inner disk,
      1-2 px bands left at 80 % of white) stays one dark ring; only the dark pixels' own noise needs the depth.
    - Elsewhere: max(mean, (max + min) / 2) - max(offset, ``relative_offset`` x range), range = max - min. The
      half-range keeps a window that the black ring fills nearly whole (a strongly tilted target, along its
      major axis) dark where the mean alone would call its ring bright; the part relative to the range keeps
      texture and noise beside a high-contrast edge out, the absolute part (from the noise) keeps flat regions
      out.

    With ``coarse`` (the pyramid level two steps down) the statistics come from it, upsampled: the same up to
    their smoothness, at a fraction of the cost. The result is a work image, overwritten by the next call; with
    it the bounding box (x0, y0, x1, y1; exclusive ends) of its dark pixels, (0, 0, 0, 0) for none.

    blur: ``_fused_blur``'s (src, side, centre): ``img8`` is first filled with ``src`` blurred, inside the
    comparison's pass (``upsample_kernel.dark_and_box``). Default None."""
    src, k, kernel = _window(img8, coarse, opts)
    top, mean = work.top_and_mean(src, k, kernel)
    bottom = cv2.erode(src, kernel, borderType=cv2.BORDER_REPLICATE)
    depth = offset if saturated_offset is None else saturated_offset
    if window_kernel.exact(opts.relative_offset, SATURATED_RELATIVE_OFFSET):
        # the arithmetic below in one compiled pass (the same image); without ``coarse`` (the pyramid's last two
        # levels, small windows) into a fresh image, as OpenCV's calls give one (~25 us a level saved)
        out = work.image("coarse_threshold", src.shape) if coarse is not None else np.empty(src.shape, np.uint8)
        threshold = window_kernel.window_threshold(top, bottom, mean, opts.relative_offset, offset,
                                                   SATURATED_RELATIVE_OFFSET, depth, SATURATED_LEVEL, out)
        if coarse is not None:
            return dark_and_box(img8, threshold, work.image("dark", img8.shape), blur,
                                _rows_blurred(img8, blur, work))
        if blur is not None:
            raise ValueError("the fused blur needs the coarse level")
        binary = cv2.compare(img8, threshold, cv2.CMP_LE, dst=threshold)  # in place: element by element
        return binary, box_of(binary)
    span = cv2.subtract(top, bottom)
    spread = cv2.max(cv2.convertScaleAbs(span, alpha=opts.relative_offset), int(round(offset)))
    middle = cv2.addWeighted(top, 0.5, bottom, 0.5, 0.0)
    threshold = cv2.subtract(cv2.max(mean, middle), spread)
    saturated = cv2.compare(top, SATURATED_LEVEL, cv2.CMP_GE)
    if cv2.countNonZero(saturated):
        spread = cv2.max(cv2.convertScaleAbs(span, alpha=SATURATED_RELATIVE_OFFSET), int(round(depth)))
        np.copyto(threshold, cv2.max(threshold, cv2.subtract(top, spread)), where=saturated.view(bool))
    if coarse is not None:  # upsampled (bilinear) and compared in one pass, which finds the box on the way
        return dark_and_box(img8, threshold, work.image("dark", img8.shape), blur, _rows_blurred(img8, blur, work))
    if blur is not None:
        raise ValueError("the fused blur needs the coarse level")
    binary = cv2.compare(img8, threshold, cv2.CMP_LE, dst=threshold)  # in place: element by element
    return binary, box_of(binary)


def _fused_blur(img8: np.ndarray, coarse: np.ndarray | None, sigma: float) -> tuple[np.ndarray, int, int] | None:
    """(img8, side, centre) when ``_dark_box(..., coarse, blur=...)`` can blur ``img8`` inside its comparison
    (``cv2.GaussianBlur(img8, (3, 3), sigma)``'s image: ``blur_kernel.kernel_taps``, an exact 4x coarse level);
    else None (the caller blurs with OpenCV)."""
    if coarse is None or not 0.0 < sigma <= 1.0 or min(img8.shape) < 2 or not is_exact_4x(coarse.shape, img8.shape):
        return None
    taps = blur_kernel.kernel_taps(float(sigma))
    return None if taps is None else (img8, taps[0], taps[1])


def _blurred_for_noise(blur: tuple[np.ndarray, int, int], out: np.ndarray,
                       work: _WorkImages | None = None) -> np.ndarray:
    """``out`` (the shape of ``blur``'s image) holding that image blurred in the rows ``_noise`` reads (every
    ``_noise_step``-th from 0; the others left as they were, for ``_dark_box(..., blur=blur)`` to fill). With
    ``work`` (the Detector's work images), recorded there for ``_rows_blurred``."""
    src, side, centre = blur
    step = _noise_step(src)
    if work is not None:
        work.noise_rows = (out, blur, step)
    return blur_kernel.blur_rows(src, out, step, side, centre)


def _rows_blurred(img8: np.ndarray, blur: tuple[np.ndarray, int, int] | None, work: _WorkImages) -> int:
    """The step of the rows of ``img8`` that hold ``blur``'s image already: ``_blurred_for_noise``'s, when its
    last call with ``work`` was for this very ``img8`` and ``blur`` (the same objects; the record is used once);
    else 0. The fused pass then does not blur them again (~0.06 ms a 1920x1200 frame)."""
    last = work.noise_rows
    if blur is None or last is None or last[0] is not img8 or last[1] is not blur:
        return 0
    work.noise_rows = None
    return last[2]


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
    v = v.copy()  # ``np.partition(v, k)``'s own steps, without its wrapper's cost
    v.partition(k)
    return float(v[k])


def _noise(img8: np.ndarray) -> tuple[float, float]:
    """``_noise_reference``'s figures, compiled (``noise_kernel.tile_noise``: the same order statistics) where
    numba is installed (it reads every ``_noise_step``-th row only)."""
    step = _noise_step(img8)
    rows, cols = -(-img8.shape[0] // step), -(-(img8.shape[1] - 2) // step)
    if noise_kernel.numba is None or rows < 1 or cols < 1:
        return _noise_reference(img8)
    th, tw = max(rows // NOISE_TILES, 1), max(cols // NOISE_TILES, 1)
    least, fine = noise_kernel.tile_noise(img8, step, th, tw, rows // th, cols // tw,
                                          max(NOISE_MIN_UNCLIPPED * th * tw, 1), SATURATED_LEVEL)
    return (0.0 if least == 255 else least / 0.954), (0.0 if fine == 255 else fine / 0.954)


def _noise_reference(img8: np.ndarray) -> tuple[float, float]:
    """Pixel noise (standard deviation, 8-bit levels), two figures: (tiles, unclipped).

    Both are the median absolute difference of pixels two apart horizontally (sqrt(2) x 0.6745 = 0.954 sd for
    Gaussian noise) in each of 8 x 8 tiles of the frame, the least of those medians; pairs with a clipped pixel
    (saturated or black) carry no noise. ``tiles`` counts them as large differences (a tile mostly clipped
    gives no figure, one half clipped the top of its other pairs: its edges); ``unclipped`` leaves them out, of
    tiles where the others are at least ``NOISE_MIN_UNCLIPPED`` of its pairs. They differ in over-exposed
    frames only: at x32, ``tiles`` read 21 levels where the pixels' noise was ~1 (``unclipped``). The local
    threshold's offset comes from ``tiles`` (conservative, as its depths were set), its offset below saturated
    pixels from ``unclipped`` (see ``_dark``).

    Texture (carpet, foliage, text) raises a tile's figure, so the cleanest tile (a sheet of paper, a wall, the
    sky) tells the camera's noise even when texture fills most of the frame. On the square-root image shot noise
    is about the same at every level, so one figure holds for the frame. Two apart so that a slight blur does
    not hide it; ~20k differences in all. 0 where no tile gives a figure."""
    step = _noise_step(img8)
    w = img8.shape[1] - 2
    left, right = img8[::step, 0:w:step], img8[::step, 2 : w + 2 : step]
    high, low = np.maximum(left, right), np.minimum(left, right)
    # Clipped pairs marked 255, which no unclipped pair reaches (at most SATURATED_LEVEL - 2): they sort last.
    clipped = (high >= SATURATED_LEVEL) | (low == 0)
    diff = np.subtract(high, low, out=high)  # |right - left| in uint8
    diff[clipped] = 255
    rows, cols = diff.shape
    th, tw = max(rows // NOISE_TILES, 1), max(cols // NOISE_TILES, 1)
    ny, nx = rows // th, cols // tw
    tiles = diff[: ny * th, : nx * tw].reshape(ny, th, nx, tw).swapaxes(1, 2).reshape(ny * nx, th * tw)
    ordered = np.sort(tiles, axis=1, kind="stable")  # uint8: a radix sort, ~3x np.partition's speed
    least = int(ordered[:, (th * tw - 1) // 2].min())
    unclipped = th * tw - np.count_nonzero(ordered == 255, axis=1)
    usable = unclipped >= max(NOISE_MIN_UNCLIPPED * th * tw, 1)
    fine = int(ordered[np.flatnonzero(usable), (unclipped[usable] - 1) // 2].min()) if usable.any() else 255
    return (0.0 if least == 255 else least / 0.954), (0.0 if fine == 255 else fine / 0.954)


def _noise_step(img8: np.ndarray) -> int:
    """The step between the rows and the columns ``_noise`` samples: ~20k differences in all."""
    return max(1, int(math.sqrt(img8.size / 20_000)))


NOISE_TILES = 8
NOISE_MIN_UNCLIPPED = 0.25


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
    """``_normalise_top`` without the top level."""
    norm = _normalise_top(img, saturation, work)
    return None if norm is None else norm[:2]


def _normalise_top(img: np.ndarray, saturation: float | None,
                   work: _WorkImages) -> tuple[np.ndarray, float, int] | None:
    """``_normalise_halved`` without the pyramid's first level."""
    norm = _normalise_halved(img, saturation, work, None)
    return None if norm is None else norm[:3]


def _normalise_halved(img: np.ndarray, saturation: float | None, work: _WorkImages,
                      half: np.ndarray | None) -> tuple[np.ndarray, float, int, bool] | None:
    """``_normalise_top``'s (8-bit image, full, top) and whether ``half`` (((H + 1) // 2, (W + 1) // 2) uint8,
    C-contiguous, or None) now holds ``cv2.pyrDown`` of the 8-bit image, computed in the look-up's pass
    (``pyramid_kernel``: 16-bit images of 3 x 3 pixels or more, with numba); when False the caller halves it.

    ``_normalise_top``: 8-bit image for the coarse stage (a work image), the input value mapped to 255 and the
    8-bit image's largest value, or None when the image is blank.

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
        cv2.LUT(img, _sqrt_table(full, 256), dst=out)
        return out, full, int(cv2.minMaxLoc(out)[1]), False
    if img.dtype == np.uint16:  # the table is non-decreasing: the top of the output is the table at the input's
        table = _sqrt_table(full, 65536)
        factor = _sqrt_factor(full)  # the map computed where it is the table's (``sqrt_kernel``)
        if half is not None and pyramid_kernel.numba is not None and min(img.shape) >= 3:
            if factor is not None:
                return out, full, int(table[sqrt_kernel.sqrt16_halved(img, factor, out, half)]), True
            return out, full, int(table[pyramid_kernel.lut16_halved(img, table, out, half)]), True
        if factor is not None:
            return out, full, int(table[sqrt_kernel.sqrt16(img, factor, out)]), False
        return out, full, int(table[lut16(img, table, out)]), False
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
    return out, full, int(cv2.minMaxLoc(out)[1]), False


@functools.lru_cache(maxsize=8)
def _sqrt_factor(full: float) -> np.float32 | None:
    """``sqrt_kernel.exact_factor`` for ``full`` (cached): the factor with which the computed map is
    ``_sqrt_table(full, 65536)`` for every input, or None (look the table up)."""
    return sqrt_kernel.exact_factor(full, _sqrt_table(full, 65536))


@functools.lru_cache(maxsize=8)
def _sqrt_table(full: float, size: int) -> npt.NDArray[np.uint8]:
    """round(255 sqrt(v / full)) for v = 0 .. size - 1, clipped to [0, 255] (read-only, cached)."""
    table = np.clip(np.round(255.0 * np.sqrt(np.arange(size) / full)), 0, 255).astype(np.uint8)
    table.flags.writeable = False
    return table



def _window(img8: np.ndarray, coarse: np.ndarray | None, opts: DetectOptions) -> tuple[np.ndarray, int, np.ndarray]:
    """The image the local threshold's window statistics come from (``coarse``, the level two steps down, when
    given, else ``img8``), the window's side on it (odd) and its square structuring element."""
    if coarse is None:
        src, k = img8, opts.threshold_window_px | 1
    else:
        src, k = coarse, max(opts.threshold_window_px // 4, 1) | 1
    return src, k, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))

CLIPPED_RELATIVE_OFFSET = 0.25
"""``_clipped_dark_box``: the depth below a saturated window's top, as a share of its top minus its mean."""


def _clipped_dark_box(img8: np.ndarray, coarse: np.ndarray | None, depth: float, opts: DetectOptions,
                      work: _WorkImages) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """A second binary image for over-exposed frames: dark where the window (as ``_dark_box``'s) is saturated
    and the pixel lies ``max(depth, CLIPPED_RELATIVE_OFFSET x (top - mean))`` below its top; nothing dark
    elsewhere. ``_dark_box`` measures the depth from the window's range, top minus min: beside a few black
    flecks of texture (foliage at x32, its darkest spots still black) that range is the full scale, and a
    target's black ring, lifted by over-exposure to ~0.9 of white, reads bright on the side that has them (its
    ring a C, no hole). The window's mean stays near the top there, so the ring is dark against it all round."""
    src, k, kernel = _window(img8, coarse, opts)
    top, mean = work.top_and_mean(src, k, kernel)  # as ``_dark_box``'s of this level: remembered
    if coarse is not None and window_kernel.clipped_exact(CLIPPED_RELATIVE_OFFSET):
        threshold = window_kernel.clipped_threshold(top, mean, CLIPPED_RELATIVE_OFFSET, depth, SATURATED_LEVEL,
                                                    work.image("clipped_threshold", src.shape))
    else:
        threshold = window_kernel.clipped_reference(top, mean, CLIPPED_RELATIVE_OFFSET, depth, SATURATED_LEVEL)
    if coarse is not None:
        return dark_and_box(img8, threshold, work.image("clipped_dark", img8.shape))
    binary = cv2.compare(img8, threshold, cv2.CMP_LE, dst=work.image("clipped_dark", img8.shape))
    binary[threshold == 0] = 0
    return binary, box_of(binary)
