"""The bag_recorder node: records topics into a rosbag2 bag (MCAP storage, metadata.yaml).

Parameters: :class:`RecorderConfig` (``output``, ``topics``, ``discovery_period``).

Every ``discovery_period`` seconds the node looks at the ROS graph and subscribes to each new
topic it should record (the listed ones, or every topic but ``/rosout`` and
``/parameter_events``) as soon as the topic has a publisher. Subscriptions take the serialised
CDR bytes (``raw=True``) and write them unchanged with :meth:`BagWriter.write_raw`, logged at
the time DDS received them (the message info's ``received_timestamp``, system clock, ns since the
epoch; not the time the callback ran, which lags behind under load; ``use_sim_time`` does not
change it: the messages' own header stamps carry the bag time).

QoS: like ``ros2 bag record``, a subscription matches the publishers it finds: reliable if every
publisher is reliable (else best effort, which a best-effort camera needs), transient-local if
every publisher is (so a latched ``face/model`` published before the recorder started is
recorded), keep-last depth 100 so a burst waits in DDS while a message is written.

On SIGINT or SIGTERM the node stops spinning, takes every message DDS has already delivered to
its subscriptions (until none arrives for ``DRAIN_QUIET_S``), closes the bag (a valid MCAP file
and metadata.yaml, readable by rosbags and the mcap reader) and logs the count per topic. A type
it cannot record (no rclpy message class, or unknown to the typestore, which writes its
definition into the bag) is skipped with one warning naming it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from contextlib import ExitStack
from dataclasses import dataclass
import math
from pathlib import Path
import time
from typing import Any

from rclpy.executors import Executor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import MessageInfo
from rosbags.typesys.store import Typestore

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io.atomic import check_output_path
from face_tracking_ros.io.bags import BagWriter
from face_tracking_ros.io.messages import RclpyMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.nodes.graceful import rcl_reason, run_until_stopped
from face_tracking_ros.nodes.processor_node import DECLARE_GIVEN, NodeParameters
from face_tracking_ros.wording import counted

NODE_NAME = 'bag_recorder'
RECORD_DEPTH = 100
DRAIN_QUIET_S = 0.2  # after a stop request, drain until no message arrived for this long
DRAIN_LIMIT_S = 5.0  # ... or at most this long (a publisher still streaming)
INFRASTRUCTURE_TOPICS = frozenset({'/rosout', '/parameter_events'})


@dataclass(frozen=True)
class RecorderConfig:
    """What the bag_recorder node records (its parameters).

    Attributes:
        output: bag directory to create; it must not exist.
        topics: topics to record (relative names resolve in the node's namespace); empty
            records every topic seen except /rosout and /parameter_events.
        discovery_period: seconds between looks at the ROS graph for new topics and
            publishers, > 0.
    """

    output: str = ''
    topics: tuple[str, ...] = ()
    discovery_period: float = 0.5

    def __post_init__(self) -> None:
        """Validate the values.

        Raises:
            ConfigError: naming the first parameter out of range.
        """
        if not self.output:
            raise ConfigError('parameter output: no bag directory given (output:=<new dir>)')
        if not (math.isfinite(self.discovery_period) and self.discovery_period > 0):
            message = (
                f'parameter discovery_period must be a finite number > 0, '
                f'got {self.discovery_period}'
            )
            raise ConfigError(message)


def subscription_qos(offered: Sequence[QoSProfile]) -> QoSProfile:
    """The QoS that receives from every publisher of a topic (rosbag2's adaptation).

    Args:
        offered: the QoS profiles of the topic's publishers (at least one).

    Returns:
        Reliable if all publishers are reliable, else best effort; transient-local if all are,
        else volatile; keep-last :data:`RECORD_DEPTH`.
    """
    reliable = all(q.reliability == ReliabilityPolicy.RELIABLE for q in offered)
    latched = all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=RECORD_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


def unrecordable(msgtype: str, classes: RclpyMessages, store: Typestore) -> str:
    """Why a message type cannot be recorded, or '' if it can.

    Args:
        msgtype: e.g. 'face_tracking_msgs/msg/FaceState'.
        classes: rclpy message classes (a subscription needs the type support).
        store: the typestore writing the type's definition into the bag.
    """
    try:
        classes.message_class(msgtype)
    except (ImportError, AttributeError, ValueError):
        return f'no rclpy message class for {msgtype}'
    if msgtype not in store.fielddefs:
        return f'{msgtype} is not in the typestore'
    return ''


class BagRecorder(Node):
    """Subscribes to topics as they appear and writes every message received into a bag."""

    def __init__(self, store: Typestore | None = None, **kwargs: Any) -> None:
        """Declare the parameters, create the bag and start discovering topics.

        Args:
            store: typestore the bag's message definitions come from; default
                :func:`~face_tracking_ros.io.typestore.typestore`.
            **kwargs: passed to :class:`rclpy.node.Node` (e.g. ``parameter_overrides``).

        Raises:
            ConfigError: If a parameter is out of range, or output lies under a file.
            BagError: If the bag cannot be created (e.g. ``output`` exists).
        """
        super().__init__(NODE_NAME, **DECLARE_GIVEN, **kwargs)
        self._resources = ExitStack()
        parameters = NodeParameters(self)
        self._config = parameters.config(RecorderConfig)
        parameters.warn_unknown()
        self._store = typestore() if store is None else store
        self._classes = RclpyMessages()
        self._wanted = frozenset(self._resolved(topic) for topic in self._config.topics)
        self._recorded: dict[str, Any] = {}  # topic -> subscription
        self._skipped: set[str] = set()
        self._counts: Counter[str] = Counter()
        check_output_path(Path(self._config.output), 'parameter output', directory=True)
        self._bag = self._resources.enter_context(BagWriter(self._config.output, self._store))
        self.get_logger().info(f'recording to {self._config.output}')
        self._discovery = self.create_timer(self._config.discovery_period, self._discover)
        self._discover()

    def _resolved(self, topic: str) -> str:
        """The full name of the ``topics`` entry ``topic`` in the node's namespace.

        Raises:
            ConfigError: for a string that is not a topic name (rcl's reason, e.g. 'topic name
                must not contain repeated '/''), which rclpy raises as an RCLError.
        """
        try:
            return self.resolve_topic_name(topic)
        except RuntimeError as error:  # rclpy's RCLError: 'failed to resolve name: ..., at ...'
            reason = rcl_reason(error).removeprefix('failed to resolve name: ')
            msg = f'parameter topics: {topic!r} is not a topic name: {reason}'
            raise ConfigError(msg) from None

    def finished(self) -> bool:
        """Never: the recorder runs until stopped."""
        return False

    def finish(self, executor: Executor) -> None:
        """Take what DDS has delivered, close the bag and log the count per topic."""
        self._discovery.cancel()
        deadline = time.monotonic() + DRAIN_LIMIT_S
        while time.monotonic() < deadline:
            before = self._counts.total()
            executor.spin_once(timeout_sec=DRAIN_QUIET_S)
            if self._counts.total() == before:
                break
        self._resources.close()
        counts = ', '.join(f'{topic}: {n}' for topic, n in sorted(self._counts.items()))
        total = counted(self._counts.total(), 'message')
        self.get_logger().info(f'{self._config.output}: {total} ({counts or "none"})')
        never = sorted(self._wanted - set(self._recorded))
        if never:
            self.get_logger().warning(f'no publisher seen on {", ".join(never)}')

    def destroy_node(self) -> None:
        """Close the bag (if still open: it is closed once), then destroy the node."""
        self._resources.close()
        super().destroy_node()

    def _discover(self) -> None:
        """Subscribe to every new topic to record that has a publisher."""
        for topic, msgtypes in self.get_topic_names_and_types():
            if topic in self._recorded or topic in self._skipped or not self._wants(topic):
                continue
            offered = [info.qos_profile for info in self.get_publishers_info_by_topic(topic)]
            if offered:
                self._subscribe(topic, msgtypes, offered)

    def _wants(self, topic: str) -> bool:
        """Whether ``topic`` is to be recorded."""
        if self._wanted:
            return topic in self._wanted
        return topic not in INFRASTRUCTURE_TOPICS

    def _subscribe(self, topic: str, msgtypes: list[str], offered: list[QoSProfile]) -> None:
        """Subscribe to ``topic`` for raw messages, or skip it with one warning."""
        msgtype = msgtypes[0]
        reason = (
            f'{len(msgtypes)} types ({", ".join(msgtypes)})'
            if len(msgtypes) > 1
            else unrecordable(msgtype, self._classes, self._store)
        )
        if reason:
            self.get_logger().warning(f'not recording {topic}: {reason}')
            self._skipped.add(topic)
            return

        def record(data: bytes, info: MessageInfo) -> None:
            self._write(topic, msgtype, data, info['received_timestamp'])

        qos = subscription_qos(offered)
        msg_class = self._classes.message_class(msgtype)
        self._recorded[topic] = self.create_subscription(msg_class, topic, record, qos, raw=True)
        self.get_logger().info(
            f'recording {topic} [{msgtype}] {qos.reliability.name.lower()} '
            f'{qos.durability.name.lower()}'
        )

    def _write(self, topic: str, msgtype: str, data: bytes, stamp_ns: int) -> None:
        """Write one received message at its receive time."""
        self._bag.write_raw(topic, msgtype, data, stamp_ns)
        self._counts[topic] += 1


def main(args: list[str] | None = None) -> None:
    """Entry point of ``ros2 run face_tracking_ros bag_recorder --ros-args -p output:=DIR``."""
    run_until_stopped(NODE_NAME, BagRecorder, args)


if __name__ == '__main__':
    main()
