"""A target of three fractal levels: its deepest level's parent and its middle level's read alike (the same code,
the same proportions), and a camera close to it sees one or two levels whole with the outer level's code beyond
the frame. Which level a pair is (hence its distance, 5x or 25x apart) must come from evidence, or be reported as
unknown (``levels._choose_level``, ``levels._nest``); before, a camera descending onto a 0.5 m three-level target
got poses at +400 %, -80 % and +2400 % of the distance, fit ok."""

import numpy as np
import pytest

from livetrack.estimator.detect import Detector
from livetrack.estimator.tracker import Tracker
from livetrack.sim.scenario import Scenario

DISTANCES_M = np.geomspace(6.0, 0.11, 16)


def _landing(exposure_factor: float) -> Scenario:
    """A 0.5 m target of three levels (0.1 m and 0.02 m nested) seen from 6 m down to 0.11 m on a 640 x 480
    camera (800 px focal length), 15 deg tilted, on grey ground."""
    poses = [{"t_m": [0.02, -0.01, float(d)], "tilt_deg": 15, "tilt_axis_deg": 30, "roll_deg": 10 + 3 * k}
             for k, d in enumerate(DISTANCES_M)]
    return Scenario.from_dict({
        "name": "landing", "seed": 5,
        "camera": {"width": 640, "height": 480, "fx": 800, "fy": 800, "cx": 319.5, "cy": 239.5,
                   "dist": [0, 0, 0, 0, 0], "bit_depth": 12},
        "sensor": {"full_well_e": 10000, "read_noise_e": 5, "black_level_dn": 0},
        "optics": {"psf_sigma_px": 0.9},
        "scene": {"white_reflectance": 0.85, "black_reflectance": 0.04, "background_reflectance": 0.2},
        "targets": [{"id": 5, "outer_radius_m": 0.5, "levels": 3}],
        "poses": poses,
        "exposure": {"nominal_us": "auto", "white_fraction_of_full_well": 0.55, "factors": [exposure_factor]},
        "timing": {"fps": 10.0}})


@pytest.mark.parametrize(("exposure_factor", "least_found"), [(1.0, 15), (8.0, 11), (32.0, 4)])
def test_a_camera_descending_onto_a_three_level_target_gets_no_wrong_level(exposure_factor, least_found):
    """Each frame searched anew: every pose reported is within 0.2 % of the distance, and some frames give one
    (the rest report the level as unknown: at x8-x32 the deepest ring inside a middle level is too faint to tell
    it from the deepest, and the outer level's surroundings are beyond the frame). Before: 10 of the 16 frames at
    +400 % or -80 % at x1 and x8, 12 at x32 (+2400 % at 0.11-0.2 m), fit ok."""
    scene = _landing(exposure_factor)
    found = 0
    for k in range(len(scene)):
        frame = scene.render_frame(k)
        result = Tracker(scene.camera, list(scene.targets)).process(frame.image, frame.exposure_us)
        posed = [t for t in result.targets if t.fit.ok]
        assert len(posed) <= 1
        for target in posed:
            error = target.pose.distance_m / frame.truth[5].distance_m - 1.0
            assert abs(error) < 2e-3, (k, frame.truth[5].distance_m, target.levels_used, error)
            found += 1
    assert found >= least_found


def test_the_middle_level_is_told_by_the_deepest_inside_it():
    """0.48 m from the target: its middle level whole (168 px), the deepest inside it (33 px), the outer level's
    code beyond the frame. The deepest reads its parent's code and has a plain inner disk: it is the deepest level,
    and the pair around it its parent (``_nest``), not the outer level by default with the deepest as the middle."""
    scene = _landing(1.0)
    k = int(np.argmin(np.abs(DISTANCES_M - 0.48)))
    frame = scene.render_frame(k)
    candidates = Detector(list(scene.targets)).detect(frame.image, saturation=4095.0)
    assert sorted((c.level, c.level_ambiguous) for c in candidates) == [(1, False), (2, False)]
