"""The gaps between a pair's code slots must be dark (texture around a dark ellipse pair reads as a code
otherwise), but over-exposure grows every dot and closes the gap between two neighbouring dots first: for a pair
whose white is clipped, only the gaps beside a dark slot are held to the limit (``code._gaps_to_test``)."""

from __future__ import annotations

import numpy as np
import pytest

from livetrack.estimator.detect import Detector
from livetrack.estimator.detect.code import BLOOM_MIN_SLOT, _gaps_to_test
from tests.sweep_frames import sweep_frame


def test_only_a_gap_between_two_dots_may_close():
    """Slots 1, 0, 0, 0, 0, 1, 1, 1 (normalised): gaps 5-6, 6-7 and 7-0 lie between dots; the whitest of them
    (6-7) is left out, the others stay tested (two merged dot pairs are refused), as do those beside a dark slot."""
    slots = np.array([1.0, 0.0, 0.02, 0.0, 0.05, 1.0, 0.98, 1.0])
    gaps = np.array([0.6, 0.1, 0.2, 0.3, 0.4, 0.42, 0.75, 0.23])
    assert np.array_equal(_gaps_to_test(slots, gaps), gaps[[0, 1, 2, 3, 4, 5, 7]])
    dim = slots.copy()
    dim[6] = BLOOM_MIN_SLOT - 0.01  # a slot not bright enough for a dot: both its gaps tested
    assert np.array_equal(_gaps_to_test(dim, gaps), gaps[[0, 1, 2, 3, 4, 5, 6]])
    # no slot dark (no code is so), or none bright: nothing left out
    assert np.array_equal(_gaps_to_test(np.ones(8), gaps), gaps)
    assert np.array_equal(_gaps_to_test(np.zeros(8), gaps), gaps)


@pytest.mark.parametrize(("seed", "case"), [(9, "no-sheet-005"), (6, "no-sheet-001")])
def test_a_small_over_exposed_target_with_dots_in_a_row_is_read(seed, case):
    """Id 3 (four dots in a row) printed without a sheet, 9 px semi-minor at 50-70 deg, at x16: its grown dots
    closed the gaps between them (0.75, 0.71 of white), and the pair was refused ("gaps between slots white")."""
    scenario, image = sweep_frame(seed, case, 16.0)
    found = Detector(scenario.targets).detect(image, saturation=float(scenario.camera.saturation_level))
    assert [(c.target_id, c.level) for c in found] == [(3, 0)]
    truth = scenario.camera.project(scenario.truth_for(0)[3].t[None, :])[0]
    assert np.hypot(*(found[0].outer.centre_px - truth)) < 3.0


def test_texture_read_with_one_closed_gap_is_refused():
    """Foliage through a wide lens at x8 (seed 3's border-001, around (454, 60)), paired from a hole: its slots
    read as id 5 with one gap between two "dots" white (0.98) and others at -0.28 and -0.2 (darker than the
    pair's black: no ink there). Refused (``code.MERGED_MIN_GAP``); the frame's target, id 1, is found."""
    scenario, image = sweep_frame(3, "border-001", 8.0)
    found = Detector(scenario.targets).detect(image, saturation=float(scenario.camera.saturation_level))
    assert {c.target_id for c in found} == {1}
