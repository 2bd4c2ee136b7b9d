"""Lens blur of the simulator: a shift-invariant point spread function (PSF) applied to an electron image.

The PSF is the convolution of up to three parts, each off when its size is 0:

* the core and halo: ``(1 - a) C + a G(halo_sigma_px)``, a core C plus a wide Gaussian halo holding the
  fraction ``a = halo_fraction`` of the energy (lens scatter, sensor cross-talk). The core is
  ``C = (1 - t) G + t T``: a Gaussian G of ``psf_sigma_px`` (along ``psf_angle_deg``; across it
  ``psf_sigma_y_px``, None for a round core: astigmatism, an anisotropic pixel response) and, with
  ``tail_fraction`` t > 0, a heavy-tailed kernel T of scale b = ``tail_scale_px`` (``tail_kind``):
  ``exponential`` T(r) = exp(-r / b) / (2 pi b^2) (transfer function (1 + (2 pi b q)^2)^-3/2) or
  ``lorentzian`` T(r) = b / (2 pi (r^2 + b^2)^3/2) (its line spread is the 1-D Lorentzian b / (pi (x^2 + b^2)),
  transfer function exp(-2 pi b q)). Unlike the Gaussian halo these have a cusp at 0 and wings that fall
  exponentially or as r^-3: the skirts of a real lens core (diffraction, aberrations, sensor diffusion);
* defocus: a uniform disk ("pillbox") of radius ``defocus_radius_px``;
* motion blur: a uniform line segment of length ``motion_blur_px`` at ``motion_blur_angle_deg`` from +x toward
  +y (image axes), centred on the pixel, so the image is the average over the exposure of a target moving at
  constant speed and the truth pose is the one at mid-exposure.

Every kernel sums to 1, so the blur conserves energy: away from the border (OpenCV ``BORDER_REPLICATE``) the
sum of the image is unchanged to float32 rounding.

Where the PSF is applied matters. The physical pixel value is the scene convolved with the PSF and then
integrated over the pixel square. Convolving the already pixel-integrated image with the PSF sampled at
whole-pixel offsets (``apply`` on a pixel image) only approximates that: a linear filter on pixel samples
cannot know where inside a pixel an edge lies, and for a Gaussian of 0.8 px the edge profile is then off by
up to 2.8 % of the step depending on the edge's sub-pixel phase (0.5 px: 8.9 %, 2 px: 0.5 %) -- which moves
threshold crossings under clipping by up to ~0.1 px. ``ImageFormation`` therefore renders the scene around
each sheet on a grid ``oversampling`` times finer, applies the PSF there (``scaled``) and bins the result to
pixels: the error falls as 1 / oversampling^2 (0.8 px Gaussian: 0.7 % at 2, 0.26 % at 3, 0.17 % at 4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.floating]

GAUSS_TRUNCATE_SIGMAS = 4.0
"""Gaussian kernels are cut at this many sigmas (energy beyond: 6e-5, renormalised into the kernel)."""


def gaussian_kernel(sigma_px: float) -> npt.NDArray[np.float32]:
    """1-D sampled Gaussian of standard deviation ``sigma_px``, cut at 4 sigma, summing to 1, shape (n,)."""
    radius = max(1, math.ceil(GAUSS_TRUNCATE_SIGMAS * sigma_px))
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma_px) ** 2)
    return (k / k.sum()).astype(np.float32)


EXPONENTIAL_TRUNCATE_SCALES = 12.0
"""The exponential tail kernel is cut at this many scales (energy beyond: 13 e^-12 = 8e-5, renormalised)."""
LORENTZIAN_TRUNCATE_SCALES = 30.0
"""The Lorentzian tail kernel is cut at this many scales (energy beyond: 1 / sqrt(1 + 30^2) = 3.3 %, renormalised
into the kernel: a wider cut costs a kernel of (2 x 30 b + 1)^2 taps)."""
TAIL_KINDS = ("exponential", "lorentzian")


def anisotropic_gaussian_kernel(sigma_x_px: float, sigma_y_px: float, angle_deg: float) -> npt.NDArray[np.float32]:
    """2-D sampled Gaussian with standard deviation ``sigma_x_px`` along the direction ``angle_deg`` (from +x
    toward +y) and ``sigma_y_px`` across it, cut at 4 of the larger sigma, summing to 1; shape (2 n + 1,) * 2."""
    n = max(1, math.ceil(GAUSS_TRUNCATE_SIGMAS * max(sigma_x_px, sigma_y_px)))
    x = np.arange(-n, n + 1, dtype=np.float64)
    a = math.radians(angle_deg)
    u = x[None, :] * math.cos(a) + x[:, None] * math.sin(a)
    v = -x[None, :] * math.sin(a) + x[:, None] * math.cos(a)
    k = np.exp(-0.5 * ((u / max(sigma_x_px, 1e-6)) ** 2 + (v / max(sigma_y_px, 1e-6)) ** 2))
    return (k / k.sum()).astype(np.float32)


def tail_kernel(kind: str, scale_px: float, subsamples: int = 5) -> npt.NDArray[np.float32]:
    """2-D radially symmetric heavy-tail kernel (module docstring) of scale ``scale_px``, each tap the mean of
    the kernel over its pixel (``subsamples`` x ``subsamples`` points: the cusp at 0 is not a point sample),
    cut at ``EXPONENTIAL_TRUNCATE_SCALES`` / ``LORENTZIAN_TRUNCATE_SCALES`` scales and renormalised to sum 1."""
    if kind not in TAIL_KINDS:
        raise ValueError(f"tail kind must be one of {TAIL_KINDS}, got {kind!r}")
    cut = EXPONENTIAL_TRUNCATE_SCALES if kind == "exponential" else LORENTZIAN_TRUNCATE_SCALES
    n = max(1, math.ceil(cut * scale_px))
    sub = (np.arange(subsamples) + 0.5) / subsamples - 0.5
    coords = (np.arange(-n, n + 1)[:, None] + sub[None, :]).ravel()
    r = np.hypot(coords[:, None], coords[None, :])
    if kind == "exponential":
        k = np.exp(-r / scale_px)
    else:
        k = (r * r + scale_px * scale_px) ** -1.5
    k = np.where(r <= cut * scale_px, k, 0.0)
    size = 2 * n + 1
    k = k.reshape(size, subsamples, size, subsamples).sum(axis=(1, 3))
    return (k / k.sum()).astype(np.float32)


def pillbox_kernel(radius_px: float, oversampling: int = 16) -> npt.NDArray[np.float32]:
    """2-D uniform disk of ``radius_px``, each tap the disk's area inside that pixel (estimated on an
    ``oversampling`` x ``oversampling`` grid), summing to 1; the area weights add the variance of a pixel box
    (1/6 px^2) to the disk's r^2 / 2. Shape (2 n + 1, 2 n + 1), n = ceil(radius_px + 0.5)."""
    n = math.ceil(radius_px + 0.5)
    sub = (np.arange(oversampling) + 0.5) / oversampling - 0.5
    coords = (np.arange(-n, n + 1)[:, None] + sub[None, :]).ravel()
    inside = (coords[:, None] ** 2 + coords[None, :] ** 2) <= radius_px**2
    size = 2 * n + 1
    k = inside.reshape(size, oversampling, size, oversampling).sum(axis=(1, 3)).astype(np.float64)
    if k.sum() == 0:  # radius far below a pixel: a delta
        k[n, n] = 1.0
    return (k / k.sum()).astype(np.float32)


def line_kernel(length_px: float, angle_deg: float) -> npt.NDArray[np.float32]:
    """2-D uniform line segment of ``length_px`` centred on the middle tap, at ``angle_deg`` from +x toward
    +y; the segment is sampled at the midpoints of 1/16 px pieces and each sample split bilinearly over its
    four nearest taps, so sub-pixel lengths and any angle are represented (the split adds about 1/6 px^2 of
    variance, like the pixel box, to the L^2 / 12 of the segment). Sums to 1; shape (2 n + 1, 2 n + 1)."""
    half = 0.5 * length_px
    n = math.ceil(half) + 1
    size = 2 * n + 1
    count = max(1, math.ceil(length_px * 16))
    s = ((np.arange(count) + 0.5) / count - 0.5) * length_px
    a = math.radians(angle_deg)
    x, y = n + s * math.cos(a), n + s * math.sin(a)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    k = np.zeros((size, size))
    splits = ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy))
    for dx, dy, w in splits:
        np.add.at(k, (y0 + dy, x0 + dx), w)
    return (k / k.sum()).astype(np.float32)


@dataclass(frozen=True)
class OpticsModel:
    """The PSF of lens and sensor, applied by ``apply``. All sizes in pixels; every part is off at 0.

    psf_sigma_px : standard deviation of the Gaussian core (default 0.8, a good lens slightly defocused); with
        ``psf_sigma_y_px`` set, along the direction ``psf_angle_deg``. Larger blurs edges and, under
        overexposure, increases the edge bias (about 0.8 sigma at 2x). Cost: a separable 2 * ceil(4 sigma) + 1
        tap filter, about 10 ms for 1920x1200.
    psf_sigma_y_px : standard deviation of the core across ``psf_angle_deg`` (default None: round core). An
        anisotropic core blurs and, under overexposure, shrinks disks more along one axis. Cost: a 2-D filter
        unless the angle is a multiple of 90 deg.
    psf_angle_deg : direction of the ``psf_sigma_px`` axis, from +x toward +y (default 0).
    tail_fraction : share of the core's energy in a heavy tail (default 0: none). Lifts the dark side of an edge
        within a few px far more than a Gaussian of the same width. Cost: a 2-D filter of (2 cut b + 1)^2 taps.
    tail_kind : ``exponential`` or ``lorentzian`` (module docstring).
    tail_scale_px : the tail's scale b (default 1).
    halo_fraction : share of the energy in the wide halo (default 0: none). Lifts the dark side of an edge
        near bright areas and so biases edge positions the way real lenses do. Doubles the cost.
    halo_sigma_px : standard deviation of the halo Gaussian (default 6). Cost grows linearly with it.
    defocus_radius_px : radius of the defocus disk (default 0: in focus). Cost: a 2-D filter (OpenCV
        switches to the DFT for large kernels), about 30 ms for 1920x1200 at 3 px.
    motion_blur_px : length of the motion-blur segment (default 0: static). Same cost class as defocus.
    motion_blur_angle_deg : direction of the motion from +x toward +y (default 0: horizontal).
    oversampling : the PSF is applied on a grid this many times finer than the pixels when ``ImageFormation``
        renders a scene (module docstring); 1 applies it to the pixel image. Default 3: edge profiles within
        0.3 % of the step for a 0.8 px Gaussian. Cost: oversampling^2 more rendered pixels around each sheet.
    """

    psf_sigma_px: float = 0.8
    psf_sigma_y_px: float | None = None
    psf_angle_deg: float = 0.0
    tail_fraction: float = 0.0
    tail_kind: str = "exponential"
    tail_scale_px: float = 1.0
    halo_fraction: float = 0.0
    halo_sigma_px: float = 6.0
    defocus_radius_px: float = 0.0
    motion_blur_px: float = 0.0
    motion_blur_angle_deg: float = 0.0
    oversampling: int = 3

    def __post_init__(self) -> None:
        for name in ("psf_sigma_px", "defocus_radius_px", "motion_blur_px"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"OpticsModel.{name} must be finite and >= 0, got {value}")
        if not 0.0 <= self.halo_fraction < 1.0:
            raise ValueError(f"OpticsModel.halo_fraction must be in [0, 1), got {self.halo_fraction}")
        if not (math.isfinite(self.halo_sigma_px) and self.halo_sigma_px > 0):
            raise ValueError(f"OpticsModel.halo_sigma_px must be > 0, got {self.halo_sigma_px}")
        if not math.isfinite(self.motion_blur_angle_deg):
            raise ValueError("OpticsModel.motion_blur_angle_deg must be finite")
        if self.psf_sigma_y_px is not None and not (math.isfinite(self.psf_sigma_y_px) and self.psf_sigma_y_px > 0
                                                    and self.psf_sigma_px > 0):
            raise ValueError(f"OpticsModel.psf_sigma_y_px must be > 0 (with psf_sigma_px > 0) or None, got "
                             f"{self.psf_sigma_y_px}")
        if not math.isfinite(self.psf_angle_deg):
            raise ValueError("OpticsModel.psf_angle_deg must be finite")
        if not 0.0 <= self.tail_fraction < 1.0:
            raise ValueError(f"OpticsModel.tail_fraction must be in [0, 1), got {self.tail_fraction}")
        if self.tail_kind not in TAIL_KINDS:
            raise ValueError(f"OpticsModel.tail_kind must be one of {TAIL_KINDS}, got {self.tail_kind!r}")
        if not (math.isfinite(self.tail_scale_px) and self.tail_scale_px > 0):
            raise ValueError(f"OpticsModel.tail_scale_px must be > 0, got {self.tail_scale_px}")
        if not (isinstance(self.oversampling, int) and 1 <= self.oversampling <= 8):
            raise ValueError(f"OpticsModel.oversampling must be an integer in 1..8, got {self.oversampling}")

    @property
    def is_identity(self) -> bool:
        """True if ``apply`` returns its input unchanged."""
        return (self.psf_sigma_px == 0 and self.halo_fraction == 0 and self.defocus_radius_px == 0
                and self.motion_blur_px == 0 and self.tail_fraction == 0)

    @property
    def tail_cut_px(self) -> float:
        """Radius where the tail kernel is cut (0 without a tail)."""
        if self.tail_fraction == 0:
            return 0.0
        cut = EXPONENTIAL_TRUNCATE_SCALES if self.tail_kind == "exponential" else LORENTZIAN_TRUNCATE_SCALES
        return cut * self.tail_scale_px

    def support_radius_px(self) -> float:
        """Distance (pixels) beyond which the PSF is zero: 4 sigma of the widest Gaussian, plus the defocus
        radius and half the motion-blur length (0 for the identity)."""
        sigma = max(self.psf_sigma_px, self.psf_sigma_y_px or 0.0,
                    self.halo_sigma_px if self.halo_fraction > 0 else 0.0)
        return (max(GAUSS_TRUNCATE_SIGMAS * sigma, self.tail_cut_px) + self.defocus_radius_px
                + 0.5 * self.motion_blur_px)

    def scaled(self, factor: float) -> OpticsModel:
        """The same PSF expressed on a grid ``factor`` times finer (all lengths x factor, oversampling 1)."""
        return OpticsModel(psf_sigma_px=self.psf_sigma_px * factor,
                           psf_sigma_y_px=None if self.psf_sigma_y_px is None else self.psf_sigma_y_px * factor,
                           psf_angle_deg=self.psf_angle_deg, tail_fraction=self.tail_fraction,
                           tail_kind=self.tail_kind, tail_scale_px=self.tail_scale_px * factor,
                           halo_fraction=self.halo_fraction,
                           halo_sigma_px=self.halo_sigma_px * factor,
                           defocus_radius_px=self.defocus_radius_px * factor,
                           motion_blur_px=self.motion_blur_px * factor,
                           motion_blur_angle_deg=self.motion_blur_angle_deg, oversampling=1)

    def apply(self, image: FloatArray) -> npt.NDArray[np.float32]:
        """Blur a (H, W) image (any float dtype; electrons or reflectance) with the PSF -> float32 (H, W).

        Energy preserving (every kernel sums to 1); borders replicate the edge pixels. On a pixel-integrated
        image this approximates PSF-then-pixel-integration only to a few % of an edge's step for a PSF below
        ~1 px (module docstring); ``ImageFormation`` applies it on a finer grid. ``oversampling`` is not used
        here.
        """
        img = np.ascontiguousarray(image, dtype=np.float32)
        if img.ndim != 2:
            raise ValueError(f"image must be (H, W), got shape {img.shape}")
        border = cv2.BORDER_REPLICATE
        if self.psf_sigma_px > 0 or self.halo_fraction > 0 or self.tail_fraction > 0:
            core = img
            if self.psf_sigma_px > 0:
                core = self._gaussian_core(img)
            if self.tail_fraction > 0:
                tail = cv2.filter2D(img, cv2.CV_32F, tail_kernel(self.tail_kind, self.tail_scale_px),
                                    borderType=border)
                core = cv2.addWeighted(core, 1.0 - self.tail_fraction, tail, self.tail_fraction, 0.0)
            if self.halo_fraction > 0:
                k = gaussian_kernel(self.halo_sigma_px)
                halo = cv2.sepFilter2D(img, cv2.CV_32F, k, k, borderType=border)
                core = cv2.addWeighted(core, 1.0 - self.halo_fraction, halo, self.halo_fraction, 0.0)
            img = core
        if self.defocus_radius_px > 0:
            img = cv2.filter2D(img, cv2.CV_32F, pillbox_kernel(self.defocus_radius_px), borderType=border)
        if self.motion_blur_px > 0:
            k = line_kernel(self.motion_blur_px, self.motion_blur_angle_deg)
            img = cv2.filter2D(img, cv2.CV_32F, k, borderType=border)
        if img is image:
            img = img.copy()
        return img

    def _gaussian_core(self, img: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """The Gaussian part of the core: separable when round or axis-aligned, else a 2-D filter."""
        border = cv2.BORDER_REPLICATE
        sx, sy = self.psf_sigma_px, self.psf_sigma_y_px
        if sy is None or sy == sx:
            k = gaussian_kernel(sx)
            return cv2.sepFilter2D(img, cv2.CV_32F, k, k, borderType=border)
        quarter = self.psf_angle_deg / 90.0
        if quarter == round(quarter):
            along_x = round(quarter) % 2 == 0
            kx, ky = (gaussian_kernel(sx), gaussian_kernel(sy)) if along_x else (gaussian_kernel(sy),
                                                                                 gaussian_kernel(sx))
            return cv2.sepFilter2D(img, cv2.CV_32F, kx, ky, borderType=border)
        return cv2.filter2D(img, cv2.CV_32F, anisotropic_gaussian_kernel(sx, sy, self.psf_angle_deg),
                            borderType=border)
