"""Model check on recordings of livetrack ring targets (``livetrack.modelcheck.rings``): hidden-effect tests.

Each seed draws one catalogue effect of the simulator (or none) and its size (``rings_simulate.draw_ring_effect``),
renders a short ring recording with it (640x480, target 3 at two poses, white paper at 0.35, 0.85, 2.5 and 8 x full
well), and runs the analysis blind: poses from the tracker, the image formation fitted on the pixels around the
edges, the effect chosen by held-out exposures. The right effect (or nothing) must be named first and its parameter
estimated within ``TOLERANCE``. Default run: a handful of seeds on a static target (one pose); slow set: 31 seeds,
at least 90 % right, in two single-threaded processes.
"""

from __future__ import annotations

import math
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest
import yaml

from livetrack.camera.io import load_camera_with_optics
from livetrack.cli import main as cli_main
from livetrack.modelcheck.rings import analyse_rings
from livetrack.modelcheck.rings_input import ring_series_from_recording
from livetrack.modelcheck.rings_simulate import RANGES, draw_ring_effect, ring_scenario, write_ring_series
from livetrack.modelcheck.simulate import HiddenEffect

TOLERANCE = {
    "halo": ("relative", 0.3),
    "exponential_tail": ("relative", 0.3),
    "lorentzian_tail": ("relative", 0.3),
    "defocus": ("absolute", 0.35),
    "anisotropic_core": ("absolute", 0.1),
    "blooming": ("factor", 3.0),
    "nonlinear": ("absolute", 0.06),
    "ink_floor": ("absolute", 0.01),
    "vignetting": ("absolute", 0.06),
}
"""Effect -> how its main parameter (the first of ``RANGES``) must match: within a fraction, px / absolute, or a
factor."""

SLOW_SEEDS = (*range(20), 22, 34)
"""Seeds 0-19 draw every effect of the ring catalogue but the exponential tail (22) and the Lorentzian tail (34)
(seeds 0-29 and 34 until session 14, trimmed as CI neared 30 min)."""
DEFAULT_SEEDS = (1, 5, 23)
"""halo (6.3 %), ink floor (0.118), none."""


def within(effect: str, estimate: float, truth: float) -> bool:
    kind, tol = TOLERANCE[effect]
    if kind == "relative":
        return abs(estimate - truth) <= tol * abs(truth)
    if kind == "factor":
        return truth / tol <= estimate <= truth * tol
    return abs(estimate - truth) <= tol


def identify(seed: int, folder: str, poses: int = 2) -> dict:
    """Render the seed's recording into ``folder``, analyse it blind, and say what was found."""
    import cv2

    cv2.setNumThreads(1)
    hidden = draw_ring_effect(seed)
    path = Path(folder) / f"ring-{seed}"
    write_ring_series(path, ring_scenario(hidden, seed, poses=poses))
    report = analyse_rings(ring_series_from_recording(path))
    named = report.named()
    first = named[0][0] if named else None
    estimate = named[0][1][hidden.parameter] if named and hidden.name and first == hidden.name else None
    ok = first == hidden.name and (hidden.name is None or within(hidden.name, estimate, hidden.value))
    return {"seed": seed, "effect": hidden.name, "truth": hidden.value, "named": [n for n, _ in named],
            "estimate": estimate, "ok": ok, "gain": report.relative_gain, "seconds": report.seconds}


def test_drawn_effects_cover_the_ring_catalogue() -> None:
    drawn = {draw_ring_effect(seed).name for seed in range(60)}
    assert drawn == {None, *RANGES}
    for seed in range(60):
        h = draw_ring_effect(seed)
        if h.name is not None:
            (lo, hi), = [RANGES[h.name][h.parameter]]
            assert lo <= h.value <= hi


@pytest.mark.parametrize("seed", DEFAULT_SEEDS)
def test_hidden_effect_is_named_on_a_static_target(seed, tmp_path) -> None:
    result = identify(seed, str(tmp_path), poses=1)
    assert result["ok"], result


def test_command_on_a_ring_recording_writes_report_plots_and_camera(tmp_path, capsys) -> None:
    hidden = HiddenEffect("halo", "fraction", 0.06, {"fraction": 0.06, "sigma_px": 4.0})
    rec = tmp_path / "rings"
    write_ring_series(rec, ring_scenario(hidden, 5, poses=1))
    out = tmp_path / "out"
    assert cli_main(["model", str(rec), "--json", str(out / "r.json"), "--plots", str(out / "plots"),
                     "--camera-out", str(out / "cam.yaml")]) == 0
    text = capsys.readouterr().out
    assert "chosen: halo" in text
    report = yaml.safe_load((out / "r.json").read_text())
    assert report["input"]["kind"] == "ring targets" and report["heldout"]["chosen"] == ["halo"]
    fraction = report["chosen_model"]["effect_parameters"]["halo"]["fraction"]
    assert abs(fraction - 0.06) < 0.015
    assert {Path(p).name for p in report["plots"]} >= {"bias_curve.png", "residuals_binned.png", "heldout.png"}
    camera, optics = load_camera_with_optics(out / "cam.yaml")
    assert camera.width == 640 and optics is not None and optics.halo is not None
    assert abs(optics.halo[0] - 0.06) < 0.015 and abs(optics.psf_sigma_px - 0.8) < 0.1
    assert optics.read_noise_dn is not None and 1.0 < optics.read_noise_dn < 3.5  # 5 e x 0.41 DN/e


def test_too_few_exposures_are_refused(tmp_path, capsys) -> None:
    rec = tmp_path / "two"
    write_ring_series(rec, ring_scenario(HiddenEffect(None, None, None, {}), 3, poses=1, white_fractions=(0.5, 2.0)))
    assert cli_main(["model", str(rec)]) == 2
    assert "three or more" in capsys.readouterr().err


@pytest.mark.slow
def test_hidden_effects_on_ring_recordings_slow_seeds(tmp_path) -> None:
    # spawn, not fork: forked from a pytest process whose earlier tests left threads (numba, Rerun, ZeroMQ)
    # holding locks, the workers deadlocked in a full slow run (they passed when this test ran alone)
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        results = list(pool.map(identify, SLOW_SEEDS, [str(tmp_path)] * len(SLOW_SEEDS)))
    for r in results:
        print(r)
    good = sum(r["ok"] for r in results)
    assert good >= math.ceil(0.9 * len(results)), [r for r in results if not r["ok"]]
