"""The compiled surround check (``surround_kernels.reaches``) against its numpy reference
(``edges.surround.reaches`` with ``LIVETRACK_KERNELS=numpy``): the same booleans, NaN and infinite values included."""

from __future__ import annotations

import numpy as np
import pytest

from livetrack.estimator.edges import surround


class _Levels:
    """Only the two fields ``reaches`` reads."""

    def __init__(self, white, black):
        self.white_level, self.black_level = white, black


def _cases(seed: int):
    rng = np.random.default_rng(seed)
    n, k = 400, 13
    contrast = rng.uniform(-200.0, 200.0, n)
    limit = surround.NEGLIGIBLE_SHARE * np.abs(contrast)
    share = rng.normal(size=(n, k)) * limit[:, None] * rng.choice([0.1, 0.9, 1.1, 10.0], size=(n, 1))
    share[rng.random((n, k)) < 0.2] = 0.0
    share[5, 3] = np.nan
    share[6, :] = np.nan
    share[7, 2] = np.inf
    share[8, 0] = -np.inf
    share[9, 4] = limit[9]  # exactly at the limit: not beyond it
    share[9, 5] = -limit[9]
    share[10:14] = 1.0
    white = 50.0 + contrast
    black = np.full(n, 50.0)
    white[10], black[11], white[12] = np.nan, np.inf, -np.inf
    share[15:20] = 0.0
    return share, _Levels(white, black)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_reaches_compiled_is_the_reference(monkeypatch, seed):
    share, fits = _cases(seed)
    got = {}
    for choice in ("numba", "numpy"):
        monkeypatch.setenv("LIVETRACK_KERNELS", choice)
        with np.errstate(invalid="ignore"):
            got[choice] = surround.reaches(share, fits)
    assert got["numba"].dtype == np.bool_ and got["numba"].shape == (len(share),)
    np.testing.assert_array_equal(got["numba"], got["numpy"])
    assert got["numpy"].any() and not got["numpy"].all()


def test_surround_share_sums_as_before(monkeypatch):
    """``surround_share`` without its zeros: the values of ``0 - step + disks`` (what it summed before)."""
    share, _ = _cases(3)
    other = np.abs(share[::-1]).copy()
    monkeypatch.setattr(surround, "step_share", lambda prof, fits, step: share.copy())
    monkeypatch.setattr(surround, "disks_share", lambda prof, fits, disks: other.copy())

    class _Prof:
        data = np.zeros(share.shape)

    prof = _Prof()
    for step, disks, want in ((1.0, object(), 0.0 - share + other), (1.0, None, 0.0 - share),
                              (None, object(), 0.0 + other), (None, None, np.zeros(share.shape))):
        got = surround.surround_share(prof, None, step, disks)
        np.testing.assert_array_equal(got, want)
