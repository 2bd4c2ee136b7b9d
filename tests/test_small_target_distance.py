"""Small targets' distance, end to end: the simulator renders a 13 px target with its nested level (a ring of 2.7 px
inside the inner disk, 2.7 px from the inner circle), the tracker poses it. Its blur darkens the inner circle's white
side; modelled as it is (``edges.surround.step_share``, ``surround_geometry.MODELLED_REACH_MARGIN_PX``) it leaves the
distance as unbiased as a target without the nested level.

Measured with 12 such frames (noise-free, 12 bit, a sheet, the PSF's core known to the tracker): mean error -0.050 %
(standard error 0.014) before session 42, -0.009 % (0.005) after, -0.001 % without the nested level; with noise and
the blur unknown (16 frames each, 8 and 12 bit): -0.16 % before, -0.04 to -0.06 % after."""

import numpy as np

from livetrack.estimator.tracker import Tracker, TrackerOptions
from livetrack.evaluation import detection
from livetrack.sim.scenario import Scenario

SEMI_MINOR_PX = 13.0
FRAMES = 8


def _errors_pct(levels: int) -> list[float]:
    width, height = 1920, 1200
    area = np.pi * SEMI_MINOR_PX**2 / (width * height)
    errors = []
    for seed in range(FRAMES):
        case = detection.make_case("small", "single", "grey", "1920x1200-12bit", [(area, 0.0)], (1.0,),
                                   9300 + 11 * seed, sheet=2.8)
        for target in case.scenario["targets"]:
            target["levels"] = levels
        case.scenario["effects"] = {}  # the PSF's Gaussian core alone, known to the tracker
        scenario = Scenario.from_dict(case.scenario)
        (target_id, pose), = scenario.truth_for(0).items()
        frame = scenario.render_frame(0, noise=False)
        tracker = Tracker(scenario.camera, scenario.targets,
                          TrackerOptions(psf_sigma_px=case.scenario["optics"]["psf_sigma_px"]))
        found = [t for t in tracker.process(frame.image, frame.exposure_us).targets
                 if t.target_id == target_id and t.fit.ok]
        assert found, f"seed {seed}: the {SEMI_MINOR_PX} px target was not posed"
        errors.append(100.0 * (found[0].pose.distance_m / pose.distance_m - 1.0))
    return errors


def test_a_small_target_with_its_nested_level_is_posed_as_without_it():
    nested = _errors_pct(levels=2)
    alone = _errors_pct(levels=1)
    assert abs(np.mean(alone)) < 0.01  # (the renderer and the edge model agree without the nested level)
    assert abs(np.mean(nested)) < 0.025, nested  # was -0.05 % (the nested ring read 20-40 % too faint)
    assert abs(np.mean(nested) - np.mean(alone)) < 0.025
