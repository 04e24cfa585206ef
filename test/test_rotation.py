"""geometry.rotation: angle_between (np.trace and np.clip's value to the bit) and quaternions."""

from __future__ import annotations

import numpy as np
import pytest

from face_tracking_ros.geometry.rotation import (
    angle_between,
    omega_to_quaternion,
    rodrigues,
    rotation_angle,
)


def _reference(rotation_a: np.ndarray, rotation_b: np.ndarray) -> float:
    """The angle as the trackers computed it before (np.trace, np.clip)."""
    relative = rotation_a.T @ rotation_b
    return float(np.arccos(np.clip(0.5 * (np.trace(relative) - 1.0), -1.0, 1.0)))


@pytest.mark.parametrize('angle', [0.0, 1e-9, 0.01, 0.35, 2.0, np.pi - 1e-9, np.pi])
def test_angle_between_is_the_relative_rotation_angle(angle):
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    start = np.array([0.2, 0.1, -0.4])
    rotation_a = rodrigues(start)[0]
    rotation_b = rotation_a @ rodrigues(angle * axis)[0]
    assert angle_between(rotation_a, rotation_b) == pytest.approx(angle, abs=1e-7)
    assert angle_between(rotation_a, rotation_b) == _reference(rotation_a, rotation_b)
    assert rotation_angle(start, start) == 0.0


def test_angle_between_matches_trace_and_clip_to_the_bit():
    rng = np.random.default_rng(0)
    for omega_a, omega_b in rng.normal(0.0, 1.0, (500, 2, 3)):
        rotation_a, rotation_b = rodrigues(omega_a)[0], rodrigues(omega_b)[0]
        assert angle_between(rotation_a, rotation_b) == _reference(rotation_a, rotation_b)


@pytest.mark.parametrize(
    ('omega_a', 'omega_b', 'angle'),
    [
        ([0.2, 0.4, -0.7], [0.2, 0.4, -0.7], 0.0),  # R' R's cosine sums to 1 + 4.4e-16
        ([0.0, 0.0, 0.0], np.pi * np.array([3.0, -2.0, 1.0]) / np.sqrt(14.0), np.pi),  # -1 - 2e-16
    ],
)
def test_a_cosine_rounded_past_one_is_clipped_to_the_exact_angle(omega_a, omega_b, angle):
    assert rotation_angle(np.array(omega_a), np.array(omega_b)) == angle


@pytest.mark.parametrize(
    ('omega', 'quaternion'),
    [
        ([0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]),
        ([np.pi, 0.0, 0.0], [1.0, 0.0, 0.0, np.cos(np.pi / 2)]),  # half a turn about x
        ([0.0, -np.pi / 2, 0.0], [0.0, -np.sqrt(0.5), 0.0, np.sqrt(0.5)]),
        ([0.0, 0.0, 2e-4], [0.0, 0.0, np.sin(1e-4), np.cos(1e-4)]),  # the Taylor series
    ],
)
def test_omega_to_quaternion_is_the_half_angle_quaternion(omega, quaternion):
    np.testing.assert_allclose(omega_to_quaternion(np.array(omega)), quaternion, atol=1e-15)
