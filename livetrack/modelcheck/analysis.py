"""The whole model check of one exposure series: baseline fit, catalogue, held-out choice, predictions versus
measurements, compensation, verdict. ``analyse(series) -> ModelReport``; ``ModelReport.to_json()`` is the
JSON report and ``summary()`` the text for a person. No file I/O here (plots: ``livetrack.modelcheck.plots``)."""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from livetrack.modelcheck import measure
from livetrack.modelcheck.fitting import (
    EXCLUSIVE,
    MAX_EFFECTS,
    MIN_RELATIVE_GAIN,
    Candidate,
    FitResult,
    ModelCheck,
    negligible,
    unidentifiable,
)
from livetrack.modelcheck.forward import centres_and_radii
from livetrack.modelcheck.series import ExposureSeries

log = logging.getLogger(__name__)
FloatArray = npt.NDArray[np.float64]

BASE_KEYS = ("radius_rel", "sigma_px", "white_dn_per_ms", "black_to_white")
MIN_CONTRAST_SD = 10.0
"""A frame's radius is measured only if its paper - ink contrast exceeds this many read-noise sd (measured levels;
the read noise ``sqrt(a)`` of the noise model, not the shot noise: the radius is a count over hundreds of pixels,
but a contrast of a few read-noise sd leaves the threshold in the noise)."""


def effect_parameters(effect: str, p: dict[str, float], series: ExposureSeries) -> dict[str, float]:
    """Fitted parameters of ``effect`` under the simulator's names (``livetrack.sim.effects``)."""
    if effect == "halo":
        return {"fraction": p["halo_fraction"], "sigma_px": p["halo_sigma_px"]}
    if effect == "defocus":
        return {"radius_px": p["defocus_radius_px"]}
    if effect == "blooming":
        return {"spill_fraction": 10.0 ** p["spill_log10"]}
    if effect == "nonlinear":
        return {"knee_fraction_of_full_well": p["knee_fraction"]}
    if effect == "veiling_glare":
        g, rho = p["glare_fraction"], p["black_to_white"]
        mean_m = 1.0 - (1.0 - rho) * math.pi * p["radius_rel"] ** 2  # mean relative reflectance of the grid
        return {"fraction": g, "equivalent_ink_black_to_white": 1.0 - (1.0 - rho) * (1.0 - g) / (1.0 - g + g * mean_m)}
    if effect == "anisotropic_core":
        c, s_ = p["aniso_c"], p["aniso_s"]
        e = math.hypot(c, s_)
        sig = p["sigma_px"]
        return {"sigma_x_px": sig * math.sqrt(1.0 + e), "sigma_y_px": sig * math.sqrt(max(1.0 - e, 0.0)),
                "angle_deg": 0.5 * math.degrees(math.atan2(s_, c)),
                "axis_ratio": math.sqrt((1.0 + e) / max(1.0 - e, 1e-9)),
                "horizontal_over_vertical_blur": math.sqrt((1.0 + c) / max(1.0 - c, 1e-9))}
    if effect == "exponential_tail":
        return {"fraction": p["exp_tail_fraction"], "scale_px": p["exp_tail_scale_px"]}
    if effect == "lorentzian_tail":
        return {"fraction": p["lor_tail_fraction"], "scale_px": p["lor_tail_scale_px"]}
    if effect == "ink_floor":
        return {"black_to_white": p["ink_black_to_white"]}
    if effect == "vignetting":
        return {"strength": p["vignetting_strength"]}
    if effect == "lens_distortion":
        out = {"k1_half_diagonal": p["k1"]}
        if series.focal_px:
            out["k1"] = p["k1"] * (series.focal_px / series.half_diagonal_px) ** 2
        return out
    if effect == "illumination_gradient":
        return {"gradient_x_per_half_diagonal": p["gradient_x"], "gradient_y_per_half_diagonal": p["gradient_y"]}
    raise KeyError(effect)


@dataclass
class ModelReport:
    """Everything the command writes; arrays kept for the plots."""

    series: ExposureSeries
    check: ModelCheck
    baseline: FitResult
    final: FitResult
    baseline_heldout: Candidate
    singles: list[Candidate]
    path: list[Candidate]
    skipped: dict[str, str]
    chosen: tuple[str, ...]
    predicted: dict[str, list[list[FloatArray]]]  # "baseline" / "extended" -> [frame][sub-image]
    disk_pixels: dict[str, measure.DiskPixels]
    bias: dict[str, FloatArray]  # per frame mean threshold radius: measured, baseline, extended
    bias_disks: dict[str, FloatArray]  # (F, M) per disk
    levels: dict[str, FloatArray]  # (F, 2) black, white
    compensated: dict[str, FloatArray]
    binned: dict[str, dict[str, Any]]
    seconds: float
    shape: dict[str, Any] = field(default_factory=dict)
    evaluated: dict[tuple[str, ...], Candidate] = field(default_factory=dict)
    """Every model whose held-out error was computed (effects -> candidate), the baseline as ()."""
    cross_filter: dict[str, Any] = field(default_factory=dict)
    """Set by ``analyse_filters``: the model chosen for this series by the other filters and how it does here."""
    verdict: list[str] = field(default_factory=list)

    # ------------------------------------------------------------------ output
    def to_json(self) -> dict[str, Any]:
        s = self.series
        gain = 1.0 - self.final_heldout / self.baseline_heldout.heldout_rms

        def fit_dict(f: FitResult) -> dict[str, Any]:
            return {"effects": list(f.effects), "chi_rms_in_sample": f.chi_rms, "pixels": f.n_pixels,
                    "converged": f.success, "baseline_parameters": {k: f.params[k] for k in BASE_KEYS},
                    "radius_px": f.params["radius_rel"] * self.check.layout.pitch_px,
                    "radius_m": f.params["radius_rel"] * s.pitch_m,
                    "effect_parameters": {e: effect_parameters(e, f.params, s) for e in f.effects},
                    "geometry_corner_offsets_px": [float(v) for v in f.corner_offsets]}

        return plain({
            "input": {"name": s.name, "exposure_ms": s.exposure_ms.tolist(), "sub_images": [g.label for g in s.grids],
                      "saturation_dn": s.saturation_dn, "pitch_m": s.pitch_m, "pitch_px": self.check.layout.pitch_px,
                      "disks": int(len(self.check.lattice.ij)), "interior_disks": int(self.check.layout.interior.sum()),
                      "black_to_white_known": s.black_to_white, "notes": plain(s.notes)},
            "noise": {"variance_dn2": f"{self.check.noise_a:.4g} + {self.check.noise_b:.4g} * DN",
                      "a_dn2": self.check.noise_a, "b_dn": self.check.noise_b},
            "baseline": fit_dict(self.baseline),
            "heldout": {
                "metric": "RMS of (predicted - measured) / noise sd over the held-out exposures' pixels (2 folds)",
                "baseline": self.baseline_heldout.heldout_rms,
                "single_effects": {"+".join(c.effects): c.heldout_rms for c in self.singles},
                "greedy_path": [{"effects": list(c.effects), "heldout_rms": c.heldout_rms} for c in self.path],
                "all_evaluated": {"+".join(k) or "baseline": c.heldout_rms for k, c in self.evaluated.items()},
                "skipped": self.skipped, "min_relative_gain": MIN_RELATIVE_GAIN,
                "chosen": list(self.chosen), "chosen_heldout_rms": self.final_heldout,
                "relative_gain": gain},
            "chosen_model": fit_dict(self.final),
            "bias_curve": {"exposure_ms": s.exposure_ms.tolist(),
                           **{f"threshold_radius_px_{k}": v.tolist() for k, v in self.bias.items()}},
            "levels": {f"{k}_black_white_dn": v.tolist() for k, v in self.levels.items()},
            "compensation": {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in self.compensated.items()},
            "binned_residuals": plain(self.binned),
            "shape_of_overexposed_disks": plain(self.shape),
            "verdict": self.verdict,
            "leave_one_filter_out": plain(self.cross_filter),
            "seconds": self.seconds,
        })

    @property
    def final_heldout(self) -> float:
        return self.path[-1].heldout_rms if self.path else self.baseline_heldout.heldout_rms

    def summary(self) -> str:
        j = self.to_json()
        lines = [f"model check of {self.series.name}: {len(self.series.exposure_ms)} exposures "
                 f"{', '.join(f'{t:g}' for t in self.series.exposure_ms)} ms, sub-images "
                 f"{'+'.join(g.label for g in self.series.grids)}, {j['input']['interior_disks']} disks analysed"]
        b = j["baseline"]
        bp = b["baseline_parameters"]
        lines.append(f"baseline: radius {b['radius_px']:.3f} px ({1e3 * b['radius_m']:.4f} mm), PSF sigma "
                     f"{bp['sigma_px']:.3f} px, white {bp['white_dn_per_ms']:.4g}"
                     f" DN/ms, ink/paper {bp['black_to_white']:.4f}; in-sample chi "
                     f"{b['chi_rms_in_sample']:.3f}")
        h = j["heldout"]
        lines.append(f"held-out RMS normalised error: baseline {h['baseline']:.4f}")
        for name, v in sorted(h["single_effects"].items(), key=lambda kv: kv[1]):
            lines.append(f"  + {name:16s} {v:.4f}  ({100 * (1 - v / h['baseline']):+.1f} %)")
        for name, why in h["skipped"].items():
            lines.append(f"  ({name} skipped: {why})")
        lines.append(f"chosen: {' + '.join(h['chosen']) or 'baseline (no extension helps)'}; held-out "
                     f"{h['chosen_heldout_rms']:.4f}, gain {100 * h['relative_gain']:.1f} %")
        for e, par in j["chosen_model"]["effect_parameters"].items():
            lines.append(f"  {e}: " + ", ".join(f"{k} = {v:.4g}" for k, v in par.items()))
        c = j["compensation"]
        for when, why in c["frames_left_out"].items():
            lines.append(f"  {when} left out of the radius measurement: {why}")
        lines.append(f"threshold radius over exposures (px): measured {_fmt(self.bias['measured'])}")
        lines.append(f"  predicted baseline {_fmt(self.bias['baseline'])}")
        lines.append(f"  predicted extended {_fmt(self.bias['extended'])}")
        bs = c.get("bias_shift")
        if bs:
            lines.append(f"bias curve (threshold radius shift from the best unclipped frame, "
                         f"{bs['reference_ms']:g} ms) over the clipped frames "
                         f"{', '.join(f'{t:g}' for t in bs['frames_ms'])} ms: measured "
                         f"{_fmt(np.asarray(bs['measured_px']))} px; RMS error of the prediction: baseline "
                         f"{bs['rms_error_baseline_px']:.3f} px, chosen {bs['rms_error_extended_px']:.3f} px")
        sh = self.shape
        if sh.get("over_exposed_ms"):
            lines.append(f"over-exposed disks, shrink vertical / horizontal: measured {sh['measured']['ratio']:.2f}, "
                         f"baseline {sh['baseline']['ratio']:.2f}; shrink beyond the baseline vertical / horizontal "
                         f"{sh['extra_ratio']:.2f}; top/bottom centroid shift "
                         f"{sh['measured']['centroid_dy_px']:+.3f} px")
            if "blooming_test" in sh:
                lines.append(f"  blooming test: {sh['blooming_test']}")
        lines.append(f"spread (std over exposures) of the disk radius: raw {c['spread_raw_px']:.4f} px, compensated "
                     f"with baseline {c['spread_baseline_px']:.4f} px, with extended {c['spread_extended_px']:.4f} px")
        lines.extend(f"verdict: {v}" for v in self.verdict)
        cf = self.cross_filter
        if cf:
            bs = cf.get("bias_shift") or {}
            model = " + ".join(cf["chosen_by_other_filters"]) or "the baseline"
            lines.append(f"leave-one-filter-out: the other filters choose {model}"
                         f" (their mean held-out error {cf['mean_relative_other_filters']:.3f} x baseline); here "
                         f"held-out {cf['heldout_rms_here']:.4f}, gain {100 * cf['relative_gain_here']:.1f} %"
                         + (f", bias-curve RMS error {bs['rms_error_extended_px']:.3f} px" if bs else ""))
        return "\n".join(lines)


def _fmt(a: FloatArray) -> str:
    return " ".join(f"{v:.3f}" for v in a)


def plain(x: Any) -> Any:
    """``x`` as plain JSON data: dicts, lists, floats (non-finite -> None), ints."""
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return [plain(v) for v in x.tolist()]
    if isinstance(x, float | np.floating):
        return None if not math.isfinite(float(x)) else float(x)
    if isinstance(x, np.integer):
        return int(x)
    return x


# ---------------------------------------------------------------------------------------------- pipeline
def _start(c: Candidate) -> dict[str, float]:
    """Mean of the fold parameters: a starting point for larger models."""
    keys = c.fold_params[0].keys()
    return {k: float(np.mean([p[k] for p in c.fold_params])) for k in keys}


def analyse(series: ExposureSeries) -> ModelReport:
    t0 = time.perf_counter()
    mc = ModelCheck(series)
    baseline = mc.fit((), fit_geometry=True, max_nfev=80)
    mc.geometry = baseline.corner_offsets.copy()
    mc.init.update({k: baseline.params[k] for k in BASE_KEYS})
    base_ho = mc.heldout(())
    log.info("baseline held-out %.4f (%.1f s)", base_ho.heldout_rms, time.perf_counter() - t0)
    names, skipped = mc.candidates()
    singles = []
    for e in names:
        c = mc.heldout((e,))
        log.info("  + %s: held-out %.4f", e, c.heldout_rms)
        singles.append(c)
    singles.sort(key=lambda c: c.heldout_rms)
    for c in singles:
        if negligible(c.effects[0], _start(c)):
            skipped[c.effects[0]] = "fitted size negligible (absorbs model-accuracy residue, not named)"
        elif (why := unidentifiable(c.effects[0], _start(c))) is not None:
            skipped[c.effects[0]] = f"not identifiable: {why}"
    bloom = next((c for c in singles if c.effects == ("blooming",)), None)
    shape = _shape_evidence(series, mc, baseline, {"blooming": _start(bloom)} if bloom is not None else {})
    if bloom is not None and "blooming" not in skipped and shape.get("blooming_consistent") is False:
        skipped["blooming"] = "ruled out by its own prediction: " + shape["blooming_test"]
    eligible = [c for c in singles if c.effects[0] not in skipped]
    path: list[Candidate] = []
    tried: list[Candidate] = []
    current = base_ho
    ranked = [c.effects[0] for c in eligible]
    if eligible and eligible[0].heldout_rms < (1 - MIN_RELATIVE_GAIN) * current.heldout_rms:
        current = eligible[0]
        path.append(current)
        while len(current.effects) < MAX_EFFECTS:
            best = None
            for e in ranked:
                if e in current.effects or any({e, f} <= pair for f in current.effects for pair in EXCLUSIVE):
                    continue
                if next(c for c in eligible if c.effects[0] == e).heldout_rms >= base_ho.heldout_rms:
                    continue  # useless alone: not tried in combination (cost)
                c = mc.heldout(current.effects + (e,), start=_start(current))
                tried.append(c)
                log.info("  + %s: held-out %.4f", "+".join(c.effects), c.heldout_rms)
                if negligible(e, _start(c)):
                    continue
                if best is None or c.heldout_rms < best.heldout_rms:
                    best = c
            if best is None or best.heldout_rms >= (1 - MIN_RELATIVE_GAIN) * current.heldout_rms:
                break
            current = best
            path.append(current)
    chosen = current.effects if path else ()
    final = mc.fit(chosen, fit_geometry=True, start=_start(current) if path else None, max_nfev=80) if chosen \
        else baseline
    report = _compare(series, mc, baseline, final)
    rep = ModelReport(series, mc, baseline, final, base_ho, singles, path, skipped, chosen, seconds=0.0,
                      shape=shape, evaluated={c.effects: c for c in [base_ho, *singles, *tried]}, **report)
    rep.verdict = _verdict(rep)
    rep.seconds = time.perf_counter() - t0
    return rep


def _compare(series: ExposureSeries, mc: ModelCheck, baseline: FitResult, final: FitResult) -> dict[str, Any]:
    frames = list(range(series.n_frames))
    pred = {"baseline": mc.predict(baseline.params, baseline.corner_offsets, frames),
            "extended": mc.predict(final.params, final.corner_offsets, frames)}
    dps, fits = {}, {"baseline": baseline, "extended": final}
    for k, f in fits.items():
        c, r = centres_and_radii(series, mc.lattice, f.params, f.corner_offsets)
        dps[k] = measure.disk_pixels(mc.layout, c, r, series.width, series.height)
    pitch = mc.layout.pitch_px
    bias_disks = {"measured": [], "baseline": [], "extended": []}
    lev = {"measured": [], "baseline": [], "extended": []}
    for i in range(series.n_frames):
        _, r = measure.threshold_radii(series.images[i], dps["extended"], pitch)
        bias_disks["measured"].append(r)
        lev["measured"].append(measure.levels(series.images[i], dps["extended"], pitch))
        for k in ("baseline", "extended"):
            _, r = measure.threshold_radii(pred[k][i], dps[k], pitch)
            bias_disks[k].append(r)
            lev[k].append(measure.levels(pred[k][i], dps[k], pitch))
    bd = {k: np.asarray(v) for k, v in bias_disks.items()}
    levels = {k: np.asarray(v) for k, v in lev.items()}
    # A frame whose disk centres clip (black >= 90 % of saturation) has no edge left to measure; one whose
    # paper-ink contrast is under MIN_CONTRAST_SD noise sd has too little signal for a radius (a threshold then
    # finds noise: a 1.7 px "radius" on paper reading under 1 DN).
    black, white = levels["measured"][:, 0], levels["measured"][:, 1]
    sd = np.full(series.n_frames, math.sqrt(mc.noise_a))  # the read noise: a threshold averages over many pixels
    left_out: dict[int, str] = {}
    for i in range(series.n_frames):
        if black[i] >= 0.9 * series.saturation_dn:
            left_out[i] = f"disk centres clipped (black {black[i]:.0f} DN): no edge left"
        elif white[i] - black[i] < MIN_CONTRAST_SD * sd[i]:
            left_out[i] = (f"too little signal: paper - ink contrast {white[i] - black[i]:.2f} DN, under "
                           f"{MIN_CONTRAST_SD:g} x the read noise ({sd[i]:.2f} DN)")
    usable = np.array([i not in left_out for i in range(series.n_frames)])
    for v in bd.values():
        v[~usable] = np.nan
    with np.errstate(invalid="ignore"):
        bias = {k: np.array([np.nanmean(row) if np.any(np.isfinite(row)) else np.nan for row in v])
                for k, v in bd.items()}
    comp: dict[str, Any] = {"frames_used": usable,
                            "frames_left_out": {f"{series.exposure_ms[i]:g} ms": why for i, why in left_out.items()}}
    raw = bias["measured"]
    comp["radius_raw_px"] = raw
    comp["spread_raw_px"] = float(np.nanstd(raw))
    for k in fits:
        true_r = float(np.mean(dps[k].radii_px[mc.layout.interior]))
        corrected = raw - (bias[k] - true_r)
        comp[f"radius_compensated_{k}_px"] = corrected
        comp[f"spread_{k}_px"] = float(np.nanstd(corrected))
        comp[f"model_radius_{k}_px"] = true_r
    # The bias curve: shift of the threshold radius from the best unclipped frame (the longest exposure whose
    # paper is not clipped) over the frames whose paper clips and whose disks are still measurable.
    clipped = (white >= 0.98 * series.saturation_dn) & usable
    clean = np.flatnonzero((white < 0.95 * series.saturation_dn) & usable)
    if clean.size and np.any(clipped):
        ref = int(clean[np.argmax(series.exposure_ms[clean])])
        shift = {k: bias[k][clipped] - bias[k][ref] for k in bias}
        comp["bias_shift"] = {"reference_ms": float(series.exposure_ms[ref]),
                              "frames_ms": series.exposure_ms[clipped].tolist(),
                              **{f"{k}_px": v.tolist() for k, v in shift.items()},
                              **{f"rms_error_{k}_px": float(np.sqrt(np.mean((shift[k] - shift["measured"]) ** 2)))
                                 for k in fits}}
    binned = {k: _binned(series, mc, f, pred[k], dps[k]) for k, f in fits.items()}
    return {"predicted": pred, "disk_pixels": dps, "bias": bias, "bias_disks": bd, "levels": levels,
            "compensated": comp, "binned": binned}


BLOOMING_SHARE = 0.5
"""Blooming is named only if the measured over-exposed disks show at least this share of the extra vertical
(along-column) shrinkage that the fitted blooming predicts (``_shape_evidence``)."""


def _shape_evidence(series: ExposureSeries, mc: ModelCheck, baseline: FitResult,
                    others: dict[str, dict[str, float]]) -> dict[str, Any]:
    """How the over-exposed disks shrink along x and y, measured and as predicted by the baseline and by each
    model in ``others`` (name -> parameters), relative to the best unclipped frame; the direct blooming test.

    Blooming along columns fills the top and bottom of each dark disk, so it predicts a larger vertical than
    horizontal shrinkage (``vertical_excess_px`` = mean vertical minus horizontal shrinkage over the over-exposed
    frames). Its test: against the blooming fit with its spill switched off, the measured vertical excess must
    reach ``BLOOMING_SHARE`` of what the spill adds (and the spill must add some)."""
    frames = list(range(series.n_frames))
    c, r = centres_and_radii(series, mc.lattice, baseline.params, baseline.corner_offsets)
    dp = measure.disk_pixels(mc.layout, c, r, series.width, series.height)
    pitch = mc.layout.pitch_px
    s = series.saturation_dn
    lev = np.array([measure.levels(series.images[i], dp, pitch) for i in frames])
    usable = (lev[:, 0] < 0.9 * s) & (lev[:, 1] - lev[:, 0] > MIN_CONTRAST_SD * math.sqrt(mc.noise_a))
    over = np.flatnonzero((lev[:, 1] >= 0.98 * s) & usable)
    clean = np.flatnonzero((lev[:, 1] < 0.95 * s) & usable)
    if over.size == 0 or clean.size == 0:
        return {"over_exposed_ms": []}
    ref = int(clean[np.argmax(series.exposure_ms[clean])])
    keep = [ref, *over.tolist()]

    def summary(images: list[list[FloatArray]]) -> dict[str, Any]:
        shp = np.array([np.nanmean(measure.dark_shapes(im, dp, pitch), axis=0) for im in images])
        sx, sy = shp[0, 0] - shp[1:, 0], shp[0, 1] - shp[1:, 1]
        return {"shrink_x_px": sx, "shrink_y_px": sy, "ratio": float(np.sum(sy) / max(np.sum(sx), 1e-9)),
                "vertical_excess_px": float(np.mean(sy - sx)), "centroid_dy_px": float(np.mean(shp[1:, 2]))}

    out: dict[str, Any] = {"reference_ms": float(series.exposure_ms[ref]),
                           "over_exposed_ms": series.exposure_ms[over].tolist(),
                           "measured": summary([series.images[i] for i in keep]),
                           "baseline": summary(mc.predict(baseline.params, baseline.corner_offsets, keep))}
    for name, p in others.items():
        out[name] = summary(mc.predict(p, baseline.corner_offsets, keep))
    m, b = out["measured"], out["baseline"]
    ex, ey = np.sum(m["shrink_x_px"] - b["shrink_x_px"]), np.sum(m["shrink_y_px"] - b["shrink_y_px"])
    out["extra_shrink_px"] = {"x": float(ex), "y": float(ey)}
    out["extra_ratio"] = float(ey / ex) if abs(ex) > 1e-9 else float("nan")
    if "blooming" in out:
        # the same fitted model with the spill switched off: what blooming itself adds
        p = {k: v for k, v in others["blooming"].items() if k != "spill_log10"}
        ref_shape = summary(mc.predict(p, baseline.corner_offsets, keep))
        need = out["blooming"]["vertical_excess_px"] - ref_shape["vertical_excess_px"]
        seen = m["vertical_excess_px"] - ref_shape["vertical_excess_px"]
        out["blooming_consistent"] = bool(need > 0 and seen >= BLOOMING_SHARE * need)
        out["blooming_test"] = (
            f"blooming (its fit, against the same fit without spill) predicts over-exposed disks shrinking "
            f"{need:+.3f} px more vertically than horizontally (vertical/horizontal shrink ratio "
            f"{out['blooming']['ratio']:.2f} against {ref_shape['ratio']:.2f}); measured {seen:+.3f} px (ratio "
            f"{m['ratio']:.2f}); top/bottom centroid shift measured {m['centroid_dy_px']:+.3f} px, blooming "
            f"{out['blooming']['centroid_dy_px']:+.3f} px")
    return out


def _binned(series: ExposureSeries, mc: ModelCheck, fit: FitResult, pred: list[list[FloatArray]],
            dp: measure.DiskPixels) -> dict[str, Any]:
    """Normalised residuals binned by edge orientation (edge pixels of the over-exposed frames), by predicted
    intensity and by distance from the image centre."""
    s = series.saturation_dn
    over = [i for i in range(series.n_frames) if series.exposure_ms[i] * fit.params["white_dn_per_ms"] > s]
    res_o, ang, res_i, lev_i, res_p, pos_p = [], [], [], [], [], []
    width = 2.0 * fit.params["sigma_px"] + 1.5
    cx, cy = series.centre_px
    for i in range(series.n_frames):
        for g in range(len(series.grids)):
            roi = mc.layout.roi[g]
            meas = series.images[i][g]
            r = (pred[i][g] - meas) / mc.sd[i][g]
            info = roi & ~((meas >= s) & (pred[i][g] >= s - 1e-6))
            res_i.append(r[info])
            lev_i.append(pred[i][g][info] / s)
            pos = np.hypot(mc.layout.xs[g] - cx, mc.layout.ys[g] - cy) / series.half_diagonal_px
            edge = info & (np.abs(dp.offset_px[g]) < width)
            res_p.append(r[edge])
            pos_p.append(pos[edge])
            if i in over:
                res_o.append(r[edge])
                ang.append(np.degrees(dp.angle_rad[g][edge]) % 360.0)
    out: dict[str, Any] = {}
    if res_o:
        c, m, q = measure.binned(np.concatenate(res_o), np.concatenate(ang), np.linspace(0, 360, 17))
        out["orientation"] = {"angle_deg": c, "mean": m, "rms": q,
                              "note": "edge pixels of over-exposed frames; 90 and 270 deg: top/bottom of disks"}
    c, m, q = measure.binned(np.concatenate(res_i), np.concatenate(lev_i), np.linspace(0, 1.0001, 11))
    out["intensity"] = {"predicted_fraction_of_saturation": c, "mean": m, "rms": q}
    c, m, q = measure.binned(np.concatenate(res_p), np.concatenate(pos_p), np.linspace(0, 1, 9))
    out["position"] = {"distance_from_centre_over_half_diagonal": c, "mean": m, "rms": q}
    return out


def orientation_harmonics(angle_deg: Any, mean: Any) -> dict[str, float]:
    """First and second harmonics of the residual mean over edge direction: amplitudes (sd) and the direction
    of their maxima (deg, image axes: 90 = down)."""
    a = np.radians(np.asarray(angle_deg, dtype=float))
    m = np.asarray(mean, dtype=float)
    ok = np.isfinite(m)
    a, m = a[ok], m[ok]
    if a.size < 4:
        return {"a1": 0.0, "a1_max_deg": 0.0, "a2": 0.0, "a2_max_deg": 0.0}
    c1 = 2 * np.mean(m * np.exp(-1j * a))
    c2 = 2 * np.mean(m * np.exp(-2j * a))
    return {"a1": float(abs(c1)), "a1_max_deg": float(np.degrees(np.angle(c1)) % 360),
            "a2": float(abs(c2)), "a2_max_deg": float(np.degrees(np.angle(c2)) / 2 % 180)}


def _verdict(rep: ModelReport) -> list[str]:
    out = []
    base = rep.baseline_heldout.heldout_rms
    if not rep.chosen:
        out.append(f"no catalogue extension lowers the held-out error by more than {100 * MIN_RELATIVE_GAIN:.0f} %: "
                   f"the baseline (Gaussian PSF, linear response, clipping) explains the series "
                   f"(held-out RMS {base:.3f}).")
    else:
        for c in rep.path:
            e = c.effects[-1]
            par = effect_parameters(e, rep.final.params, rep.series)
            out.append(f"cause: {e} ({', '.join(f'{k} = {v:.4g}' for k, v in par.items())}); with it the held-out "
                       f"error falls to {c.heldout_rms:.4f} from {base:.4f} for the baseline.")
    final = rep.final_heldout
    if final > 1.25:
        b = rep.binned["extended"]
        worst = []
        for view, key in (("intensity", "predicted_fraction_of_saturation"), ("position",
                                                                               "distance_from_centre_over_half_diagonal"),
                          ("orientation", "angle_deg")):
            if view in b:
                m = np.asarray(b[view]["mean"], dtype=float)
                if np.any(np.isfinite(m)):
                    j = int(np.nanargmax(np.abs(m)))
                    worst.append(f"{view}: mean residual {m[j]:+.2f} sd at {key} = {float(b[view][key][j]):.3g}")
        text = (f"structure remains (held-out RMS {final:.3f} sd, noise alone would give about 1): "
                + "; ".join(worst) + ".")
        if "orientation" in b:
            h = orientation_harmonics(b["orientation"]["angle_deg"], b["orientation"]["mean"])
            text += (f" Over edge direction the mean residual has a 180-degree period of amplitude {h['a2']:.2f} sd "
                     f"(predicted brightest at {h['a2_max_deg']:.0f} and {h['a2_max_deg'] + 180:.0f} deg; elliptical "
                     f"disk images or an anisotropic PSF, e.g. astigmatism) and a 360-degree period of "
                     f"{h['a1']:.2f} sd (max at {h['a1_max_deg']:.0f} deg; one-sided smear or coma).")
        out.append(text + " Nothing else in the catalogue explains it.")
    comp = rep.compensated
    out.append(f"downstream: the apparent disk radius varies by {comp['spread_raw_px']:.3f} px (std over exposures); "
               f"compensated with the baseline {comp['spread_baseline_px']:.3f} px, with the chosen model "
               f"{comp['spread_extended_px']:.3f} px.")
    return out


# ---------------------------------------------------------------------------------------------- several filters
def leave_one_filter_out(heldout: dict[str, dict[tuple[str, ...], float]],
                         exclude: dict[str, set[tuple[str, ...]]] | None = None) -> dict[str, dict[str, Any]]:
    """The model for each filter chosen by the *other* filters' held-out errors: among the models evaluated in
    every other filter (and not excluded there, e.g. ruled out by an identifiability rule), the one with the lowest
    mean held-out error relative to that filter's baseline. ``heldout[F][effects]`` = held-out RMS (effects ()
    = baseline). Returns F -> {chosen, mean_relative_other_filters}. Pure."""
    out = {}
    for f in heldout:
        others = [g for g in heldout if g != f]
        if not others:
            continue
        common = set.intersection(*(set(heldout[g]) for g in others))
        for g in others:
            common -= (exclude or {}).get(g, set())
        scores = {m: float(np.mean([heldout[g][m] / heldout[g][()] for g in others])) for m in common}
        best = min(scores, key=lambda m: (scores[m], len(m)))
        out[f] = {"chosen": best, "mean_relative_other_filters": scores[best]}
    return out


def analyse_filters(series_by_filter: dict[str, ExposureSeries]) -> dict[str, ModelReport]:
    """``analyse`` every series, then choose each one's model also by leave-one-filter-out
    (``leave_one_filter_out``), evaluate that model on the filter's own held-out exposures if it was not, fit it to
    all its exposures and predict its bias curve. Stored in each report's ``cross_filter``."""
    reports = {f: analyse(s) for f, s in series_by_filter.items()}

    def ruled_out(rep: ModelReport) -> set[tuple[str, ...]]:
        bad = {e for e, why in rep.skipped.items() if not why.startswith("fitted size negligible")}
        return {m for m in rep.evaluated if bad & set(m)}

    lofo = leave_one_filter_out({f: {m: c.heldout_rms for m, c in r.evaluated.items()} for f, r in reports.items()},
                                {f: ruled_out(r) for f, r in reports.items()})
    for f, choice in lofo.items():
        rep, model = reports[f], choice["chosen"]
        mc = rep.check
        if model not in rep.evaluated:
            rep.evaluated[model] = mc.heldout(model, start=_start(rep.path[-1]) if rep.path else None)
        cand = rep.evaluated[model]
        fit = mc.fit(model, fit_geometry=True, start=_start(cand), max_nfev=80) if model else rep.baseline
        comp = _compare(rep.series, mc, rep.baseline, fit)["compensated"]
        rep.cross_filter = {
            "chosen_by_other_filters": list(model), **choice,
            "heldout_rms_here": cand.heldout_rms,
            "relative_gain_here": 1.0 - cand.heldout_rms / rep.baseline_heldout.heldout_rms,
            "effect_parameters": {e: effect_parameters(e, fit.params, rep.series) for e in model},
            "bias_shift": comp.get("bias_shift", {}), "spread_compensated_px": comp["spread_extended_px"]}
    return reports
