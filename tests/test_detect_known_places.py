"""Blobs at the place of a pair already found are not examined (``pairs._at_known_place``, ``detector.SKIP_KNOWN``):
a target's ring pairs on several pyramid levels and in both the plain and the closed pass; only the finest level's
pair, the plain pass's first, is kept (``places._dedupe_pairs``). The candidates are the same without those blobs,
at ~30 % fewer ``_pair_of`` calls on the bench's frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect.detector import _box_of
from livetrack.estimator.detect.pairs import _at_known_place
from tests.detect_switches import with_and_without
from tests.sweep_frames import paper_lab_frames, sweep_frame


def test_the_box_of_a_turned_ellipse():
    e = Ellipse(np.array([50.0, 40.0]), np.array([20.0, 10.0]), math.pi / 2)
    assert np.allclose(_box_of(e), (50.0, 40.0, 10.0, 20.0))
    e = Ellipse(np.array([50.0, 40.0]), np.array([20.0, 10.0]), math.pi / 4)
    half = math.sqrt(0.5 * (400.0 + 100.0))
    assert np.allclose(_box_of(e), (50.0, 40.0, half, half))


def test_a_box_is_at_a_known_place_only_near_its_centre_and_size():
    known = [(50.0, 40.0, 20.0, 10.0)]  # a 40 x 20 px box centred on (50, 40)
    # a contour of pixel centres spanning x 30..69 and y 30..49: centre (49.5, 39.5), half sides 20 and 10
    assert _at_known_place((30, 30, 40, 20), known)
    assert _at_known_place((31, 30, 40, 20), known)  # a pixel off
    assert not _at_known_place((34, 30, 40, 20), known)  # 4 px off: more than 0.1 of 10 px + 1
    assert not _at_known_place((30, 30, 40, 26), known)  # 30 % taller
    assert not _at_known_place((20, 30, 60, 20), known)  # half as wide again
    assert not _at_known_place((30, 30, 40, 20), [])


@pytest.mark.parametrize("pose_index,factor", [(0, 1.0), (6, 0.25), (12, 4.0), (18, 16.0)])
def test_paper_lab_fewer_blobs_and_the_same_candidates(pose_index, factor, monkeypatch):
    scenario, frames = paper_lab_frames(pose_index, [factor])
    found, again, examined, examined_all = with_and_without(monkeypatch, "SKIP_KNOWN", scenario, frames[0].image,
                                                            counted="_pair_of")
    assert 3 in [c[0] for c in found]
    assert examined_all > examined
    assert again == found


@pytest.mark.parametrize("seed,case,factor", [(0, "multi-000", 1.0), (0, "multi-005", 8.0),
                                              (0, "no-sheet-001", 2.0), (0, "border-005", 0.5)])
def test_sweep_frames_the_same_candidates(seed, case, factor, monkeypatch):
    """Several targets on carpet and on white ground, one printed without a sheet, one at a wide lens's border."""
    scenario, image = sweep_frame(seed, case, factor)
    found, again, _, _ = with_and_without(monkeypatch, "SKIP_KNOWN", scenario, image)
    assert found
    assert again == found
