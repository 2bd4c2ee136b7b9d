"""The shared contrast of clipped edge profiles by group (``fit_edges_two_pass(contrast_groups=...)``)."""

import dataclasses

import numpy as np
import pytest

from livetrack.estimator.edges import EdgeFits
from livetrack.estimator.edges.two_pass import CONTRAST_DEEP_CLIP, CONTRAST_SPLIT_MIN_FITS, _group_contrasts


def _fits(contrast: np.ndarray, ok: np.ndarray | None = None) -> EdgeFits:
    n = len(contrast)
    zeros = np.zeros(n)
    return EdgeFits(points_px=np.zeros((n, 2)), normals=np.tile([1.0, 0.0], (n, 1)), offset_px=zeros,
                    sigma_px=zeros + 0.8, black_level=zeros + 100.0, white_level=100.0 + contrast,
                    position_std_px=zeros + 0.01, residual_rms=zeros, ok=np.ones(n, bool) if ok is None else ok,
                    n_samples=np.full(n, 9), n_clipped=np.full(n, 3))


def _scattered(value: float, n: int, rng: np.random.Generator, spread: float = 0.05) -> np.ndarray:
    return value * (1.0 + spread * rng.standard_normal(n))


def test_ground_clearly_darker_than_the_white_gets_its_own_contrast():
    rng = np.random.default_rng(0)
    contrast = np.concatenate([_scattered(30000.0, 60, rng), _scattered(7000.0, 40, rng)])
    groups = np.repeat([0, 1], [60, 40])
    out = _group_contrasts(_fits(contrast), groups, groups, 5, 4095.0)
    assert np.allclose(out[:60], np.median(contrast[:60])) and np.allclose(out[60:], np.median(contrast[60:]))


@pytest.mark.parametrize("ground, spread", [(30000.0, 0.05), (24000.0, 0.3), (40000.0, 0.3)])
def test_a_sheet_of_the_same_paper_shares_one_contrast(ground, spread):
    """The same paper, or a sheet read within ``CONTRAST_SPLIT_RATIO`` of the white or brighter than it with the
    scatter of deeply clipped fits (a sheet read 0.4-1.8 of its white, never more than 6.2 standard errors from
    it): one value."""
    rng = np.random.default_rng(1)
    contrast = np.concatenate([_scattered(30000.0, 60, rng, spread), _scattered(ground, 40, rng, spread)])
    groups = np.repeat([0, 1], [60, 40])
    out = _group_contrasts(_fits(contrast), groups, groups, 5, 4095.0)
    assert np.all(out == np.median(contrast))


@pytest.mark.parametrize("ground", [24000.0, 36000.0])
def test_a_ground_measured_apart_from_the_white_keeps_its_own_contrast(ground):
    """0.8x or 1.2x the white at ~17 standard errors (5 % scatter over 60 and 40 fits): a sheet never reads that far
    apart, a ground around a target without one does (``CONTRAST_SPLIT_Z_APART``); 2x brighter is a white read low,
    not a ground (``CONTRAST_SPLIT_APART_MAX_DIFF``)."""
    rng = np.random.default_rng(1)
    contrast = np.concatenate([_scattered(30000.0, 60, rng), _scattered(ground, 40, rng)])
    groups = np.repeat([0, 1], [60, 40])
    out = _group_contrasts(_fits(contrast), groups, groups, 5, 4095.0)
    assert np.allclose(out[:60], np.median(contrast[:60])) and np.allclose(out[60:], np.median(contrast[60:]))
    contrast = np.concatenate([_scattered(30000.0, 60, rng), _scattered(2.0 * 30000.0, 40, rng)])
    out = _group_contrasts(_fits(contrast), groups, groups, 5, 4095.0)
    assert np.all(out == np.median(contrast))


def test_a_poorly_measured_difference_is_not_split():
    """Darker but within the scatter (a small target's few clipped fits): one value."""
    rng = np.random.default_rng(2)
    contrast = np.concatenate([_scattered(30000.0, 12, rng, 0.8), _scattered(12000.0, 12, rng, 0.8)])
    groups = np.repeat([0, 1], [12, 12])
    out = _group_contrasts(_fits(np.abs(contrast)), groups, groups, 5, 4095.0)
    assert np.all(out == out[0])


def test_too_few_fits_of_a_group_is_not_split():
    rng = np.random.default_rng(3)
    n1 = CONTRAST_SPLIT_MIN_FITS - 1
    contrast = np.concatenate([_scattered(30000.0, 60, rng), _scattered(7000.0, n1, rng)])
    groups = np.repeat([0, 1], [60, n1])
    out = _group_contrasts(_fits(contrast), groups, groups, 5, 4095.0)
    assert np.all(out == np.median(contrast))


def test_the_inner_circle_darker_than_the_ground_is_not_split():
    """Only the ground can be darker than the target's white: a low contrast measured on the target's own circles
    (the blurred inner circle of a 9 px target) is the measurement's, not the paper's."""
    rng = np.random.default_rng(4)
    contrast = np.concatenate([_scattered(500.0, 40, rng), _scattered(2100.0, 40, rng)])
    groups = np.repeat([0, 1], [40, 40])
    out = _group_contrasts(_fits(contrast), groups, groups, 5, 4095.0)
    assert np.all(out == np.median(contrast))


def test_deep_clip_splits_a_ground_many_standard_errors_darker():
    """Deeply clipped (group 0's contrast over ``CONTRAST_DEEP_CLIP`` times the room to the clip level), a ground
    at 0.55 of the white measured on 70 and 150 fits (a target without a sheet on carpet at x8): far more
    standard errors apart than a sheet's circles ever read, so each group gets its own median; a sheet's outer
    circle read low at 0.6 of the inner one's, from a dozen scattered fits, still shares."""
    rng = np.random.default_rng(5)
    saturation = 4054.0
    contrast = np.concatenate([_scattered(14000.0, 70, rng, 0.12), _scattered(7700.0, 150, rng, 0.3)])
    assert np.median(contrast[:70]) > CONTRAST_DEEP_CLIP * (saturation - 100.0)
    groups = np.repeat([0, 1], [70, 150])
    out = _group_contrasts(_fits(contrast), groups, groups, 5, saturation)
    assert np.allclose(out[:70], np.median(contrast[:70])) and np.allclose(out[70:], np.median(contrast[70:]))
    contrast = np.concatenate([_scattered(14000.0, 14, rng, 0.3), _scattered(8400.0, 14, rng, 0.3)])
    groups = np.repeat([0, 1], [14, 14])
    out = _group_contrasts(_fits(contrast), groups, groups, 5, saturation)
    assert np.all(out == np.median(contrast))


def test_a_shared_contrast_that_cannot_reach_the_clip_is_replaced():
    """Deep in an 8-bit clip the inner circles' per-point fits put their white at the clip level (contrast ~28
    levels over a black of 223, clip 252.45) and outnumber the outer circle's (91 over a black of 216): shared,
    28 leaves the outer circle's white under the clip, which its clipped samples rule out. The least group median
    that reaches the clip for every group is shared instead. Where the shared value reaches it, nothing changes."""
    rng = np.random.default_rng(6)
    contrast = np.concatenate([_scattered(28.0, 480, rng, 0.03), _scattered(91.0, 20, rng, 0.2)])
    black = np.concatenate([np.full(480, 223.0), np.full(20, 216.0)])
    fits = dataclasses.replace(_fits(contrast), black_level=black, white_level=black + contrast)
    groups = np.repeat([0, 1], [480, 20])
    measured = fits.white_level - fits.black_level
    out = _group_contrasts(fits, groups, groups, 5, 252.45)
    assert np.allclose(out, np.median(measured[480:]), rtol=0, atol=1e-9)
    out = _group_contrasts(fits, groups, groups, 5, 240.0)  # the clip 24 levels over the lowest black: reached
    assert np.allclose(out, np.median(measured), rtol=0, atol=1e-9)
