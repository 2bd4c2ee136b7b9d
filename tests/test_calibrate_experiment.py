"""The exposure comparison's bookkeeping (livetrack.calibration.experiment): noise seeds redraw the noise of the same
views; the summary's mean, standard error and z-scores."""

from __future__ import annotations

import math

import numpy as np

from livetrack.calibration.experiment import GRID, NEAR_SCENARIO, ring_images, summarise
from livetrack.sim.scenario import Scenario


def test_noise_seeds_redraw_the_noise_of_the_same_views():
    data = dict(NEAR_SCENARIO, trajectory=dict(NEAR_SCENARIO["trajectory"], count=2),
                exposure={"factors": [1]})
    scenario = Scenario.from_dict(data)
    a, b, clean = ring_images(scenario, 11), ring_images(scenario, 12), ring_images(scenario, None)
    own = list(scenario.frames())
    assert len(a) == len(own) == 2
    for fa, fb, fc, fo in zip(a, b, clean, own, strict=True):
        assert fa.truth.keys() == fo.truth.keys() == {3}
        np.testing.assert_array_equal(fa.truth[3].t, fo.truth[3].t)
        assert not np.array_equal(fa.image, fb.image)
        # the same views: the noise-free frame is the mean of the noisy ones, to the noise
        diff = fa.image.astype(float) - fc.image.astype(float)
        assert abs(diff.mean()) < 2 and 1 < diff.std() < 60
    np.testing.assert_array_equal(ring_images(scenario, scenario.seed)[0].image, own[0].image)


def test_summary_mean_standard_error_and_z_scores():
    method = "rings (default: edges measured again, delta per exposure)"
    rows = [{"noise_seed": s, "exposure_factor": 1.0, "method": method, "fx_pct": fx, "sd_fx_pct": 0.1,
             "k1_pct": 0.0, "sd_k1_pct": 1.0, "cx_px": 0.0, "cy_px": 0.0}
            for s, fx in ((1, 0.1), (2, -0.1), (3, 0.2), (4, 0.0))]
    rows.append({"noise_seed": None, "exposure_factor": 1.0, "method": method, "fx_pct": 0.01, "sd_fx_pct": 0.1,
                 "k1_pct": 0.0, "sd_k1_pct": 1.0, "cx_px": 0.0, "cy_px": 0.0})
    rows.append({"noise_seed": 1, "exposure_factor": 1.0, "method": GRID, "views": 0})
    by_method = {s["method"]: s for s in summarise(rows)}
    s = by_method[method]
    assert s["runs"] == 4 and math.isclose(s["fx_pct_mean"], 0.05)
    assert math.isclose(s["fx_pct_se"], np.std([0.1, -0.1, 0.2, 0.0], ddof=1) / 2)
    assert math.isclose(s["fx_pct_z_rms"], np.sqrt(np.mean(np.array([1.0, -1.0, 2.0, 0.0]) ** 2)))
    assert s["fx_pct_noise_free"] == 0.01
    assert by_method[GRID]["runs"] == 0 and by_method[GRID]["failed"] == 1
