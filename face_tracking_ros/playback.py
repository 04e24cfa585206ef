"""Bag playback without a ROS runtime: topic selection, remapping, timing, start offset and loops.

The ``bag_player`` node (:mod:`face_tracking_ros.nodes.bag_player`) supplies the DDS side (a
:class:`PlaybackSink` that publishes serialised messages and ``/clock``) and a
:class:`WallClock` that can be stopped; everything that decides *what* is published *when* is
here and is tested with a fake clock.

Timing: a pass maps bag time to wall time by ``wall = wall_origin + (stamp - bag_origin) / rate``,
with ``bag_origin`` the first played message's stamp plus ``start_offset`` and ``wall_origin`` the
moment the pass starts. Each message is published when its wall time comes; a message already
late is published at once, so a slow consumer delays playback but never reorders it. ``/clock``
gets each message's stamp just before the message and the interpolated bag time every
:data:`CLOCK_PERIOD_S` in between; it never goes back within a pass, and jumps back to the start
offset when a loop begins a new pass (as ``ros2 bag play --loop`` does).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import Protocol

from face_tracking_ros.errors import BagError, ConfigError
from face_tracking_ros.io.bags import NS_PER_S, RawMessage
from face_tracking_ros.wording import counted

CLOCK_PERIOD_S = 0.025  # /clock is published at 40 Hz between messages (rosbag2's default)
REMAP_SEPARATOR = ':='


@dataclass(frozen=True)
class PlaybackConfig:
    """How a bag is played (the bag_player node's parameters).

    Attributes:
        bag: bag directory to play (rosbag2, MCAP or SQLite 3; a damaged MCAP bag is played up
            to the damage).
        rate: playback speed factor, > 0 (2.0 plays twice as fast as recorded).
        start_offset: seconds of the bag skipped from its first played message, >= 0.
        loop: play the bag again from its start offset each time it ends, until stopped.
        topics: bag topics to play ('/' prefix optional); empty plays every topic.
        remap: topic renames 'from:=to', 'from' a bag topic ('/' prefix optional). On the
            command line each rule is quoted inside the list, or rcl cannot parse it:
            -p "remap:=['/camera/image_raw:=image', '/camera/camera_info:=camera_info']".
        clock: publish the bag time on /clock (rosgraph_msgs/Clock) for nodes with
            use_sim_time.
        wait_for_subscribers: wait until every played topic has at least this many
            subscribers before starting (0: start at once).
    """

    bag: str = ''
    rate: float = 1.0
    start_offset: float = 0.0
    loop: bool = False
    topics: tuple[str, ...] = ()
    remap: tuple[str, ...] = ()
    clock: bool = True
    wait_for_subscribers: int = 0

    def __post_init__(self) -> None:
        """Validate the values.

        Raises:
            ConfigError: naming the first parameter out of range.
        """
        if not self.bag:
            raise ConfigError('parameter bag: no bag given (bag:=<bag directory>)')
        if not (math.isfinite(self.rate) and self.rate > 0):
            raise ConfigError(f'parameter rate must be a finite number > 0, got {self.rate}')
        if not (math.isfinite(self.start_offset) and self.start_offset >= 0):
            message = (
                f'parameter start_offset must be a finite number >= 0, got {self.start_offset}'
            )
            raise ConfigError(message)
        if self.wait_for_subscribers < 0:
            message = (
                f'parameter wait_for_subscribers must be >= 0, got {self.wait_for_subscribers}'
            )
            raise ConfigError(message)
        parse_remap(self.remap)


@dataclass(frozen=True)
class PlayedTopic:
    """A bag topic chosen for playback.

    Attributes:
        topic: name in the bag.
        output: name published on (after remapping).
        msgtype: ROS type name, e.g. 'face_tracking_msgs/msg/FaceState'.
    """

    topic: str
    output: str
    msgtype: str


def parse_remap(rules: Iterable[str]) -> dict[str, str]:
    """Parse ``'from:=to'`` rules.

    Args:
        rules: e.g. ``['face/state:=played/state']``.

    Returns:
        Bag topic without a leading '/' -> output topic.

    Raises:
        ConfigError: For a rule without ``:=``, with an empty side, or renaming a topic twice.
    """
    remap: dict[str, str] = {}
    for rule in rules:
        source, separator, target = (part.strip() for part in rule.partition(REMAP_SEPARATOR))
        if not (separator and source.strip('/') and target.strip('/')):
            raise ConfigError(f'parameter remap: {rule!r} must be written from:=to')
        key = source.lstrip('/')
        if key in remap:
            raise ConfigError(f'parameter remap: {source!r} is renamed twice')
        remap[key] = target
    return remap


def plan_topics(
    bag: Path | str, bag_topics: Mapping[str, str], config: PlaybackConfig
) -> list[PlayedTopic]:
    """Choose the bag topics to play and the names to publish them on.

    Topic names in ``topics`` and ``remap`` match a bag topic with or without a leading '/'.

    Args:
        bag: the bag, for error messages.
        bag_topics: bag topic -> message type (:func:`~face_tracking_ros.io.bags.bag_topics`).
        config: playback configuration.

    Returns:
        The played topics, in bag order.

    Raises:
        BagError: If a topic asked for is not in the bag.
        ConfigError: If a remap rule names no topic of the bag.
    """
    by_key = {topic.lstrip('/'): topic for topic in bag_topics}
    available = ', '.join(sorted(bag_topics)) or 'none'
    missing = sorted(name for name in config.topics if name.lstrip('/') not in by_key)
    if missing:
        message = f'{bag}: no topic {", ".join(missing)} in bag (it has: {available})'
        raise BagError(message)
    remap = parse_remap(config.remap)
    unknown = sorted(set(remap) - set(by_key))
    if unknown:
        message = f'parameter remap: no topic {", ".join(unknown)} in {bag} (it has: {available})'
        raise ConfigError(message)
    wanted = {name.lstrip('/') for name in config.topics} or set(by_key)
    return [
        PlayedTopic(topic, remap.get(key, topic), bag_topics[topic])
        for key, topic in by_key.items()
        if key in wanted
    ]


@dataclass(frozen=True)
class Timeline:
    """The bag-time to wall-time map of one pass.

    Attributes:
        bag_origin_ns: bag time played at ``wall_origin_ns``.
        wall_origin_ns: wall time (monotonic ns) the pass started.
        rate: playback speed factor.
    """

    bag_origin_ns: int
    wall_origin_ns: int
    rate: float

    def wall_due_ns(self, stamp_ns: int) -> int:
        """Wall time at which the message recorded at ``stamp_ns`` is due."""
        return self.wall_origin_ns + round((stamp_ns - self.bag_origin_ns) / self.rate)

    def bag_time_ns(self, wall_ns: int) -> int:
        """Bag time played at wall time ``wall_ns``."""
        return self.bag_origin_ns + round((wall_ns - self.wall_origin_ns) * self.rate)


class PlaybackSink(Protocol):
    """Where played messages go (the node's publishers)."""

    def publish(self, message: RawMessage) -> None:
        """Publish one serialised message on its (remapped) topic."""
        ...

    def clock(self, stamp_ns: int) -> None:
        """Publish the bag time ``stamp_ns`` (ns since the epoch) on /clock."""
        ...


class WallClock(Protocol):
    """Wall time and a sleep that a stop request interrupts."""

    def now_ns(self) -> int:
        """Monotonic wall time, ns."""
        ...

    def sleep(self, seconds: float) -> bool:
        """Sleep up to ``seconds`` (0: just check); False if playback must stop."""
        ...


@dataclass(frozen=True)
class PlaybackSummary:
    """What a playback did.

    Attributes:
        counts: messages published per bag topic, over all passes.
        passes: passes played to their end.
        stopped: True if a stop request ended playback.
        bag_span_s: bag time covered by one pass, first to last played message, s (stopped in
            the first pass: by the part played).
        wall_s: wall time from the first pass's start to the end, s.
    """

    counts: Mapping[str, int] = field(default_factory=dict)
    passes: int = 0
    stopped: bool = False
    bag_span_s: float = 0.0
    wall_s: float = 0.0

    def describe(self) -> str:
        """One line for the log, e.g. '30 messages on 2 topics, 1 pass, 1.5 s of bag in 0.8 s'."""
        total = sum(self.counts.values())
        if not total and not self.stopped:
            return (
                'finished: no message played (the played topics have none, or start_offset is '
                'past the end of the bag)'
            )
        per_topic = ', '.join(f'{topic}: {n}' for topic, n in sorted(self.counts.items()))
        ending = 'stopped' if self.stopped else 'finished'
        return (
            f'{ending}: {counted(total, "message")} on {counted(len(self.counts), "topic")} in '
            f'{counted(self.passes, "complete pass", "complete passes")}, '
            f'{self.bag_span_s:.3f} s of bag in {self.wall_s:.3f} s'
            f'{" (" + per_topic + ")" if per_topic else ""}'
        )


class Playback:
    """Plays bag messages into a sink with their recorded timing, scaled by the rate."""

    def __init__(self, config: PlaybackConfig, sink: PlaybackSink, clock: WallClock) -> None:
        """Play according to ``config`` into ``sink``, timed by ``clock``."""
        self._config = config
        self._sink = sink
        self._clock = clock
        self._offset_ns = round(config.start_offset * NS_PER_S)
        self._counts: Counter[str] = Counter()
        self._last_clock_ns = -1
        self._passes = 0
        self._span_ns = 0  # of one pass: the last complete one's, or the first's so far
        self._start_ns = clock.now_ns()

    def run(self, open_bag: Callable[[], Iterable[RawMessage]]) -> PlaybackSummary:
        """Play passes over ``open_bag()`` (called once per pass) until the end or a stop.

        A pass that plays nothing (empty bag, or offset beyond its end) ends a loop.

        Args:
            open_bag: opens the bag's messages of the played topics, in record-time order.

        Returns:
            What was played.

        Raises:
            BagError: If the bag stops being readable; :meth:`summary` tells what was played.
        """
        self._start_ns = self._clock.now_ns()
        while True:
            published_before = self._counts.total()
            played = self._pass(open_bag())
            if played is None:
                return self.summary(stopped=True)
            self._span_ns = played
            self._passes += 1
            if not self._config.loop or self._counts.total() == published_before:
                return self.summary(stopped=False)

    def summary(self, stopped: bool) -> PlaybackSummary:
        """What has been played so far; ``stopped`` says playback ended before its end."""
        return PlaybackSummary(
            counts=dict(self._counts),
            passes=self._passes,
            stopped=stopped,
            bag_span_s=self._span_ns / NS_PER_S,
            wall_s=(self._clock.now_ns() - self._start_ns) / NS_PER_S,
        )

    def _pass(self, messages: Iterable[RawMessage]) -> int | None:
        """Play one pass; return the bag time it covered (ns), or None if stopped."""
        timeline: Timeline | None = None
        first_ns = last_ns = 0
        self._last_clock_ns = -1
        for message in messages:
            if timeline is None:
                first_ns = message.stamp_ns + self._offset_ns
                timeline = Timeline(first_ns, self._clock.now_ns(), self._config.rate)
            if message.stamp_ns < first_ns:
                continue
            if not self._wait(timeline, message.stamp_ns):
                return None
            if self._config.clock:
                self._publish_clock(message.stamp_ns)
            self._sink.publish(message)
            self._counts[message.topic] += 1
            last_ns = max(last_ns, message.stamp_ns)
            if not self._passes:
                self._span_ns = max(last_ns - first_ns, 0)
        return max(last_ns - first_ns, 0)

    def _wait(self, timeline: Timeline, stamp_ns: int) -> bool:
        """Wait until ``stamp_ns`` is due, ticking /clock; False if stopped meanwhile."""
        due_ns = timeline.wall_due_ns(stamp_ns)
        while True:
            now_ns = self._clock.now_ns()
            remaining_s = max(due_ns - now_ns, 0) / NS_PER_S
            if self._config.clock and remaining_s > 0:
                self._publish_clock(timeline.bag_time_ns(now_ns))
                remaining_s = min(remaining_s, CLOCK_PERIOD_S)
            if not self._clock.sleep(remaining_s):
                return False
            if self._clock.now_ns() >= due_ns:
                return True

    def _publish_clock(self, stamp_ns: int) -> None:
        """Publish the bag time, never going back within a pass."""
        self._last_clock_ns = max(self._last_clock_ns, stamp_ns)
        self._sink.clock(self._last_clock_ns)
