"""bag_recorder: QoS matching, skipped types and errors in-process; recording over real DDS.

The recording tests run the node as its own process (``python -m
face_tracking_ros.nodes.bag_recorder``), stop it with SIGTERM or SIGINT, and read the bag back
with rosbags (read_messages) and with the mcap reader's ROS 2 decoder.
"""

from __future__ import annotations

from pathlib import Path
import signal
import time

from bag_processes import (
    T0,
    finish,
    plain_by_topic,
    spin_until,
    start_node,
    write_bag,
)
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import (
    DurabilityPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from face_tracking_ros.errors import BagError, ConfigError
from face_tracking_ros.io.bags import (
    BagWriter,
    read_messages,
    read_raw,
)
from face_tracking_ros.io.messages import RclpyMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.nodes.bag_recorder import (
    RECORD_DEPTH,
    BagRecorder,
    subscription_qos,
    unrecordable,
)

from message_samples import rclpy_class, sample_fields, to_plain, to_rclpy

FACE_STATE = 'face_tracking_msgs/msg/FaceState'
FACE_MODEL = 'face_tracking_msgs/msg/FaceModel'
FLOAT = 'std_msgs/msg/Float64'
IMAGE = 'sensor_msgs/msg/Image'
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
ACK_TIMEOUT = rclpy.duration.Duration(seconds=5)
MATCH_SETTLE_S = 0.5  # best effort: let the recorder's reader match our writer too


# --- QoS matching, types, errors (no recording) ---


@pytest.mark.parametrize(
    ('offered', 'reliability', 'durability'),
    [
        ([RELIABLE], ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE),
        ([LATCHED, LATCHED], ReliabilityPolicy.RELIABLE, DurabilityPolicy.TRANSIENT_LOCAL),
        ([qos_profile_sensor_data], ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.VOLATILE),
        ([LATCHED, RELIABLE], ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE),
        (
            [RELIABLE, qos_profile_sensor_data],
            ReliabilityPolicy.BEST_EFFORT,
            DurabilityPolicy.VOLATILE,
        ),
    ],
)
def test_subscription_qos_matches_every_publisher(
    offered: list[QoSProfile], reliability: ReliabilityPolicy, durability: DurabilityPolicy
) -> None:
    qos = subscription_qos(offered)

    assert (qos.reliability, qos.durability, qos.depth) == (reliability, durability, RECORD_DEPTH)


def test_types_without_rclpy_class_or_definition_are_unrecordable() -> None:
    classes = RclpyMessages()
    standard_only = get_typestore(Stores.ROS2_KILTED)

    assert unrecordable(FACE_STATE, classes, typestore()) == ''
    assert unrecordable('nowhere_msgs/msg/Thing', classes, typestore()) == (
        'no rclpy message class for nowhere_msgs/msg/Thing'
    )
    assert unrecordable(FACE_STATE, classes, standard_only) == (
        f'{FACE_STATE} is not in the typestore'
    )


def recorder(
    context: Context, store: Typestore | None = None, **parameters: object
) -> BagRecorder:
    """A recorder node in this process, with parameter overrides."""
    overrides = [Parameter(name, value=value) for name, value in parameters.items()]
    return BagRecorder(store, context=context, parameter_overrides=overrides)


@pytest.mark.parametrize(
    ('parameters', 'match'),
    [
        ({'output': ''}, 'parameter output: no bag directory given'),
        ({'discovery_period': 0.0}, 'discovery_period must be a finite number > 0, got 0.0'),
        # These were an RCLError traceback from resolve_topic_name.
        (
            {'topics': ['image', 'bad topic!']},
            "parameter topics: 'bad topic!' is not a topic name: topic name must not contain "
            'characters other than alphanumerics',
        ),
        ({'topics': ['a//b']}, "'a//b' is not a topic name: topic name must not contain repe"),
    ],
)
def test_bad_parameters_are_config_errors(
    ros_context: Context, tmp_path: Path, parameters: dict, match: str
) -> None:
    with pytest.raises(ConfigError, match=match):
        recorder(ros_context, **{'output': str(tmp_path / 'bag'), **parameters})


def test_an_output_under_a_file_is_a_config_error(ros_context: Context, tmp_path: Path) -> None:
    """It was a NotADirectoryError traceback from the bag writer's mkdir."""
    (tmp_path / 'file').write_text('mine')
    output = tmp_path / 'file' / 'bag'
    expected = f'parameter output {output}: {tmp_path / "file"} is a file, not a directory'
    with pytest.raises(ConfigError, match=expected):
        recorder(ros_context, output=str(output))
    assert (tmp_path / 'file').read_text() == 'mine'


def test_an_existing_output_is_a_bag_error(ros_context: Context, tmp_path: Path) -> None:
    with pytest.raises(BagError, match=f'{tmp_path}: cannot create bag'):
        recorder(ros_context, output=str(tmp_path))


def test_a_topic_of_unknown_type_is_skipped_with_one_warning(
    ros_context: Context, tmp_path: Path, store: Typestore, capfd: pytest.CaptureFixture
) -> None:
    bag = tmp_path / 'bag'
    node = recorder(
        ros_context, get_typestore(Stores.ROS2_KILTED), output=str(bag), discovery_period=0.05
    )
    source = rclpy.create_node('source', context=ros_context)
    states = source.create_publisher(rclpy_class(FACE_STATE), 'x/state', RELIABLE)
    numbers = source.create_publisher(rclpy_class(FLOAT), 'x/num', RELIABLE)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(source)
    sent = 0

    def publish_and_spin() -> None:
        nonlocal sent
        states.publish(to_rclpy(store, FACE_STATE, sample_fields(store, FACE_STATE)))
        numbers.publish(to_rclpy(store, FLOAT, {'data': float(sent)}))
        sent += 1
        executor.spin_once(timeout_sec=0.02)

    deadline = time.monotonic() + 20.0
    while not numbers.get_subscription_count():
        assert time.monotonic() < deadline, 'the recorder did not subscribe to x/num'
        publish_and_spin()
    matched_at = sent
    for _ in range(20):  # several discovery periods: the warning must not repeat
        publish_and_spin()
    node.finish(executor)
    executor.shutdown()
    source.destroy_node()
    node.destroy_node()

    warnings = [line for line in capfd.readouterr().err.splitlines() if 'not recording' in line]
    assert len(warnings) == 1
    assert f'not recording /x/state: {FACE_STATE} is not in the typestore' in warnings[0]
    numbers_recorded = [m.msg.data for m in read_messages(bag)]  # only /x/num: it would raise
    assert numbers_recorded[-20:] == [float(i) for i in range(matched_at, sent)]


# --- Recording over DDS ---

N = 12
# topic, type, QoS of the publisher
STREAMS = [
    ('rec/state', FACE_STATE, RELIABLE),
    ('rec/num', FLOAT, RELIABLE),
    ('rec/image', IMAGE, qos_profile_sensor_data),
]


def test_recorder_keeps_every_message_received_until_sigterm(
    tmp_path: Path, ros_context: Context, store: Typestore
) -> None:
    bag = tmp_path / 'bag'
    node = rclpy.create_node('recorder_source', context=ros_context)
    publishers = {
        topic: node.create_publisher(rclpy_class(msgtype), topic, qos)
        for topic, msgtype, qos in STREAMS
    }
    model = sample_fields(store, FACE_MODEL, seed=99)
    latched = node.create_publisher(rclpy_class(FACE_MODEL), 'rec/model', LATCHED)
    latched.publish(to_rclpy(store, FACE_MODEL, model))  # before the recorder exists
    process = start_node('bag_recorder', output=bag, discovery_period=0.2)
    try:
        everyone = [*publishers.values(), latched]
        spin_until(node, lambda: all(p.get_subscription_count() for p in everyone))
        time.sleep(MATCH_SETTLE_S)
        sent: dict[str, list[dict]] = {f'/{topic}': [] for topic, _, _ in STREAMS}
        first_sent_ns = time.time_ns()
        for index in range(N):
            for topic, msgtype, _ in STREAMS:
                fields = sample_fields(store, msgtype, seed=100 * index + len(topic))
                publishers[topic].publish(to_rclpy(store, msgtype, fields))
                sent[f'/{topic}'].append(fields)
            time.sleep(0.005)
        for topic, _, qos in STREAMS:
            if qos.reliability == ReliabilityPolicy.RELIABLE:
                assert publishers[topic].wait_for_all_acked(ACK_TIMEOUT)
        all_acked_ns = time.time_ns()
    finally:
        code, output = finish(process, signal.SIGTERM)
    node.destroy_node()

    assert code == 0, output
    sent['/rec/model'] = [model]
    types = {f'/{topic}': msgtype for topic, msgtype, _ in STREAMS} | {'/rec/model': FACE_MODEL}
    by_rosbags: dict[str, list[dict]] = {topic: [] for topic in types}
    for message in read_messages(bag, topics=list(types)):
        by_rosbags[message.topic].append(to_plain(store, message.msgtype, message.msg))
    assert by_rosbags == sent
    (mcap_file,) = bag.glob('*.mcap')
    by_mcap: dict[str, list[dict]] = {topic: [] for topic in types}
    with mcap_file.open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for schema, channel, _, decoded in reader.iter_decoded_messages(topics=list(types)):
            by_mcap[channel.topic].append(to_plain(store, schema.name, decoded))
    assert by_mcap == sent
    stamps = [m.stamp_ns for m in read_raw(bag, topics=['/rec/state', '/rec/num'])]
    assert first_sent_ns <= min(stamps) and max(stamps) <= all_acked_ns  # receive times
    assert f'/rec/state: {N}' in output
    assert 'recording /rec/model [face_tracking_msgs/msg/FaceModel] reliable transient_local' in (
        output
    )
    assert 'recording /rec/image [sensor_msgs/msg/Image] best_effort volatile' in output


def test_player_to_recorder_round_trip_gives_the_same_messages(
    tmp_path: Path, store: Typestore
) -> None:
    original, recorded = tmp_path / 'original', tmp_path / 'recorded'
    streams = [('face/state', FACE_STATE), ('num', FLOAT), ('camera/image', IMAGE)]
    played = [('face/model', FACE_MODEL, 1, 0)] + [
        (topic, msgtype, 10 * i + k, 100 * i + k)
        for i in range(8)
        for k, (topic, msgtype) in enumerate(streams)
    ]
    write_bag(original, played)
    topics = ['/face/model', '/face/state', '/num', '/camera/image']
    process = start_node('bag_recorder', output=recorded, topics=topics, discovery_period=0.2)
    try:
        player = start_node('bag_player', bag=original, rate=4.0, wait_for_subscribers=1)
        player_code, player_output = finish(player)
    finally:
        code, output = finish(process, signal.SIGINT)

    assert player_code == 0, player_output
    assert code == 0, output
    # Same fields; the bytes may differ in trailing padding (DDS pads payloads to 4 bytes).
    assert plain_by_topic(store, recorded) == plain_by_topic(store, original)
    state_ns = np.array([m.stamp_ns for m in read_raw(recorded, topics=['/face/state'])])
    assert state_ns.min() > T0 + 60 * 10**9  # receive times, not the bag's
    # Paced at rate 4: the 8 states 100 ms apart in the bag span 175 ms (700 ms at rate 1, 350 at
    # 2). The span, not each gap: one message delivered late on a loaded machine moves two gaps.
    assert np.all(np.diff(state_ns) > 0)
    assert abs((state_ns[-1] - state_ns[0]) / 1e6 - 175.0) < 75.0


def test_write_raw_keeps_the_bytes_and_refuses_unknown_types(tmp_path: Path) -> None:
    path = tmp_path / 'bag'
    data = typestore().serialize_cdr(typestore().types[FLOAT](data=2.5), FLOAT)
    with BagWriter(path) as bag:
        bag.write_raw('/n', FLOAT, data, T0)
        with pytest.raises(BagError, match='cannot write nowhere_msgs/msg/Thing on /m'):
            bag.write_raw('/m', 'nowhere_msgs/msg/Thing', data, T0)

    assert [tuple(m) for m in read_raw(path)] == [('/n', FLOAT, T0, data, 'float64 data\n')]
    assert [m.msg.data for m in read_messages(path)] == [2.5]
