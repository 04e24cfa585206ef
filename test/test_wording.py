"""Counts in messages read '1 frame' and '2 frames' (face_tracking_ros.wording)."""

from __future__ import annotations

import numpy as np
import pytest

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.camera import StereoRig
from face_tracking_ros.tracking.stereo import StereoTracker
from face_tracking_ros.tracking.stereo_config import StereoTrackerConfig
from face_tracking_ros.wording import counted


def test_a_count_of_one_takes_the_singular_and_any_other_the_plural() -> None:
    assert counted(1, 'frame') == '1 frame'
    assert [counted(n, 'frame') for n in (0, 2, 30)] == ['0 frames', '2 frames', '30 frames']
    assert counted(np.int64(1), 'neutral frame') == '1 neutral frame'  # a numpy count
    assert counted(1, 'mesh', 'meshes') == '1 mesh'
    assert counted(3, 'mesh', 'meshes') == '3 meshes'
    assert counted(2, 'kind of problem', 'kinds of problem') == '2 kinds of problem'


def test_one_node_given_is_said_in_the_singular() -> None:
    tracker = StereoTracker(StereoRig.ideal(), StereoTrackerConfig())
    one = np.full((34, 2), np.nan)
    one[0] = 100.0
    with pytest.raises(InputError, match=r'^only 1 node given; at least 6 are needed$'):
        tracker.reset(one)
