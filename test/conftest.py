"""Shared fixtures: a DDS environment that stays on this host, and a private rclpy context.

The environment is set with setdefault (so `make test` and `.ci/run` choose the domain) when
conftest is imported, before any rclpy context exists: rclpy reads it in `rclpy.init`. BLAS is
limited to one thread, as in the nodes and the ``face-tracking`` command, so the tests compute
what they run.

Test files import nothing from here: test/tracking/conftest.py is a module named ``conftest``
too, and whichever was loaded last answers ``from conftest import``. What they share is in
modules of their own names (repo_root.py, message_samples.py), as pytest advises.
"""

from __future__ import annotations

from collections.abc import Iterator
import os
import sys

import pytest
import rclpy
from rclpy.context import Context
from rosbags.typesys.store import Typestore

from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.threads import limit_blas_threads

from repo_root import REPO
from xdist_workers import worker_domain

pytest.register_assert_rewrite('tracked_expressions')  # its checks report their values

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('ROS_DOMAIN_ID', '42')
os.environ['ROS_DOMAIN_ID'] = worker_domain(os.environ['ROS_DOMAIN_ID'])
os.environ.setdefault(
    'FASTDDS_DEFAULT_PROFILES_FILE', str(REPO / 'config' / 'fastdds_profile.xml')
)
os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
limit_blas_threads()


@pytest.fixture
def ros_context() -> Iterator[Context]:
    """An initialised rclpy context of its own, shut down after the test."""
    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


@pytest.fixture(scope='session')
def store() -> Typestore:
    """The project typestore."""
    return typestore()
