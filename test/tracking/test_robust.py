"""The median by one partial sort (tracking.robust): np.median's value, to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from face_tracking_ros.tracking.robust import median, nanmedian


@pytest.mark.parametrize('size', [1, 2, 3, 4, 5, 34, 35, 2754, 2755])
def test_median_is_numpys_to_the_bit(size):
    rng = np.random.default_rng(size)
    for values in (
        np.abs(rng.normal(0.0, 3.0, size)),  # residual magnitudes
        rng.integers(0, 4, size).astype(float),  # ties across the middle
    ):
        assert median(values) == np.median(values)


def test_median_of_two_is_their_mean():
    assert median(np.array([3.0, 1.0])) == 2.0
    assert median(np.array([0.1, 0.7, 0.2, 0.4])) == (0.2 + 0.4) / 2


@pytest.mark.parametrize('size', [1, 2, 3, 4, 34, 68, 69])
def test_nanmedian_is_numpys_to_the_bit(size):
    rng = np.random.default_rng(size)
    values = np.abs(rng.normal(0.0, 3.0, (2, size)))  # per-camera node ratios
    values[rng.uniform(size=values.shape) < 0.2] = np.nan
    values[rng.uniform(size=values.shape) < 0.1] = np.inf  # a node without template contrast
    expected = np.nanmedian(values)
    assert nanmedian(values) == expected or (np.isnan(expected) and np.isnan(nanmedian(values)))


def test_nanmedian_ignores_nan_and_is_nan_without_values():
    assert nanmedian(np.array([np.nan, 3.0, 1.0, np.nan])) == 2.0
    assert np.isnan(nanmedian(np.full((2, 3), np.nan)))
