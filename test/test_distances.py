"""RMS distances of point sets (:mod:`face_tracking_ros.geometry.distances`)."""

from __future__ import annotations

import numpy as np

from face_tracking_ros.geometry.distances import rms_length, rms_spread


def test_rms_length_of_vectors() -> None:
    # lengths 5 and 13: sqrt((25 + 169) / 2)
    assert rms_length(np.array([[3.0, 4.0], [5.0, 12.0]])) == np.sqrt(97.0)


def test_rms_spread_does_not_depend_on_where_the_points_are() -> None:
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    assert rms_spread(square) == np.sqrt(2.0)  # every corner sqrt(2) from the centre
    assert rms_spread(square + [100.0, -7.0]) == np.sqrt(2.0)
