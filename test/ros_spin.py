"""Spinning a test's rclpy executor while a node process works: a while, or until a condition."""

from __future__ import annotations

from collections.abc import Callable
import time

SPIN_S = 0.02  # one turn of the executor


def spin_for(executor, seconds: float, until: Callable[[], bool] = lambda: False) -> None:
    """Spin for ``seconds``, or until ``until()`` holds."""
    end = time.monotonic() + seconds
    while time.monotonic() < end and not until():
        executor.spin_once(timeout_sec=SPIN_S)


def wait_for(executor, condition: Callable[[], bool], what: str, timeout_s: float) -> None:
    """Spin until ``condition()`` holds; fail naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        executor.spin_once(timeout_sec=SPIN_S)
