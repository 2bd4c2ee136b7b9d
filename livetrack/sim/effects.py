"""Catalogue of optional image-formation effects, each OFF unless named in ``Effects``.

``EFFECTS`` is the single registry: effect name -> parameter dataclass. Every parameter carries its unit,
bounds and meaning in the field metadata (``Effect.parameters()``), so a model-fitting loop can enumerate
the effects and their free parameters without knowing them. In a scenario file::

    effects:
      halo: {fraction: 0.03, sigma_px: 6.0}
      blooming: {spill_fraction: 1.0}

Where each effect acts (see ``livetrack.sim.formation`` for the whole chain):

=================  ===========================================================================================
halo               wide Gaussian added to the PSF: ``(1 - a) G(psf_sigma) + a G(sigma_px)`` (optics)
anisotropic_core   the Gaussian core is ``sigma_x_px`` along ``angle_deg`` and ``sigma_y_px`` across (optics;
                   replaces ``optics.psf_sigma_px``)
exponential_tail   the core becomes ``(1 - t) G + t T``, T(r) ~ exp(-r / scale_px) (optics, see its docstring)
lorentzian_tail    the same with T(r) ~ (r^2 + scale_px^2)^-3/2 (its line spread is a 1-D Lorentzian)
ink_floor          the printed black reflects ``black_to_white`` x the paper (more than the texture says): every
                   target texture's ``black`` is replaced before rendering
defocus            uniform disk of ``radius_px`` convolved with the PSF (optics)
motion_blur        uniform line of ``length_px`` at ``angle_deg``, centred: truth is the mid-exposure pose
veiling_glare      the fraction ``f`` of all light spread uniformly over the frame: E -> (1 - f) E + f mean(E)
vignetting         irradiance x ``1 - strength r^2``, r = distance to principal point / image half-diagonal
lens_distortion    the scene is rendered with ``dist`` instead of the camera file's (an unmodelled lens)
blooming           charge a pixel cannot hold spills along its column (sensor, ``SensorModel`` docstring)
nonlinear          pixel response bends from the knee towards full well (sensor, ``SensorModel`` docstring)
srgb_encoding      the output is sRGB-encoded (IEC 61966-2-1 curve on the DN scale), as a renderer's or a
                   phone's image: other renderers' convention (output, after the ADC's noise, before rounding)
gamma_encoding     the output is ``full (dn / full)^(1 / gamma)`` (a display gamma; output, as srgb_encoding)
jpeg               the 8-bit output is JPEG-compressed at ``quality`` and decoded (output, after rounding)
=================  ===========================================================================================
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from livetrack.config import checks as cc
from livetrack.sim.optics import OpticsModel


def _param(default: float, *, unit: str, doc: str, gt: float | None = None, ge: float | None = None,
           lt: float | None = None, le: float | None = None) -> Any:
    """A float parameter with its unit, meaning and bounds in the field metadata."""
    return field(default=default, metadata={"unit": unit, "doc": doc, "gt": gt, "ge": ge, "lt": lt, "le": le})


@dataclass(frozen=True)
class Effect:
    """Base of all effect parameter sets. Subclasses set ``NAME`` and declare fields with ``_param``."""

    NAME: ClassVar[str] = ""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            if "unit" not in f.metadata:
                continue
            value = getattr(self, f.name)
            problem = _bound_problem(float(value), f.metadata)
            if problem:
                raise ValueError(f"effects.{self.NAME}.{f.name}: {problem}")

    @classmethod
    def parameters(cls) -> dict[str, dict[str, Any]]:
        """Free parameters: name -> {default, unit, doc, gt, ge, lt, le} (bounds None when absent)."""
        return {f.name: {"default": f.default, **f.metadata} for f in dataclasses.fields(cls)
                if "unit" in f.metadata}

    @classmethod
    def from_dict(cls, data: Any, path: str) -> Effect:
        """Validated construction from a YAML mapping; every parameter optional (default in the class)."""
        if data is None:
            data = {}
        params = cls.parameters()
        cc.mapping(data, path, optional=params)
        values = {}
        for name, meta in params.items():
            values[name] = cc.number(data, name, path, default=meta["default"], gt=meta["gt"], ge=meta["ge"],
                                     lt=meta["lt"], le=meta["le"])
        return cls(**values)

    def to_dict(self) -> dict[str, Any]:
        return {f.name: _plain(getattr(self, f.name)) for f in dataclasses.fields(self)}


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):
        return [float(v) for v in value]
    return float(value)


def _bound_problem(value: float, meta: Mapping[str, Any]) -> str | None:
    if not math.isfinite(value):
        return f"must be finite, got {value}"
    for key, ok in (("gt", lambda b: value > b), ("ge", lambda b: value >= b), ("lt", lambda b: value < b),
                    ("le", lambda b: value <= b)):
        bound = meta.get(key)
        if bound is not None and not ok(bound):
            sign = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}[key]
            return f"must be {sign} {bound}, got {value}"
    return None


@dataclass(frozen=True)
class Halo(Effect):
    """Wide, faint part of the PSF (lens scatter, sensor cross-talk): lifts dark sides near bright areas."""

    NAME: ClassVar[str] = "halo"
    fraction: float = _param(0.03, unit="1", gt=0.0, lt=1.0,
                             doc="share of the PSF energy in the halo (cost: one more separable blur)")
    sigma_px: float = _param(6.0, unit="px", gt=0.0, doc="standard deviation of the halo Gaussian")


@dataclass(frozen=True)
class Defocus(Effect):
    """Out of focus: the PSF is convolved with a uniform disk."""

    NAME: ClassVar[str] = "defocus"
    radius_px: float = _param(1.5, unit="px", gt=0.0,
                              doc="radius of the blur disk (cost: a 2-D filter of (2 r + 3)^2 taps)")


@dataclass(frozen=True)
class MotionBlur(Effect):
    """Target or camera moving at constant image speed during the exposure (centred on the truth pose)."""

    NAME: ClassVar[str] = "motion_blur"
    length_px: float = _param(3.0, unit="px", gt=0.0, doc="image distance travelled during the exposure")
    angle_deg: float = _param(0.0, unit="deg", doc="direction of motion, from +x toward +y")


@dataclass(frozen=True)
class VeilingGlare(Effect):
    """Stray light: a fraction of all light reaching the sensor is spread uniformly over it (energy kept)."""

    NAME: ClassVar[str] = "veiling_glare"
    fraction: float = _param(0.02, unit="1", gt=0.0, lt=1.0, doc="share of the light spread over the frame")


@dataclass(frozen=True)
class Vignetting(Effect):
    """Irradiance falls off towards the corners as ``1 - strength r^2``, r = distance to the principal point
    over the image half-diagonal (strength 0.3: corners at 70 %)."""

    NAME: ClassVar[str] = "vignetting"
    strength: float = _param(0.3, unit="1", gt=0.0, le=1.0, doc="relative loss at the image corners")


@dataclass(frozen=True)
class LensDistortion(Effect):
    """The scene is rendered through these distortion coefficients instead of the camera file's, so the
    camera model used by the tracker is wrong by the difference (an unmodelled or miscalibrated lens)."""

    NAME: ClassVar[str] = "lens_distortion"
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    @classmethod
    def parameters(cls) -> dict[str, dict[str, Any]]:
        return {f"dist[{i}]": {"default": 0.0, "unit": "1", "doc": f"OpenCV coefficient {name}", "gt": None,
                               "ge": None, "lt": None, "le": None}
                for i, name in enumerate(("k1", "k2", "p1", "p2", "k3"))}

    def __post_init__(self) -> None:
        if len(self.dist) != 5 or not all(math.isfinite(d) for d in self.dist):
            raise ValueError(f"effects.lens_distortion.dist: need 5 finite numbers, got {self.dist}")
        object.__setattr__(self, "dist", tuple(float(d) for d in self.dist))

    @classmethod
    def from_dict(cls, data: Any, path: str) -> LensDistortion:
        cc.mapping(data, path, required=["dist"])
        dist = cc.number_list(data, "dist", path)
        if not 1 <= len(dist) <= 5:
            raise cc.ConfigError(cc.join(path, "dist"), f"must have 1 to 5 numbers (k1, k2, p1, p2, k3), got "
                                 f"{len(dist)}")
        return cls(tuple(dist + [0.0] * (5 - len(dist))))  # type: ignore[arg-type]


@dataclass(frozen=True)
class Blooming(Effect):
    """Charge a pixel cannot hold spills along its column, up and down (CCD/CMOS blooming)."""

    NAME: ClassVar[str] = "blooming"
    spill_fraction: float = _param(1.0, unit="1", gt=0.0, le=1.0,
                                   doc="share of the excess charge that spills (the rest drains)")


@dataclass(frozen=True)
class Nonlinear(Effect):
    """Pixel response bends smoothly from linear towards full well above a knee."""

    NAME: ClassVar[str] = "nonlinear"
    knee_fraction_of_full_well: float = _param(0.8, unit="1", gt=0.0, lt=1.0,
                                               doc="charge (fraction of full well) where the response bends")


@dataclass(frozen=True)
class AnisotropicCore(Effect):
    """The Gaussian PSF core is elliptical (astigmatism, anisotropic pixel response): over-exposed disks shrink
    more along the wide axis. Replaces the optics' round ``psf_sigma_px``."""

    NAME: ClassVar[str] = "anisotropic_core"
    sigma_x_px: float = _param(1.0, unit="px", gt=0.0, le=20.0, doc="core sigma along angle_deg")
    sigma_y_px: float = _param(0.85, unit="px", gt=0.0, le=20.0, doc="core sigma across angle_deg")
    angle_deg: float = _param(0.0, unit="deg", ge=-180.0, le=180.0,
                              doc="direction of the sigma_x axis, from +x toward +y")


@dataclass(frozen=True)
class ExponentialTail(Effect):
    """A heavy tail of the PSF core, T(r) = exp(-r / b) / (2 pi b^2): the dark side of an edge is lifted within a
    few px much more than by a Gaussian (energy fraction and scale, distinct from the wide Gaussian ``halo``)."""

    NAME: ClassVar[str] = "exponential_tail"
    fraction: float = _param(0.2, unit="1", gt=0.0, lt=1.0, doc="share of the core energy in the tail")
    scale_px: float = _param(1.0, unit="px", gt=0.0, le=10.0,
                             doc="scale b of the tail (cost: a 2-D filter of (24 b + 1)^2 taps)")


@dataclass(frozen=True)
class LorentzianTail(Effect):
    """A heavy tail of the PSF core, T(r) = b / (2 pi (r^2 + b^2)^3/2), wings falling as r^-3 (its line spread
    is the 1-D Lorentzian); cut at 30 b (3.3 % of its energy beyond, renormalised)."""

    NAME: ClassVar[str] = "lorentzian_tail"
    fraction: float = _param(0.1, unit="1", gt=0.0, lt=1.0, doc="share of the core energy in the tail")
    scale_px: float = _param(0.5, unit="px", gt=0.0, le=3.0,
                             doc="scale b of the tail (cost: a 2-D filter of (60 b + 1)^2 taps)")


@dataclass(frozen=True)
class InkFloor(Effect):
    """The printed black reflects more than the texture says: ``black_to_white`` x the paper's reflectance
    (real inks: a few %; the real disk series: 6-7 %). Acts on every target texture with a ``black`` and a
    ``white`` (the recording's meta still states the nominal print, so a model that trusts it is wrong)."""

    NAME: ClassVar[str] = "ink_floor"
    black_to_white: float = _param(0.06, unit="1", ge=0.0, lt=1.0, doc="ink reflectance / paper reflectance")


@dataclass(frozen=True)
class SrgbEncoding(Effect):
    """The image is delivered sRGB-encoded, as most renderers (Blender, game engines), phones and webcams
    deliver it: each value, as a share x of the range from the black level to full scale, becomes 12.92 x below
    x = 0.0031308, else 1.055 x^(1/2.4) - 0.055. Applied to the DN after the read noise, before rounding (an
    image signal processor works at a finer depth than it outputs)."""

    NAME: ClassVar[str] = "srgb_encoding"


@dataclass(frozen=True)
class GammaEncoding(Effect):
    """The image is delivered through a power curve: each value, as a share x of the range from the black
    level to full scale, becomes x^(1/gamma) (a display gamma; 1 is linear). Where ``srgb_encoding`` acts."""

    NAME: ClassVar[str] = "gamma_encoding"
    gamma: float = _param(2.2, unit="1", ge=1.0, le=4.0, doc="display gamma (the output is x^(1/gamma))")


@dataclass(frozen=True)
class Jpeg(Effect):
    """The 8-bit image is JPEG-compressed (OpenCV's baseline encoder, 4:2:0 irrelevant for grey) and decoded:
    block artefacts and ringing at the edges, as in phone photos and compressed streams. 8-bit cameras only."""

    NAME: ClassVar[str] = "jpeg"
    quality: float = _param(85.0, unit="1", ge=10.0, le=100.0, doc="JPEG quality (rounded to an integer)")


def encode_dn(dn: npt.NDArray[np.float32], black_dn: float, top_dn: float, srgb: bool, gamma: float | None
              ) -> npt.NDArray[np.float32]:
    """``dn`` (float32, modified in place and returned) through the sRGB curve (``srgb``) or the power
    ``1 / gamma`` (``gamma``), each value as a share of [``black_dn``, ``top_dn``], clipped to it."""
    span = float(top_dn - black_dn)
    x = np.clip((dn - np.float32(black_dn)) / np.float32(span), 0.0, 1.0, out=dn)
    if srgb:
        low = x <= 0.0031308
        y = np.float32(1.055) * np.power(x, np.float32(1.0 / 2.4)) - np.float32(0.055)
        y[low] = np.float32(12.92) * x[low]
    elif gamma is not None:
        y = np.power(x, np.float32(1.0 / gamma))
    else:
        y = x
    np.multiply(y, np.float32(span), out=dn)
    return np.add(dn, np.float32(black_dn), out=dn)


EFFECTS: dict[str, type[Effect]] = {cls.NAME: cls for cls in (
    Halo, Defocus, MotionBlur, VeilingGlare, Vignetting, LensDistortion, Blooming, Nonlinear, AnisotropicCore,
    ExponentialTail, LorentzianTail, InkFloor, SrgbEncoding, GammaEncoding, Jpeg)}
"""The registry: effect name (scenario key) -> parameter dataclass."""


@dataclass(frozen=True)
class Effects:
    """The effects switched on (None = off; the default is all off). Field names are the ``EFFECTS`` keys."""

    halo: Halo | None = None
    defocus: Defocus | None = None
    motion_blur: MotionBlur | None = None
    veiling_glare: VeilingGlare | None = None
    vignetting: Vignetting | None = None
    lens_distortion: LensDistortion | None = None
    blooming: Blooming | None = None
    nonlinear: Nonlinear | None = None
    anisotropic_core: AnisotropicCore | None = None
    exponential_tail: ExponentialTail | None = None
    lorentzian_tail: LorentzianTail | None = None
    ink_floor: InkFloor | None = None
    srgb_encoding: SrgbEncoding | None = None
    gamma_encoding: GammaEncoding | None = None
    jpeg: Jpeg | None = None

    def __post_init__(self) -> None:
        for name, cls in EFFECTS.items():
            value = getattr(self, name)
            if value is not None and not isinstance(value, cls):
                raise TypeError(f"Effects.{name} must be a {cls.__name__} or None, got "
                                f"{type(value).__name__}")
        if self.exponential_tail is not None and self.lorentzian_tail is not None:
            raise ValueError("effects: exponential_tail and lorentzian_tail cannot both be on (one tail per core)")
        if self.srgb_encoding is not None and self.gamma_encoding is not None:
            raise ValueError("effects: srgb_encoding and gamma_encoding cannot both be on (one output curve)")

    def fold_optics(self, optics: OpticsModel) -> OpticsModel:
        """``optics`` with the PSF effects applied (halo, defocus, motion blur, anisotropic core, tails).
        ValueError if an effect is also set on the model (one place for each part)."""
        o = optics
        clashes = [("halo", self.halo, o.halo_fraction > 0), ("defocus", self.defocus, o.defocus_radius_px > 0),
                   ("motion_blur", self.motion_blur, o.motion_blur_px > 0),
                   ("anisotropic_core", self.anisotropic_core, o.psf_sigma_y_px is not None),
                   ("exponential_tail", self.exponential_tail, o.tail_fraction > 0),
                   ("lorentzian_tail", self.lorentzian_tail, o.tail_fraction > 0)]
        for name, effect, on_model in clashes:
            if effect is not None and on_model:
                raise ValueError(f"effect {name!r} is set both in effects and on the optics model")
        if self.halo is not None:
            o = dataclasses.replace(o, halo_fraction=self.halo.fraction, halo_sigma_px=self.halo.sigma_px)
        if self.defocus is not None:
            o = dataclasses.replace(o, defocus_radius_px=self.defocus.radius_px)
        if self.motion_blur is not None:
            o = dataclasses.replace(o, motion_blur_px=self.motion_blur.length_px,
                                    motion_blur_angle_deg=self.motion_blur.angle_deg)
        if self.anisotropic_core is not None:
            a = self.anisotropic_core
            o = dataclasses.replace(o, psf_sigma_px=a.sigma_x_px, psf_sigma_y_px=a.sigma_y_px,
                                    psf_angle_deg=a.angle_deg)
        for kind, tail in (("exponential", self.exponential_tail), ("lorentzian", self.lorentzian_tail)):
            if tail is not None:
                o = dataclasses.replace(o, tail_fraction=tail.fraction, tail_kind=kind, tail_scale_px=tail.scale_px)
        return o

    def texture_with_ink(self, texture: Any) -> Any:
        """``texture`` with the ``ink_floor``'s black (``black_to_white`` x its white) if it is a dataclass with
        ``black`` and ``white``; otherwise (or without the effect) unchanged."""
        if self.ink_floor is None or not dataclasses.is_dataclass(texture):
            return texture
        if not (hasattr(texture, "black") and hasattr(texture, "white")):
            return texture
        return dataclasses.replace(texture, black=self.ink_floor.black_to_white * float(texture.white))

    @classmethod
    def from_dict(cls, data: Any, path: str = "effects") -> Effects:
        """From a mapping effect name -> parameters (a mapping, or null for the defaults)."""
        if data is None:
            return cls()
        cc.mapping(data, path, optional=EFFECTS)
        return cls(**{name: EFFECTS[name].from_dict(value, cc.join(path, name))
                      for name, value in data.items()})

    def to_dict(self) -> dict[str, Any]:
        """Enabled effects only, name -> parameters."""
        return {name: effect.to_dict() for name, effect in self.enabled().items()}

    def enabled(self) -> dict[str, Effect]:
        """name -> parameters of each effect that is on, in registry order."""
        return {name: getattr(self, name) for name in EFFECTS if getattr(self, name) is not None}

    def with_effect(self, name: str, params: Effect | None) -> Effects:
        """A copy with effect ``name`` set to ``params`` (None switches it off)."""
        if name not in EFFECTS:
            raise KeyError(f"unknown effect {name!r} (known: {', '.join(EFFECTS)})")
        return dataclasses.replace(self, **{name: params})
