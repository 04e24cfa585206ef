"""A live mono_tracker process fed a bad image over DDS: WARN on /diagnostics, tracking goes on."""

from __future__ import annotations

import signal
import time

from bag_processes import finish, start_node
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from face_tracking_msgs.msg import FaceState
from fault_scenes import CAMERA, FaultScene, stamp
import numpy as np
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image

from face_tracking_ros.io import conversions
from face_tracking_ros.io.messages import RclpyMessages
from face_tracking_ros.synthetic.clicks import write_init_file
from face_tracking_ros.tracking.result import TrackStatus

WAIT_S = 60.0
RESEND_S = 0.5
FACTORY = RclpyMessages()


def _image(pixels: np.ndarray, stamp_ns: int, encoding: str = 'mono8') -> Image:
    header = conversions.make_header(FACTORY, stamp_ns, 'camera_optical')
    msg = conversions.array_to_image(FACTORY, header, pixels)
    msg.encoding = encoding
    return msg


def _spin_until(executor, done, what: str, publish=lambda: None) -> None:
    """Spin until ``done()``, calling ``publish()`` every RESEND_S (best effort may lose one)."""
    deadline = time.monotonic() + WAIT_S
    while not done():
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        publish()
        resend = time.monotonic() + RESEND_S
        while not done() and time.monotonic() < resend:
            executor.spin_once(timeout_sec=0.02)


def test_bad_image_gives_a_warn_status_and_the_node_keeps_tracking(ros_context, tmp_path):
    scene = FaultScene()
    frame = scene.render()
    init_file = write_init_file(scene.initialisation(frame), tmp_path / 'init.json')
    process = start_node('mono_tracker', init_file=init_file)
    node = Node('hardening_driver', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    states: list[FaceState] = []
    warnings: list[DiagnosticStatus] = []
    node.create_subscription(FaceState, 'face/state', states.append, 10)
    node.create_subscription(
        DiagnosticArray, '/diagnostics', lambda array: warnings.extend(array.status), 10
    )
    image_pub = node.create_publisher(Image, 'image', qos_profile_sensor_data)
    info_pub = node.create_publisher(CameraInfo, 'camera_info', qos_profile_sensor_data)
    info = conversions.camera_to_info(
        FACTORY, conversions.make_header(FACTORY, stamp(0), 'camera_optical'), CAMERA
    )
    sent = iter(range(1, 10_000))
    try:
        _spin_until(
            executor,
            lambda: image_pub.get_subscription_count() and info_pub.get_subscription_count(),
            'the node to subscribe',
        )
        for _ in range(5):  # calibration first, so the first image is rarely held
            info_pub.publish(info)
            executor.spin_once(timeout_sec=0.2)
        _spin_until(
            executor,
            lambda: states,
            'a first state',
            lambda: (info_pub.publish(info), image_pub.publish(_image(frame.image, stamp(0)))),
        )
        warnings.clear()  # e.g. 'no calibration yet' if the first image beat camera_info
        _spin_until(
            executor,
            lambda: any('mono16' in status.message for status in warnings),
            'a diagnostic of the bad image',
            lambda: image_pub.publish(_image(frame.image, stamp(next(sent)), 'mono16')),
        )
        before = len(states)
        _spin_until(
            executor,
            lambda: len(states) >= before + 3,
            'states after the bad image',
            lambda: image_pub.publish(_image(frame.image, stamp(next(sent)))),
        )
    finally:
        executor.shutdown()
        node.destroy_node()
        code, output = finish(process, stop=signal.SIGINT)
    assert code == 0, output
    assert 'Traceback' not in output, output
    warning = next(status for status in warnings if 'mono16' in status.message)
    assert warning.level == DiagnosticStatus.WARN
    assert warning.name.endswith('mono_tracker')
    assert "image: unsupported image encoding 'mono16'" in warning.message
    # The log line: rclpy throttles per call site, so a warning logged less than 5 s before
    # (an image that beat camera_info) hides this one from the log, not from /diagnostics.
    if 'no calibration' not in output:
        assert "unsupported image encoding 'mono16'" in output
    assert all(state.status == TrackStatus.TRACKING for state in states[before:])
