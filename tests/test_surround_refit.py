"""A search's fits made again once the code dots are placed (``fit_edges_two_pass(start_fits_these=True, memo=...)``):
only the profiles the surround reaches are fitted again, with the same result as fitting them all again."""

from __future__ import annotations

import numpy as np
import pytest

import livetrack.estimator.tracker.tracker as tracker_module  # the module whose Tracker calls it
from livetrack.estimator.edges import two_pass
from livetrack.estimator.tracker import Tracker
from tests.test_tracker import _small_scene


@pytest.mark.parametrize(("bits", "distance_m", "factor"),
                         [(12, 9.0, 1.0), (8, 9.0, 1.0), (12, 9.0, 4.0), (12, 6.0, 16.0), (12, 12.0, 8.0)])
def test_a_search_fits_again_only_what_its_surround_reaches(bits, distance_m, factor, monkeypatch):
    """11-20 px targets, clean and clipped: after the dots are placed, the restricted fit (the touched clean
    profiles; with clipped ones, the touched part of the contrast sample, then every clipped profile with the shared
    contrast measured again) gives the fits of fitting every profile again within 2e-4 px, blurs 2e-3 (untouched
    ones keep fits that a new fit would move by its convergence tolerance), the same ok flags, and fits fewer
    rows."""
    calls = []
    fit_edges = tracker_module.fit_edges_two_pass

    def spy(*args, **kwargs):
        memo = kwargs.get("memo")
        before = None if memo is None else dict(memo)
        out = fit_edges(*args, **kwargs)
        if kwargs.get("start_fits_these"):
            calls.append((args, kwargs, before, out))
        return out

    monkeypatch.setattr(tracker_module, "fit_edges_two_pass", spy)
    scene = _small_scene(bits, distance_m, [factor])
    frame = scene.render_frame(0)
    got = Tracker(scene.camera, list(scene.targets)).process(frame.image, frame.exposure_us)
    assert [t.target_id for t in got.targets if t.fit.ok] == [5]
    assert len(calls) == 1  # the dots were placed
    args, kwargs, before, restricted = calls[0]
    assert before is not None and before["fits"] is kwargs["start"]

    rows = []
    fit = two_pass._fit
    monkeypatch.setattr(two_pass, "_fit", lambda prof, pts, *a: rows.append(len(pts)) or fit(prof, pts, *a))
    again = fit_edges(*args, **{**kwargs, "memo": dict(before)})
    n_restricted, rows[:] = sum(rows), []
    full = fit_edges(*args, **{**kwargs, "start_fits_these": False, "memo": None})
    n_full = sum(rows)

    for name in ("offset_px", "sigma_px", "ok"):  # deterministic
        np.testing.assert_array_equal(getattr(again, name), getattr(restricted, name))
    np.testing.assert_array_equal(restricted.ok, full.ok)
    ok = full.ok
    assert ok.sum() >= 20
    assert np.abs(restricted.offset_px[ok] - full.offset_px[ok]).max() < 2e-4
    assert np.abs(restricted.sigma_px[ok] - full.sigma_px[ok]).max() < 2e-3  # (the blur converges less tightly)
    # at 16x too few clipped profiles fit with a free contrast to measure one (the contrast at the clip level is
    # taken instead): without that sample every profile is fitted again
    assert n_restricted < n_full or (factor == 16.0 and n_restricted == n_full), (n_restricted, n_full)
