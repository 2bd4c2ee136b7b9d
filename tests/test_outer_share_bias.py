"""The outermost circle's own bias in the pose covariance (livetrack/estimator/shared_edge_bias.py,
``outer_circle_bias_covariance``; ``TrackerOptions.outer_share_sd``): the term is the gain of that circle alone, the
distance's standard deviation is honest on edges whose outer circle alone is offset (which the residuals cannot show),
and the tracker reports the wider covariance with the same poses and the outer circle's share of delta
(``TargetResult.outer_share``)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from livetrack.estimator.pose_fit import fit_pose
from livetrack.estimator.shared_edge_bias import (
    circle_bias_covariance,
    outer_circle_bias_covariance,
    with_outer_circle_bias,
)
from tests.test_shared_edge_bias import CAMERA, POSE, RADII_M, edges, z_plain_and_widened


def test_the_term_is_the_outer_circles_column_of_the_gain():
    obs, _ = edges(POSE)
    fit = fit_pose(CAMERA, obs, POSE)
    added = outer_circle_bias_covariance(fit, 0.05)
    # the gain's columns are by ascending radius: the last is the outermost circle's
    alone = dataclasses.replace(fit, circle_bias_gain=fit.circle_bias_gain[:, -1:])
    np.testing.assert_allclose(added, circle_bias_covariance(alone, 0.05), rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(outer_circle_bias_covariance(fit, 0.1), 4.0 * added, rtol=1e-12)
    np.testing.assert_allclose(added, added.T, atol=1e-18)
    # one circle's share of the floor over every circle: what is left is a covariance too
    assert np.all(np.linalg.eigvalsh(circle_bias_covariance(fit, 0.05) - added) >= -1e-12 * np.abs(added).max())
    assert added[2, 2] > 0.0


def test_the_distance_sd_is_honest_when_the_outer_circle_alone_is_offset():
    """The outermost circle's edges offset by N(0, 0.1 px) as a whole (a share of the white's bias other than the
    one modelled), plus independent noise of 0.05 px per point: the edges' covariance claims far too little; with
    the term at the offset's sd, about what a Gaussian gives."""
    plain, wide = z_plain_and_widened(np.random.default_rng(5), lambda rng: {max(RADII_M): float(rng.normal(0.0, 0.1))},
                                      lambda fit: with_outer_circle_bias(fit, 0.1))
    assert np.mean(plain <= 3.0) < 0.6
    assert np.mean(wide <= 3.0) >= 0.98
    assert 0.5 < np.median(wide) < 0.85


@pytest.mark.parametrize("bias_px", [0.0, -0.1, math.nan])
def test_no_term_without_a_bias_and_failed_fits_alone(bias_px):
    obs, _ = edges(POSE)
    fit = fit_pose(CAMERA, obs, POSE)
    assert with_outer_circle_bias(fit, bias_px) is fit
    failed = dataclasses.replace(fit, ok=False, reason="test")
    assert with_outer_circle_bias(failed, 0.1) is failed
    bare = dataclasses.replace(fit, circle_bias_gain=None)
    assert outer_circle_bias_covariance(bare, 0.1) is None and with_outer_circle_bias(bare, 0.1) is bare


def test_the_tracker_reports_the_term_and_the_outer_share_with_the_same_poses():
    """A target printed without a sheet on grey ground (0.2), at x1 then x8, tracked: at x8 its outer circle takes a
    modelled share of delta (``TargetResult.outer_share`` < 1); ``outer_share_sd`` changes only that frame's
    covariance, by ``outer_share_sd * |delta|`` on that circle."""
    from livetrack.estimator.tracker import Tracker, TrackerOptions, target_result_to_dict
    from livetrack.evaluation import detection
    from livetrack.sim.scenario import Scenario

    case = detection.make_case("c", "single", "grey", "1280x800-8bit", [(0.01, 30.0)], (1.0, 8.0), 8003,
                               sheet="none")
    scenario = Scenario.from_dict(case.scenario)
    frames = [scenario.render_frame(k) for k in range(len(scenario))]

    def run(share_sd: float) -> list:
        tracker = Tracker(scenario.camera, scenario.targets, TrackerOptions(compensate_exposure=True, tracking=True,
                                                                            outer_share_sd=share_sd))
        return [r for f in frames for r in tracker.process(f.image, f.exposure_us).targets]

    plain, wide = run(0.0), run(0.5)
    assert len(plain) == len(wide) == 2
    assert plain[0].outer_share is None  # unexposed: every circle takes delta whole
    assert 0.0 <= plain[1].outer_share < 0.5 and plain[1].outer_share == wide[1].outer_share
    for p, w in zip(plain, wide, strict=True):
        assert p.fit.ok and w.fit.ok and p.target_model is None
        np.testing.assert_array_equal(p.pose.t, w.pose.t)
        assert p.delta_px == w.delta_px
        # (only where the outer circle takes a share of its own: at x1 every circle takes delta whole, no term)
        added = (np.zeros((7, 7)) if p.outer_share is None
                 else outer_circle_bias_covariance(p.fit, 0.5 * abs(p.delta_px)))
        np.testing.assert_allclose(w.fit.covariance - p.fit.covariance, added, rtol=1e-6,
                                   atol=1e-9 * np.abs(p.fit.covariance).max())
    assert wide[1].fit.covariance[2, 2] > 1.5 * plain[1].fit.covariance[2, 2]
    # and in the JSON of ``livetrack detect`` (docs/detect-json.md)
    assert target_result_to_dict(plain[0])["outer_share"] is None
    assert target_result_to_dict(plain[1])["outer_share"] == pytest.approx(plain[1].outer_share)
