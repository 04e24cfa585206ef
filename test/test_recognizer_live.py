"""The expression_recognizer node over DDS: a smile's onset, and its offset when the face is lost.

The test publishes ActionParams and FaceState messages to an expression_recognizer process, as a
tracker would (a smile, then a LOST state and no more actions), and checks the ExpressionEvents
it publishes: the node subscribes face/state besides face/action, and a state that is not
TRACKING ends the active expression.
"""

from __future__ import annotations

import signal

from bag_processes import finish, start_node
from face_tracking_msgs.msg import ActionParams, ExpressionEvent, FaceState
import numpy as np
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from ros_spin import spin_for, wait_for

from face_tracking_ros.recognition.events import EventKind
from face_tracking_ros.recognition.expression import ExpressionClassifier
from face_tracking_ros.tracking.result import TrackStatus

Q = 5  # the packaged model's, which the node loads by default
FPS = 30.0
WAIT_S = 60.0
SETTLE_S = 1.0  # after matching, as test_live_vs_replay: the node's side of discovery finishes
DEPTH = 100  # every message of the test stays in the publishers' history until delivered
SMILE_FRAMES = 20


def _smile_classifier() -> ExpressionClassifier:
    """'smile' when alpha_0 > 0.5, for the packaged model's q (posterior sigmoid(20 a - 10))."""
    weights = np.zeros((2, 3 * Q))
    weights[1, 0] = 20.0
    return ExpressionClassifier(
        labels=('neutral', 'smile'),
        q=Q,
        window=0.2,
        calibration=0.0,
        feature_mean=np.zeros(3 * Q),
        feature_scale=np.ones(3 * Q),
        weights=weights,
        intercepts=np.array([0.0, -10.0]),
    )


def _stamp(message, frame: int):
    seconds = 100.0 + frame / FPS
    message.header.stamp.sec = int(seconds)
    message.header.stamp.nanosec = round((seconds - int(seconds)) * 1e9)
    message.header.frame_id = 'camera_optical'
    message.face_id = 'face_0'
    return message


def _action(frame: int, smile: float) -> ActionParams:
    message = _stamp(ActionParams(), frame)
    message.alpha = [smile, 0.0, 0.0, 0.0, 0.0]
    return message


def _state(frame: int, status: TrackStatus) -> FaceState:
    message = _stamp(FaceState(), frame)
    message.status = int(status)
    return message


def test_the_node_ends_the_smile_of_a_face_that_is_lost(ros_context, tmp_path):
    classifier_file = tmp_path / 'smile.npz'
    _smile_classifier().save(classifier_file)
    process = start_node('expression_recognizer', classifier_file=classifier_file)
    node = Node('recognizer_live_driver', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    events: list[ExpressionEvent] = []
    node.create_subscription(ExpressionEvent, 'face/expression', events.append, 10)
    actions = node.create_publisher(ActionParams, 'face/action', DEPTH)
    states = node.create_publisher(FaceState, 'face/state', DEPTH)
    try:
        wait_for(
            executor,
            lambda: actions.get_subscription_count() and states.get_subscription_count(),
            'the node to subscribe',
            WAIT_S,
        )
        spin_for(executor, SETTLE_S)
        for frame in range(SMILE_FRAMES):  # a tracked smile
            states.publish(_state(frame, TrackStatus.TRACKING))
            actions.publish(_action(frame, 1.0))
        wait_for(executor, lambda: len(events) >= 1, 'the onset', WAIT_S)
        states.publish(_state(SMILE_FRAMES, TrackStatus.LOST))  # lost: no action comes
        wait_for(executor, lambda: len(events) >= 2, 'the offset', WAIT_S)
    finally:
        executor.shutdown()
        node.destroy_node()
        code, output = finish(process, stop=signal.SIGINT)
    assert code == 0, output
    assert [(e.label, e.event) for e in events] == [
        ('smile', EventKind.ONSET),
        ('smile', EventKind.OFFSET),
    ]
    offset = events[1]
    assert (offset.header.stamp.sec, offset.header.stamp.nanosec) == (
        _state(SMILE_FRAMES, TrackStatus.LOST).header.stamp.sec,
        _state(SMILE_FRAMES, TrackStatus.LOST).header.stamp.nanosec,
    )
    onset_s = events[0].header.stamp.sec + events[0].header.stamp.nanosec * 1e-9
    lost_s = 100.0 + SMILE_FRAMES / FPS
    assert abs(offset.duration - (lost_s - onset_s)) < 1e-6
