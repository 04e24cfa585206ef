"""The median by one partial sort (tracking.robust): np.median's value, to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from face_tracking_ros.tracking.robust import median


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
