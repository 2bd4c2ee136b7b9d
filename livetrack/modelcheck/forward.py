"""The fast forward model of a disk-grid exposure series, with the physics of ``livetrack.sim``.

Scene: black disks (reflectance ratio ``rho`` to the paper) of one printed radius on a square lattice, imaged
through a homography (nearly fronto-parallel sheet) and, with ``lens_distortion``, a radial distortion
``x_d = c + (x_u - c)(1 + k1 rho^2)``, rho = |x_u - c| / image half-diagonal, c = ``series.centre_px``.
Each disk's image is the ellipse the local affine map of the lattice makes of a circle of radius ``radius_rel``
pitches (``local_affines``; until 2026-12-02 a circle of the mean local scale, which left a 180-degree periodic
residual over edge direction on the real disks, whose images are 9 % longer along -17 deg than across).

Optics: the blurred disk indicator ``P(r)`` is computed once per parameter set as a Hankel transform,
``P(r) = 2 pi int q D(q) H(q) J0(2 pi q r) dq``, D the disk's transform ``R J1(2 pi q R) / q`` and H the
transfer function of the PSF: ``(1 - a) G(sigma) + a G(halo_sigma)`` (Gaussian core and ``halo``) x the
``defocus`` pillbox x the pixel box (its transfer function averaged over directions). Every pixel then
reads ``m = 1 - (1 - rho) sum_k P(|x - c_k| - (R_k - R))`` over its 4 nearest disks (exact superposition:
the blur is linear) -- a table look-up, so a whole frame costs milliseconds.

Noise: the prediction is the mean of the clipped noisy reading (``expected_reading``).

Radiometry and sensor, per frame of exposure t (ms), in DN: ``E = t w V(x) ((1 - f) m + f mean(m))``,
w the white rate (DN/ms), V = 1 - s rho^2 (``vignetting``), f the ``veiling_glare`` fraction; then the
simulator's own ``SensorModel.well`` (full-well clip at the saturation code, ``nonlinear`` knee,
``blooming`` along columns, its spill fraction fitted as ``spill_log10``: at 10x over-exposure a spill of
1e-6 already moves edge pixels by DN) and clipping to [0, saturation].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt
from scipy import special
from scipy.spatial import cKDTree

from livetrack.modelcheck import reading_kernel
from livetrack.modelcheck.series import ExposureSeries
from livetrack.sim.sensor import SensorModel

FloatArray = npt.NDArray[np.float64]

SIGMA_MIN_PX = 0.5
"""Lower bound of the PSF core sigma (px); sets the frequency range of the Hankel transform."""
PROFILE_STEP_PX = 0.05
"""Radial step of the profile table (linear interpolation error < 1e-3 of the step for sigma >= 0.5 px)."""
NEIGHBOURS = 4
"""Disks summed per pixel (the nearest ones)."""

BASE_PARAMETERS: dict[str, tuple[float, float]] = {
    "radius_rel": (0.02, 0.49),  # disk radius / lattice pitch
    "sigma_px": (SIGMA_MIN_PX, 6.0),  # Gaussian PSF core
    "white_dn_per_ms": (1e-9, 1e9),  # paper white rate
    "black_to_white": (0.0, 0.9),  # ink / paper (fixed when the print is known)
}
EFFECT_PARAMETERS: dict[str, dict[str, tuple[float, float, float]]] = {
    # effect -> parameter -> (initial, lower, upper)
    "halo": {"halo_fraction": (0.03, 1e-4, 0.6), "halo_sigma_px": (6.0, 1.5, 25.0)},
    "defocus": {"defocus_radius_px": (1.0, 0.05, 8.0)},
    "blooming": {"spill_log10": (-3.0, -8.0, 0.0)},
    "nonlinear": {"knee_fraction": (0.8, 0.2, 0.995)},
    "veiling_glare": {"glare_fraction": (0.02, 0.0, 0.5)},
    "vignetting": {"vignetting_strength": (0.05, -0.8, 0.95)},
    "lens_distortion": {"k1": (0.0, -1.0, 1.0)},
    "illumination_gradient": {"gradient_x": (0.0, -0.9, 0.9), "gradient_y": (0.0, -0.9, 0.9)},
    "anisotropic_core": {"aniso_c": (0.02, -0.8, 0.8), "aniso_s": (0.02, -0.8, 0.8)},
    "exponential_tail": {"exp_tail_fraction": (0.1, 1e-4, 0.8), "exp_tail_scale_px": (1.0, 0.15, 6.0)},
    "lorentzian_tail": {"lor_tail_fraction": (0.05, 1e-4, 0.8), "lor_tail_scale_px": (0.5, 0.15, 4.0)},
    "ink_floor": {"ink_black_to_white": (0.05, 0.0, 0.9)},
}
"""The catalogue of model extensions and their parameters (names match ``livetrack.sim.effects`` where the
effect exists there; ``k1`` is relative to the image half-diagonal). ``illumination_gradient`` is not a
simulator effect: the irradiance changes linearly across the image, ``1 + gx (x - cx) / hd + gy (y - cy) / hd``
(uneven lighting, e.g. a projector; vignetting is its radially symmetric counterpart).

``anisotropic_core``: the core's variance across an edge of normal direction theta is
``sigma^2 (1 + aniso_c cos 2 theta + aniso_s sin 2 theta)`` (exact for a straight edge; sigma^2 is the mean of
the two axes' variances); in the simulator's terms ``e = hypot(c, s)``, axis ``atan2(s, c) / 2``,
``sigma_x = sigma sqrt(1 + e)``, ``sigma_y = sigma sqrt(1 - e)``. The disk profile is interpolated, per pixel,
between profiles at ``ANISO_TABLES`` variances. ``exponential_tail`` / ``lorentzian_tail``: the core becomes
``(1 - t) G + t T`` as in ``livetrack.sim.optics`` (analytic transfer functions). ``ink_floor``: the ink/paper
ratio is fitted although the print is stated (``black_to_white`` known); when it is not, the ratio is already in
the baseline."""
ANISO_TABLES = 7
"""Profiles per anisotropic prediction (linear interpolation in the variance between them). Cost."""
RADIOMETRIC_PARAMETERS = frozenset({"white_dn_per_ms", "vignetting_strength", "gradient_x", "gradient_y",
                                    "glare_fraction", "knee_fraction", "spill_log10"})
"""Parameters that act after the scene (on its irradiance or in the sensor): changing them keeps the scene."""
SCENES_KEPT = 6
"""Scenes kept by ``ForwardModel.scene`` (a Jacobian's base point outlives its geometric steps). Memory: a few
full-size float64 images each."""
DISTANCES_KEPT = 2
"""Pixel-to-disk distance sets kept by ``ForwardModel`` (the fitted pixels' and the whole images')."""
Pixels = list[npt.NDArray[np.intp]] | None


def _pixels_key(pixels: Pixels) -> tuple[int, ...] | None:
    """What the kept scenes and distances are keyed on for ``pixels`` (their contents, not the list's identity)."""
    return None if pixels is None else tuple(hash(np.ascontiguousarray(p).tobytes()) for p in pixels)


# ---------------------------------------------------------------------------------------------- optics
class RadialProfiles:
    """Blurred disk profiles ``P(r)`` on a fixed radial grid 0..``r_max_px`` by a Hankel transform."""

    def __init__(self, r_max_px: float, radius_guess_px: float):
        self.r = np.arange(0.0, r_max_px + PROFILE_STEP_PX, PROFILE_STEP_PX)
        dq = 1.0 / (6.0 * (r_max_px + 2.0 * radius_guess_px))
        q_max = math.sqrt(18.0 / (2.0 * math.pi**2 * SIGMA_MIN_PX**2))  # core transfer < 1e-8 beyond
        self.q = (np.arange(int(q_max / dq)) + 0.5) * dq
        self.dq = dq
        self.j0 = special.j0(2.0 * np.pi * np.outer(self.q, self.r))  # (Nq, Nr)
        theta = (np.arange(64) + 0.5) * (0.5 * np.pi / 64)
        self.box = np.mean(np.sinc(np.outer(self.q, np.cos(theta))) * np.sinc(np.outer(self.q, np.sin(theta))),
                           axis=1)

    def transfer(self, sigma_px: float, halo_fraction: float = 0.0, halo_sigma_px: float = 6.0,
                 defocus_radius_px: float = 0.0, tail: tuple[str, float, float] | None = None) -> FloatArray:
        """Transfer function of PSF x pixel box on ``self.q``; ``tail`` = (kind, fraction, scale_px) or None."""
        q2 = (2.0 * np.pi**2) * self.q**2
        h = np.exp(-q2 * sigma_px**2)
        if tail is not None and tail[1] > 0:
            kind, t, b = tail
            w = 2.0 * np.pi * b * self.q
            ht = (1.0 + w * w) ** -1.5 if kind == "exponential" else np.exp(-w)
            h = (1.0 - t) * h + t * ht
        if halo_fraction > 0:
            h = (1.0 - halo_fraction) * h + halo_fraction * np.exp(-q2 * halo_sigma_px**2)
        if defocus_radius_px > 0:
            z = 2.0 * np.pi * self.q * defocus_radius_px
            h = h * 2.0 * special.j1(z) / z
        return h * self.box

    def disk(self, radius_px: float, transfer: FloatArray) -> FloatArray:
        """P(r) on ``self.r`` for a disk of ``radius_px`` (1 deep inside, 0 far outside)."""
        d = radius_px * special.j1(2.0 * np.pi * self.q * radius_px) / self.q
        return (2.0 * np.pi * self.dq) * ((self.q * d * transfer) @ self.j0)


# ---------------------------------------------------------------------------------------------- geometry
def homography_from_points(src: FloatArray, dst: FloatArray) -> FloatArray:
    """3x3 homography mapping 4 points ``src`` (4, 2) to ``dst`` (4, 2) (float64 DLT, h33 = 1)."""
    a = np.zeros((8, 8))
    b = np.zeros(8)
    for k, ((x, y), (u, v)) in enumerate(zip(src, dst, strict=True)):
        a[2 * k] = [x, y, 1, 0, 0, 0, -u * x, -u * y]
        a[2 * k + 1] = [0, 0, 0, x, y, 1, -v * x, -v * y]
        b[2 * k], b[2 * k + 1] = u, v
    return np.append(np.linalg.solve(a, b), 1.0).reshape(3, 3)


def apply_homography(h: FloatArray, pts: FloatArray) -> FloatArray:
    p = pts @ h[:, :2].T + h[:, 2]
    return p[:, :2] / p[:, 2:3]


@dataclass(frozen=True)
class LatticeGeometry:
    """Initial lattice: integer points ``ij`` (N, 2), corners (4, 2) of their box and where the fitted
    homography puts them (``corners_px`` (4, 2)); ``radius_rel`` the initial radius / pitch."""

    ij: FloatArray
    corners_ij: FloatArray
    corners_px: FloatArray
    radius_rel: float


def detect_lattice(series: ExposureSeries) -> LatticeGeometry:
    """Find the disks in the frame best exposed (white nearest half the saturation code) and fit the lattice."""
    s = series.saturation_dn
    medians = [float(np.median(fr[0])) for fr in series.images]
    k = int(np.argmin([abs(m - 0.5 * s) for m in medians]))
    img = series.images[k][0]
    grid = series.grids[0]
    u8 = np.clip(img / max(np.percentile(img, 99.5), 1e-9) * 255, 0, 255).astype(np.uint8)
    thr, _ = cv2.threshold(u8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    n, labels, stats, cents = cv2.connectedComponentsWithStats((u8 < thr).astype(np.uint8), connectivity=8)
    h, w = img.shape
    keep = []
    for i in range(1, n):
        x, y, bw, bh, area = stats[i]
        if area >= 6 and x > 0 and y > 0 and x + bw < w and y + bh < h and 0.6 < bw / bh < 1.6:
            keep.append(i)
    if len(keep) < 6:
        raise ValueError(f"{series.name}: found only {len(keep)} disks")
    areas = stats[keep, cv2.CC_STAT_AREA].astype(np.float64) * grid.step**2
    med = np.median(areas)
    good = np.abs(areas / med - 1) < 0.5
    pts = np.column_stack([grid.x0 + grid.step * cents[keep, 0], grid.y0 + grid.step * cents[keep, 1]])[good]
    areas = areas[good]
    cx, cy = series.centre_px
    o = int(np.argmin(np.hypot(pts[:, 0] - cx, pts[:, 1] - cy)))
    d = pts - pts[o]
    dist = np.hypot(d[:, 0], d[:, 1])
    dist[o] = np.inf
    v1 = d[int(np.argmin(dist))]
    cross = np.abs(d[:, 0] * v1[1] - d[:, 1] * v1[0]) / np.maximum(dist * np.hypot(*v1), 1e-9)
    dist2 = np.where(cross > 0.7, dist, np.inf)
    v2 = d[int(np.argmin(dist2))]
    basis = np.column_stack([v1, v2])
    ij = np.linalg.solve(basis, d.T).T
    ij_round = np.round(ij)
    ok = np.all(np.abs(ij - ij_round) < 0.25, axis=1)
    hom, _ = cv2.findHomography(ij_round[ok], pts[ok], 0)
    # Lattice points whose disks can touch the image.
    corners = np.array([[0, 0], [series.width, 0], [series.width, series.height], [0, series.height]], float)
    inv = apply_homography(np.linalg.inv(hom), corners - 0.5)
    lo, hi = np.floor(inv.min(axis=0)) - 1, np.ceil(inv.max(axis=0)) + 1
    ii, jj = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
    lattice = np.column_stack([ii.ravel(), jj.ravel()])
    corners_ij = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    pitch_px = math.sqrt(abs(np.linalg.det(basis)))
    radius_rel = math.sqrt(float(np.median(areas)) / math.pi) / pitch_px
    return LatticeGeometry(lattice, corners_ij, apply_homography(hom, corners_ij), radius_rel)


# ---------------------------------------------------------------------------------------------- model
@dataclass(frozen=True)
class Layout:
    """Pixels used by the model, per sub-image: coordinates, nearest disks, ROI mask; lattice info."""

    xs: list[FloatArray]  # (h, w) per sub-image
    ys: list[FloatArray]
    nearest: list[npt.NDArray[np.intp]]  # (h*w, NEIGHBOURS) lattice indices
    roi: list[npt.NDArray[np.bool_]]  # (h, w): pixels near an interior disk, valid in every frame
    interior: npt.NDArray[np.bool_]  # (N,) disks fully inside the image
    pitch_px: float


def centres_and_radii(series: ExposureSeries, lattice: LatticeGeometry, p: dict[str, float],
                      corner_offsets: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Disk centres (N, 2) and radii (N,) in px for the parameters ``p`` (``k1`` optional); the radius is the
    mean one, ``radius_rel`` x sqrt(det) of the local affine map (``local_affines``)."""
    centres, affine = local_affines(series, lattice, p, corner_offsets)
    return centres, p["radius_rel"] * np.sqrt(np.abs(np.linalg.det(affine)))


def local_affines(series: ExposureSeries, lattice: LatticeGeometry, p: dict[str, float],
                  corner_offsets: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Disk centres (N, 2) px and the local affine map of the lattice at each (N, 2, 2): columns the image of one
    lattice step along i and along j (px). A disk of radius r (lattice units) images as the ellipse
    ``{c + A u : |u| = r}``: a tilted sheet (or non-square pixels) makes disks elliptical."""
    hom = homography_from_points(lattice.corners_ij, lattice.corners_px + corner_offsets.reshape(4, 2))
    k1 = p.get("k1", 0.0)
    c = np.asarray(series.centre_px)
    hd = series.half_diagonal_px

    def project(ij: FloatArray) -> FloatArray:
        x = apply_homography(hom, ij)
        if k1 == 0.0:
            return x
        v = x - c
        rho2 = np.sum(v * v, axis=1, keepdims=True) / hd**2
        return c + v * (1.0 + k1 * rho2)

    ij = lattice.ij
    centres = project(ij)
    dx = project(ij + [0.5, 0.0]) - project(ij - [0.5, 0.0])
    dy = project(ij + [0.0, 0.5]) - project(ij - [0.0, 0.5])
    return centres, np.stack([dx, dy], axis=2)


def make_layout(series: ExposureSeries, lattice: LatticeGeometry, p: dict[str, float]) -> Layout:
    centres, radii = centres_and_radii(series, lattice, p, np.zeros(8))
    pitch_px = float(np.median(radii) / p["radius_rel"])
    tree = cKDTree(centres)
    margin = float(np.median(radii)) + 4.0 + 3.0 * p.get("sigma_px", 1.0)
    interior = ((centres[:, 0] > margin) & (centres[:, 1] > margin) & (centres[:, 0] < series.width - 1 - margin)
                & (centres[:, 1] < series.height - 1 - margin))
    xs, ys, nearest, roi = [], [], [], []
    valid_all = [np.logical_and.reduce([series.valid[f][g] for f in range(series.n_frames)])
                 for g in range(len(series.grids))]
    for g, grid in enumerate(series.grids):
        x, y = grid.coords(series.images[0][g].shape)
        dist, idx = tree.query(np.column_stack([x.ravel(), y.ravel()]), k=NEIGHBOURS)
        xs.append(x)
        ys.append(y)
        nearest.append(idx)
        r = (interior[idx[:, 0]] & (dist[:, 0] < 0.45 * pitch_px)).reshape(x.shape)
        roi.append(r & valid_all[g])
    return Layout(xs, ys, nearest, roi, interior, pitch_px)


@dataclass
class _Distances:
    """Per sub-image (NEIGHBOURS, P) arrays over its P pixels: the equivalent radial distance ``rho g`` (px) of
    each pixel from its nearest disks, their local scale g (px per lattice unit along the pixel's direction) and
    cos 2 theta, sin 2 theta of that direction; and the disks' mean scales (N,)."""

    radial: list[FloatArray]
    scale: list[FloatArray]
    cos2: list[FloatArray]
    sin2: list[FloatArray]
    disk_scale: FloatArray


class ForwardModel:
    """Predicts every frame of ``series`` from a parameter dict (see the module docstring)."""

    def __init__(self, series: ExposureSeries, lattice: LatticeGeometry, layout: Layout):
        self.series = series
        self.lattice = lattice
        self.layout = layout
        r0 = lattice.radius_rel * layout.pitch_px
        self.profiles = RadialProfiles(r_max_px=1.9 * layout.pitch_px + r0, radius_guess_px=r0)
        self.noise_a = 0.0
        self.noise_b = 0.0
        self._scenes: dict[tuple, list[FloatArray]] = {}
        self._distances_kept: dict[tuple, _Distances] = {}

    def expected_reading(self, mean_dn: FloatArray) -> FloatArray:
        """Mean of the clipped noisy reading, ``E[clip(X, 0, S)]`` with X ~ N(mean, a + b mean) (the noise model
        ``noise_a``, ``noise_b``; both 0: the plain clip). Near saturation a noisy pixel reads less on average
        than ``min(mean, S)``; without this term a nonlinear knee would be fitted to the noise. Compiled
        (``reading_kernel``) where numba is, else ``expected_reading_reference``."""
        s = self.series.saturation_dn
        if self.noise_a <= 0 and self.noise_b <= 0:
            return np.clip(mean_dn, 0.0, s)
        if reading_kernel.numba is None:  # pragma: no cover - numba is installed by pyproject.toml
            return expected_reading_reference(mean_dn, self.noise_a, self.noise_b, s)
        mu = np.ascontiguousarray(mean_dn, dtype=np.float64)
        out = np.empty_like(mu)
        reading_kernel.expected_clipped(mu.reshape(-1), float(self.noise_a), float(self.noise_b), float(s),
                                        out.reshape(-1))
        return out

    def _distances(self, p: dict[str, float], corner_offsets: FloatArray, pixels: Pixels) -> _Distances:
        """The pixels' distances from their nearest disks (all pixels, or ``pixels``: flat indices per sub-image);
        the last ``DISTANCES_KEPT`` are kept (most fit steps leave the geometry alone).

        With the disk's local affine map A and u = A^-1 (x - c) (lattice units), rho = |u| and
        ``g = 1 / |A^-T u / rho|``, so a disk of radius r has its edge at rho g = r g and a pixel lies
        (rho - r) g px outside it along the edge normal: the ellipse of a projected disk, not a circle."""
        key = (np.asarray(corner_offsets, dtype=np.float64).tobytes(), p.get("k1", 0.0), _pixels_key(pixels))
        if key in self._distances_kept:
            self._distances_kept[key] = self._distances_kept.pop(key)  # most recently used last
            return self._distances_kept[key]
        centres, affine = local_affines(self.series, self.lattice, p, corner_offsets)
        inv = np.linalg.inv(affine)  # (N, 2, 2)
        out = _Distances([], [], [], [], np.sqrt(np.abs(np.linalg.det(affine))))
        for g, (x, y, idx) in enumerate(zip(self.layout.xs, self.layout.ys, self.layout.nearest, strict=True)):
            x, y = x.ravel(), y.ravel()
            if pixels is not None:
                x, y, idx = x[pixels[g]], y[pixels[g]], idx[pixels[g]]
            c = centres[idx.T]  # (K, P, 2)
            dx, dy = x - c[..., 0], y - c[..., 1]
            m = inv[idx.T]  # (K, P, 2, 2)
            u0 = m[..., 0, 0] * dx + m[..., 0, 1] * dy
            u1 = m[..., 1, 0] * dx + m[..., 1, 1] * dy
            rho = np.maximum(np.hypot(u0, u1), 1e-12)
            # gradient of rho in px: A^-T u / rho
            g0 = (m[..., 0, 0] * u0 + m[..., 1, 0] * u1) / rho
            g1 = (m[..., 0, 1] * u0 + m[..., 1, 1] * u1) / rho
            scale = 1.0 / np.maximum(np.hypot(g0, g1), 1e-12)
            out.radial.append(rho * scale)
            out.scale.append(scale)
            d2 = np.maximum(dx * dx + dy * dy, 1e-18)
            out.cos2.append((dx * dx - dy * dy) / d2)
            out.sin2.append(2.0 * dx * dy / d2)
        self._distances_kept[key] = out
        while len(self._distances_kept) > DISTANCES_KEPT:
            del self._distances_kept[next(iter(self._distances_kept))]
        return out

    @staticmethod
    def _tail(p: dict[str, float]) -> tuple[str, float, float] | None:
        if p.get("exp_tail_fraction", 0.0) > 0:
            return ("exponential", p["exp_tail_fraction"], p["exp_tail_scale_px"])
        if p.get("lor_tail_fraction", 0.0) > 0:
            return ("lorentzian", p["lor_tail_fraction"], p["lor_tail_scale_px"])
        return None

    def scene(self, p: dict[str, float], corner_offsets: FloatArray, pixels: Pixels = None) -> list[FloatArray]:
        """Relative blurred reflectance m per sub-image (1 on paper): (h, w), or with ``pixels`` (flat indices per
        sub-image) 1-D at those pixels. The last ``SCENES_KEPT`` are kept: a fit's finite-difference steps in
        the radiometric parameters (``RADIOMETRIC_PARAMETERS``) reuse their base point's scene."""
        key = (tuple(sorted((k, v) for k, v in p.items() if k not in RADIOMETRIC_PARAMETERS)),
               np.asarray(corner_offsets, dtype=np.float64).tobytes(), _pixels_key(pixels))
        if key in self._scenes:
            self._scenes[key] = self._scenes.pop(key)  # most recently used last
            return self._scenes[key]
        out = self._scene(p, corner_offsets, pixels)
        self._scenes[key] = out
        while len(self._scenes) > SCENES_KEPT:
            del self._scenes[next(iter(self._scenes))]
        return out

    def _scene(self, p: dict[str, float], corner_offsets: FloatArray, pixels: Pixels) -> list[FloatArray]:
        dist = self._distances(p, corner_offsets, pixels)
        interior = self.layout.interior if np.any(self.layout.interior) else np.ones(dist.disk_scale.size, bool)
        s_mean = float(np.mean(dist.disk_scale[interior]))
        r_mean = p["radius_rel"] * s_mean
        halo = p.get("halo_fraction", 0.0)
        tail = self._tail(p)
        ac, as_ = p.get("aniso_c", 0.0), p.get("aniso_s", 0.0)
        e = math.hypot(ac, as_)
        sigma = p["sigma_px"]
        factors = np.linspace(1.0 - e, 1.0 + e, ANISO_TABLES) if e > 0 else np.ones(1)
        profs = [self.profiles.disk(r_mean, self.profiles.transfer(
            sigma * math.sqrt(f), halo, p.get("halo_sigma_px", 6.0), p.get("defocus_radius_px", 0.0), tail))
            for f in factors]
        reach = r_mean + 5.0 * sigma * math.sqrt(1.0 + e) + 1.5 * p.get("defocus_radius_px", 0.0) + 1.0
        if halo > 0:
            reach = max(reach, r_mean + 5.0 * p.get("halo_sigma_px", 6.0))
        if tail is not None:
            reach = max(reach, r_mean + (12.0 if tail[0] == "exponential" else 60.0) * tail[2])
        k_used = 1 if reach < 0.5 * self.layout.pitch_px else NEIGHBOURS
        rho = p["black_to_white"]
        if "ink_black_to_white" in p:
            rho = p["ink_black_to_white"]
        out = []
        for g, x in enumerate(self.layout.xs):
            total = np.zeros(dist.radial[g].shape[1])
            for k in range(k_used):
                d = dist.radial[g][k] - p["radius_rel"] * (dist.scale[g][k] - s_mean)
                if len(profs) == 1:
                    total += np.interp(d, self.profiles.r, profs[0], left=profs[0][0], right=0.0)
                    continue
                c2, s2 = dist.cos2[g][k], dist.sin2[g][k]
                pos = (ac * c2 + as_ * s2 + e) / (2.0 * e) * (ANISO_TABLES - 1)  # 0 .. ANISO_TABLES - 1
                lo = np.clip(np.floor(pos).astype(np.intp), 0, ANISO_TABLES - 2)
                w = np.clip(pos - lo, 0.0, 1.0)
                vals = np.stack([np.interp(d, self.profiles.r, pr, left=pr[0], right=0.0) for pr in profs])
                cols = np.arange(d.size)
                total += (1.0 - w) * vals[lo, cols] + w * vals[lo + 1, cols]
            m = 1.0 - (1.0 - rho) * total
            out.append(m.reshape(x.shape) if pixels is None else m)
        return out

    def frames(self, p: dict[str, float], corner_offsets: FloatArray, frames: list[int] | None = None,
               scene: list[FloatArray] | None = None, pixels: Pixels = None) -> list[list[FloatArray]]:
        """Predicted mean DN [frame][sub-image]: (h, w) images, or with ``pixels`` (flat indices per sub-image)
        1-D at those pixels (what a fit compares; blooming and glare act on the whole image, which is then
        predicted and sampled)."""
        s = self.series
        if frames is None:
            frames = list(range(s.n_frames))
        if pixels is not None and ("spill_log10" in p or p.get("glare_fraction", 0.0) > 0):
            whole = self.frames(p, corner_offsets, frames, scene)
            return [[a.ravel()[pix] for a, pix in zip(row, pixels, strict=True)] for row in whole]
        m = self.scene(p, corner_offsets, pixels) if scene is None else scene
        xs, ys = self.layout.xs, self.layout.ys
        if pixels is not None:
            xs = [x.ravel()[pix] for x, pix in zip(xs, pixels, strict=True)]
            ys = [y.ravel()[pix] for y, pix in zip(ys, pixels, strict=True)]
        f = p.get("glare_fraction", 0.0)
        if f > 0:
            mbar = float(np.mean(np.concatenate([a.ravel() for a in m])))
            m = [(1.0 - f) * a + f * mbar for a in m]
        vs = p.get("vignetting_strength", 0.0)
        if vs != 0.0:
            cx, cy = s.centre_px
            hd2 = s.half_diagonal_px**2
            m = [a * np.maximum(1.0 - vs * ((x - cx) ** 2 + (y - cy) ** 2) / hd2, 0.0)
                 for a, x, y in zip(m, xs, ys, strict=True)]
        gx, gy = p.get("gradient_x", 0.0), p.get("gradient_y", 0.0)
        if gx != 0.0 or gy != 0.0:
            cx, cy = s.centre_px
            hd = s.half_diagonal_px
            m = [a * np.maximum(1.0 + gx * (x - cx) / hd + gy * (y - cy) / hd, 0.0)
                 for a, x, y in zip(m, xs, ys, strict=True)]
        knee = p.get("knee_fraction", 1.0)
        spill = 10.0 ** p["spill_log10"] if "spill_log10" in p else 0.0
        sensor = None
        if knee < 1.0 or spill > 0.0:
            sensor = SensorModel(full_well_e=s.saturation_dn, read_noise_e=0.0, bit_depth=16,
                                 knee_fraction_of_full_well=min(knee, 1.0), bloom_spill_fraction=spill)
        out = []
        for i in frames:
            scale = s.exposure_ms[i] * p["white_dn_per_ms"]
            row = []
            for a in m:
                e = scale * a
                if sensor is not None:
                    e = sensor.well(e.astype(np.float32)).astype(np.float64)
                row.append(self.expected_reading(e))
            out.append(row)
        return out


def expected_reading_reference(mean_dn: FloatArray, noise_a: float, noise_b: float, saturation_dn: float
                               ) -> FloatArray:
    """numpy ``ForwardModel.expected_reading`` (noise a + b mean, not both 0): the reference of the compiled one."""
    s = saturation_dn
    mu = np.asarray(mean_dn, dtype=np.float64)
    out = np.clip(mu, 0.0, s)
    sd_max = math.sqrt(noise_a + noise_b * s)
    near = (np.abs(mu - s) < 6.0 * sd_max) | (mu < 6.0 * sd_max)
    m = mu[near]
    sd = np.sqrt(noise_a + noise_b * np.maximum(m, 0.0))
    zt = (m - s) / sd
    z0 = m / sd
    over = (m - s) * special.ndtr(zt) + sd * np.exp(-0.5 * zt * zt) / math.sqrt(2 * math.pi)
    under = -m * special.ndtr(-z0) + sd * np.exp(-0.5 * z0 * z0) / math.sqrt(2 * math.pi)
    out[near] = np.clip(m - over + under, 0.0, s)
    return out
