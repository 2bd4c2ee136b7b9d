"""The detector's fast paths against the plain computations they replace: equal bit for bit."""

import warnings

import numpy as np

from livetrack.estimator.detect.levels import _row_nanmedian


def test_row_nanmedian_is_numpys_nanmedian():
    rng = np.random.default_rng(3)
    for k in range(400):
        values = rng.normal(100.0, 50.0, (int(rng.integers(1, 60)), int(rng.integers(1, 30))))
        if k % 3 == 0:
            values = np.round(values)  # ties
        values[rng.random(values.shape) < rng.random()] = np.nan  # rows of every fill, all-NaN ones included
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows
            want = np.nanmedian(values, axis=1)
        assert np.array_equal(_row_nanmedian(values), want, equal_nan=True)
