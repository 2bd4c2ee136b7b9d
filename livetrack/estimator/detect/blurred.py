"""The code of a small, heavily blurred pair, read against the image each code would give at this size and blur.

Blur over a few pixels lifts the narrow black bands of a small target (its black samples read half-way to white)
and lowers its code dots (0.2-0.6 of the ring's contrast), so the fixed thresholds of ``code._read_code`` refuse
it, though the code is legible. Here each hypothesis (a code of the pair's geometry at each slot rotation, or no
dots at all) is drawn in the pixels around the pair through the pair's map (the design's inner disk, code dots
and, inside the inner disk, the child's black ring or not), blurred by a Gaussian of each of ``BLUR_SIGMAS_PX``,
and fitted to the image by linear least squares: the black level, the contrast and the surroundings (the ground
beyond the outer edge, one level per sector) are free. The hypotheses are compared by their squared residuals over
the code annulus alone (the rest of the window is the same for every code and only dilutes the dots' evidence).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.estimator.detect.geometry import _Entry, _Geometry

FloatArray = npt.NDArray[np.float64]

MIN_SEMI_MINOR_PX = 9.0
MAX_SEMI_MINOR_PX = 16.0
"""Pairs whose outer semi-minor axis lies in this range are read so when their black bands are not dark. Smaller
ones are not identifiable (the sweep counts targets from 8 px; texture pairs of 8-9 px came closest to passing);
larger ones show their bands dark enough under the blurs met (a PSF of up to ~3 px)."""
BLUR_SIGMAS_PX = (0.7, 1.0, 1.4, 1.9, 2.5, 3.2)
"""The Gaussian blurs tried (pixels). Above 3.2 px every pair of 10 px is one blob and any code fits its noise."""
SECTORS = 8
"""Sectors of the ground beyond the outer edge, each with its own level (a textured or graded ground)."""
OVERSAMPLING = 3
"""Sub-pixel samples per pixel side of the drawn hypotheses."""
FIT_RADIUS = 1.3
"""The fit covers the pixels within this radius (units of R) of the centre: the target and a rim of ground."""
MIN_RIVAL_RATIO = 1.6
"""Least ratio of the code annulus's squared residual of the best rival hypothesis (another code, another rotation,
or no dots) to the winner's. Of the pairs of 9-16 px refused so before that pass the other tests and reach this
fit (recorded on the sweep's seeds 0-9: optics scenes, no-target frames, photos): 15 on true targets (id 1 of
10-12 px in 11 frames read 1.07-2.39, the 6 at 1.6 or more as id 1; id 3 in 4 frames at most 1.08), 231
elsewhere at most 1.40."""
MIN_UNCODED_RATIO = 1.8
"""Least ratio of the best no-dot hypothesis's squared residual (code annulus) to the winner's: a plain ring (an
uncoded decoy) or a blob of texture fits without dots. The true codes passing ``MIN_RIVAL_RATIO`` read 1.87-3.07."""
MIN_BLACK = -0.03
MAX_WHITE = 1.05
"""A hypothesis's fitted black level must be at least ``MIN_BLACK`` and its white (black + contrast) at most
``MAX_WHITE`` of full scale, its contrast positive: a fit beyond them is a blur too wide for the pair."""


def read_blurred_code(img: np.ndarray, H0: FloatArray, g: _Geometry, entries: list[_Entry], phase: float,
                      full: float) -> tuple[str, int] | str:
    """The code (bits) and rotation (slots, as ``codebook.decode`` gives it: slot j holds bit ``(j - rotation) mod
    N``) that the pair's pixels fit best, with the slot grid at ``phase`` through ``H0``; or why none."""
    n = g.slots
    codes = sorted({e.spec.code.bits for e in entries if e.spec.code is not None and len(e.spec.code.bits) == n})
    child = _child_radii(entries)
    window = _window(img.shape, H0)
    if window is None:
        return "blurred: window outside the image"
    x0, y0, x1, y1 = window
    basis, radius = _basis(H0, g, child, phase, x0, y0, x1, y1)
    vals = img[y0:y1 + 1, x0:x1 + 1].astype(np.float64)
    use = (radius <= FIT_RADIUS) & (vals < 0.98 * full)
    if np.count_nonzero(use) < 4 * basis.shape[0]:
        return "blurred: too few pixels"
    on_ring = ((radius >= g.ring - g.dot - 0.1) & (radius <= g.ring + g.dot + 0.1))[use]
    y = vals[use]
    y_ring = y[on_ring]
    index, T = _hypotheses(tuple(codes), n, child is not None)
    Tt = T.transpose(0, 2, 1)
    best: list[tuple[float, int, int]] = []  # (code annulus rss, code index or -1, rotation)
    for sigma_px in BLUR_SIGMAS_PX:
        blurred = np.stack([cv2.GaussianBlur(b, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE) for b in basis])
        A = blurred[:, use]
        Gh = Tt @ (A @ A.T) @ T  # (H, Q, Q): each hypothesis's normal equations
        bh = Tt @ (A @ y)
        try:
            coef = np.linalg.solve(Gh, bh[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:  # a parameter without pixels (a sector outside the image), in every map
            continue
        black, contrast = coef[:, 0], coef[:, 1]
        ok = (contrast > 0.0) & (black >= MIN_BLACK * full) & (black + contrast <= MAX_WHITE * full)
        residual = y_ring[None, :] - np.einsum("hq,hqm->hm", coef, Tt @ A[:, on_ring])
        rss = np.einsum("hm,hm->h", residual, residual)
        best += [(float(rss[h]), int(index[h, 0]), int(index[h, 1])) for h in np.flatnonzero(ok)]
    if not best:
        return "blurred: no hypothesis fits"
    best.sort()
    rss, code, rotation = best[0]
    if code < 0:
        return "blurred: no dots fit best"
    rival = min((r for r, c, k in best[1:] if c != code or k != rotation), default=np.inf)
    uncoded = min((r for r, c, _ in best if c < 0), default=np.inf)
    if rival < MIN_RIVAL_RATIO * rss or uncoded < MIN_UNCODED_RATIO * rss:
        return "blurred: no code ahead"
    return codes[code], rotation


def _child_radii(entries: list[_Entry]) -> tuple[float, float] | None:
    """The outer and inner radii (units of R) of the black ring of the child inside the inner disk, when a level
    of the group has one (the pair may be that level or the child itself: both are tried)."""
    for e in entries:
        if e.spec.child is not None:
            R = e.spec.outer_radius_m
            return e.spec.child.outer_radius_m / R, e.spec.child.inner_radius_m / R
    return None


def _window(shape: tuple[int, ...], H0: FloatArray) -> tuple[int, int, int, int] | None:
    """The pixel box (x0, y0, x1, y1, inclusive) of the fit circle and the widest blur's reach, within the
    image; None when too little of it is inside."""
    t = np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)
    p = H0 @ np.stack([FIT_RADIUS * np.cos(t), FIT_RADIUS * np.sin(t), np.ones_like(t)])
    x, y = p[0] / p[2], p[1] / p[2]
    reach = 3.0 * max(BLUR_SIGMAS_PX) + 1.0
    height, width = shape[:2]
    x0, x1 = max(int(np.floor(x.min() - reach)), 0), min(int(np.ceil(x.max() + reach)), width - 1)
    y0, y1 = max(int(np.floor(y.min() - reach)), 0), min(int(np.ceil(y.max() + reach)), height - 1)
    if x1 - x0 < 4 or y1 - y0 < 4:
        return None
    return x0, y0, x1, y1


def _basis(H0: FloatArray, g: _Geometry, child: tuple[float, float] | None, phase: float, x0: int, y0: int,
           x1: int, y1: int) -> tuple[FloatArray, FloatArray]:
    """The share of each pixel of the box covered by: the outer disk, the inner disk, the child's black ring
    (zeros without a child), each slot's dot (N), each ground sector beyond the outer edge (``SECTORS``), as
    (3 + N + SECTORS, h, w); and the mean radius (units of R) of each pixel's samples."""
    ys, xs = np.mgrid[y0:y1 + 1, x0:x1 + 1].astype(np.float64)
    off = (np.arange(OVERSAMPLING) + 0.5) / OVERSAMPLING - 0.5
    sx = np.broadcast_to(xs[..., None, None] + off[None, None, None, :], xs.shape + (OVERSAMPLING, OVERSAMPLING))
    sy = np.broadcast_to(ys[..., None, None] + off[None, None, :, None], xs.shape + (OVERSAMPLING, OVERSAMPLING))
    Hi = np.linalg.inv(H0)
    w = Hi[2, 0] * sx + Hi[2, 1] * sy + Hi[2, 2]
    u = (Hi[0, 0] * sx + Hi[0, 1] * sy + Hi[0, 2]) / w
    v = (Hi[1, 0] * sx + Hi[1, 1] * sy + Hi[1, 2]) / w
    r = np.hypot(u, v)

    def share(covered: np.ndarray) -> FloatArray:
        return covered.reshape(covered.shape[0], covered.shape[1], -1).mean(axis=2)

    inside = r < 1.0
    planes = [share(inside), share(r < g.ratio)]
    planes.append(share((r < child[0]) & (r >= child[1])) if child is not None else np.zeros(xs.shape))
    for j in range(g.slots):
        a = phase + 2.0 * np.pi * j / g.slots
        planes.append(share(np.hypot(u - g.ring * np.cos(a), v - g.ring * np.sin(a)) < g.dot))
    sector = np.floor((np.arctan2(v, u) + np.pi) / (2.0 * np.pi) * SECTORS).astype(np.int64) % SECTORS
    for k in range(SECTORS):
        planes.append(share(~inside & (sector == k)))
    return np.stack(planes), share(r)


@functools.lru_cache(maxsize=64)
def _hypotheses(codes: tuple[str, ...], n: int, with_child: bool) -> tuple[npt.NDArray[np.int64], FloatArray]:
    """Per hypothesis (code index and rotation, -1 and 0: no dots; with the child's ring dark or not): (H, 2) its
    code index and rotation, and (H, planes, 2 + SECTORS) the map T from the planes of ``_basis`` to the
    parameters: the black level (the outer disk), the contrast (the white parts: the inner disk less the child's
    ring, the code's dots) and the ground sectors. Read-only (cached)."""
    planes = 3 + n + SECTORS
    index, maps = [], []
    for code, bits in [(i, c) for i, c in enumerate(codes)] + [(-1, "0" * n)]:
        for rotation in range(n if code >= 0 else 1):
            for dark_child in ((False, True) if with_child else (False,)):
                T = np.zeros((planes, 2 + SECTORS))
                T[0, 0] = 1.0
                T[1, 1] = 1.0
                T[2, 1] = -1.0 if dark_child else 0.0
                for j in range(n):
                    if bits[(j - rotation) % n] == "1":
                        T[3 + j, 1] = 1.0
                T[3 + n:, 2:] = np.eye(SECTORS)
                index.append((code, rotation))
                maps.append(T)
    out = np.array(index, dtype=np.int64), np.stack(maps)
    for a in out:
        a.flags.writeable = False
    return out
