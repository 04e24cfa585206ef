"""The node glue on its own (no traffic): publish a message's outputs, then the deferred work."""

from __future__ import annotations

import rclpy
from std_msgs.msg import Float64

from face_tracking_ros.errors import InputError
from face_tracking_ros.nodes import processor_node
from face_tracking_ros.processing.base import Output, Port

FLOAT = 'std_msgs/msg/Float64'


class Doubling:
    """Doubles a number (refuses negative ones) and leaves work until its outputs are out."""

    inputs = (Port('in', FLOAT),)
    outputs = (Port('out', FLOAT),)

    def __init__(self, events: list) -> None:
        """Record what it does in ``events``."""
        self._events = events

    def handle(self, topic, msg, wanted):
        """Double the number."""
        self._events.append('handle')
        if msg.data < 0:
            raise InputError('negative')
        return [Output('out', Float64(data=2.0 * msg.data))]

    def run_deferred(self):
        """Record the run."""
        self._events.append('deferred')


def test_deferred_work_runs_after_the_outputs_are_published_even_after_a_bad_input(
    monkeypatch, ros_context
):
    events: list = []

    def factory(_params, _messages):
        return Doubling(events)

    monkeypatch.setattr(processor_node, 'processor_factory', lambda _name: factory)
    monkeypatch.setattr(rclpy.node, 'get_default_context', lambda: ros_context)
    node = processor_node.ProcessorNode('doubling')
    try:
        publisher = node._output_publishers['out']
        monkeypatch.setattr(publisher, 'publish', lambda msg: events.append(msg.data))
        node._handle('in', Float64(data=1.5))
        node._handle('in', Float64(data=-1.0))
    finally:
        node.destroy_node()
    assert events == ['handle', 3.0, 'deferred', 'handle', 'deferred']
