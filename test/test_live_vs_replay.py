"""A bag through the live mono_tracker node over DDS equals the same bag through offline replay.

The test publishes the bag's camera_info and images (raw CDR, as recorded) to a mono_tracker
process in lock step (the next image only after the previous image's face/state arrived, so no
frame is dropped) and compares every received FaceState with the one offline replay wrote for
the same stamp.
"""

from __future__ import annotations

import signal
import time

from bag_processes import finish, start_node
from face_tracking_msgs.msg import FaceState
import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.serialization import deserialize_message
from ros_spin import spin_for, wait_for
from sensor_msgs.msg import CameraInfo, Image

from face_tracking_ros.io.bags import read_messages, read_raw, stamp_to_ns
from face_tracking_ros.model.model_file import save_model
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.replay import replay_bag
from face_tracking_ros.synthetic.clicks import clicks_from_bag, write_init_file
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.synthetic.recording import record
from face_tracking_ros.synthetic.scenes import SceneConfig
from face_tracking_ros.synthetic.true_model import true_face_model

FRAMES = 12
WAIT_S = 60.0
RETRY_S = 0.5
RESEND_IMAGE_S = 5.0
SETTLE_S = 2.0


@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    """A short mono synthetic bag, a model file and an init file."""
    root = tmp_path_factory.mktemp('live')
    config = SceneConfig(kind='mono', frames=FRAMES, fps=15, width=320, height=240, focal=300.0)
    bag = record(config, root / 'bags')[0].path
    model_file = root / 'model.npz'
    save_model(true_face_model(FacePopulation(config.population, config.seed)), model_file)
    init_file = write_init_file(clicks_from_bag(bag, 0.5), root / 'init.json')
    return bag, model_file, init_file, root


def _offline_states(bag, model_file, init_file, out):
    params = OverrideParameters({'model_file': str(model_file), 'init_file': str(init_file)})
    replay_bag(['mono_tracker'], bag, out, params, progress=False)
    return {
        stamp_to_ns(m.msg.header.stamp): m.msg for m in read_messages(out, topics=['face/state'])
    }


def _live_states(ros_context, bag, model_file, init_file):
    process = start_node('mono_tracker', model_file=model_file, init_file=init_file)
    node = Node('live_vs_replay_driver', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    received: dict[int, FaceState] = {}
    node.create_subscription(
        FaceState, 'face/state', lambda m: received.update({stamp_to_ns(m.header.stamp): m}), 10
    )
    publishers = {
        'image': node.create_publisher(Image, 'image', qos_profile_sensor_data),
        'camera_info': node.create_publisher(CameraInfo, 'camera_info', qos_profile_sensor_data),
    }
    try:
        wait_for(
            executor,
            lambda: all(p.get_subscription_count() for p in publishers.values()),
            what='the node to subscribe',
            timeout_s=WAIT_S,
        )
        spin_for(executor, SETTLE_S)  # let the node's side of discovery finish too
        for info, image in _frames(bag):
            stamp = stamp_to_ns(deserialize_message(image.data, Image).header.stamp)
            _send_until_tracked(executor, publishers, info, image, lambda s=stamp: s in received)
    finally:
        executor.shutdown()
        node.destroy_node()
        code, output = finish(process, stop=signal.SIGINT)
    assert code == 0, output
    return received


def _frames(bag):
    """(camera_info, image) raw message pairs of each frame, in order."""
    by_topic = {'image': [], 'camera_info': []}
    for message in read_raw(bag, topics=list(by_topic)):
        by_topic[message.topic].append(message)
    return list(zip(by_topic['camera_info'], by_topic['image'], strict=True))


def _send_until_tracked(executor, publishers, info, image, tracked) -> None:
    """Publish a frame's camera_info and image and wait until its state comes back.

    Best effort may lose a message while discovery settles. camera_info is idempotent and the
    node holds an image until it has one, so camera_info is resent every RETRY_S; an image
    whose state has not come after RESEND_IMAGE_S was lost and is sent again.
    """
    deadline = time.monotonic() + WAIT_S
    while not tracked():
        publishers['camera_info'].publish(info.data)
        publishers['image'].publish(image.data)
        resend = time.monotonic() + RESEND_IMAGE_S
        while not tracked() and time.monotonic() < resend:
            assert time.monotonic() < deadline, 'timed out waiting for the live state'
            spin_for(executor, RETRY_S, until=tracked)
            publishers['camera_info'].publish(info.data)


def test_live_node_and_offline_replay_agree(recorded, ros_context):
    bag, model_file, init_file, root = recorded
    offline = _offline_states(bag, model_file, init_file, root / 'replayed')
    live = _live_states(ros_context, bag, model_file, init_file)
    assert len(offline) == FRAMES
    assert sorted(live) == sorted(offline)
    for stamp, state in live.items():
        reference = offline[stamp]
        assert state.status == reference.status
        np.testing.assert_allclose(state.omega, reference.omega, atol=1e-9)
        np.testing.assert_allclose(state.alpha, reference.alpha, atol=1e-9)
        live_nodes = np.array([(p.x, p.y, p.z) for p in state.nodes])
        offline_nodes = np.array([(p.x, p.y, p.z) for p in reference.nodes])
        np.testing.assert_allclose(live_nodes, offline_nodes, atol=1e-9)
