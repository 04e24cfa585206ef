"""Tests of head trajectories and expression scripts (motion.py)."""

from __future__ import annotations

import numpy as np
import pytest

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.synthetic.faces import ACTIVE_EXPRESSIONS
from face_tracking_ros.synthetic.motion import (
    STILL_ANGLE_LIMIT,
    ExpressionScript,
    HeadTrajectory,
)
from face_tracking_ros.synthetic.scenes import Kind, SceneConfig, SequenceRenderer

TIMES = np.linspace(0.0, 60.0, 1201)


@pytest.mark.parametrize('seed', range(5))
def test_free_motion_stays_in_the_working_volume_at_human_speed(seed: int):
    trajectory = HeadTrajectory.random('free', np.random.default_rng(seed))
    angles = np.array([trajectory.angles(t) for t in TIMES])
    positions = np.array([trajectory.pose(t)[1] for t in TIMES])
    assert np.all(np.abs(angles) <= np.radians([25.0, 35.0, 20.0]) + 1e-12)
    assert np.max(np.abs(angles[:, 1])) > np.radians(10.0)  # it does move
    assert np.all(np.ptp(positions, axis=0) <= 0.15)
    assert np.all((positions[:, 2] >= 0.5) & (positions[:, 2] <= 0.8))
    speed = np.abs(np.diff(angles, axis=0)) / np.diff(TIMES)[:, None]
    assert np.max(speed) < np.radians(120.0)


@pytest.mark.parametrize('seed', range(5))
def test_still_motion_is_a_small_residual_sway(seed: int):
    trajectory = HeadTrajectory.random('still', np.random.default_rng(seed), lateral_offset=0.055)
    angles = np.array([trajectory.angles(t) for t in TIMES])
    positions = np.array([trajectory.pose(t)[1] for t in TIMES])
    assert np.max(np.abs(angles)) <= STILL_ANGLE_LIMIT < np.radians(1.0)
    assert np.max(np.abs(positions - trajectory.centre)) <= 0.003
    assert abs(trajectory.centre[0] - 0.055) <= 0.02


def test_unknown_motion_raises():
    with pytest.raises(ConfigError, match="unknown motion 'jumping'"):
        HeadTrajectory.random('jumping', np.random.default_rng(0))


def test_training_script_starts_neutral_and_plays_expressions_in_turn():
    script = ExpressionScript.training(duration=12.0, first=2)
    labels = [script.state(t).label for t in np.arange(0.0, 12.0, 0.1)]
    assert set(labels[:24]) == {'neutral'}  # the first 20 %
    played = [s.label for s in script.segments]
    assert played == [ACTIVE_EXPRESSIONS[(2 + k) % 6] for k in range(len(played))]
    assert len(played) == 4
    apex = script.segments[0].start + script.segments[0].rise + 0.5 * script.segments[0].hold
    state = script.state(apex)
    assert state.label == played[0] and state.intensity == pytest.approx(1.0)
    np.testing.assert_array_equal(state.alpha, np.eye(6)[ACTIVE_EXPRESSIONS.index(played[0])])


def test_short_training_script_still_has_a_neutral_start_and_one_expression():
    script = ExpressionScript.training(duration=1.0)
    assert len(script.segments) == 1 and script.segments[0].start >= 0.5
    assert script.segments[0].label == 'smile'  # by default the first expression comes first
    assert script.state(0.2).label == 'neutral'


@pytest.mark.parametrize('seed', range(4))
def test_random_script_has_onsets_offsets_and_neutral_between(seed: int):
    script = ExpressionScript.random(30.0, np.random.default_rng(seed))
    assert len(script.segments) >= 4
    for before, after in zip(script.segments, script.segments[1:], strict=False):
        assert after.start >= before.end + 0.3
    assert script.segments[-1].end <= 30.0
    states = [script.state(t) for t in np.arange(0.0, 30.0, 0.02)]
    intensities = np.array([s.intensity for s in states])
    assert np.all((intensities >= 0.0) & (intensities <= 1.0))
    assert np.max(np.abs(np.diff(intensities))) < 0.2  # smooth onsets and offsets
    for state in states:
        assert (state.label == 'neutral') == (state.intensity == 0.0)
        assert np.count_nonzero(state.alpha) == (state.label != 'neutral')
    assert all(segment.label == 'jaw_open' for segment in script.segments if segment.talk)


def test_random_segments_span_their_documented_rise_hold_and_fall_ranges():
    scripts = [ExpressionScript.random(60.0, np.random.default_rng(seed)) for seed in range(20)]
    segments = [s for script in scripts for s in script.segments]
    for name, low, high in (('rise', 0.2, 0.5), ('hold', 0.4, 2.0), ('fall', 0.2, 0.6)):
        values = np.array([getattr(s, name) for s in segments])
        assert low <= values.min() < low + 0.05 and high - 0.05 < values.max() <= high, name
    peaks = np.array([s.peak for s in segments])
    assert 0.5 <= peaks.min() < 0.55 and 0.95 < peaks.max() <= 1.0


def test_half_the_random_jaw_open_segments_talk():
    scripts = [ExpressionScript.random(60.0, np.random.default_rng(seed)) for seed in range(20)]
    jaw = [s for script in scripts for s in script.segments if s.label == 'jaw_open']
    talking = sum(s.talk for s in jaw)
    assert len(jaw) >= 30 and 0.3 * len(jaw) <= talking <= 0.7 * len(jaw)


def test_static_motion_holds_head_and_face_while_the_sensor_noise_changes():
    config = SceneConfig(kind=Kind.MONO, motion='static', frames=3, width=160, height=120)
    frames = list(SequenceRenderer(config, 0).frames(0))
    first, last = frames[0], frames[-1]
    np.testing.assert_array_equal(first.truth.nodes_camera, last.truth.nodes_camera)
    assert first.truth.label == last.truth.label == 'neutral'
    difference = first.images['image'].astype(float) - last.images['image'].astype(float)
    assert 0.5 < difference.std() < 6.0  # sensor noise only: a few grey levels
    assert abs(difference.mean()) < 0.5  # the light does not change
