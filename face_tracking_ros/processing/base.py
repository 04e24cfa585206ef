"""The processor interface: what a node consumes and produces, independent of DDS.

A processor turns one input message into zero or more output messages. The live node
(:mod:`face_tracking_ros.nodes.processor_node`) subscribes to its input ports and publishes its
outputs; offline replay (:mod:`face_tracking_ros.replay`) feeds it the messages of a bag and
writes the outputs to another bag. Both run exactly the same :meth:`Processor.handle` code.
A processor may also hold outputs back until the end of the stream (:class:`Finishing`), which
only a replay has, and leave work that does not change a message's outputs until they are out
(:class:`Deferring`): the node publishes first, so that work adds nothing to their latency.

Topics are relative names so users can remap them; each port states its QoS class.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Protocol, runtime_checkable


class QosClass(IntEnum):
    """QoS of a port: sensor data (rclpy's: best effort, depth 5), reliable results, or latched."""

    SENSOR = 0
    RELIABLE = 1
    LATCHED = 2


@dataclass(frozen=True)
class Port:
    """A topic a processor reads or writes.

    Attributes:
        topic: relative topic name, e.g. 'face/state'.
        msgtype: ROS type name, e.g. 'face_tracking_msgs/msg/FaceState'.
        qos: QoS class of the stream.
        on_demand: output produced only while someone subscribes (e.g. overlay images).
    """

    topic: str
    msgtype: str
    qos: QosClass = QosClass.RELIABLE
    on_demand: bool = False


@dataclass(frozen=True)
class Output:
    """One message to publish (live) or write (replay) on ``topic``."""

    topic: str
    msg: Any


class Processor(Protocol):
    """What a node does with messages, with no ROS runtime involved."""

    @property
    def inputs(self) -> tuple[Port, ...]:
        """Ports the processor consumes."""
        ...

    @property
    def outputs(self) -> tuple[Port, ...]:
        """Ports the processor produces."""
        ...

    def handle(self, topic: str, msg: Any, wanted: frozenset[str]) -> list[Output]:
        """Process one input message.

        Args:
            topic: the input port's topic the message arrived on.
            msg: the message (rclpy or rosbags; same fields).
            wanted: on-demand output topics that currently have subscribers.

        Returns:
            Output messages, built with the processor's message factory.

        Raises:
            FaceTrackingError: for a bad input message; the caller logs it and carries on.
        """
        ...


@runtime_checkable
class Deferring(Protocol):
    """A processor with work that can wait until the outputs of a message are out."""

    def run_deferred(self) -> None:
        """Do the work the last handled message left; called once its outputs are published.

        Raises:
            FaceTrackingError: for a problem the caller logs before carrying on.
        """
        ...


@runtime_checkable
class Reporting(Protocol):
    """A processor with counts and measurements to report: on /diagnostics live, after a replay."""

    def status(self) -> dict[str, str]:
        """What is worth reporting now, as key -> value text (a DiagnosticStatus's values)."""
        ...


@runtime_checkable
class Warns(Protocol):
    """A reporting processor that can tell when its status should warn (a WARN diagnostic)."""

    def warning(self) -> str:
        """What the status should warn of now, or '' (a tracker that tracks nothing)."""
        ...


@runtime_checkable
class Finishing(Protocol):
    """A processor with outputs for the end of its input stream (offline replay calls it)."""

    def finish(self) -> list[Output]:
        """The end of the input stream: the outputs held back until then, in order."""
        ...
