"""Fitting the forward model, held-out prediction error, and the greedy choice of model extensions.

``ModelCheck(series)`` finds the lattice, estimates the noise (``sd^2 = a + b DN``, from the data alone) and
then fits any set of catalogue effects (``fit``). ``heldout_error`` fits on some exposures and predicts the
others (two folds: even and odd positions in exposure order; the white rate predicts the levels of the unseen
exposures from their shutter times) and returns the RMS of the normalised residuals of the predictions.
``select`` adds effects one at a time, each time the one that lowers the held-out error most, while the
relative gain exceeds ``MIN_RELATIVE_GAIN``.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from livetrack.modelcheck.forward import (
    EFFECT_PARAMETERS,
    ForwardModel,
    centres_and_radii,
    detect_lattice,
    make_layout,
)
from livetrack.modelcheck.series import ExposureSeries

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

MIN_RELATIVE_GAIN = 0.02
"""An effect is added only if it lowers the held-out RMS normalised error by more than this fraction (2 %).
Lower finds weaker effects and risks naming noise; calibrated on simulated series (docs/model-check.md)."""
MAX_EFFECTS = 3
"""At most this many effects are combined (each greedy round costs one fit per remaining effect and fold)."""
FOLDS = 2
HELDOUT_MAX_NFEV = 30
"""Iterations (function evaluations, Jacobian steps excluded) of each held-out fit; they start at the
all-exposure baseline and converge in a few. Cost."""
MODEL_TOLERANCE = 0.002
"""Relative accuracy granted to any edge model (of the frame's unclipped white level), added in quadrature to
the noise: the simulator itself approximates edge profiles to ~0.1-0.3 % of the step, which 10x over-exposed
frames would otherwise magnify into 'effects'."""
FLAT_PIXEL_SHARE = 0.15
"""Share of the pixels far (> 6 px + 3 steps) from any edge that are fitted; all edge pixels are. Cost."""
"""Held-out folds over the exposures (every FOLDS-th exposure held out in turn)."""


@dataclass(frozen=True)
class FitResult:
    """One fit: the effects on, the parameters (name -> value), the geometry offsets (8,) px, the RMS of the
    normalised residuals over the fitted frames, and whether the optimiser converged."""

    effects: tuple[str, ...]
    params: dict[str, float]
    corner_offsets: FloatArray
    frames: tuple[int, ...]
    chi_rms: float
    n_pixels: int
    success: bool
    seconds: float


@dataclass
class Candidate:
    """Held-out evaluation of one model (a set of effects)."""

    effects: tuple[str, ...]
    heldout_rms: float
    fold_params: list[dict[str, float]] = field(default_factory=list)


def noise_model(series: ExposureSeries, model: ForwardModel, centres: FloatArray, radius_px: float,
                sigma_px: float) -> tuple[float, float]:
    """(a, b) of ``var = a + b DN`` from flat areas: the variance of pixel minus the mean of its 4 neighbours
    (x 4/5 for white noise), binned by level and fitted by least squares. Model-free."""
    xs, vs = [], []
    lay = model.layout
    for f in range(series.n_frames):
        for g, img in enumerate(series.images[f]):
            x, y = lay.xs[g], lay.ys[g]
            nb = 0.25 * (img[:-2, 1:-1] + img[2:, 1:-1] + img[1:-1, :-2] + img[1:-1, 2:])
            centre = img[1:-1, 1:-1]
            cx = centres[lay.nearest[g][:, 0]]
            d = np.abs(np.hypot(x.ravel() - cx[:, 0], y.ravel() - cx[:, 1]) - radius_px).reshape(img.shape)
            flat = d > 3.0 * sigma_px + 2.0 + 2.0 * series.grids[g].step
            patch = img[:-2, 1:-1], img[2:, 1:-1], img[1:-1, :-2], img[1:-1, 2:], centre
            ok = flat[1:-1, 1:-1] & np.all([(p < 0.8 * series.saturation_dn) & (p > 0) for p in patch], axis=0)
            ok &= series.valid[f][g][1:-1, 1:-1]
            xs.append(nb[ok])
            vs.append(0.8 * (centre[ok] - nb[ok]) ** 2)
    level = np.concatenate(xs)
    var = np.concatenate(vs)
    if level.size < 100:
        return 1.0, 0.0
    edges = np.quantile(level, np.linspace(0, 1, 21))
    mids, vars_ = [], []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (level >= lo) & (level <= hi)
        if np.count_nonzero(sel) > 30:
            mids.append(float(np.mean(level[sel])))
            vars_.append(float(np.mean(var[sel])))
    a_mat = np.column_stack([np.ones(len(mids)), mids])
    (a, b), *_ = np.linalg.lstsq(a_mat, np.asarray(vars_), rcond=None)
    return max(float(a), 0.25), max(float(b), 0.0)


NEGLIGIBLE: dict[str, tuple[str, float, float]] = {
    "halo": ("halo_fraction", -1.0, 0.005),
    "defocus": ("defocus_radius_px", -1.0, 0.3),
    "blooming": ("spill_log10", -9.0, -4.0),
    "nonlinear": ("knee_fraction", 0.97, 2.0),
    "veiling_glare": ("glare_fraction", -1.0, 0.003),
    "vignetting": ("vignetting_strength", -0.03, 0.03),
    "lens_distortion": ("k1", -0.002, 0.002),
    "illumination_gradient": ("gradient_norm", -1.0, 0.02),
    "anisotropic_core": ("aniso_norm", -1.0, 0.03),
    "exponential_tail": ("exp_tail_fraction", -1.0, 0.01),
    "lorentzian_tail": ("lor_tail_fraction", -1.0, 0.01),
    "ink_floor": ("ink_lift", -1.0, 0.003),
}
"""effect -> (parameter, lo, hi): an effect fitted inside [lo, hi] changes the images by less than the
simulator's own edge accuracy (e.g. a knee above 97 % of full well bends only the last few DN); it is then
not named as a cause even if it lowers the held-out error (it absorbs model-accuracy residue, not physics)."""


EXCLUSIVE = [{"exponential_tail", "lorentzian_tail"}]
"""Effects never combined (one tail per core)."""
TAIL_MIN_SCALE_PX = 0.3
"""A heavy tail whose scale is under this (px) lies inside one pixel's box: it only sharpens the core, which the
Gaussian's sigma absorbs; such a fit is not named a tail (``identifiable``)."""
ANISO_MIN_BLUR_PX = 0.3
"""The core's anisotropy is identifiable only if the core itself is wider than this (px): a much narrower core
is lost in the pixel box."""


def parameter_space(names: list[str], lo: list[float], hi: list[float], fit_ink: bool, effects: Sequence[str],
                    catalogue: Mapping[str, Mapping[str, tuple[float, float, float]]],
                    start: Mapping[str, float]) -> tuple[list[str], FloatArray, FloatArray, FloatArray]:
    """The fitted parameters of a model: the baseline's ``names`` with bounds ``lo``/``hi``, then the ink/paper
    ratio when the print does not state it (``fit_ink``), then each effect's parameters from ``catalogue``
    (name -> (start, lower, upper)); returns (names, start vector, lower, upper), each start from ``start`` else
    the catalogue's, moved just inside its bounds."""
    names, lo, hi = list(names), list(lo), list(hi)
    if fit_ink:
        names.append("black_to_white")
        lo.append(0.0)
        hi.append(0.9)
    for e in effects:
        for name, (_, a, b) in catalogue[e].items():
            names.append(name)
            lo.append(a)
            hi.append(b)
    x0 = []
    for n, a, b in zip(names, lo, hi, strict=True):
        v = start.get(n)
        if v is None:
            v = next(p[0] for e in effects for k, p in catalogue[e].items() if k == n)
        x0.append(min(max(v, a + 1e-9 * (b - a)), b - 1e-9 * (b - a)))
    return names, np.asarray(x0), np.asarray(lo), np.asarray(hi)


def negligible(effect: str, params: dict[str, float]) -> bool:
    name, lo, hi = NEGLIGIBLE[effect]
    if name == "gradient_norm":
        return math.hypot(params["gradient_x"], params["gradient_y"]) <= hi
    if name == "aniso_norm":
        return math.hypot(params["aniso_c"], params["aniso_s"]) <= hi
    if name == "ink_lift":  # the fitted ratio differs from the stated print by less than hi of the paper
        return abs(params["ink_black_to_white"] - params["black_to_white"]) <= hi
    return lo <= params[name] <= hi


def unidentifiable(effect: str, params: dict[str, float]) -> str | None:
    """Why a fitted effect cannot be told apart from the baseline's own parameters (None: it can). Each effect's
    rule: a tail of sub-pixel scale is a sharper core; an anisotropy of a sub-0.3 px core is below the pixel."""
    for kind in ("exp", "lor"):
        if effect.startswith(kind) and params[f"{kind}_tail_scale_px"] < TAIL_MIN_SCALE_PX:
            return (f"tail scale {params[f'{kind}_tail_scale_px']:.2f} px is inside a pixel: the same as a sharper "
                    "Gaussian core")
    if effect == "anisotropic_core" and params["sigma_px"] < ANISO_MIN_BLUR_PX:
        return "the core is narrower than the pixel box: its shape is not seen"
    return None


class ModelCheck:
    """Fits of the forward model to one exposure series (see the module docstring)."""

    def __init__(self, series: ExposureSeries):
        t0 = time.perf_counter()
        self.series = series
        self.lattice = detect_lattice(series)
        self.init: dict[str, float] = {"radius_rel": self.lattice.radius_rel, "sigma_px": 1.2}
        self.layout = make_layout(series, self.lattice, self.init)
        self.model = ForwardModel(series, self.lattice, self.layout)
        centres, radii = centres_and_radii(series, self.lattice, self.init, np.zeros(8))
        self.noise_a, self.noise_b = noise_model(series, self.model, centres, float(np.median(radii)), 1.2)
        dist_edge = []
        for g in range(len(series.grids)):
            c = centres[self.layout.nearest[g][:, 0]]
            d = np.hypot(self.layout.xs[g].ravel() - c[:, 0], self.layout.ys[g].ravel() - c[:, 1])
            dist_edge.append((d - float(np.median(radii))).reshape(self.layout.xs[g].shape))
        self.model.noise_a, self.model.noise_b = self.noise_a, self.noise_b
        s = series.saturation_dn
        rates = [float(np.percentile(fr[0][self.layout.roi[0]], 95)) / t for fr, t in
                 zip(series.images, series.exposure_ms, strict=True)
                 if np.percentile(fr[0][self.layout.roi[0]], 99) < 0.95 * s]
        if not rates:  # everything clipped: the shortest exposure's median is a lower bound
            rates = [float(np.percentile(series.images[0][0], 50)) / series.exposure_ms[0]]
        self.init["white_dn_per_ms"] = float(np.median(rates))
        if series.black_to_white is not None:
            self.init["black_to_white"] = series.black_to_white
        else:
            self.init["black_to_white"] = 0.05
        # Weights: noise plus MODEL_TOLERANCE of the frame's (unclipped) white level, and the pixels fitted.
        self.sd = []
        for fr, t in zip(series.images, series.exposure_ms, strict=True):
            tol2 = (MODEL_TOLERANCE * t * self.init["white_dn_per_ms"]) ** 2
            self.sd.append([np.sqrt(self.noise_a + self.noise_b * np.maximum(img, 0.0) + tol2) for img in fr])
        rng = np.random.default_rng(0)
        self.fit_mask = []
        for g in range(len(series.grids)):
            near = (np.abs(dist_edge[g]) < 6.0 + 3.0 * series.grids[g].step).ravel()
            keep = near | (rng.random(near.size) < FLAT_PIXEL_SHARE)
            self.fit_mask.append(keep.reshape(self.layout.roi[g].shape) & self.layout.roi[g])
        self.fit_pixels = [np.flatnonzero(m) for m in self.fit_mask]
        """Flat indices (per sub-image) of the fitted pixels: where fits predict (``predict_fitted``)."""
        self._measured_fitted = [[img.ravel()[pix] for img, pix in zip(fr, self.fit_pixels, strict=True)]
                                 for fr in series.images]
        self._sd_fitted = [[sd.ravel()[pix] for sd, pix in zip(fr, self.fit_pixels, strict=True)] for fr in self.sd]
        self.geometry = np.zeros(8)
        log.info("setup %.2f s: %d disks (%d interior), pitch %.2f px, noise a=%.3g b=%.3g", time.perf_counter() - t0,
                 len(self.lattice.ij), int(self.layout.interior.sum()), self.layout.pitch_px, self.noise_a,
                 self.noise_b)

    # ------------------------------------------------------------------ parameters
    def _spec(self, effects: tuple[str, ...], start: dict[str, float]) -> tuple[list[str], FloatArray, FloatArray,
                                                                             FloatArray]:
        return parameter_space(["radius_rel", "sigma_px", "white_dn_per_ms"], [0.02, 0.5, 1e-9], [0.49, 6.0, 1e9],
                               self.series.black_to_white is None, effects, EFFECT_PARAMETERS, start)

    def params_dict(self, names: list[str], x: FloatArray) -> dict[str, float]:
        p = dict(self.init)
        p.update({n: float(v) for n, v in zip(names, x, strict=True)})
        return p

    # ------------------------------------------------------------------ residuals
    def predict(self, p: dict[str, float], offsets: FloatArray, frames: list[int]) -> list[list[FloatArray]]:
        """Predicted mean DN [frame][sub-image], whole (h, w) images."""
        return self.model.frames(p, offsets, frames)

    def predict_fitted(self, p: dict[str, float], offsets: FloatArray, frames: list[int]) -> list[list[FloatArray]]:
        """Predicted mean DN [frame][sub-image] at the fitted pixels only (1-D, ``fit_pixels`` order)."""
        return self.model.frames(p, offsets, frames, pixels=self.fit_pixels)

    def normalised_residuals(self, pred: list[list[FloatArray]], frames: list[int],
                             informative_only: bool = False) -> FloatArray:
        """(pred - measured) / sd at the fitted pixels, ``pred`` from ``predict_fitted``; ``informative_only``
        drops pixels clipped in both."""
        out = []
        s = self.series.saturation_dn
        for row, f in zip(pred, frames, strict=True):
            for g, pr in enumerate(row):
                meas = self._measured_fitted[f][g]
                r = (pr - meas) / self._sd_fitted[f][g]
                if informative_only:
                    r = r[~((meas >= s) & (pr >= s - 1e-6))]
                out.append(r)
        return np.concatenate(out)

    def fit(self, effects: tuple[str, ...], frames: list[int] | None = None, start: dict[str, float] | None = None,
            fit_geometry: bool = False, max_nfev: int = 60) -> FitResult:
        t0 = time.perf_counter()
        frames = list(range(self.series.n_frames)) if frames is None else list(frames)
        st = dict(self.init)
        if start:
            st.update(start)
        names, x0, lo, hi = self._spec(effects, st)
        ng = len(names)
        # Distortion moves the disk centres, which the (otherwise frozen) homography partly absorbed: refit both.
        fit_geometry = fit_geometry or "lens_distortion" in effects
        if fit_geometry:
            x0 = np.concatenate([x0, self.geometry])
            lo = np.concatenate([lo, np.full(8, -20.0)])
            hi = np.concatenate([hi, np.full(8, 20.0)])

        def fun(x: FloatArray) -> FloatArray:
            p = self.params_dict(names, x[:ng])
            offsets = x[ng:] if fit_geometry else self.geometry
            return self.normalised_residuals(self.predict_fitted(p, offsets, frames), frames)

        x_scale = np.concatenate([np.maximum(np.abs(x0[:ng]) * 0.1, 1e-2), np.ones(len(x0) - ng)])
        res = least_squares(fun, x0, bounds=(lo, hi), x_scale=x_scale, diff_step=1e-4, max_nfev=max_nfev,
                            method="trf")
        p = self.params_dict(names, res.x[:ng])
        offsets = res.x[ng:] if fit_geometry else self.geometry.copy()
        r = self.normalised_residuals(self.predict_fitted(p, offsets, frames), frames, informative_only=True)
        return FitResult(tuple(effects), p, np.asarray(offsets), tuple(frames), float(np.sqrt(np.mean(r**2))), r.size,
                         bool(res.success), time.perf_counter() - t0)

    # ------------------------------------------------------------------ held-out
    def folds(self) -> list[tuple[list[int], list[int]]]:
        n = self.series.n_frames
        out = []
        for k in range(FOLDS):
            test = list(range(k, n, FOLDS))
            train = [i for i in range(n) if i not in test]
            out.append((train, test))
        return out

    def heldout(self, effects: tuple[str, ...], start: dict[str, float] | None = None) -> Candidate:
        sq, count, params = 0.0, 0, []
        for train, test in self.folds():
            fit = self.fit(effects, train, start, max_nfev=HELDOUT_MAX_NFEV)
            r = self.normalised_residuals(self.predict_fitted(fit.params, fit.corner_offsets, test), test,
                                          informative_only=True)
            sq += float(np.sum(r**2))
            count += r.size
            params.append(fit.params)
        return Candidate(tuple(effects), math.sqrt(sq / max(count, 1)), params)

    def candidates(self) -> tuple[list[str], dict[str, str]]:
        """Catalogue effects to try and, for those left out, why."""
        skipped = {}
        names = []
        for e in EFFECT_PARAMETERS:
            if e == "veiling_glare" and self.series.black_to_white is None:
                skipped[e] = ("not identifiable: with the ink/paper reflectance ratio unknown, a uniform veil is "
                              "the same as a lighter ink (it only raises the black level)")
                continue
            if e == "ink_floor":
                if self.series.black_to_white is None:
                    skipped[e] = ("in the baseline: the print is not stated, so the ink/paper ratio (the ink floor) "
                                  "is fitted with every model (black_to_white)")
                else:
                    skipped[e] = ("not identifiable apart from veiling_glare: on a pattern that fills the frame a "
                                  "lighter ink and a uniform veil give the same images (the white rate absorbs "
                                  "the difference); a veiling glare g is reported with its equivalent ink ratio")
                continue
            names.append(e)
        return names, skipped
