"""What a detector measures, applied alike to measured and predicted frames: the 50 %-threshold disk radius
(the exposure-bias curve), the black and white levels, and residuals binned by edge orientation, intensity and
position in the image."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from livetrack.modelcheck.forward import Layout

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class DiskPixels:
    """For each sub-image: per pixel the index of its disk (-1 outside any interior disk's cell), the distance
    to the disk centre minus its radius (px, > 0 outside), and the direction from the centre (rad, image axes)."""

    disk: list[npt.NDArray[np.intp]]
    offset_px: list[FloatArray]
    angle_rad: list[FloatArray]
    radii_px: FloatArray
    area_per_sample_px2: float


def disk_pixels(layout: Layout, centres: FloatArray, radii: FloatArray, width: int, height: int) -> DiskPixels:
    disk, off, ang = [], [], []
    n_samples = 0
    for x, y, idx, roi in zip(layout.xs, layout.ys, layout.nearest, layout.roi, strict=True):
        k = idx[:, 0].reshape(x.shape)
        c = centres[k]
        dx, dy = x - c[..., 0], y - c[..., 1]
        disk.append(np.where(roi, k, -1))
        off.append(np.hypot(dx, dy) - radii[k])
        ang.append(np.arctan2(dy, dx))
        n_samples += x.size
    return DiskPixels(disk, off, ang, radii, width * height / n_samples)


def threshold_radii(images: list[FloatArray], dp: DiskPixels, pitch_px: float) -> tuple[FloatArray, FloatArray]:
    """Per interior disk: the radius (px) of the area darker than the mid-level between the disk's own black
    (median inside half its radius) and white (median of its cell's outer ring) -- what a threshold detector
    sees. Returns (disk indices (M,), radii (M,))."""
    ids = np.unique(np.concatenate([d[d >= 0] for d in dp.disk]))
    vals = np.concatenate([im.ravel() for im in images])
    dsk = np.concatenate([d.ravel() for d in dp.disk])
    off = np.concatenate([o.ravel() for o in dp.offset_px])
    order = np.argsort(dsk, kind="stable")
    dsk, vals, off = dsk[order], vals[order], off[order]
    starts = np.searchsorted(dsk, ids)
    ends = np.searchsorted(dsk, ids, side="right")
    out = np.full(ids.size, np.nan)
    for n, (a, b) in enumerate(zip(starts, ends, strict=True)):
        v, o = vals[a:b], off[a:b]
        r = dp.radii_px[ids[n]]
        black = v[o < -0.5 * r]
        ring = 0.45 * pitch_px - r
        white = v[o > 0.6 * ring] if ring > 0 else v[o > 0]
        if black.size < 3 or white.size < 3:
            continue
        t = 0.5 * (np.median(black) + np.median(white))
        dark = np.count_nonzero(v < t) * dp.area_per_sample_px2
        out[n] = math.sqrt(dark / math.pi)
    return ids, out


def levels(images: list[FloatArray], dp: DiskPixels, pitch_px: float) -> tuple[float, float]:
    """(black, white): medians over all interior disks' centres (inside half the radius) and cell rings."""
    b, w = [], []
    for im, d, o in zip(images, dp.disk, dp.offset_px, strict=True):
        r = float(np.median(dp.radii_px))
        b.append(im[(d >= 0) & (o < -0.5 * r)])
        w.append(im[(d >= 0) & (o > 0.6 * (0.45 * pitch_px - r))])
    return float(np.median(np.concatenate(b))), float(np.median(np.concatenate(w)))


def binned(values: FloatArray, keys: FloatArray, edges: FloatArray,
           min_count: int = 1) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Mean and RMS of ``values`` in the bins ``edges`` of ``keys``; (centres, mean, rms), NaN in a bin with fewer
    than ``min_count`` values."""
    idx = np.digitize(keys, edges) - 1
    n = edges.size - 1
    ok = (idx >= 0) & (idx < n)
    cnt = np.bincount(idx[ok], minlength=n).astype(np.float64)
    s1 = np.bincount(idx[ok], values[ok], minlength=n)
    s2 = np.bincount(idx[ok], values[ok] ** 2, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(cnt >= max(min_count, 1), s1 / cnt, np.nan)
        rms = np.where(cnt >= max(min_count, 1), np.sqrt(s2 / cnt), np.nan)
    return 0.5 * (edges[1:] + edges[:-1]), mean, rms


def dark_shapes(images: list[FloatArray], dp: DiskPixels, pitch_px: float) -> FloatArray:
    """Per interior disk, the shape of the area darker than the mid-level (as ``threshold_radii``): horizontal
    and vertical radii ``2 sqrt(var)`` of its pixel positions (the radius, for a uniform disk) and the vertical
    offset of its centroid from the disk centre (px, + = down). Shape (M, 3), NaN where not measurable."""
    ids = np.unique(np.concatenate([d[d >= 0] for d in dp.disk]))
    out = np.full((ids.size, 3), np.nan)
    cols = {k: [] for k in ("v", "o", "x", "y", "d")}
    for im, d, o, a in zip(images, dp.disk, dp.offset_px, dp.angle_rad, strict=True):
        keep = d >= 0
        rr = o[keep] + dp.radii_px[d[keep]]
        cols["v"].append(im[keep])
        cols["o"].append(o[keep])
        cols["x"].append(rr * np.cos(a[keep]))
        cols["y"].append(rr * np.sin(a[keep]))
        cols["d"].append(d[keep])
    v, o, x, y, dsk = (np.concatenate(cols[k]) for k in ("v", "o", "x", "y", "d"))
    order = np.argsort(dsk, kind="stable")
    v, o, x, y, dsk = v[order], o[order], x[order], y[order], dsk[order]
    starts, ends = np.searchsorted(dsk, ids), np.searchsorted(dsk, ids, side="right")
    for n, (lo, hi) in enumerate(zip(starts, ends, strict=True)):
        r = dp.radii_px[ids[n]]
        vv, oo = v[lo:hi], o[lo:hi]
        black = vv[oo < -0.5 * r]
        ring = 0.45 * pitch_px - r
        white = vv[oo > 0.6 * ring] if ring > 0 else vv[oo > 0]
        if black.size < 3 or white.size < 3:
            continue
        dark = (vv < 0.5 * (np.median(black) + np.median(white))) & (oo < 0.5 * ring)
        if np.count_nonzero(dark) < 6:
            continue
        xd, yd = x[lo:hi][dark], y[lo:hi][dark]
        out[n] = (2.0 * float(np.std(xd)), 2.0 * float(np.std(yd)), float(np.mean(yd)))
    return out
