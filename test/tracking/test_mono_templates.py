"""Templates made on demand and the nearest keyframe (tracking/mono_templates.py)."""

from __future__ import annotations

import numpy as np

from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.imaging import PhotometricModel, square_offsets
from face_tracking_ros.imaging.photometric import PhotometricInvariance
from face_tracking_ros.tracking.mono_projection import FaceProjection
from face_tracking_ros.tracking.mono_rois import Params
from face_tracking_ros.tracking.mono_templates import (
    Keyframe,
    OnDemand,
    Templates,
    TemplateSampler,
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
        covered=np.zeros(2, dtype=bool),
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


def test_a_keyframes_projection_is_its_level_0_templates(model_factory) -> None:
    """It removes the level-0 template's own gain and bias: 2 T_0 + 5 projects to zero."""
    rng = np.random.default_rng(0)
    level_0, level_1 = rng.uniform(20.0, 200.0, size=(2, 2, 9))
    zeros = np.zeros(3)
    templates = Templates(
        levels=(level_0, level_1),
        visibility=np.ones(2),
        inside=np.ones((2, 9), dtype=bool),
        params=Params(zeros, zeros, np.zeros(1), np.zeros(1)),
        covered=np.zeros(2, dtype=bool),
    )
    invariance = PhotometricInvariance.of(PhotometricModel.GAIN_BIAS, square_offsets(1))
    face = FaceProjection(model_factory(), PinholeCamera.ideal(), 1, 0.1)
    omega = np.array([0.1, -0.2, 0.05])

    keyframe = TemplateSampler(face, invariance).keyframe(omega, templates)

    np.testing.assert_array_equal(keyframe.rotation, rodrigues(omega)[0])
    assert np.abs(keyframe.projection.apply(2.0 * level_0 + 5.0)).max() < 1e-9
    assert np.abs(keyframe.projection.apply(level_1)).max() > 1.0


def test_covered_nodes_keep_the_last_templates_of_every_level() -> None:
    zeros = np.zeros(3)
    params = Params(zeros, zeros, np.zeros(1), np.zeros(1))
    last = Templates(
        (np.zeros((3, 9)), np.zeros((3, 4))),
        np.ones(3),
        np.ones((3, 9), dtype=bool),
        params,
        np.zeros(3, dtype=bool),
    )
    covered = np.array([False, True, False])
    new = Templates((np.ones((3, 9)), np.ones((3, 4))), np.ones(3), last.inside, params, covered)
    kept = new.kept(last)
    assert [level[:, 0].tolist() for level in kept.levels] == [[1.0, 0.0, 1.0]] * 2
    assert kept.seen.tolist() == [1.0, 0.0, 1.0]
    assert last.kept(new) is last  # nothing covered: the templates as they are
