"""Templates made on demand and the nearest keyframe (tracking/mono_templates.py)."""

from __future__ import annotations

import numpy as np

from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.tracking.mono_rois import Params
from face_tracking_ros.tracking.mono_templates import (
    Keyframe,
    OnDemand,
    Templates,
    nearest_keyframe,
)


def test_on_demand_levels_are_made_once_each_and_read_their_source_until_all_are() -> None:
    made: list[int] = []
    source = object()

    def make(level: int) -> np.ndarray:
        made.append(level)
        return np.full(2, float(level))

    levels = OnDemand(4, make, source, first=np.zeros(2))
    assert len(levels) == 4
    assert levels.reads(source) and not levels.reads(object()) and not levels.reads(None)
    np.testing.assert_array_equal(levels[2], [2.0, 2.0])
    np.testing.assert_array_equal(levels[2], [2.0, 2.0])
    assert made == [2]
    assert [float(level[0]) for level in levels.made()] == [0.0, 1.0, 2.0, 3.0]
    assert made == [2, 1, 3]
    assert not levels.reads(source)  # nothing left to make


def test_templates_sampled_in_full_are_kept_as_they_are() -> None:
    zeros = np.zeros(3)
    templates = Templates(
        levels=(np.ones((2, 9)), np.ones((2, 9))),
        visibility=np.ones(2),
        inside=np.ones((2, 9), dtype=bool),
        params=Params(zeros, zeros, np.zeros(1), np.zeros(1)),
    )
    assert templates.sampled() is templates
    assert not templates.reads(object())


def test_the_nearest_keyframe_is_the_one_nearest_in_rotation() -> None:
    """Keyframes at 0, 0.3 and -0.5 rad of yaw: 0.25 is nearest 0.3, -0.2 nearest 0."""
    keyframes = [
        Keyframe(rodrigues(np.array([0.0, yaw, 0.0]))[0], None, None) for yaw in (0.0, 0.3, -0.5)
    ]
    for yaw, nearest in ((0.25, 1), (-0.2, 0), (-0.3, 2), (0.0, 0)):
        assert nearest_keyframe(keyframes, np.array([0.0, yaw, 0.0])) is keyframes[nearest]
    assert nearest_keyframe(keyframes[:2], np.array([0.0, 0.25, 0.0])) is keyframes[1]
    assert nearest_keyframe(keyframes[:1], np.array([0.0, 1.0, 0.0])) is keyframes[0]
