"""The node glue on its own (no traffic): publish a message's outputs, then the deferred work.

Messages cross rclpy as CDR bytes (rclpy's serialisation here, as DDS carries them) and reach
the processor as rosbags messages, as in a replay.
"""

from __future__ import annotations

from dataclasses import dataclass
import re

from diagnostic_msgs.msg import DiagnosticStatus
import pytest
from rcl_interfaces.msg import ParameterType
import rclpy
from rclpy.clock import ClockType
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Float64

from face_tracking_ros.errors import ConfigError, InputError, check_fields
from face_tracking_ros.imaging.photometric import PhotometricModel
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.nodes import processor_node
from face_tracking_ros.processing.base import Output, Port, QosClass
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.processing.track_counts import UNTRACKED_WARNING, TrackCounts
from face_tracking_ros.tracking.mono_config import MonoTrackerConfig
from face_tracking_ros.tracking.result import TrackStatus

FLOAT = 'std_msgs/msg/Float64'
ROSBAGS_FLOAT = typestore().types[FLOAT]
OK, WARN = DiagnosticStatus.OK, DiagnosticStatus.WARN


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
        return [Output('out', ROSBAGS_FLOAT(data=2.0 * msg.data))]

    def run_deferred(self):
        """Record the run."""
        self._events.append('deferred')


def _node_running(monkeypatch, context, processor, name: str) -> processor_node.ProcessorNode:
    """A ProcessorNode named ``name`` around ``processor``, in ``context``."""
    monkeypatch.setattr(processor_node, 'processor_factory', lambda _name: lambda *_: processor)
    monkeypatch.setattr(rclpy.node, 'get_default_context', lambda: context)
    return processor_node.ProcessorNode(name)


def test_deferred_work_runs_after_the_outputs_are_published_even_after_a_bad_input(
    monkeypatch, ros_context
):
    events: list = []
    node = _node_running(monkeypatch, ros_context, Doubling(events), 'doubling')
    try:
        publisher = node._output_publishers['out']

        def publish(cdr):
            events.append(deserialize_message(cdr, Float64).data)

        monkeypatch.setattr(publisher, 'publish', publish)
        (subscription,) = node._input_subscriptions
        subscription.callback(serialize_message(Float64(data=1.5)))
        subscription.callback(serialize_message(Float64(data=-1.0)))
    finally:
        node.destroy_node()
    assert events == ['handle', 3.0, 'deferred', 'handle', 'deferred']


def test_bytes_that_are_not_the_input_s_type_are_a_warning_naming_it(monkeypatch, ros_context):
    events: list = []
    node = _node_running(monkeypatch, ros_context, Doubling(events), 'doubling')
    statuses: list = []
    try:
        monkeypatch.setattr(node._diagnostics, 'publish', lambda a: statuses.extend(a.status))
        (subscription,) = node._input_subscriptions
        subscription.callback(serialize_message(Float64(data=1.5))[:6])  # cut short
    finally:
        node.destroy_node()
    assert events == []  # never reached the processor
    assert [s.level for s in statuses] == [WARN]
    assert statuses[0].message.startswith('in: cannot deserialise 6 bytes as std_msgs/msg/Float64')


class CountingDoubling(Doubling):
    """Doubling that reports how many numbers it has seen (processing.base.Reporting)."""

    def status(self):
        """The count, as a diagnostic value."""
        return {'seen': str(self._events.count('handle'))}


def test_a_reporting_processor_s_status_is_published_with_the_last_problem(
    monkeypatch, ros_context
):
    node = _node_running(monkeypatch, ros_context, CountingDoubling([]), 'reporting')
    statuses: list = []

    def publish(array):
        statuses.extend(array.status)

    try:
        monkeypatch.setattr(node._diagnostics, 'publish', publish)
        assert [t.timer_period_ns for t in node.timers] == [1_000_000_000]  # STATUS_PERIOD_S
        # Steady: with use_sim_time, ROS time stops with a paused bag, the status must not.
        assert [t.clock.clock_type for t in node.timers] == [ClockType.STEADY_TIME]
        node._handle('in', Float64(data=1.5))
        node._publish_status()
        node._handle('in', Float64(data=-1.0))  # a bad input: WARN now, and in the next status
        node._publish_status()
        monkeypatch.setattr(processor_node, 'STATUS_PERIOD_S', 0.0)  # the problem is old
        node._publish_status()
    finally:
        node.destroy_node()
    values = [{v.key: v.value for v in status.values} for status in statuses]
    assert [s.level for s in statuses] == [OK, WARN, WARN, OK]
    assert [s.message for s in statuses] == ['running', 'in: negative', 'in: negative', 'running']
    assert [v.get('seen') for v in values] == ['1', '2', '2', '2']  # the problem's too
    assert all(v['node'] == 'reporting' for v in values)


class SensorCounting(CountingDoubling):
    """CountingDoubling fed by a sensor stream, as images and camera_info are."""

    inputs = (Port('in', FLOAT, QosClass.SENSOR),)


def test_the_status_warns_of_a_sensor_input_without_messages_naming_its_publishers(
    monkeypatch, ros_context
):
    node = _node_running(monkeypatch, ros_context, SensorCounting([]), 'sensing')
    statuses: list = []
    logged: list = []
    try:
        monkeypatch.setattr(node._diagnostics, 'publish', lambda a: statuses.extend(a.status))
        monkeypatch.setattr(node, 'get_logger', lambda: _Logger(logged))
        node._publish_status()  # just started: not silent yet
        monkeypatch.setattr(processor_node, 'SILENT_INPUT_S', 0.0)
        node._publish_status()  # no publisher: a misspelt topic or remapping
        node._publish_status()  # logged once per WARNING_PERIOD_S
        publisher = node.create_publisher(Float64, '/in', 10)
        node._publish_status()  # a publisher that sends nothing: a stopped camera
        monkeypatch.setattr(processor_node, 'SILENT_INPUT_S', 60.0)
        node._handle('in', Float64(data=1.0))
        node._publish_status()
        node.destroy_publisher(publisher)
    finally:
        node.destroy_node()
    assert [s.level for s in statuses] == [OK, WARN, WARN, WARN, OK]
    messages = [s.message for s in statuses]
    no_publisher = 'no publisher: check the topic name or remapping, and that its node runs'
    assert messages[1] == f'no message on /in for 0 s ({no_publisher})'
    assert messages[3] == 'no message on /in for 0 s (1 publisher)'
    assert logged == [messages[1]]
    assert [{v.key: v.value for v in s.values}.get('seen') for s in statuses] == [
        '0',
        '0',
        '0',
        '0',
        '1',
    ]


class _Logger:
    """Records warnings."""

    def __init__(self, logged: list) -> None:
        self.warning = logged.append


@dataclass(frozen=True)
class Tunables:
    """Two parameters.

    Attributes:
        rate: a float.
        name: a string.
    """

    rate: float = 0.5
    name: str = 'x'


def _node_with(context, **overrides) -> rclpy.node.Node:
    parameters = [Parameter(name, value=value) for name, value in overrides.items()]
    return rclpy.create_node('tunable', context=context, parameter_overrides=parameters)


def test_a_float_parameter_takes_an_integer_and_none_can_be_changed_later(ros_context):
    node = _node_with(ros_context, rate=10)  # as `-p rate:=10` gives it
    config = processor_node.NodeParameters(node).config(Tunables)
    assert config == Tunables(rate=10.0) and isinstance(config.rate, float)
    assert node.describe_parameter('rate').description == 'a float.'
    (result,) = node.set_parameters([Parameter('rate', value=1.0)])
    assert not result.successful and 'read-only' in result.reason
    node.destroy_node()
    node = _node_with(ros_context, rate='fast')
    with pytest.raises(ConfigError, match="parameter rate must be a number, got 'fast'"):
        processor_node.NodeParameters(node).config(Tunables)
    node.destroy_node()
    node = _node_with(ros_context, name=3)  # a node would end in rclpy's traceback
    with pytest.raises(ConfigError, match="parameter 'name' to '3' of type 'INTEGER', expecting"):
        processor_node.NodeParameters(node).config(Tunables)
    node.destroy_node()


@dataclass(frozen=True)
class Checked:
    """One checked parameter.

    Attributes:
        share: in [0, 1].
    """

    share: float = 0.5

    def __post_init__(self) -> None:
        """Check the share."""
        check_fields(self, {'share': 0.0 <= self.share <= 1.0})


def test_a_value_out_of_range_is_named_as_its_parameter_live_and_offline(ros_context):
    node = _node_with(ros_context, **{'inner.share': 2.0})
    expected = r'^invalid parameter inner\.share = 2\.0: in \[0, 1\]\.$'  # its description
    with pytest.raises(ConfigError, match=expected):
        processor_node.NodeParameters(node).config(Checked, prefix='inner.')
    node.destroy_node()
    with pytest.raises(ConfigError, match=expected):
        OverrideParameters.parse(['inner.share=2']).config(Checked, prefix='inner.')


def test_a_parameters_file_nests_the_dotted_names_and_its_integers_are_floats(tmp_path):
    path = tmp_path / 'tunable.yaml'
    path.write_text('tunable:\n  ros__parameters:\n    rate: 3\n    inner:\n      share: 1\n')
    context = rclpy.Context()
    rclpy.init(args=['--ros-args', '--params-file', str(path)], context=context)
    try:
        node = rclpy.create_node('tunable', context=context)
        parameters = processor_node.NodeParameters(node)
        assert parameters.config(Tunables) == Tunables(rate=3.0)
        assert parameters.config(Checked, prefix='inner.') == Checked(share=1.0)
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


class Refusing(Doubling):
    """Refuses every number, naming it, as the trackers name a repeated image stamp."""

    def handle(self, topic, msg, wanted):
        """Refuse the number."""
        kind = 'repeats' if msg.data > 0 else 'went back'
        raise InputError(f'stamp {msg.data:.0f} ns {kind} (stamp {1e9 * msg.data:.3g})')


def test_problems_that_differ_in_their_numbers_alone_are_logged_as_one_kind(
    monkeypatch, ros_context
):
    node = _node_running(monkeypatch, ros_context, Refusing([]), 'refusing')
    logged: list = []
    try:
        monkeypatch.setattr(node, 'get_logger', lambda: _Logger(logged))
        for data in (1700000000017.0, 1700000000050.0, 2.5e-3, -1.0, -2.0):
            node._handle('in', Float64(data=data))
    finally:
        node.destroy_node()
    assert logged == [
        'in: stamp 1700000000017 ns repeats (stamp 1.7e+21)',
        'in: stamp -1 ns went back (stamp -1e+09)',
    ]


class CompressedDoubling(Doubling):
    """Doubling fed on an image-like topic's compressed transport and a plain input."""

    inputs = (Port('image/compressed', FLOAT, QosClass.SENSOR), Port('camera_info', FLOAT))


@pytest.mark.parametrize(
    ('remaps', 'expected'),
    [
        ([], ['/image/compressed', '/camera_info']),
        # image_transport's rule: the base's remapping carries to its compressed topic.
        (['image:=/cam/image_raw'], ['/cam/image_raw/compressed', '/camera_info']),
        (['image/compressed:=/other/c', 'image:=/cam/image_raw'], ['/other/c', '/camera_info']),
        (['camera_info:=/cam/camera_info'], ['/image/compressed', '/cam/camera_info']),
    ],
)
def test_a_compressed_input_follows_the_remapping_of_its_base_topic(monkeypatch, remaps, expected):
    context = rclpy.Context()
    rclpy.init(
        args=['--ros-args', *(arg for rule in remaps for arg in ('-r', rule))], context=context
    )
    try:
        node = _node_running(monkeypatch, context, CompressedDoubling([]), 'compressed')
        try:
            assert [s.topic_name for s in node._input_subscriptions] == expected
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


class Untracked(CountingDoubling):
    """CountingDoubling whose status warns as a tracker's does when it tracks nothing."""

    def __init__(self, events: list) -> None:
        """Count tracker results; feed them with :meth:`add`."""
        super().__init__(events)
        self.counts = TrackCounts('images')

    def warning(self):
        """The counts' warning."""
        return self.counts.warning()


def test_the_status_warns_while_a_tracker_tracks_nothing(monkeypatch, ros_context):
    """A tracker that never initialises (clicks that do not fit) was OK, 'running'."""
    processor = Untracked([])
    node = _node_running(monkeypatch, ros_context, processor, 'untracked')
    statuses: list = []
    try:
        monkeypatch.setattr(node._diagnostics, 'publish', lambda a: statuses.extend(a.status))
        reason = 'initialisation failed: the points do not fit'
        for _ in range(UNTRACKED_WARNING - 1):
            processor.counts.add(TrackStatus.INITIALIZING, reason)
        node._publish_status()
        processor.counts.add(TrackStatus.INITIALIZING, reason)
        node._publish_status()
        processor.counts.add(TrackStatus.TRACKING, '')
        node._publish_status()
    finally:
        node.destroy_node()
    assert [s.level for s in statuses] == [OK, WARN, OK]
    assert statuses[1].message == f'{UNTRACKED_WARNING} images in a row not tracked: {reason}'


def test_track_counts_count_each_status_and_warn_from_30_untracked_in_a_row():
    counts = TrackCounts('pairs')
    assert counts.report() == {
        'initializing_pairs': '0',
        'tracking_pairs': '0',
        'lost_pairs': '0',
        'last_reason': '-',
    }
    counts.add(TrackStatus.INITIALIZING, 'waiting for an initialisation')
    counts.add(TrackStatus.TRACKING, '')  # no reason: the last one stays
    for _ in range(29):  # 29 in a row after a tracked pair: no warning yet
        counts.add(TrackStatus.LOST, 'lost: residual too high')
    assert counts.warning() == ''
    counts.add(TrackStatus.LOST, 'lost: drifted')
    assert counts.warning() == '30 pairs in a row not tracked: lost: drifted'
    assert counts.report() == {
        'initializing_pairs': '1',
        'tracking_pairs': '1',
        'lost_pairs': '30',
        'last_reason': 'lost: drifted',
    }


def test_an_enum_parameter_is_given_by_its_member_s_name_live_and_offline(ros_context):
    """tracker.photometric, documented by name: GAIN_BIAS was refused.

    Live it was an INTEGER parameter; offline '2' was refused too (the enum called with text).
    """
    for value in ('GAIN_BIAS', 'gain_bias', 2):
        node = _node_with(ros_context, photometric=value)
        config = processor_node.NodeParameters(node).config(MonoTrackerConfig)
        assert config.photometric is PhotometricModel.GAIN_BIAS
        node.destroy_node()
        offline = OverrideParameters.parse([f'photometric={value}']).config(MonoTrackerConfig)
        assert offline.photometric is PhotometricModel.GAIN_BIAS
    node = _node_with(ros_context)
    assert processor_node.NodeParameters(node).config(MonoTrackerConfig).photometric is (
        PhotometricModel.GAIN_FIELD
    )
    node.destroy_node()
    expected = "parameter photometric = 'GAIN' is not one of NONE, BIAS, GAIN_BIAS, GAIN_FIELD"
    with pytest.raises(ConfigError, match=expected):
        OverrideParameters.parse(['photometric=GAIN']).config(MonoTrackerConfig)


def test_a_parameter_the_node_does_not_have_is_named_in_a_warning(ros_context):
    """A misspelt init_flie, which rclpy ignores, left the tracker waiting without a word.

    Setting it on the running node succeeded too, with no effect; now it is read-only, as the
    node's own parameters are, and its description says it is not used.
    """
    given = [
        Parameter('rate', value=3.0),
        Parameter('init_flie', value='clicks.yaml'),
        Parameter('nodez', value=[1, 2]),
    ]
    node = rclpy.create_node(
        'tunable', context=ros_context, parameter_overrides=given, **processor_node.DECLARE_GIVEN
    )
    logged: list = []
    try:
        parameters = processor_node.NodeParameters(node)
        assert parameters.config(Tunables) == Tunables(rate=3.0)
        assert node.describe_parameter('rate').description == 'a float.'
        node.get_logger = lambda: _Logger(logged)
        parameters.warn_unknown()
        assert node.get_parameter('init_flie').value == 'clicks.yaml'
        (result,) = node.set_parameters([Parameter('init_flie', value='other.yaml')])
        assert not result.successful and 'read-only' in result.reason
        expected = 'unknown to this node, not used (misspelt, or meant for another node?)'
        descriptors = node.describe_parameters(['init_flie', 'nodez'])
        assert [(d.name, d.type, d.description) for d in descriptors] == [
            ('init_flie', ParameterType.PARAMETER_STRING, expected),
            ('nodez', ParameterType.PARAMETER_INTEGER_ARRAY, expected),
        ]
    finally:
        node.destroy_node()
    assert logged == [
        'unknown parameters init_flie, nodez, not used (misspelt, or meant for another node?)'
    ]


def _node_given(monkeypatch, overrides: list[str]) -> processor_node.ProcessorNode:
    """A ProcessorNode around SensorCounting, given ``-p`` overrides, in a context of its own.

    The caller shuts down ``node.context``.
    """
    context = rclpy.Context()
    rclpy.init(args=['--ros-args', *(a for o in overrides for a in ('-p', o))], context=context)
    try:
        return _node_running(monkeypatch, context, SensorCounting([]), 'overridden')
    except BaseException:
        rclpy.try_shutdown(context=context)
        raise


def test_qos_overrides_of_the_node_s_topics_apply_and_others_are_named_unknown(monkeypatch):
    """ROS 2's qos_overrides parameters: a viewer that can only subscribe reliably.

    They were neither applied nor named in the unknown-parameter warning: `-p
    qos_overrides./face/overlay.publisher.reliability:=reliable` left the overlay best effort,
    without a word.
    """
    logged: list = []
    monkeypatch.setattr(rclpy.node.Node, 'get_logger', lambda _node: _Logger(logged))
    node = _node_given(
        monkeypatch,
        [
            'qos_overrides./in.subscription.reliability:=reliable',
            'qos_overrides./in.subscription.depth:=2',
            'qos_overrides./out.publisher.reliability:=best_effort',
            'qos_overrides./inn.subscription.reliability:=reliable',  # misspelt topic
        ],
    )
    try:
        (subscription,) = node._input_subscriptions
        assert subscription.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        assert subscription.qos_profile.depth == 2
        publisher = node._output_publishers['out']
        assert publisher.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
        assert publisher.qos_profile.depth == 10  # not overridden: the port's own
        # the shared profiles are left as they were (rclpy writes the overrides into the one given)
        assert processor_node.QOS_PROFILES[QosClass.SENSOR].depth == 5
        name = 'qos_overrides./in.subscription.depth'
        (result,) = node.set_parameters([Parameter(name, value=1)])
        assert not result.successful and 'read-only' in result.reason
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=node.context)
    assert logged == [
        'unknown parameter qos_overrides./inn.subscription.reliability, not used '
        '(misspelt, or meant for another node?)'
    ]


@pytest.mark.parametrize(
    ('override', 'expected'),
    [
        (
            'qos_overrides./in.subscription.reliability:=sometimes',
            'qos_overrides./in.subscription.reliability = sometimes: must be one of '
            'system_default, reliable, best_effort, best_available',
        ),
        (
            'qos_overrides./out.publisher.depth:=0',
            'qos_overrides./out.publisher.depth = 0: must be an integer >= 1',
        ),
        (
            "qos_overrides./out.publisher.depth:='3'",  # a string
            'qos_overrides./out.publisher.depth = 3: must be an integer >= 1',
        ),
    ],
)
def test_a_qos_override_rclpy_cannot_apply_is_refused_naming_it(monkeypatch, override, expected):
    """It was rclpy's RuntimeError (a bad name) or an AssertionError without a message (depth)."""
    with pytest.raises(ConfigError, match=f'^invalid parameter {re.escape(expected)}$'):
        _node_given(monkeypatch, [override])


def test_a_latched_sensor_input_is_watched_until_its_first_message(monkeypatch):
    """A camera_info published once (a static calibration, transient-local).

    The subscription could not be made transient-local (durability was not overridable), so
    the message never came; made so, the status warned 'no message on /in' for ever after it.
    """
    latched = [
        'qos_overrides./in.subscription.durability:=transient_local',
        'qos_overrides./in.subscription.reliability:=reliable',
    ]
    node = _node_given(monkeypatch, latched)
    statuses: list = []
    try:
        (subscription,) = node._input_subscriptions
        assert subscription.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
        monkeypatch.setattr(node._diagnostics, 'publish', lambda a: statuses.extend(a.status))
        monkeypatch.setattr(processor_node, 'SILENT_INPUT_S', 0.0)
        node._publish_status()  # nothing came yet: watched
        node._handle('in', Float64(data=1.0))
        node._publish_status()  # it came: nothing more is expected of it
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=node.context)
    assert [s.level for s in statuses] == [WARN, OK]
