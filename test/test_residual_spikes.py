"""A node patch's residual leaping from its usual level (:mod:`.residual_spikes`)."""

from __future__ import annotations

import numpy as np

from face_tracking_ros.tracking.residual_spikes import MEMORY, MIN_PAIRS, PatchResiduals


def test_a_leap_is_measured_against_each_patch_s_own_usual_level() -> None:
    """Patch 1 usually reads 0.6 and patch 0 0.1: 0.5 is a leap for patch 0 alone."""
    residuals = PatchResiduals()
    usual = np.array([0.1, 0.6, 0.1])
    for _ in range(MIN_PAIRS - 1):
        residuals.add(usual)
    assert not residuals.leapt(np.array([0.9, 0.6, 0.1]))  # too few pairs to tell
    residuals.add(usual)
    assert residuals.leapt(np.array([0.5, 0.6, 0.1]))  # 5 times patch 0's usual level
    assert not residuals.leapt(np.array([0.1, 2.0, 0.1]))  # 3.3 times patch 1's
    assert not residuals.leapt(np.array([0.1, 0.6, np.nan]))  # no valid sample


def test_a_flat_patch_does_not_leap_below_the_floor_and_old_pairs_are_forgotten() -> None:
    residuals = PatchResiduals()
    for _ in range(MEMORY):
        residuals.add(np.array([0.02, 0.3]))
    assert not residuals.leapt(np.array([0.2, 0.3]))  # 10 times, but below the floor
    for _ in range(MEMORY):
        residuals.add(np.array([0.3, 0.3]))
    assert residuals.recent is not None and residuals.recent.shape == (MEMORY, 2)
    assert not residuals.leapt(np.array([0.9, 0.3]))  # the usual level is now 0.3
