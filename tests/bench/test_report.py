"""Report statistics: the vectorised NaN-aware percentiles equal numpy's, bit for bit."""

import warnings

import numpy as np
import pytest

from manualcontrol.bench.report import nan_median, nan_percentiles


def _numpy(stack, percentiles):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns
        return np.nanpercentile(stack, percentiles, axis=0), np.nanmedian(stack, axis=0)


@pytest.mark.parametrize("seed", range(12))
def test_equal_to_numpy_with_nans(seed):
    rng = np.random.default_rng(seed)
    runs, samples = int(rng.integers(1, 60)), int(rng.integers(1, 400))
    stack = rng.standard_normal((runs, samples)) * 10.0 ** rng.uniform(-3, 3)
    stack[rng.random(stack.shape) < rng.uniform(0.0, 0.6)] = np.nan
    stack[:, :2] = np.nan  # all-NaN columns (the first 10 s of a moving VAF)
    stack[:, 2] = 1.5  # ties
    percentiles = [0, 10, 25, 50, 75, 99.9, 100]
    expected, median = _numpy(stack, percentiles)
    np.testing.assert_array_equal(nan_percentiles(stack, percentiles), expected)
    np.testing.assert_array_equal(nan_median(stack), median)


def test_empty_stack_gives_nan():
    assert np.all(np.isnan(nan_percentiles(np.zeros((0, 3)), [25, 75])))
    assert np.all(np.isnan(nan_median(np.zeros((0, 3)))))
