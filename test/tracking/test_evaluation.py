"""The tracker evaluation (tracking/evaluation.py): jitter and CPU time with values by hand.

A stand-in tracker returns set poses and a stand-in clock set step times, so the still-head
jitter (the spread of the tracked frames' angles) and the time per frame have exact values.
"""

from __future__ import annotations

import numpy as np
import pytest
from recognition_streams import truth_model

from face_tracking_ros.geometry.rotation import angles_to_omega, rodrigues
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.tracking import evaluation
from face_tracking_ros.tracking.evaluation import evaluate_tracker
from face_tracking_ros.tracking.result import TrackResult, TrackStatus

MODEL = truth_model(FacePopulation('default', 0))
T = np.array([0.0, 0.0, 0.6])


def _result(status: TrackStatus, angles_deg: list[float]) -> TrackResult:
    """A result of the mean shape at the given angles and 0.6 m in front of the camera."""
    omega = angles_to_omega(np.radians(np.array(angles_deg)))
    nodes = MODEL.shape() @ rodrigues(omega)[0].T + T
    zeros = np.zeros(MODEL.num_nodes)
    return TrackResult(
        status, omega, T, np.zeros(MODEL.q), np.zeros(MODEL.p), nodes, nodes[:, :2], zeros, 0.0
    )


class _Replay:
    """A tracker that returns the given results in turn."""

    def __init__(self, results: list[TrackResult]) -> None:
        self._results = iter(results)

    def reset(self, init: object = None) -> None:
        """Nothing to restart."""

    def step(self, image: object) -> TrackResult:
        return next(self._results)


def _clock(monkeypatch, step_seconds: list[float]) -> None:
    """Make each step take the given CPU time, s, with the clock far from zero."""
    ticks = iter(np.cumsum([100.0, *[s for step in step_seconds for s in (step, 1.0)]]))
    monkeypatch.setattr(evaluation.time, 'process_time', lambda: float(next(ticks)))


def test_jitter_counts_the_tracked_frames_and_time_leaves_out_the_first(monkeypatch):
    # x angles of the tracked frames 1, 3, 1, 3: std 1; y 0, 0, 0, 4: std sqrt(3); z constant.
    # The LOST frame's 99 degrees stay out. Steps after the first: 10, 20, 30, 40 ms.
    angles = [[1, 0, 2], [3, 0, 2], [99, 99, 99], [1, 0, 2], [3, 4, 2]]
    status = [TrackStatus.TRACKING] * 2 + [TrackStatus.LOST] + [TrackStatus.TRACKING] * 2
    results = [_result(s, a) for s, a in zip(status, angles, strict=True)]
    _clock(monkeypatch, [0.5, 0.010, 0.020, 0.030, 0.040])
    true_nodes = np.array([r.nodes_cam for r in results])

    scored = evaluate_tracker(_Replay(results), MODEL, [None] * 5, true_nodes, None)

    np.testing.assert_allclose(scored.angle_std_deg, [1.0, np.sqrt(3.0), 0.0], atol=1e-9)
    assert scored.ms_median == pytest.approx(25.0)
    assert scored.ms_p95 == pytest.approx(38.5)  # 30 + 0.85 (40 - 30), linear interpolation
    assert scored.accuracy.lost == 1
    as_dict = scored.as_dict()
    assert (as_dict['ms_median'], as_dict['ms_p95']) == (scored.ms_median, scored.ms_p95)
    assert as_dict['angle_std_deg'] == scored.angle_std_deg
    assert as_dict['lost'] == 1


def test_one_frame_has_its_own_time_and_no_jitter_two_have_one(monkeypatch):
    result = _result(TrackStatus.TRACKING, [1, 2, 3])
    _clock(monkeypatch, [0.007])
    scored = evaluate_tracker(_Replay([result]), MODEL, [None], result.nodes_cam[None], None)
    assert np.isnan(scored.angle_std_deg).all()
    assert scored.ms_median == pytest.approx(7.0)
    assert scored.ms_p95 == pytest.approx(7.0)
    two = [result, _result(TrackStatus.TRACKING, [3, 2, 3])]
    _clock(monkeypatch, [0.007, 0.002])
    true_nodes = np.array([r.nodes_cam for r in two])
    scored = evaluate_tracker(_Replay(two), MODEL, [None] * 2, true_nodes, None)
    np.testing.assert_allclose(scored.angle_std_deg, [1.0, 0.0, 0.0], atol=1e-9)
    assert scored.ms_median == pytest.approx(2.0)
