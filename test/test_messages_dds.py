"""Every face_tracking_msgs message and service goes through real DDS on loopback, fields intact.

One process, its own rclpy context and node; the Fast DDS profile of config/ and
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (conftest) keep the traffic on this host.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
import time

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from face_tracking_ros.io.typestore import msg_dir, typestore

from message_samples import custom_msgtypes, rclpy_class, sample_fields, to_plain, to_rclpy

TIMEOUT_S = 20.0
RELIABLE = QoSProfile(
    depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE
)


def service_types() -> list[str]:
    """The face_tracking_msgs service types, e.g. ``'face_tracking_msgs/srv/ResetTracking'``."""
    return sorted(f'face_tracking_msgs/srv/{path.stem}' for path in srv_dir().glob('*.srv'))


def srv_dir() -> Path:
    """The directory of the .srv files (sibling of the .msg directory)."""
    return msg_dir().parent / 'srv'


def service_store() -> Typestore:
    """A typestore with the custom messages and the services' request and response types."""
    store = get_typestore(Stores.ROS2_KILTED)
    store.register({name: typestore().fielddefs[name] for name in custom_msgtypes()})
    for srvtype in service_types():
        request, response = (
            (srv_dir() / f'{srvtype.rsplit("/", 1)[1]}.srv').read_text().split('---')
        )
        for part, text in (('Request', request), ('Response', response)):
            # rosbags files a type under .../msg/; key it as rclpy names it.
            (fielddefs,) = get_types_from_msg(text, f'{srvtype}_{part}').values()
            store.register({f'{srvtype}_{part}': fielddefs})
    return store


def spin_until(
    node: Node, done: Callable[[], bool], step: Callable[[], None] | None = None
) -> None:
    """Spin ``node`` until ``done()``; fail after TIMEOUT_S. ``step`` runs before every spin."""
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    deadline = time.monotonic() + TIMEOUT_S
    try:
        while not done():
            assert time.monotonic() < deadline, f'nothing received within {TIMEOUT_S} s'
            if step is not None:
                step()
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()


@pytest.fixture
def node(ros_context: Context) -> Node:
    """A fresh node in the test's own context."""
    node = rclpy.create_node('test_messages_dds', context=ros_context)
    yield node
    node.destroy_node()


@pytest.mark.parametrize('msgtype', custom_msgtypes())
def test_message_round_trips_over_dds(node: Node, store: Typestore, msgtype: str) -> None:
    sent = sample_fields(store, msgtype, seed=7)
    message_class = rclpy_class(msgtype)
    received = []
    node.create_subscription(message_class, 'roundtrip', received.append, RELIABLE)
    publisher = node.create_publisher(message_class, 'roundtrip', RELIABLE)

    spin_until(
        node, lambda: bool(received), lambda: publisher.publish(to_rclpy(store, msgtype, sent))
    )

    assert to_plain(store, msgtype, received[0]) == sent


@pytest.mark.parametrize('srvtype', service_types())
def test_service_call_round_trips_over_dds(node: Node, srvtype: str) -> None:
    store = service_store()
    request = sample_fields(store, f'{srvtype}_Request', seed=3)
    response = sample_fields(store, f'{srvtype}_Response', seed=5)
    seen_requests = []

    def serve(call: object, reply: object) -> object:
        seen_requests.append(to_plain(store, f'{srvtype}_Request', call))
        return to_rclpy(store, f'{srvtype}_Response', response)

    service_class = rclpy_class(srvtype)
    node.create_service(service_class, 'roundtrip_service', serve)
    client = node.create_client(service_class, 'roundtrip_service')
    spin_until(node, client.service_is_ready)
    future = client.call_async(to_rclpy(store, f'{srvtype}_Request', request))
    spin_until(node, future.done)

    assert seen_requests == [request]
    assert to_plain(store, f'{srvtype}_Response', future.result()) == response
