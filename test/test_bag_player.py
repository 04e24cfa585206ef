"""bag_player: playback timing and selection with a fake clock; the node over real DDS.

The DDS tests run the node as its own process (``python -m face_tracking_ros.nodes.bag_player``)
with a subscriber in this process, on loopback (conftest's environment).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
import signal

from bag_processes import T0, finish, spin_until, start_node, write_bag
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosbags.typesys.store import Typestore

from face_tracking_ros.errors import BagError, ConfigError
from face_tracking_ros.io.bags import NS_PER_S, BagWriter, RawMessage
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.playback import (
    CLOCK_PERIOD_S,
    Playback,
    PlaybackConfig,
    PlayedTopic,
    parse_remap,
    plan_topics,
)

from message_samples import rclpy_class, sample_fields, to_plain

MS = 1_000_000
FACE_STATE = 'face_tracking_msgs/msg/FaceState'
FLOAT = 'std_msgs/msg/Float64'
IMAGE = 'sensor_msgs/msg/Image'


class FakeClock:
    """Wall time that advances only when slept; stops playback after ``stop_after_s``."""

    def __init__(self, stop_after_s: float | None = None) -> None:
        """Start at 5 s of wall time."""
        self.ns = 5 * NS_PER_S
        self.stop_ns = None if stop_after_s is None else self.ns + round(stop_after_s * NS_PER_S)

    def now_ns(self) -> int:
        """The fake wall time."""
        return self.ns

    def sleep(self, seconds: float) -> bool:
        """Advance the wall time; False once the stop time is reached."""
        self.ns += round(seconds * NS_PER_S)
        return self.stop_ns is None or self.ns < self.stop_ns


class Sink:
    """Records what playback publishes and when (fake wall ns)."""

    def __init__(self, clock: FakeClock, publish_cost_s: float = 0.0) -> None:
        """Record at ``clock``'s time; each publish takes ``publish_cost_s``."""
        self.wall = clock
        self.cost_ns = round(publish_cost_s * NS_PER_S)
        self.published: list[tuple[int, str, int]] = []  # (wall ns, topic, stamp ns)
        self.clocks: list[tuple[int, int]] = []  # (wall ns, bag ns)

    def publish(self, message: RawMessage) -> None:
        """Record a message."""
        self.published.append((self.wall.ns, message.topic, message.stamp_ns))
        self.wall.ns += self.cost_ns

    def clock(self, stamp_ns: int) -> None:
        """Record a clock tick."""
        self.clocks.append((self.wall.ns, stamp_ns))


def messages(offsets_ms: list[int], topic: str = 'a') -> list[RawMessage]:
    return [RawMessage(topic, FLOAT, T0 + ms * MS, b'') for ms in offsets_ms]


def config(**fields: object) -> PlaybackConfig:
    return PlaybackConfig(bag='bag', **fields)


def play(
    records: list[RawMessage], stop_after_s: float | None = None, **fields: object
) -> tuple[Sink, object]:
    clock = FakeClock(stop_after_s)
    sink = Sink(clock)
    summary = Playback(config(**fields), sink, clock).run(lambda: iter(records))
    return sink, summary


# --- Timing, offset, loop and clock (no DDS) ---


def test_messages_are_published_at_their_recorded_times_divided_by_the_rate() -> None:
    offsets = [0, 40, 41, 300, 1000]

    sink, summary = play(messages(offsets), rate=2.0)

    start = sink.published[0][0]
    assert [(wall - start) / MS for wall, _, _ in sink.published] == [o / 2 for o in offsets]
    assert [stamp for _, _, stamp in sink.published] == [T0 + o * MS for o in offsets]
    assert summary.counts == {'a': 5}
    assert summary.passes == 1
    assert not summary.stopped
    assert summary.bag_span_s == pytest.approx(1.0)
    assert summary.wall_s == pytest.approx(0.5)


def test_start_offset_skips_the_beginning_and_plays_the_rest_from_now() -> None:
    sink, _ = play(messages([0, 100, 250, 400]), start_offset=0.2)

    start = FakeClock().ns
    assert [(wall - start) / MS for wall, _, _ in sink.published] == [50, 200]
    assert [stamp for _, _, stamp in sink.published] == [T0 + 250 * MS, T0 + 400 * MS]


def test_late_messages_are_published_at_once_in_order() -> None:
    clock = FakeClock()
    sink = Sink(clock, publish_cost_s=0.3)  # a consumer slower than the bag

    Playback(config(clock=False), sink, clock).run(lambda: iter(messages([0, 10, 20, 500])))

    walls = [(wall - FakeClock().ns) / MS for wall, _, _ in sink.published]
    assert walls == [0, 300, 600, 900]


def test_clock_ticks_between_messages_and_never_goes_back() -> None:
    sink, _ = play(messages([0, 100, 100, 330]), rate=0.5)

    walls = np.array([wall for wall, _ in sink.clocks])
    stamps = np.array([stamp for _, stamp in sink.clocks])
    assert np.all(np.diff(stamps) >= 0)
    assert stamps[0] == T0 and stamps[-1] == T0 + 330 * MS
    assert np.diff(walls).max() <= CLOCK_PERIOD_S * NS_PER_S
    start = walls[0]
    np.testing.assert_allclose(stamps - T0, (walls - start) * 0.5, atol=1)
    message_stamps = {stamp for _, _, stamp in sink.published}
    assert message_stamps <= set(stamps.tolist())


def test_no_clock_is_published_when_disabled() -> None:
    sink, _ = play(messages([0, 100]), clock=False)

    assert sink.clocks == []
    assert len(sink.published) == 2


def test_loop_replays_the_bag_until_stopped() -> None:
    sink, summary = play(messages([0, 100, 200]), stop_after_s=0.75, loop=True, clock=False)

    stamps = [(stamp - T0) // MS for _, _, stamp in sink.published]
    assert stamps[:9] == [0, 100, 200] * 3
    assert summary.stopped
    assert summary.passes >= 3
    assert 'stopped' in summary.describe()


def test_a_loop_with_nothing_to_play_ends() -> None:
    sink, summary = play(messages([0, 100]), loop=True, start_offset=5.0)

    assert sink.published == []
    assert summary.passes == 1
    assert not summary.stopped
    assert summary.counts == {}
    assert summary.describe() == (
        'finished: no message played (the played topics have none, or start_offset is past the '
        'end of the bag)'
    )


def test_stop_while_waiting_ends_playback_at_once() -> None:
    sink, summary = play(messages([0, 100, 10_000]), stop_after_s=1.0)

    assert [(stamp - T0) // MS for _, _, stamp in sink.published] == [0, 100]
    assert summary.stopped
    assert summary.passes == 0
    assert summary.describe().startswith('stopped: 2 messages on 1 topic in 0 complete passes')
    assert summary.bag_span_s == pytest.approx(0.1)  # the part played ('0.000 s of bag')


def test_a_bag_error_part_way_propagates_and_the_summary_tells_what_was_played() -> None:
    def damaged() -> Iterator[RawMessage]:
        yield from messages([0, 10])
        raise BagError('bag.mcap: damaged MCAP file, 2 messages recovered before: EOF')

    clock = FakeClock()
    playback = Playback(config(), Sink(clock), clock)

    with pytest.raises(BagError, match='2 messages recovered'):
        playback.run(damaged)
    summary = playback.summary(stopped=True)
    assert summary.counts == {'a': 2}
    assert summary.passes == 0
    assert summary.wall_s == pytest.approx(0.01)


# --- Topic selection and remapping (no DDS) ---

BAG_TOPICS = {'/cam/image': 'sensor_msgs/msg/Image', 'face/state': FACE_STATE, 'num': FLOAT}


def test_every_topic_is_played_under_its_own_name_by_default() -> None:
    planned = plan_topics('bag', BAG_TOPICS, config())

    assert planned == [PlayedTopic(topic, topic, msgtype) for topic, msgtype in BAG_TOPICS.items()]


def test_topics_and_remap_match_with_or_without_a_leading_slash() -> None:
    chosen = config(topics=('cam/image', '/face/state'), remap=('/face/state:=played/state',))

    planned = plan_topics('bag', BAG_TOPICS, chosen)

    assert planned == [
        PlayedTopic('/cam/image', '/cam/image', 'sensor_msgs/msg/Image'),
        PlayedTopic('face/state', 'played/state', FACE_STATE),
    ]


def test_a_topic_missing_from_the_bag_is_a_bag_error_listing_what_it_has() -> None:
    with pytest.raises(BagError, match=r'bag: no topic face/nothing in bag \(it has: /cam/image'):
        plan_topics('bag', BAG_TOPICS, config(topics=('face/nothing',)))


def test_a_remap_of_no_bag_topic_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match='parameter remap: no topic other in bag'):
        plan_topics('bag', BAG_TOPICS, config(remap=('other:=x',)))


def test_remap_rules_are_parsed() -> None:
    assert parse_remap(['/a/b:=c', ' d := /e ']) == {'a/b': 'c', 'd': '/e'}


@pytest.mark.parametrize(
    ('rules', 'match'),
    [
        (['a=b'], "'a=b' must be written from:=to"),
        (['a:='], "'a:=' must be written from:=to"),
        ([':=b'], "':=b' must be written from:=to"),
        (['a:=b', '/a:=c'], "'/a' is renamed twice"),
    ],
)
def test_bad_remap_rules_are_config_errors(rules: list[str], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        parse_remap(rules)


@pytest.mark.parametrize(
    ('fields', 'match'),
    [
        ({'bag': ''}, 'parameter bag: no bag given'),
        ({'rate': 0.0}, 'rate must be a finite number > 0, got 0.0'),
        ({'rate': float('nan')}, 'rate must be a finite number > 0, got nan'),
        ({'start_offset': -1.0}, 'start_offset must be a finite number >= 0, got -1.0'),
        ({'wait_for_subscribers': -1}, 'wait_for_subscribers must be >= 0, got -1'),
        ({'remap': ('x',)}, "remap: 'x' must be written from:=to"),
    ],
)
def test_bad_parameters_are_config_errors(fields: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        PlaybackConfig(**{'bag': 'bag', **fields})


# --- The node over DDS ---

RATE = 2.0
TIMING_TOLERANCE_MS = 40.0
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
BEST_EFFORT_1 = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
# (topic, type, seed, ms from the bag start): irregular gaps, two topics interleaved.
PLAYED = [
    ('face/state', FACE_STATE, 1, 0),
    ('num', FLOAT, 2, 30),
    ('face/state', FACE_STATE, 3, 90),
    ('num', FLOAT, 4, 95),
    ('face/state', FACE_STATE, 5, 260),
    ('num', FLOAT, 6, 400),
    ('face/state', FACE_STATE, 7, 610),
]
NOT_PLAYED = [('ignored', FLOAT, 8, 100)]


def test_player_publishes_every_message_in_order_with_its_timing_and_the_clock(
    tmp_path: Path, ros_context: Context, store: Typestore
) -> None:
    bag = tmp_path / 'bag'
    write_bag(bag, sorted(PLAYED + NOT_PLAYED, key=lambda r: r[3]))
    node = rclpy.create_node('player_listener', context=ros_context)
    received: list[tuple[str, dict, int]] = []  # (topic, fields, receive time ns)
    clocks: list[int] = []

    def listen(topic: str, msgtype: str) -> None:
        def callback(msg: object, info: dict) -> None:
            received.append((topic, to_plain(store, msgtype, msg), info['received_timestamp']))

        node.create_subscription(rclpy_class(msgtype), topic, callback, RELIABLE)

    listen('face/state', FACE_STATE)
    listen('played/num', FLOAT)
    listen('ignored', FLOAT)
    node.create_subscription(
        rclpy_class('rosgraph_msgs/msg/Clock'),
        '/clock',
        lambda msg: clocks.append(msg.clock.sec * NS_PER_S + msg.clock.nanosec),
        BEST_EFFORT_1,  # what rclpy's time source uses
    )
    player = start_node(
        'bag_player',
        bag=bag,
        rate=RATE,
        topics=['face/state', 'num'],
        remap=['num:=played/num'],
        wait_for_subscribers=1,
    )

    spin_until(node, lambda: len(received) >= len(PLAYED) and player.poll() is not None)
    code, output = finish(player)

    assert code == 0, output
    assert 'finished: 7 messages on 2 topics in 1 complete pass, ' in output
    renamed = {'num': 'played/num'}
    expected = [
        (renamed.get(topic, topic), sample_fields(store, msgtype, seed))
        for topic, msgtype, seed, _ in PLAYED
    ]
    assert [(topic, fields) for topic, fields, _ in received] == expected
    arrival_ms = np.array([ns for _, _, ns in received]) / MS
    recorded_ms = np.array([ms for _, _, _, ms in PLAYED], dtype=float)
    np.testing.assert_allclose(
        arrival_ms - arrival_ms[0], recorded_ms / RATE, atol=TIMING_TOLERANCE_MS
    )
    assert clocks == sorted(clocks)
    assert clocks[0] >= T0
    assert clocks[-1] == T0 + 610 * MS
    assert len(set(clocks)) > len(PLAYED)  # ticks between messages, not only at them
    node.destroy_node()


def test_player_in_a_loop_stops_cleanly_on_sigint(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    write_bag(bag, [('num', FLOAT, i, 10 * i) for i in range(5)])
    player = start_node('bag_player', bag=bag, loop=True, rate=1.0)

    try:
        output = ''
        while 'num -> num' not in output:
            output += player.stdout.readline()
            assert player.poll() is None, output
    finally:
        code, rest = finish(player, signal.SIGINT)

    assert code == 0, output + rest
    assert 'stopped:' in rest


@pytest.mark.parametrize(
    ('parameters', 'message'),
    [
        ({'bag': '/nonexistent/bag'}, '/nonexistent/bag: cannot read bag'),
        ({'bag': '/nonexistent/bag', 'rate': 0.0}, 'parameter rate must be a finite number > 0'),
        ({'bag': '/nonexistent/bag', 'rate': 'fast'}, "parameter rate must be a number, got 'f"),
        ({'bag': '/nonexistent/bag', 'rate': 2}, '/nonexistent/bag: cannot read bag'),  # 2.0
    ],
)
def test_bad_bag_or_parameter_gives_one_error_line_and_exit_code_2(
    parameters: dict, message: str
) -> None:
    code, output = finish(start_node('bag_player', **parameters))

    assert code == 2
    errors = [line for line in output.splitlines() if '[ERROR]' in line]
    assert len(errors) == 1 and message in errors[0], output
    assert 'Traceback' not in output


def test_truncated_bag_is_played_up_to_the_damage_then_exits_with_code_2(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    factory = RosbagsMessages(typestore())
    with BagWriter(bag) as writer:  # 4 MB: several MCAP chunks
        for i in range(40):
            image = factory.make(
                IMAGE, height=1, width=100_000, data=np.full(100_000, i, np.uint8)
            )
            writer.write('image', IMAGE, image, T0 + i * MS)
    (mcap_file,) = bag.glob('*.mcap')
    mcap_file.write_bytes(mcap_file.read_bytes()[: mcap_file.stat().st_size // 2])

    code, output = finish(start_node('bag_player', bag=bag, rate=10.0))

    assert code == 2
    errors = [line for line in output.splitlines() if '[ERROR]' in line]
    assert len(errors) == 1, output
    assert f'{mcap_file}: damaged MCAP file, ' in errors[0]
    recovered = int(errors[0].split('damaged MCAP file, ')[1].split()[0])
    assert 0 < recovered < 40
    assert f'stopped: {recovered} messages on 1 topic' in output
