"""The bag_player node: plays a bag's topics over DDS with their recorded timing.

Parameters: :class:`~face_tracking_ros.playback.PlaybackConfig` (``bag``, ``rate``,
``start_offset``, ``loop``, ``topics``, ``remap``, ``clock``, ``wait_for_subscribers``).

Messages are published as the CDR bytes stored in the bag (no deserialisation), from a playback
thread while the node spins; ``/clock`` carries the bag time for nodes run with
``use_sim_time:=true``. Timing, selection and remapping are :mod:`face_tracking_ros.playback`.

QoS: every topic is published reliable, volatile, keep-last depth 10 — images too, unlike a
camera's best-effort depth 1, so a reliable recorder or test subscriber gets every message, while
best-effort subscribers (the trackers' image inputs) still match. ``FaceModel`` topics are
published transient-local depth 1, like the learner's latched ``face/model``, so a tracker
started later still gets the model. ``/clock`` is reliable depth 1 (rclpy's time source
subscribes best-effort depth 1; a reliable publisher serves both).

At the end of the bag (without ``loop``) the node logs a summary and exits with code 0; a bag
that cannot be read gives one error line naming it and exit code 2.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from rclpy.executors import Executor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.time import Time
from rosgraph_msgs.msg import Clock

from face_tracking_ros.errors import BagError, FaceTrackingError
from face_tracking_ros.io.bags import RawMessage, bag_topics, read_raw
from face_tracking_ros.io.messages import RclpyMessages
from face_tracking_ros.nodes.graceful import run_until_stopped
from face_tracking_ros.nodes.processor_node import DECLARE_GIVEN, NodeParameters
from face_tracking_ros.playback import (
    Playback,
    PlaybackConfig,
    PlaybackSummary,
    PlayedTopic,
    plan_topics,
)
from face_tracking_ros.wording import counted

NODE_NAME = 'bag_player'
LATCHED_TYPES = frozenset({'face_tracking_msgs/msg/FaceModel'})
WAIT_LOG_PERIOD_S = 5.0

MESSAGE_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
LATCHED_QOS = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)


class BagPlayer(Node):
    """Publishes a bag's messages with their recorded timing, on a thread of its own."""

    def __init__(self, **kwargs: Any) -> None:
        """Declare the parameters, open the bag, create the publishers and start playing.

        Args:
            **kwargs: passed to :class:`rclpy.node.Node` (e.g. ``parameter_overrides``).

        Raises:
            ConfigError: If a parameter is out of range or a remap rule names no bag topic.
            BagError: If the bag cannot be read or lacks a topic asked for.
        """
        super().__init__(NODE_NAME, **DECLARE_GIVEN, **kwargs)
        self._stop = threading.Event()
        self._done = threading.Event()
        self._thread: threading.Thread | None = None
        self._summary: PlaybackSummary | None = None
        self._error: FaceTrackingError | None = None
        parameters = NodeParameters(self)
        self._config = parameters.config(PlaybackConfig)
        parameters.warn_unknown()
        planned = plan_topics(self._config.bag, bag_topics(self._config.bag), self._config)
        self._topic_publishers = self._create_publishers(planned)
        self._clock_publisher = (
            self.create_publisher(Clock, '/clock', CLOCK_QOS) if self._config.clock else None
        )
        self._thread = threading.Thread(target=self._play, name='bag_player', daemon=True)
        self._thread.start()

    def _create_publishers(self, planned: list[PlayedTopic]) -> dict[str, Any]:
        """A publisher per played topic (by bag topic); types without an rclpy class are skipped.

        Raises:
            BagError: If no topic can be played.
        """
        classes = RclpyMessages()
        publishers = {}
        for played in planned:
            try:
                msg_class = classes.message_class(played.msgtype)
            except (ImportError, AttributeError, ValueError):
                self.get_logger().warning(
                    f'{played.topic}: no rclpy message class for {played.msgtype}; not played'
                )
                continue
            qos = LATCHED_QOS if played.msgtype in LATCHED_TYPES else MESSAGE_QOS
            publishers[played.topic] = self.create_publisher(msg_class, played.output, qos)
            self.get_logger().info(f'{played.topic} -> {played.output} [{played.msgtype}]')
        if not publishers:
            raise BagError(f'{self._config.bag}: no topic to play')
        return publishers

    def finished(self) -> bool:
        """Whether playback has ended (the bag was played, or it failed)."""
        return self._done.is_set()

    def finish(self, executor: Executor) -> None:
        """Stop playback if it still runs and log its summary.

        Raises:
            FaceTrackingError: The error that ended playback, if any (e.g. a damaged bag).
        """
        self._stop_playback()
        if self._summary is not None:
            self.get_logger().info(f'{self._config.bag}: {self._summary.describe()}')
        if self._error is not None:
            raise self._error

    def destroy_node(self) -> None:
        """Stop the playback thread, then destroy the node."""
        self._stop_playback()
        super().destroy_node()

    def _stop_playback(self) -> None:
        """Ask the playback thread to stop and wait for it."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()

    def _play(self) -> None:
        """The playback thread: wait for subscribers, then play the bag."""
        playback = Playback(self._config, self, _StoppableClock(self._stop))
        try:
            if self._wait_for_subscribers():
                topics = list(self._topic_publishers)
                self._summary = playback.run(lambda: read_raw(self._config.bag, topics))
        except FaceTrackingError as error:  # e.g. a bag damaged part way: report what played
            self._summary = playback.summary(stopped=True)
            self._error = error
        finally:
            self._done.set()

    def _wait_for_subscribers(self) -> bool:
        """Wait until each topic has ``wait_for_subscribers`` subscribers; False if stopped."""
        wanted = self._config.wait_for_subscribers
        next_log = time.monotonic() + WAIT_LOG_PERIOD_S
        while True:
            waiting = [
                topic
                for topic, publisher in self._topic_publishers.items()
                if publisher.get_subscription_count() < wanted
            ]
            if not waiting:
                return True
            if time.monotonic() >= next_log:
                next_log += WAIT_LOG_PERIOD_S
                self.get_logger().info(
                    f'waiting for {counted(wanted, "subscriber")} on {waiting} (the topics '
                    'parameter plays only the topics named)'
                )
            if self._stop.wait(0.05):
                return False

    def publish(self, message: RawMessage) -> None:
        """Publish one message's CDR bytes on its (remapped) topic (PlaybackSink)."""
        self._topic_publishers[message.topic].publish(bytes(message.data))

    def clock(self, stamp_ns: int) -> None:
        """Publish the bag time on /clock (PlaybackSink)."""
        if self._clock_publisher is not None:
            self._clock_publisher.publish(Clock(clock=Time(nanoseconds=stamp_ns).to_msg()))


class _StoppableClock:
    """Monotonic wall time and a sleep that the node's stop event interrupts (WallClock)."""

    def __init__(self, stop: threading.Event) -> None:
        """Sleep until ``stop`` is set."""
        self._stop = stop

    def now_ns(self) -> int:
        """Monotonic wall time, ns."""
        return time.monotonic_ns()

    def sleep(self, seconds: float) -> bool:
        """Sleep up to ``seconds``; False if the node is stopping."""
        return not self._stop.wait(seconds)


def main(args: list[str] | None = None) -> None:
    """Entry point of ``ros2 run face_tracking_ros bag_player --ros-args -p bag:=BAG``."""
    run_until_stopped(NODE_NAME, BagPlayer, args)


if __name__ == '__main__':
    main()
