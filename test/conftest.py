"""Shared fixtures: a DDS environment that stays on this host, and a private rclpy context.

The environment is set before rclpy is imported by any test module (conftest is imported first),
with setdefault so `make test` and `.ci/run` can choose the domain.
"""

from __future__ import annotations

from collections.abc import Iterator
import os
from pathlib import Path
import sys

import pytest

REPO = Path(__file__).resolve().parents[1]

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('ROS_DOMAIN_ID', '42')
os.environ.setdefault('FASTDDS_DEFAULT_PROFILES_FILE', str(REPO / 'config' / 'fastdds_profile.xml'))
os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)


@pytest.fixture
def ros_context() -> Iterator[object]:
    """An initialised rclpy context of its own, shut down after the test."""
    from rclpy.context import Context
    import rclpy

    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)
