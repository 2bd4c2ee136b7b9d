"""Model versus measurement (livetrack.modelcheck): forward model against exact integrals and the simulator,
hidden-effect identification on simulated exposure series, and the command end to end."""

from __future__ import annotations

import json
import math
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest
from scipy.special import ndtr

from livetrack.modelcheck import reading_kernel
from livetrack.modelcheck.analysis import analyse, effect_parameters
from livetrack.modelcheck.fitting import ModelCheck
from livetrack.modelcheck.forward import RadialProfiles, expected_reading_reference
from livetrack.modelcheck.series import from_recording
from livetrack.modelcheck.simulate import (
    NEW_HIDDEN_EFFECTS,
    HiddenEffect,
    draw_hidden_effect,
    write_disk_grid_series,
)

TOLERANCE = {
    # effect -> (fitted parameter name in effect_parameters, absolute tolerance, relative tolerance)
    "halo": ("fraction", 0.0, 0.5),
    "defocus": ("radius_px", 0.35, 0.0),
    "blooming": ("spill_fraction", 0.0, 2.0),
    "nonlinear": ("knee_fraction_of_full_well", 0.06, 0.0),
    "veiling_glare": ("fraction", 0.01, 0.0),
    "vignetting": ("strength", 0.06, 0.0),
    "lens_distortion": ("k1", 0.0, 0.35),
    "anisotropic_core": ("axis_ratio", 0.0, 0.1),
    "exponential_tail": ("fraction", 0.06, 0.0),
    "lorentzian_tail": ("fraction", 0.04, 0.0),
    "ink_floor": ("black_to_white", 0.01, 0.0),
}
SAME_IMAGES = {"ink_floor": ("veiling_glare", "equivalent_ink_black_to_white")}
"""Hidden effect -> (the effect it is reported as, and that effect's parameter holding the hidden one's): on a
disk grid filling the frame a lighter ink and a uniform veil give the same images (docs/model-check.md)."""
"""Stated tolerances of the parameter estimates in the hidden-effect tests."""


def test_radial_profile_matches_direct_integration():
    """Hankel-transform profile of a blurred, pixel-integrated disk vs a direct 2-D quadrature."""
    prof = RadialProfiles(60.0, 8.0)
    p = prof.disk(8.0, prof.transfer(1.0))
    h = 0.02
    g = np.arange(-8 + h / 2, 8, h)
    x, y = np.meshgrid(g, g)
    inside = x**2 + y**2 <= 64
    xi, yi = x[inside], y[inside]

    def box_gauss(u: np.ndarray) -> np.ndarray:
        return ndtr((u + 0.5) / 1.0) - ndtr((u - 0.5) / 1.0)

    for r in (0.0, 6.0, 7.5, 8.0, 8.5, 10.0):
        ref = float(np.sum(box_gauss(xi - r) * box_gauss(yi)) * h * h)
        assert abs(np.interp(r, prof.r, p) - ref) < 2e-3, r


def test_forward_model_matches_simulator(tmp_path):
    """The fast model, at the parameters the simulator used, reproduces its noise-free frames."""
    write_disk_grid_series(tmp_path / "rec", HiddenEffect(None, None, None, {}), seed=5,
                           white_fractions=(0.5, 0.9, 3.0))
    series = from_recording(tmp_path / "rec")
    mc = ModelCheck(series)
    fit = mc.fit((), fit_geometry=True)
    # True values: reflectance ratio known; sigma 0.9 px; white rate 0.85 * 3.2 e/us * 4095/10000 DN/e.
    assert fit.params["sigma_px"] == pytest.approx(0.9, abs=0.05)
    assert fit.params["white_dn_per_ms"] == pytest.approx(0.85 * 3.2 * 409.5, rel=0.01)
    assert fit.params["radius_rel"] * series.pitch_m == pytest.approx(0.002, rel=0.01)
    assert fit.chi_rms < 1.1


def test_whole_images_are_predicted_where_no_pixel_is_fitted(tmp_path):
    """``predict`` gives the fitted pixels' values and, elsewhere (a large disk's middle, flat paper left out of
    the fits), values as close to the frames. Until session 34 those were predicted as paper: off by up to 150 DN
    on the real disks, in the plots and in the predicted radii of the downstream verdict."""
    write_disk_grid_series(tmp_path / "rec", HiddenEffect(None, None, None, {}), seed=5, distance_m=0.07,
                           white_fractions=(0.5, 1.0, 3.0))
    series = from_recording(tmp_path / "rec")
    mc = ModelCheck(series)
    fit = mc.fit(())
    frames = list(range(series.n_frames))
    whole = mc.predict(fit.params, fit.corner_offsets, frames)
    fitted = mc.predict_fitted(fit.params, fit.corner_offsets, frames)
    for f in frames:
        for g, pix in enumerate(mc.fit_pixels):
            np.testing.assert_allclose(whole[f][g].ravel()[pix], fitted[f][g], rtol=0, atol=1e-9)
            rest = mc.layout.roi[g] & ~mc.fit_mask[g]
            assert rest.sum() > 100
            r = ((whole[f][g] - series.images[f][g]) / mc.sd[f][g])[rest]
            assert np.sqrt(np.mean(r**2)) < 1.3
    # any other pixels: their own values (the kept scenes are keyed on the pixels, not on "some pixels")
    every_other = [pix[::2] for pix in mc.fit_pixels]
    again = mc.model.frames(fit.params, fit.corner_offsets, frames, pixels=every_other)
    for f in frames:
        for g, pix in enumerate(every_other):
            np.testing.assert_allclose(whole[f][g].ravel()[pix], again[f][g], rtol=0, atol=1e-9)


def test_the_compiled_expected_reading_is_the_numpy_reference():
    rng = np.random.default_rng(3)
    mean = np.concatenate([rng.uniform(-50, 4200, 20000), [-1e3, 0.0, 4095.0, 4095.0 + 1e-9, 1e6]])
    for a, b in [(4.0, 0.0), (4.0, 1.3), (0.5, 0.7), (100.0, 10.0)]:
        ref = expected_reading_reference(mean, a, b, 4095.0)
        out = np.empty_like(mean)
        reading_kernel.expected_clipped(mean, a, b, 4095.0, out)
        np.testing.assert_allclose(out, ref, rtol=1e-12, atol=1e-9)
        assert out.min() >= 0.0 and out.max() <= 4095.0


SMALL = {"width": 200, "height": 160, "white_fractions": (0.3, 0.8, 2.4, 9.6)}
"""A cheaper series for the default test run (fewer disks and exposures)."""


def _check_hidden(seed: int, tmp_path, small: bool = False, size: dict | None = None,
                  names: tuple[str | None, ...] | None = None) -> dict:
    hidden = draw_hidden_effect(seed) if names is None else draw_hidden_effect(seed, names)
    tag = "" if names is None else "new"
    write_disk_grid_series(tmp_path / f"rec{tag}{seed}", hidden, seed, **(SMALL if small else size or {}))
    rep = analyse(from_recording(tmp_path / f"rec{tag}{seed}"))
    out = {"seed": seed, "hidden": hidden.name, "value": hidden.value, "chosen": list(rep.chosen),
           "gain": 1 - rep.final_heldout / rep.baseline_heldout.heldout_rms}
    if hidden.name is None:
        out["named_ok"] = rep.chosen == ()
        out["param_ok"] = True
        return out
    named, key = hidden.name, TOLERANCE[hidden.name][0]
    if hidden.name in SAME_IMAGES:
        named, key = SAME_IMAGES[hidden.name]
    out["named_ok"] = bool(rep.chosen) and rep.chosen[0] == named
    if out["named_ok"]:
        _, atol, rtol = TOLERANCE[hidden.name]
        est = effect_parameters(named, rep.final.params, rep.series)[key]
        out["estimate"] = est
        out["param_ok"] = math.isclose(est, hidden.value, abs_tol=atol, rel_tol=rtol)
    else:
        out["param_ok"] = False
    return out


@pytest.mark.parametrize("seed", [23, 14])
def test_hidden_effect_default(seed, tmp_path):
    """Two seeds on the small series, run blind (the slow set runs seeds 0-19, nonlinear response (1) and lens
    distortion (18) among them; the default set ran those two too until session 13 put it over 10 min): none (23),
    halo (14): the right effect named first (or nothing), its parameter within ``TOLERANCE``, a held-out
    gain. (Vignetting: the command test below; all effects: the slow set.)"""
    r = _check_hidden(seed, tmp_path, small=True)
    assert r["named_ok"] and r["param_ok"], r
    assert (r["hidden"] is None) == (seed == 23)
    if r["hidden"] is not None:
        assert r["gain"] > 0.02, r


@pytest.mark.parametrize("seed", [6])
def test_hidden_new_effect_default(seed, tmp_path):
    """One seed of the effects added for the real disks, on the small series, blind: an exponential tail (seed 6:
    17 % at 1.0 px) named first, its fraction within ``TOLERANCE``. (All new effects: the slow set.)"""
    r = _check_hidden(seed, tmp_path, small=True, names=NEW_HIDDEN_EFFECTS)
    assert r["hidden"] == "exponential_tail"
    assert r["named_ok"] and r["param_ok"] and r["gain"] > 0.02, r


SLOW_SEEDS = [*range(0, 13), 21, 27]
"""Every effect of the catalogue: seeds 0-12 draw all but blooming (21) and none (27)."""
SLOW_NEW_SEEDS = [0, 1, 4, 5, 6, 7, 11, 14, 21, 23]
"""Seeds of ``draw_hidden_effect(seed, NEW_HIDDEN_EFFECTS)`` in the slow set: ink floor (0, 7), exponential tail
(1, 6, 21), Lorentzian tail (4, 5), anisotropic core (11, 14, 23)."""
SLOW_SIZE = {"width": 240, "height": 180}
"""The slow set's series: all six exposures, 240x180 px (about half the 320x240 series' disks and time)."""


@pytest.mark.slow
def test_hidden_effect_identification_rate(tmp_path, monkeypatch):
    """15 seeds over all effects and none (30 until session 13 and 20 until session 14, trimmed as CI neared 30
    min) and the 10 of the new effects, ``SLOW_SIZE`` series: the rate of right names and of parameters within
    ``TOLERANCE``. Cost: about 15 s per seed on one free core; the seeds run in one process per core."""
    workers = max(1, min(len(SLOW_SEEDS), os.cpu_count() or 1))
    # One BLAS/OpenMP thread per worker (they inherit the environment at spawn): a worker per core, not more.
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.setenv(name, "1")
    seeds = SLOW_SEEDS + SLOW_NEW_SEEDS
    names = [None] * len(SLOW_SEEDS) + [NEW_HIDDEN_EFFECTS] * len(SLOW_NEW_SEEDS)
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        results = list(pool.map(_check_hidden, seeds, [tmp_path] * len(seeds), [False] * len(seeds),
                                [SLOW_SIZE] * len(seeds), names))
    named = np.mean([r["named_ok"] for r in results])
    both = np.mean([r["named_ok"] and r["param_ok"] for r in results])
    print(json.dumps(results, indent=1))
    assert named >= 0.85, results  # measured: 29 of 30 (seeds 0-29), 39 of 40 with the new effects' 10
    assert both >= 0.8, results
    assert all(r["gain"] > 0.02 for r in results if r["named_ok"] and r["hidden"] is not None), results


def test_command_on_simulated_recording(tmp_path, capsys):
    from livetrack.commands.model import main

    hidden = HiddenEffect("vignetting", "strength", 0.35, {"strength": 0.35})
    # a first frame with almost no light (paper at 0.05 % of full well: 2 DN against 2 DN read noise)
    small = {**SMALL, "white_fractions": (0.0005, *SMALL["white_fractions"])}
    write_disk_grid_series(tmp_path / "rec", hidden, seed=2, **small)
    rc = main([str(tmp_path / "rec"), "--json", str(tmp_path / "out.json"), "--plots", str(tmp_path / "plots")])
    assert rc == 0
    data = json.loads((tmp_path / "out.json").read_text())
    assert data["heldout"]["chosen"][:1] == ["vignetting"]
    assert data["chosen_model"]["effect_parameters"]["vignetting"]["strength"] == pytest.approx(0.35, abs=0.06)
    assert data["heldout"]["chosen_heldout_rms"] < data["heldout"]["baseline"]
    radii = data["bias_curve"]["threshold_radius_px_measured"]
    assert radii[0] is None and "too little signal" in " ".join(data["compensation"]["frames_left_out"].values())
    assert radii[-1] < radii[1]  # the disks shrink as the exposure grows
    for name in ("bias_curve.png", "residual_maps.png", "residuals_binned.png", "edge_profiles.png", "levels.png",
                 "heldout.png"):
        assert (tmp_path / "plots" / name).stat().st_size > 1000
    out = capsys.readouterr().out
    assert "chosen:" in out and "left out of the radius measurement: too little signal" in out


def test_leave_one_filter_out_chooses_by_the_other_filters():
    from livetrack.modelcheck.analysis import leave_one_filter_out

    base = ()
    heldout = {"500nm": {base: 2.0, ("a",): 1.0, ("b",): 1.9, ("a", "c"): 0.9},
               "550nm": {base: 3.0, ("a",): 2.4, ("b",): 1.5},
               "600nm": {base: 1.0, ("a",): 0.9, ("b",): 0.5, ("a", "c"): 0.8}}
    out = leave_one_filter_out(heldout)
    # 500 nm: models evaluated at 550 and 600 alike: a (0.8, 0.9 -> 0.85), b (0.5, 0.5 -> 0.5): b
    assert out["500nm"]["chosen"] == ("b",) and out["500nm"]["mean_relative_other_filters"] == 0.5
    assert out["600nm"]["chosen"] == ("a",)  # a: (0.5 + 0.8) / 2 = 0.65, b: (0.95 + 0.5) / 2 = 0.725
    # a model ruled out in another filter is not chosen
    assert leave_one_filter_out(heldout, {"550nm": {("b",)}})["500nm"]["chosen"] == ("a",)
