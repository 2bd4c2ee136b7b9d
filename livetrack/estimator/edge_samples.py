"""Pixel sampling for the edge fits: the pixels along each edge normal, their distances, and the profile record.

For each edge point (an initial position and the unit normal pointing from black to white) the actual pixels of
a strip along the normal are taken (no interpolation): stencil positions on a half-pixel grid rounded to pixel
centres, deduplicated, those outside the image dropped.  Their geometry (pixel indices and distances to the
initial edge, a line or a circle) depends on the points alone and is remembered for the last few point sets
(a tracked static target samples the same points every frame); the pixel values are read per image.
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from livetrack.estimator import edge_glue_kernels, edge_kernels
from livetrack.estimator.edge_glue_kernels import kernel_array
from livetrack.estimator.edge_model import footprint_widths

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]


@functools.lru_cache(maxsize=16)
def _stencil(half_width_px: float, tangent_half_width_px: float) -> FloatArray:
    """(K0, 2) sample offsets (along the normal, along the tangent) in px, on a half-pixel grid (cached,
    read-only)."""
    n_steps = int(np.ceil(2.0 * half_width_px))
    s = np.arange(-n_steps, n_steps + 1) * 0.5
    s = s[np.abs(s) <= half_width_px + 1e-9]
    if tangent_half_width_px > 0:
        m = int(np.ceil(2.0 * tangent_half_width_px))
        t = np.linspace(-tangent_half_width_px, tangent_half_width_px, 2 * m + 1)
    else:
        t = np.zeros(1)
    ss, tt = np.meshgrid(s, t, indexing="ij")
    out = np.stack([ss.ravel(), tt.ravel()], axis=1)
    out.flags.writeable = False
    return out


def _sample_pixels(
    shape: tuple[int, ...], points: FloatArray, normals: FloatArray, stencil: FloatArray
) -> tuple[IntArray, IntArray, BoolArray]:
    """Distinct in-image pixels near each normal line: (N, K) x and y indices and a validity mask.

    Stencil positions are rounded to the nearest pixel centre; duplicates and pixels outside the image are
    masked and moved to the end of each row, and K is the largest number of valid pixels of any row.
    """
    height, width = shape
    nx, ny = normals[:, 0:1], normals[:, 1:2]
    s, t = stencil[:, 0], stencil[:, 1]
    ix = np.rint(points[:, 0:1] + s * nx - t * ny)
    iy = np.rint(points[:, 1:2] + s * ny + t * nx)
    inside = (ix >= 0) & (ix < width) & (iy >= 0) & (iy < height)
    sentinel = height * width
    lin = np.where(inside, iy * width + ix, sentinel).astype(np.int64)
    lin.sort(axis=1)
    lin[:, 1:][lin[:, 1:] == lin[:, :-1]] = sentinel
    lin.sort(axis=1)
    valid = lin < sentinel
    k = max(int(valid.sum(axis=1).max(initial=0)), 1)
    lin = np.where(valid, lin, 0)[:, :k]
    return lin % width, lin // width, valid[:, :k]


class Profiles:
    """Sampled pixels of N edge points, (N, K) unless noted: distance u0 (px) of each pixel centre from the
    initial edge (line or circle) along the normal, footprint widths a, b (N, 1), data, masks (valid,
    clipped high / low), weights w, ``top`` (N, 1), 1.0 where the profile is clipped at 0 only, and
    ``half_kappa`` (N, 1), half the signed curvature (1/px).  Derived: ``valid_f`` (valid as 0.0 / 1.0),
    ``n_valid`` (N,), ``n_span`` (N,) one past each row's last valid sample (valid samples come first in each
    row unless ``reach_px`` of :func:`sample_profiles` left some out between them), and whether any row has a
    clipped sample (``any_clipped``) or is clipped at 0 only (``any_top``), which lets the model evaluation of
    :mod:`livetrack.estimator.edges` skip the clipping logic of clean profiles.  ``ix``, ``iy`` (N, K): the
    column and row of each sample's pixel (None when not given), for models of the design around the edge."""

    _ARRAYS = ("u0", "a", "b", "data", "valid", "clip_hi", "clip_lo", "w", "top", "half_kappa", "valid_f")

    def __init__(self, u0, a, b, data, valid, clip_hi, clip_lo, w, top, half_kappa, valid_f=None, n_valid=None,
                 any_clipped=None, n_span=None, ix=None, iy=None):
        self.ix, self.iy = ix, iy
        self.u0, self.a, self.b, self.data, self.valid = u0, a, b, data, valid
        self.clip_hi, self.clip_lo, self.w, self.top, self.half_kappa = clip_hi, clip_lo, w, top, half_kappa
        self.valid_f = valid.astype(np.float64) if valid_f is None else valid_f
        self.n_valid = valid.sum(axis=1) if n_valid is None else n_valid
        self.n_span = _span(valid) if n_span is None else n_span
        self.any_clipped = bool(clip_hi.any() or clip_lo.any()) if any_clipped is None else bool(any_clipped)
        self.any_top = bool(top.any())

    def __len__(self) -> int:
        return len(self.u0)

    def take(self, rows: IntArray | slice) -> Profiles:
        """The profiles of ``rows`` (indices, or a slice: views), trimmed to the columns holding their valid
        samples (``n_span``: the trailing columns where no row has one)."""
        k = max(int(self.n_span[rows].max(initial=0)), 1)
        pixels = (None, None) if self.ix is None else (self.ix[rows, :k], self.iy[rows, :k])
        return Profiles(*(getattr(self, name)[rows, :k] for name in self._ARRAYS), n_valid=self.n_valid[rows],
                        n_span=self.n_span[rows], ix=pixels[0], iy=pixels[1])


def _span(valid: BoolArray) -> IntArray:
    """(N,) one past the last True of each row of ``valid`` (N, K), 0 for a row without one."""
    k = valid.shape[1]
    return np.where(valid.any(axis=1), k - np.argmax(valid[:, ::-1], axis=1), 0)


def check_points(image, points_px, normals) -> tuple[FloatArray, FloatArray]:
    """(N, 2) points and unit normals as float64; raises on a non-2-D image or mismatched lengths."""
    if np.ndim(image) != 2:
        raise ValueError(f"image must be 2-D (H, W), got shape {np.shape(image)}")
    pts = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
    nrm = np.asarray(normals, dtype=np.float64).reshape(-1, 2)
    if len(pts) != len(nrm):
        raise ValueError(f"points_px ({len(pts)}) and normals ({len(nrm)}) differ in length")
    if edge_kernels.kernels() == "numba":  # the numpy lines below, compiled: the same numbers
        return pts, edge_glue_kernels.unit_normals(kernel_array(nrm, np.float64))
    norm = np.sqrt(nrm[:, 0:1] ** 2 + nrm[:, 1:2] ** 2)
    return pts, nrm / np.where(norm > 0, norm, 1.0)


class _PointsKey:
    """Hashable identity of a set of sample points (their exact coordinates, normals, curvatures, the image
    shape, the stencil and the kernels computing them), the key of :func:`_geometry`."""

    __slots__ = ("pts", "nrm", "kappa", "kernels", "params", "_bytes", "_hash")

    def __init__(self, shape, pts, nrm, kappa, half_width_px, tangent_half_width_px, kernels="numpy"):
        self.pts, self.nrm, self.kappa, self.kernels = pts, nrm, kappa, kernels
        self.params = (tuple(shape), float(half_width_px), float(tangent_half_width_px), kappa is None, len(pts),
                       kernels)
        self._bytes = pts.tobytes() + nrm.tobytes() + (b"" if kappa is None else kappa.tobytes())
        self._hash = hash((self._bytes, self.params))

    def __hash__(self) -> int:
        return self._hash

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _PointsKey) and self.params == other.params and self._bytes == other._bytes


@functools.lru_cache(maxsize=8)
def _geometry(key: _PointsKey) -> tuple[IntArray, IntArray, BoolArray, FloatArray, FloatArray]:
    """Pixel indices ix, iy (N, K), validity (N, K), distances u0 (N, K) and half curvatures (N, 1) of the
    samples of N points: a function of the points alone, remembered for the last few point sets (a tracked
    static target samples the same points every frame; ~0.45 ms per 500 points in numpy, ~0.03 ms compiled).
    Read-only arrays. Compiled (:func:`~livetrack.estimator.edge_glue_kernels.sample_geometry`, the same numbers)
    or the numpy reference :func:`_geometry_numpy`, as ``key`` says."""
    pts, nrm, kappa = key.pts, key.nrm, key.kappa
    shape, half_width_px, tangent_half_width_px = key.params[:3]
    stencil = _stencil(half_width_px, tangent_half_width_px)
    if key.kernels == "numba":
        f8 = np.float64
        ix, iy, valid, u0, half_kappa = edge_glue_kernels.sample_geometry(
            int(shape[0]), int(shape[1]), kernel_array(pts, f8), kernel_array(nrm, f8),
            np.zeros(len(pts)) if kappa is None else kernel_array(kappa, f8), kappa is not None,
            kernel_array(stencil, f8))
        out = (ix, iy, valid, u0, half_kappa[:, None])
    else:
        out = _geometry_numpy(shape, pts, nrm, kappa, stencil)
    for x in out:
        x.flags.writeable = False
    return out


def _geometry_numpy(shape, pts, nrm, kappa, stencil):
    """The reference of :func:`_geometry` (numpy): ix, iy, valid, u0 (N, K), half curvatures (N, 1)."""
    n = len(pts)
    ix, iy, valid = _sample_pixels(shape, pts, nrm, stencil)
    dx, dy = ix - pts[:, 0:1], iy - pts[:, 1:2]
    u0 = nrm[:, 0:1] * dx + nrm[:, 1:2] * dy
    if kappa is None:
        half_kappa = np.zeros((n, 1))
    else:
        kappa = kappa[:, None]
        half_kappa = 0.5 * kappa
        t = nrm[:, 0:1] * dy - nrm[:, 1:2] * dx
        # signed distance to the circle through the point with centre point + normal / kappa, stable at 0
        u0 = (2.0 * u0 - kappa * (u0 * u0 + t * t)) / (
            1.0 + np.sqrt((1.0 - kappa * u0) ** 2 + (kappa * t) ** 2)
        )
    return ix, iy, valid, u0, half_kappa


def _compiled_read(img) -> bool:
    """Whether the compiled :func:`~livetrack.estimator.edge_glue_kernels.read_profiles` reads ``img`` (a dtype and
    layout it was warmed up for; others are read by the numpy lines of :func:`sample_profiles`, the same numbers)."""
    return img.flags.c_contiguous and img.dtype in _READ_DTYPES


_READ_DTYPES = frozenset(np.dtype(d) for d in edge_glue_kernels.READ_DTYPES)


def sample_profiles(img, pts, nrm, sat, half_width_px, tangent_half_width_px, noise_model, curvature_per_px,
                    reach_px=None):
    """The profiles of all N points (see :class:`Profiles`), samples per point and clipped samples per point. The
    pixels are read by the compiled :func:`~livetrack.estimator.edge_glue_kernels.read_profiles` or by numpy (the
    reference), as ``LIVETRACK_KERNELS`` says.

    reach_px: None, or (N, 2) how far each profile may reach toward its black side and toward its white side
    (pixels, along the normal): samples beyond are left out, on top of ``half_width_px`` (another edge of the
    target there: its blur would move the fitted one)."""
    n = len(pts)
    kappa = None if curvature_per_px is None else np.ascontiguousarray(
        np.broadcast_to(np.asarray(curvature_per_px, dtype=np.float64), (n,)))
    key = _PointsKey(img.shape, np.ascontiguousarray(pts), np.ascontiguousarray(nrm), kappa, half_width_px,
                     tangent_half_width_px, edge_kernels.kernels())
    ix, iy, valid, u0, half_kappa = _geometry(key)
    if reach_px is not None:
        reach = np.asarray(reach_px, dtype=np.float64).reshape(n, 2)
        valid = valid & (u0 >= -reach[:, 0:1]) & (u0 <= reach[:, 1:2])
    a, b = footprint_widths(nrm)
    weighted = noise_model is not None
    if key.kernels == "numba" and _compiled_read(img):
        noise = (float(noise_model[0]), float(noise_model[1])) if weighted else (0.0, 0.0)
        if valid.flags.writeable:  # the type the kernel was warmed up for: read-only, as _geometry's
            valid = valid.view()
            valid.flags.writeable = False
        data, valid, clip_hi, clip_lo, w, n_samples, n_clipped, top, any_clipped, span = \
            edge_glue_kernels.read_profiles(img, ix, iy, valid, float(sat), weighted, *noise)
        prof = Profiles(u0, a[:, None], b[:, None], data, valid, clip_hi, clip_lo, w, top[:, None], half_kappa,
                        None if weighted else w, n_samples, any_clipped, span, ix=ix, iy=iy)
        return prof, n_samples, n_clipped
    data = np.where(valid, img[iy, ix], 0).astype(np.float64)
    if img.dtype.kind == "f":
        valid = valid & np.isfinite(data)
        data[~valid] = 0.0
    clip_hi = valid & (data >= sat)
    clip_lo = valid & (data <= 0.0)
    any_hi, any_lo = clip_hi.any(axis=1), clip_lo.any(axis=1)
    if any_hi.any():  # a clipped sample says "at or above the clip level", which the clipped model meets exactly
        data[clip_hi] = sat
    if any_lo.any():
        data[clip_lo] = 0.0
    n_samples = valid.sum(axis=1)
    n_clipped = (clip_hi | clip_lo).sum(axis=1) if (any_hi.any() or any_lo.any()) else np.zeros(n, np.int64)
    if noise_model is None:
        w = valid.astype(np.float64)
    else:
        var = float(noise_model[0]) + float(noise_model[1]) * np.maximum(data, 0.0)
        w = np.where(valid, 1.0 / np.maximum(var, 1e-12 * max(sat * sat, 1e-300)), 0.0)
    top = (any_lo & ~any_hi).astype(np.float64)[:, None]
    prof = Profiles(u0, a[:, None], b[:, None], data, valid, clip_hi, clip_lo, w, top, half_kappa,
                    w if noise_model is None else None, ix=ix, iy=iy)
    return prof, n_samples, n_clipped
