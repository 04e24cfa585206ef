"""A node's start-up objects are frozen out of the garbage collector before it spins."""

from __future__ import annotations

import gc

import pytest

from face_tracking_ros.nodes.graceful import run_until_stopped


class _Executor:
    """Spins nothing: the node ends at its first check."""

    def add_node(self, node: object) -> None:
        """Accept the node."""

    def spin_once(self, timeout_sec: float) -> None:
        """Nothing to spin."""

    def shutdown(self) -> None:
        """Nothing to stop."""


class _Node:
    """Holds an object made while it was built; records whether the collector still sees it."""

    def __init__(self) -> None:
        """Make the start-up object (a container: the collector tracks it)."""
        self.start_up = [object()]
        self.seen: list[bool] = []

    def finished(self) -> bool:
        """Record whether the start-up object is in a collected generation; done."""
        self.seen.append(any(o is self.start_up for o in gc.get_objects()))
        return True

    def finish(self, executor: object) -> None:
        """Nothing left."""

    def destroy_node(self) -> None:
        """Nothing to release."""


@pytest.fixture
def unfrozen():
    """Give the frozen objects back to the collector after the test."""
    yield
    gc.unfreeze()


def test_start_up_objects_are_frozen_before_the_spin(unfrozen):
    node = _Node()
    assert any(o is node.start_up for o in gc.get_objects())  # collected, until the node runs
    run_until_stopped('frozen', lambda: node, [], _Executor)
    assert node.seen == [False]
    assert gc.get_freeze_count() > 0
