"""Image formation: from target placements to the digital image a camera would deliver.

The chain, per pixel (H, W images; pixel (x, y), (0, 0) the centre of the top-left pixel):

1. optical image (``optical_image``): the scene reflectance (``render_reflectance``: exact area averages,
   lens distortion included, the ``lens_distortion`` effect replacing the camera's coefficients) blurred by
   the PSF (``OpticsModel``: Gaussian core, ``halo``, ``defocus``, ``motion_blur``; energy kept) and
   integrated over each pixel. Around each sheet the scene is rendered ``optics.oversampling`` times finer,
   blurred there and binned, so that the PSF acts before the pixel integration as in a camera (see
   ``livetrack.sim.optics``); elsewhere the image is the uniform background, which the PSF leaves unchanged;
2. electrons: x ``radiometry.white_rate_e_per_us`` (electrons per microsecond on a pixel of reflectance 1,
   illumination and lens aperture folded in) x the ``vignetting`` falloff x ``exposure_us``. Vignetting is
   applied after the blur: it changes by < 0.2 % per pixel, so the order matters by < 0.1 % of an edge step;
3. ``veiling_glare``: E -> (1 - f) E + f mean(E), the fraction f of the light spread over the frame;
4. sensor (``SensorModel``): shot noise, the well (full-well clip or the ``nonlinear`` knee), ``blooming``,
   read noise, gain, black level, ADC rounding and clipping;
5. output (other renderers' and cameras' conventions): ``srgb_encoding`` or ``gamma_encoding`` on the DN
   before rounding, ``jpeg`` after it.

Steps 1-3 give ``expected_electrons`` (noise-free, before the well); ``expected_dn`` is the noise-free DN
(clipped, not rounded); ``render`` the uint8/uint16 image.

Speed: steps 2-4 take about 0.1 s for a 1920x1200 frame (float32, OpenCV); step 1 depends on the size of the
sheets in the image, ``oversampling`` and ``supersampling`` (0.1-2 s per pose for paper-lab, most of it the
renderer inverting the lens model on the fine grid). To render several exposures of one scene, compute
``optical_image`` once and use the ``*_from_optical`` variants (``Scenario.frames`` does).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.sim.coverage import DEFAULT_SUPERSAMPLING, Placement, render_reflectance, sheet_roi
from livetrack.sim.effects import Effects, encode_dn
from livetrack.sim.optics import OpticsModel
from livetrack.sim.sensor import SensorModel
from livetrack.sim.texture import BackgroundPattern, background_image

FloatArray = npt.NDArray[np.floating]

DEFAULT_WHITE_RATE_E_PER_US = 3.2
"""Puts white paper of reflectance 0.85 at 55 % of a 10000 e full well in about 2000 us."""


@dataclass(frozen=True)
class Radiometry:
    """Light reaching the sensor.

    white_rate_e_per_us : electrons per microsecond collected by a pixel imaging a surface of reflectance 1
        (default 3.2: reflectance 0.85 gives 5500 e, 55 % of 10000 e, in 2022 us). Folds in illumination,
        aperture, quantum efficiency and pixel area; only exposure x rate matters for the image.
    """

    white_rate_e_per_us: float = DEFAULT_WHITE_RATE_E_PER_US

    def __post_init__(self) -> None:
        if not (math.isfinite(self.white_rate_e_per_us) and self.white_rate_e_per_us > 0):
            raise ValueError(f"Radiometry.white_rate_e_per_us must be > 0, got {self.white_rate_e_per_us}")

    def exposure_for(self, reflectance: float, electrons: float) -> float:
        """Exposure (us) at which a surface of ``reflectance`` collects ``electrons`` (no vignetting)."""
        return electrons / (reflectance * self.white_rate_e_per_us)


@dataclass(frozen=True)
class Illumination:
    """Uneven light over the scene (targets and background alike): irradiance x ``1 + gradient * p``, p the
    position along the direction ``angle_deg`` (from +x toward +y) from the image centre, -1 at one side of the
    image and +1 at the other (the half-extent of the image along that direction). ``gradient`` in [0, 1)."""

    gradient: float = 0.0
    angle_deg: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.gradient) and 0.0 <= self.gradient < 1.0):
            raise ValueError(f"Illumination.gradient must be in [0, 1), got {self.gradient}")

    def factor_map(self, camera: CameraModel) -> npt.NDArray[np.float32]:
        """(H, W) float32 irradiance factor at the pixel centres of ``camera``."""
        a = math.radians(self.angle_deg)
        c, s = math.cos(a), math.sin(a)
        x = np.arange(camera.width, dtype=np.float64) - (camera.width - 1) / 2.0
        y = np.arange(camera.height, dtype=np.float64) - (camera.height - 1) / 2.0
        half = 0.5 * (abs(c) * (camera.width - 1) + abs(s) * (camera.height - 1))
        p = (c * x[None, :] + s * y[:, None]) / max(half, 1e-9)
        return (1.0 + self.gradient * p).astype(np.float32)


@dataclass(frozen=True)
class ImageFormation:
    """Camera, light, lens, sensor and effects: everything needed to render a frame.

    camera : geometry and bit depth (``sensor.bit_depth`` must match ``camera.bit_depth``).
    radiometry, optics, sensor : see their classes; defaults give a 0.8 px Gaussian PSF, 10000 e full well,
        5 e read noise.
    effects : optional effects (all off by default, see ``livetrack.sim.effects``). Halo, defocus and motion
        blur act through the optics, blooming and nonlinear through the sensor: set each either in
        ``effects`` or on the model, not both (ValueError).
    background_reflectance : reflectance where no target sheet is seen (default 0.2).
    background_pattern : a ``texture.BackgroundPattern`` seen where no sheet is (in pixel positions),
        replacing ``background_reflectance``; None (default): the uniform background. The pattern is rendered
        on the pixels (2 x 2 points per pixel) and blurred by the PSF there, and on the oversampled grid around
        each sheet.
    illumination : ``Illumination`` (an irradiance gradient over the scene, targets included), or None.
    supersampling : sub-cells per mixed (edge) pixel for the reflectance, a perfect square (passed to
        ``render_reflectance``; default its ``DEFAULT_SUPERSAMPLING``, 16). Straight edges are exact at any
        value; more makes curved edges more exact and the edge pixels proportionally slower.
    """

    camera: CameraModel
    radiometry: Radiometry = field(default_factory=Radiometry)
    optics: OpticsModel = field(default_factory=OpticsModel)
    sensor: SensorModel = field(default_factory=SensorModel)
    effects: Effects = field(default_factory=Effects)
    background_reflectance: float = 0.2
    supersampling: int = DEFAULT_SUPERSAMPLING
    background_pattern: BackgroundPattern | None = None
    illumination: Illumination | None = None

    def __post_init__(self) -> None:
        if self.sensor.bit_depth != self.camera.bit_depth:
            raise ValueError(f"sensor.bit_depth ({self.sensor.bit_depth}) differs from camera.bit_depth "
                             f"({self.camera.bit_depth})")
        if not 0.0 <= self.background_reflectance <= 1.0:
            raise ValueError(f"background_reflectance must be in [0, 1], got {self.background_reflectance}")
        e, o, s = self.effects, self.optics, self.sensor
        clashes = [("halo", e.halo, o.halo_fraction > 0), ("defocus", e.defocus, o.defocus_radius_px > 0),
                   ("motion_blur", e.motion_blur, o.motion_blur_px > 0),
                   ("blooming", e.blooming, s.bloom_spill_fraction > 0),
                   ("nonlinear", e.nonlinear, s.knee_fraction_of_full_well < 1)]
        for name, effect, on_model in clashes:
            if effect is not None and on_model:
                raise ValueError(f"effect {name!r} is set both in effects and on the optics/sensor model")
        if e.jpeg is not None and s.bit_depth != 8:
            raise ValueError(f"effect 'jpeg' needs an 8-bit camera, got {s.bit_depth} bits")

    # ------------------------------------------------------------------ resolved models
    @cached_property
    def optics_in_use(self) -> OpticsModel:
        """``optics`` with the PSF effects applied (``Effects.fold_optics``: halo, defocus, motion blur,
        anisotropic core, heavy tails)."""
        return self.effects.fold_optics(self.optics)

    @cached_property
    def sensor_in_use(self) -> SensorModel:
        """``sensor`` with the blooming and nonlinear effects applied."""
        s, e = self.sensor, self.effects
        if e.blooming is not None:
            s = replace(s, bloom_spill_fraction=e.blooming.spill_fraction)
        if e.nonlinear is not None:
            s = replace(s, knee_fraction_of_full_well=e.nonlinear.knee_fraction_of_full_well)
        return s

    @cached_property
    def render_camera(self) -> CameraModel:
        """The camera the scene is rendered through: ``camera`` or its ``lens_distortion`` replacement."""
        if self.effects.lens_distortion is None:
            return self.camera
        return replace(self.camera, dist=self.effects.lens_distortion.dist)

    @cached_property
    def vignetting_map(self) -> npt.NDArray[np.float32] | None:
        """(H, W) float32 irradiance factor ``max(0, 1 - s r^2)``, or None without vignetting."""
        if self.effects.vignetting is None:
            return None
        cam = self.camera
        half_diag = 0.5 * math.hypot(cam.width, cam.height)
        x = (np.arange(cam.width, dtype=np.float64) - cam.cx) / half_diag
        y = (np.arange(cam.height, dtype=np.float64) - cam.cy) / half_diag
        r2 = y[:, None] ** 2 + x[None, :] ** 2
        return np.maximum(1.0 - self.effects.vignetting.strength * r2, 0.0).astype(np.float32)

    def _with_ink(self, placements: Sequence[Placement]) -> list[Placement]:
        """The placements with the ``ink_floor`` effect's black in their textures (unchanged without it)."""
        if self.effects.ink_floor is None:
            return list(placements)
        return [replace(p, texture=self.effects.texture_with_ink(p.texture)) for p in placements]

    @cached_property
    def illumination_map(self) -> npt.NDArray[np.float32] | None:
        """(H, W) float32 irradiance factor of ``illumination`` (pixel centres), or None."""
        if self.illumination is None:
            return None
        return self.illumination.factor_map(self.camera)

    @cached_property
    def _background_frame(self) -> float | npt.NDArray[np.float32]:
        """``background`` on the whole ``render_camera`` (kept: it is the same for every frame)."""
        return self.background(self.render_camera)

    def background(self, camera: CameraModel, x0_px: float = 0.0, y0_px: float = 0.0,
                   step_px: float = 1.0) -> float | npt.NDArray[np.float32]:
        """The background on ``camera``'s grid, whose pixel (0, 0) is at position (x0_px, y0_px) of the frame and
        whose pixels are ``step_px`` frame pixels apart: ``background_reflectance`` or an (H, W) image."""
        if self.background_pattern is None:
            return self.background_reflectance
        return background_image(self.background_pattern, camera.width, camera.height, x0_px, y0_px, step_px)

    # ------------------------------------------------------------------ exposure
    def nominal_exposure_us(self, white_reflectance: float, fraction_of_full_well: float) -> float:
        """Exposure that puts a surface of ``white_reflectance`` at ``fraction_of_full_well`` (at the
        principal point: no vignetting, before blur)."""
        electrons = fraction_of_full_well * self.sensor.full_well_e
        return self.radiometry.exposure_for(white_reflectance, electrons)

    # ------------------------------------------------------------------ the chain
    def reflectance(self, placements: Sequence[Placement]) -> npt.NDArray[np.float64]:
        """(H, W) float64 pixel-averaged reflectance of the scene through ``render_camera`` (no blur)."""
        placements = self._with_ink(placements)
        cam = self.render_camera
        return render_reflectance(cam, placements, background=self._background_frame,
                                  supersampling=self.supersampling)

    def optical_image(self, placements: Sequence[Placement]) -> npt.NDArray[np.float32]:
        """(H, W) float32: the reflectance blurred by the PSF, then integrated over each pixel (step 1).

        The core (with defocus and motion blur) acts on an ``oversampling`` times finer rendering around each
        sheet; the wide halo (with the same defocus and motion blur) on the pixel image, where its sampling
        error is negligible (< 0.1 % of the halo's share for halo_sigma_px >= 4).
        """
        optics = self.optics_in_use
        n = optics.oversampling
        if optics.is_identity or n == 1:
            return self._lit(optics.apply(self.reflectance(placements)))
        cam = self.render_camera
        placements = self._with_ink(placements)
        a = optics.halo_fraction
        core = replace(optics, halo_fraction=0.0)
        fine_core = core.scaled(n)
        reflectance = np.empty((cam.height, cam.width), dtype=np.float32)
        reflectance[:] = self._background_frame
        # A uniform background is left as it is by the PSF; a pattern is blurred on the pixels.
        blurred = reflectance.copy() if self.background_pattern is None else core.apply(reflectance)
        pad = math.ceil(core.support_radius_px()) + 1
        placements = list(placements)
        for placement in placements:
            roi = sheet_roi(cam, placement.pose, placement.texture.bounds_m, margin_px=2 * pad)
            if roi is None:
                continue
            i0, i1, j0, j1 = roi
            fine_cam = CameraModel(width=(j1 - j0) * n, height=(i1 - i0) * n, fx=cam.fx * n, fy=cam.fy * n,
                                   cx=(cam.cx - j0 + 0.5) * n - 0.5, cy=(cam.cy - i0 + 0.5) * n - 0.5,
                                   dist=cam.dist, bit_depth=cam.bit_depth)
            fine_bg = self.background(fine_cam, j0 - 0.5 + 0.5 / n, i0 - 0.5 + 0.5 / n, 1.0 / n)
            fine = render_reflectance(fine_cam, placements, background=fine_bg,
                                      supersampling=self.supersampling).astype(np.float32)
            # Keep only pixels at least ``pad`` from a cut side of the ROI (the image border is no cut: the
            # blur replicates it there as ``OpticsModel.apply`` does).
            a0 = i0 + pad if i0 > 0 else 0
            a1 = i1 - pad if i1 < cam.height else i1
            b0 = j0 + pad if j0 > 0 else 0
            b1 = j1 - pad if j1 < cam.width else j1
            if a0 >= a1 or b0 >= b1:
                continue
            inner = (slice(a0 - i0, a1 - i0), slice(b0 - j0, b1 - j0))
            for target, image in ((reflectance, fine), (blurred, fine_core.apply(fine))):
                binned = image.reshape(i1 - i0, n, j1 - j0, n).mean(axis=(1, 3), dtype=np.float64)
                target[a0:a1, b0:b1] = binned[inner]
        if a > 0:
            halo = OpticsModel(psf_sigma_px=optics.halo_sigma_px, defocus_radius_px=optics.defocus_radius_px,
                               motion_blur_px=optics.motion_blur_px,
                               motion_blur_angle_deg=optics.motion_blur_angle_deg, oversampling=1)
            blurred = cv2.addWeighted(blurred, 1.0 - a, halo.apply(reflectance), a, 0.0)
        return self._lit(blurred)

    def _lit(self, optical: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """The optical image times the illumination map (after the blur: the map is smooth)."""
        if self.illumination_map is None:
            return optical
        return optical * self.illumination_map

    def electrons_from_optical(self, optical: FloatArray, exposure_us: float) -> npt.NDArray[np.float32]:
        """Mean electrons (H, W) float32 from an ``optical_image`` (H, W): steps 2-3 of the chain."""
        if not (math.isfinite(exposure_us) and exposure_us >= 0):
            raise ValueError(f"exposure_us must be finite and >= 0, got {exposure_us}")
        img = np.asarray(optical)
        if img.shape != (self.camera.height, self.camera.width):
            raise ValueError(f"image shape {img.shape} != camera (height, width) "
                             f"{(self.camera.height, self.camera.width)}")
        e = img.astype(np.float32) * np.float32(self.radiometry.white_rate_e_per_us * exposure_us)
        if self.vignetting_map is not None:
            e *= self.vignetting_map
        if self.effects.veiling_glare is not None:
            f = self.effects.veiling_glare.fraction
            mean = float(np.mean(e, dtype=np.float64))
            e *= np.float32(1.0 - f)
            e += np.float32(f * mean)
        return e

    def electrons_from_reflectance(self, reflectance: FloatArray,
                                   exposure_us: float) -> npt.NDArray[np.float32]:
        """Mean electrons (H, W) float32 from a pixel reflectance image (H, W), the PSF applied to the pixels
        (``OpticsModel.apply``: exact for uniform areas, approximate at sharp edges; module docstring)."""
        return self.electrons_from_optical(self.optics_in_use.apply(reflectance), exposure_us)

    def expected_electrons(self, placements: Sequence[Placement],
                           exposure_us: float) -> npt.NDArray[np.float64]:
        """Mean electrons (H, W) float64: noise-free, before the well (no clipping, knee or blooming)."""
        return self.electrons_from_optical(self.optical_image(placements), exposure_us).astype(np.float64)

    def expected_dn(self, placements: Sequence[Placement], exposure_us: float,
                    gain_db: float = 0.0) -> npt.NDArray[np.float64]:
        """Noise-free DN (H, W) float64: well, gain, black level, clipped to [0, top code], not rounded."""
        return self.expected_dn_from_optical(self.optical_image(placements), exposure_us, gain_db)

    def expected_dn_from_optical(self, optical: FloatArray, exposure_us: float,
                                 gain_db: float = 0.0) -> npt.NDArray[np.float64]:
        """``expected_dn`` from a precomputed ``optical_image`` (through the output curve, if any; not JPEG)."""
        dn = self.sensor_in_use.expected_dn(self.electrons_from_optical(optical, exposure_us), gain_db)
        if self._output_curve is None:
            return dn
        return self._output_curve(dn.astype(np.float32)).astype(np.float64)

    def render(self, placements: Sequence[Placement], exposure_us: float, gain_db: float = 0.0,
               rng: np.random.Generator | None = None, noise: bool = True) -> npt.NDArray[np.unsignedinteger]:
        """The camera image (H, W), uint8 for 8 bit else uint16.

        ``noise=True`` draws shot and read noise from ``rng`` (a fresh unseeded generator if None: pass one
        for reproducible images); ``noise=False`` gives the rounded ``expected_dn``.
        """
        return self.render_from_optical(self.optical_image(placements), exposure_us, gain_db, rng, noise)

    def render_from_optical(self, optical: FloatArray, exposure_us: float, gain_db: float = 0.0,
                            rng: np.random.Generator | None = None,
                            noise: bool = True) -> npt.NDArray[np.unsignedinteger]:
        """``render`` from a precomputed ``optical_image`` (H, W)."""
        if noise and rng is None:
            rng = np.random.default_rng()
        electrons = self.electrons_from_optical(optical, exposure_us)
        image = self.sensor_in_use.digitise(electrons, gain_db, rng if noise else None, encode=self._output_curve)
        if self.effects.jpeg is not None:
            quality = int(round(self.effects.jpeg.quality))
            ok, buffer = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
            if not ok:  # pragma: no cover - OpenCV encodes any 8-bit grey image
                raise RuntimeError("JPEG encoding failed")
            image = cv2.imdecode(buffer, cv2.IMREAD_GRAYSCALE)
        return image

    @cached_property
    def _output_curve(self) -> Callable[[npt.NDArray[np.float32]], npt.NDArray[np.float32]] | None:
        """The ``srgb_encoding`` or ``gamma_encoding`` curve on float DN (in place), or None (linear output)."""
        e, s = self.effects, self.sensor_in_use
        if e.srgb_encoding is None and e.gamma_encoding is None:
            return None
        gamma = None if e.gamma_encoding is None else e.gamma_encoding.gamma
        return functools.partial(encode_dn, black_dn=s.black_level_dn, top_dn=float(s.top_code),
                                 srgb=e.srgb_encoding is not None, gamma=gamma)
