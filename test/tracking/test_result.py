"""The tracker result type (tracking/result.py): its status values and the empty result."""

from __future__ import annotations

from face_tracking_msgs.msg import FaceState
import numpy as np

from face_tracking_ros.tracking.result import TrackResult, TrackStatus


def test_an_empty_result_has_nan_pose_and_nodes_of_the_model_s_sizes():
    empty = TrackResult.empty(34, 2, 5, 'waiting for init points')
    assert (empty.status, empty.reason, empty.ok) == (
        TrackStatus.INITIALIZING,
        'waiting for init points',
        False,
    )
    for value, shape in (
        (empty.omega, (3,)),
        (empty.t, (3,)),
        (empty.nodes_cam, (34, 3)),
        (empty.nodes_px, (34, 2)),
        (empty.node_residuals, (34,)),
    ):
        assert value.shape == shape
        assert np.isnan(value).all()
    assert empty.t is not empty.omega
    np.testing.assert_array_equal(empty.alpha, np.zeros(5))
    np.testing.assert_array_equal(empty.sigma, np.zeros(2))
    assert np.isnan(empty.mean_residual)
    assert (empty.iterations, empty.cost_history, empty.right_node_residuals) == (0, (), None)


def test_the_status_values_are_the_face_state_message_constants():
    assert [(status.name, int(status)) for status in TrackStatus] == [
        ('INITIALIZING', FaceState.STATUS_INITIALIZING),
        ('TRACKING', FaceState.STATUS_TRACKING),
        ('LOST', FaceState.STATUS_LOST),
    ]
