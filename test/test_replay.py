"""Offline replay: topic matching, outputs and stamps, bad messages, truncated bags, Ctrl-C."""

from __future__ import annotations

from dataclasses import replace
import os
from pathlib import Path
import signal

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest

from face_tracking_ros import replay as replay_module
from face_tracking_ros.cli.main import main
from face_tracking_ros.cli.replay import describe, print_stats
from face_tracking_ros.data import default_model_path
from face_tracking_ros.errors import BagError, ConfigError, InputError
from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import BagWriter, read_messages
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.provenance import KEY as PROVENANCE_KEY
from face_tracking_ros.io.provenance import Provenance
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.model.model_file import load_model, save_model
from face_tracking_ros.processing.base import Output, Port, QosClass
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.replay import replay, replay_bag, resolve_inputs

from repo_root import REPO

IMAGE = 'sensor_msgs/msg/Image'
FLOAT = 'std_msgs/msg/Float64'


class MeanProcessor:
    """Publishes each image's mean grey level; rejects 'bad' frames; Ctrl-C on a chosen one."""

    def __init__(self, interrupt_at: int = -1) -> None:
        """Raise KeyboardInterrupt on the ``interrupt_at``-th message (1-based; -1: never)."""
        self.inputs = (Port('image', IMAGE, QosClass.SENSOR),)
        self.outputs = (Port('mean', FLOAT), Port('preview', FLOAT, on_demand=True))
        self._factory = RosbagsMessages(typestore())
        self._seen = 0
        self._interrupt_at = interrupt_at

    def handle(self, topic, msg, wanted):
        """Output the mean grey level of an image."""
        self._seen += 1
        if self._seen == self._interrupt_at:
            raise KeyboardInterrupt
        if msg.header.frame_id == 'bad':
            raise InputError('frame marked bad')
        mean = float(conversions.image_to_gray(msg).mean())
        outputs = [Output('mean', self._factory.make(FLOAT, data=mean))]
        if 'preview' in wanted:
            outputs.append(Output('preview', self._factory.make(FLOAT, data=-mean)))
        return outputs


class CountingProcessor(MeanProcessor):
    """A MeanProcessor that reports how many messages it has seen (processing.base.Reporting)."""

    def status(self):
        """The count, as a diagnostic value."""
        return {'seen': str(self._seen)}


def _write_images(
    path: Path, count: int, topic: str = '/cam/image', size: tuple[int, int] = (24, 32)
) -> list[int]:
    factory = RosbagsMessages(typestore())
    stamps = [1_000_000_000 + 33_000_000 * i for i in range(count)]
    with BagWriter(path) as bag:
        for i, stamp in enumerate(stamps):
            frame = 'bad' if i == 3 else 'cam'
            header = conversions.make_header(factory, stamp, frame)
            pixels = np.full(size, i, dtype=np.uint8)
            bag.write(topic, IMAGE, conversions.array_to_image(factory, header, pixels), stamp)
    return stamps


def _run(bag: Path, out: Path, processor: MeanProcessor):
    with BagWriter(out) as writer:
        return replay([processor], read_messages(bag), writer.write, {'/cam/image': 'image'})


def test_inputs_match_by_name_then_by_type():
    ports = [Port('image', IMAGE), Port('camera_info', 'sensor_msgs/msg/CameraInfo')]
    topics = {'/cam/image': IMAGE, '/cam/info': 'sensor_msgs/msg/CameraInfo', '/x': FLOAT}
    assert resolve_inputs(ports, topics, {}) == {'/cam/image': 'image', '/cam/info': 'camera_info'}


def test_a_topic_another_port_has_by_name_is_not_matched_by_type_too():
    info = 'sensor_msgs/msg/CameraInfo'
    ports = [Port('left/camera_info', info), Port('right/camera_info', info)]
    assert resolve_inputs(ports, {'/stereo/left/camera_info': info}, {}) == {
        '/stereo/left/camera_info': 'left/camera_info'  # the right port stays without
    }


def test_ambiguous_topics_are_left_unmatched():
    topics = {'/a/raw': IMAGE, '/b/raw': IMAGE}
    assert resolve_inputs([Port('image', IMAGE)], topics, {}) == {}
    assert resolve_inputs([Port('image', IMAGE)], topics, {'image': '/b/raw'}) == {
        '/b/raw': 'image'
    }


def test_a_remap_matches_the_bag_s_topic_with_or_without_its_leading_slash():
    topics = {'/a/raw': IMAGE, 'b/raw': IMAGE}
    for given, expected in (('a/raw', '/a/raw'), ('/b/raw', 'b/raw'), ('/a/raw', '/a/raw')):
        assert resolve_inputs([Port('image', IMAGE)], topics, {'image': given}) == {
            expected: 'image'
        }
    with pytest.raises(BagError, match=r"'/c/raw' .*: no such topic \(the bag has /a/raw, b/raw"):
        resolve_inputs([Port('image', IMAGE)], topics, {'image': '/c/raw'})


def test_remap_to_a_topic_of_another_type_is_refused():
    with pytest.raises(
        BagError, match="topic '/x' for input 'image' must be sensor_msgs/msg/Image"
    ):
        resolve_inputs([Port('image', IMAGE)], {'/x': FLOAT}, {'image': '/x'})


def test_a_remap_of_an_input_the_nodes_lack_is_refused_naming_their_inputs(tmp_path, capsys):
    """It was silently ignored (a misspelt input read the topic matched by name instead)."""
    mono = str(Path(__file__).resolve().parents[1] / 'bags' / 'mono_test' / 'subject_00_seq_00')
    remap = ['--remap', 'nosuch=image']
    for argv in (
        ['replay', 'mono_tracker', mono, '--out', str(tmp_path / 'a'), *remap],
        ['track', mono, '--simulate-clicks', '1', '--out', str(tmp_path / 'b'), *remap],
    ):
        assert main(argv) == 2
        assert capsys.readouterr().err == (
            "error: remap nosuch=image: 'nosuch' is not an input of mono_tracker; its inputs "
            'from the bag are camera_info, face/model, image\n'
        )
    assert not (tmp_path / 'a').exists() and not (tmp_path / 'b').exists()
    graph = ['replay', 'mono_tracker,expression_recognizer', mono, '--out', str(tmp_path / 'c')]
    assert main([*graph, '--remap', 'face/state=face/state']) == 2  # made by the tracker
    error = capsys.readouterr().err
    assert "'face/state' is not an input of mono_tracker, expression_recognizer; their" in error


def test_one_topic_for_two_inputs_is_refused():
    """The second input took the topic from the first: a stereo pair of one camera, unnamed."""
    ports = [Port('left/image_raw', IMAGE), Port('right/image_raw', IMAGE)]
    topics = {'/cam/left': IMAGE, '/cam/right': IMAGE}
    both = {'left/image_raw': '/cam/left', 'right/image_raw': 'cam/left'}
    with pytest.raises(
        ConfigError,
        match="topic '/cam/left' would feed both inputs 'left/image_raw' and 'right/image_raw'",
    ):
        resolve_inputs(ports, topics, both)
    # A topic given to one input is not matched by type to another too.
    assert resolve_inputs(ports, {'/image': IMAGE}, {'left/image_raw': 'image'}) == {
        '/image': 'left/image_raw'
    }


def test_an_input_two_nodes_read_is_one_input_fed_to_both(tmp_path, capsys):
    """Both recognisers read face/state: the demo's replay of them was refused.

    As one topic for two inputs, 'face/state' and 'face/state'.
    """
    _write_states(tmp_path / 'tracked')
    argv = ['replay', 'expression_recognizer,identity_recognizer', str(tmp_path / 'tracked')]
    assert main([*argv, '--out', str(tmp_path / 'out'), '--quiet']) == 0
    assert 'read: 3 face/state\n' in capsys.readouterr().out


def _write_states(path: Path, provenance: Provenance | None = None) -> None:
    """Three FaceState messages, as a tracker's replay made them if ``provenance`` is given."""
    factory = RosbagsMessages(typestore())
    state_type = 'face_tracking_msgs/msg/FaceState'
    with BagWriter(path) as bag:
        for i in range(3):
            header = conversions.make_header(factory, 1000 + i, 'camera')
            bag.write('face/state', state_type, factory.make(state_type, header=header), 1000 + i)
        if provenance is not None:
            bag.set_custom_data(PROVENANCE_KEY, provenance.text())


def test_recognisers_over_tracks_of_another_face_model_are_refused(tmp_path, capsys):
    """The recognisers read the tracks' sigma and alpha with their own model_file.

    Replayed without it over tracks of another model, they read that model's coefficients with
    the packaged one: identities and expression events came out wrong without a word.
    """
    default = load_model(default_model_path())
    other = save_model(replace(default, shape_basis=-default.shape_basis), tmp_path / 'other.npz')
    camera = tmp_path / 'camera'
    _write_states(tmp_path / 'packaged', Provenance.of(camera, ['mono_tracker'], {}))
    _write_states(
        tmp_path / 'other', Provenance.of(camera, ['mono_tracker'], {'model_file': str(other)})
    )
    graph = 'expression_recognizer,identity_recognizer'
    assert main(['replay', graph, str(tmp_path / 'packaged'), '--out', str(tmp_path / 'a')]) == 0
    capsys.readouterr()
    assert main(['replay', graph, str(tmp_path / 'other'), '--out', str(tmp_path / 'b')]) == 2
    assert capsys.readouterr().err == (
        f'error: {tmp_path / "other"} was tracked with the face model {other}, not '
        f'{default_model_path()}: give that model\n'
    )
    assert not (tmp_path / 'b').exists()
    given = ['--param', f'model_file={other}', '--out', str(tmp_path / 'c'), '--quiet']
    assert main(['replay', 'identity_recognizer', str(tmp_path / 'other'), *given]) == 0


def test_replay_writes_one_output_per_good_frame_at_the_input_stamp(tmp_path):
    stamps = _write_images(tmp_path / 'in', 8)
    stats = _run(tmp_path / 'in', tmp_path / 'out', MeanProcessor())
    assert stats.inputs['image'] == 8
    assert stats.outputs['mean'] == 7
    assert stats.errors == {'image: frame marked bad': 1}
    assert stats.summary(tmp_path / 'out') == [
        'read: 8 image',
        f'wrote to {tmp_path / "out"}: 7 mean',
        'input problems, each kind as its first message (the live node reports these on'
        ' /diagnostics):',
        '  1x image: frame marked bad',
    ]
    written = list(read_messages(tmp_path / 'out'))
    assert [m.stamp_ns for m in written] == stamps[:3] + stamps[4:]
    assert [m.msg.data for m in written] == [0, 1, 2, 4, 5, 6, 7]


def test_a_replay_ends_with_what_the_reporting_processors_report(tmp_path, monkeypatch, capsys):
    _write_images(tmp_path / 'in', 5)
    monkeypatch.setattr(
        replay_module, 'processor_factory', lambda _node: lambda _params, _f: CountingProcessor()
    )
    params = OverrideParameters.parse([])
    stats = replay_bag(['counter'], tmp_path / 'in', tmp_path / 'out', params, progress=False)
    assert stats.status == {'counter': {'seen': '5'}}
    print_stats(stats, tmp_path / 'out')
    assert 'counter: seen 5' in capsys.readouterr().out


@pytest.mark.parametrize('progress', [True, False])
def test_the_progress_bar_counts_the_messages_on_stderr_only_when_asked(
    tmp_path, monkeypatch, capsys, progress
):
    _write_images(tmp_path / 'in', 5)
    monkeypatch.setattr(
        replay_module, 'processor_factory', lambda _node: lambda _params, _f: CountingProcessor()
    )
    params = OverrideParameters.parse([])
    replay_bag(['counter'], tmp_path / 'in', tmp_path / 'out', params, progress=progress)
    err = capsys.readouterr().err
    assert ('| 5/5 [' in err) if progress else (err == '')


def test_a_tracker_that_tracked_none_of_the_last_images_warns_as_the_live_status_does(
    tmp_path, capsys
):
    bag = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'  # 30 images, no initialisation given
    assert (
        main(['replay', 'mono_tracker', str(bag), '--out', str(tmp_path / 'out'), '--quiet']) == 0
    )
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1] == (
        'mono_tracker: warning: 30 images in a row not tracked: waiting for an initialisation '
        '(init points or a detection)'
    )


def test_a_replay_given_the_bag_topics_does_not_read_them_again(tmp_path, monkeypatch):
    """A caller that read the bag's topics (track, learn) hands them over: read once."""
    _write_images(tmp_path / 'in', 5)
    monkeypatch.setattr(
        replay_module, 'processor_factory', lambda _node: lambda _params, _f: CountingProcessor()
    )

    def read_again(bag):
        raise AssertionError(f'the topics of {bag} read again')

    monkeypatch.setattr(replay_module, 'bag_topics', read_again)
    params = OverrideParameters.parse([])
    topics = {'/cam/image': IMAGE}
    stats = replay_bag(
        ['counter'], tmp_path / 'in', tmp_path / 'out', params, progress=False, topics=topics
    )
    assert stats.inputs == {'image': 5} and stats.status == {'counter': {'seen': '5'}}


def test_truncated_input_bag_is_replayed_up_to_the_damage(tmp_path):
    _write_images(tmp_path / 'in', 40, size=(240, 320))  # ~3 MB: several MCAP chunks
    mcap_file = next((tmp_path / 'in').glob('*.mcap'))
    data = mcap_file.read_bytes()
    mcap_file.write_bytes(data[: len(data) // 2])
    stats = _run(tmp_path / 'in', tmp_path / 'out', MeanProcessor())
    assert stats.read_error, 'a truncated bag must be reported'
    assert 0 < stats.inputs['image'] < 40
    # The output bag is complete and readable by an independent reader.
    with open(next((tmp_path / 'out').glob('*.mcap')), 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        means = [msg.data for _, _, _, msg in reader.iter_decoded_messages()]
    assert len(means) == stats.outputs['mean']


class TerminatedProcessor(MeanProcessor):
    """A MeanProcessor whose process receives SIGTERM (timeout, a CI runner) at one message."""

    def handle(self, topic, msg, wanted):
        """As MeanProcessor, but SIGTERM to this process on the 11th message."""
        if self._seen == 10:
            os.kill(os.getpid(), signal.SIGTERM)
        return super().handle(topic, msg, wanted)


def test_sigterm_stops_the_command_as_ctrl_c_does_leaving_a_valid_bag(tmp_path, monkeypatch):
    _write_images(tmp_path / 'in', 20)
    monkeypatch.setattr(
        replay_module, 'processor_factory', lambda _node: lambda _p, _f: TerminatedProcessor()
    )
    node = 'mono_tracker'  # a registered name; its processor is replaced
    argv = ['replay', node, str(tmp_path / 'in'), '--out', str(tmp_path / 'out'), '--quiet']
    assert main(argv) == 1  # interrupted
    means = [m.msg.data for m in read_messages(tmp_path / 'out')]
    assert means == [0, 1, 2, 4, 5, 6, 7, 8, 9, 10]  # the 11th image's output, then stopped
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL  # restored after the command


class SignalledProcessor(MeanProcessor):
    """A MeanProcessor that sends its process SIGINT part way through the 11th message."""

    def __init__(self, signals: int) -> None:
        """Send SIGINT this many times on the 11th message."""
        super().__init__()
        self._signals = signals

    def handle(self, topic, msg, wanted):
        """As MeanProcessor, with the signals sent part way through the 11th message."""
        if self._seen == 10:
            for _ in range(self._signals):
                os.kill(os.getpid(), signal.SIGINT)
        return super().handle(topic, msg, wanted)


@pytest.mark.parametrize(
    ('signals', 'means'), [(1, [*range(3), *range(4, 11)]), (2, [0, 1, 2, 4, 5, 6, 7, 8, 9])]
)
def test_ctrl_c_stops_after_the_input_it_came_in_and_twice_at_once(tmp_path, signals, means):
    """A Ctrl-C part way through an input cut its outputs short.

    The output bag then held face/state but not face/pose of the last image, and the tracker's
    counts were one image ahead of it. A second Ctrl-C is for an input that does not end.
    """
    _write_images(tmp_path / 'in', 20)
    stats = _run(tmp_path / 'in', tmp_path / 'out', SignalledProcessor(signals))
    assert stats.interrupted
    assert stats.inputs['image'] == 11
    assert [m.msg.data for m in read_messages(tmp_path / 'out')] == means
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored


class DoublingProcessor:
    """Consumes MeanProcessor's output and doubles it: a second node in the graph."""

    def __init__(self) -> None:
        """Read 'mean', write 'double'."""
        self.inputs = (Port('mean', FLOAT),)
        self.outputs = (Port('double', FLOAT),)
        self._factory = RosbagsMessages(typestore())

    def handle(self, topic, msg, wanted):
        """Output twice the input."""
        return [Output('double', self._factory.make(FLOAT, data=2 * msg.data))]


def test_outputs_of_one_processor_feed_the_next(tmp_path):
    _write_images(tmp_path / 'in', 5)
    fired = []
    with BagWriter(tmp_path / 'out') as writer:
        stats = replay(
            [MeanProcessor(), DoublingProcessor()],
            read_messages(tmp_path / 'in'),
            writer.write,
            {'/cam/image': 'image'},
            on_output=lambda output, stamp: fired.append((output.topic, output.msg.data)),
        )
    assert stats.outputs == {'mean': 4, 'double': 4}
    assert fired[:4] == [('mean', 0), ('double', 0), ('mean', 1), ('double', 2)]
    doubled = [m.msg.data for m in read_messages(tmp_path / 'out', topics=['double'])]
    assert doubled == [0, 2, 4, 8]  # frame 3 is rejected by MeanProcessor


class HoldingProcessor(MeanProcessor):
    """MeanProcessor holding its outputs back until the end of the stream (Finishing)."""

    def __init__(self, interrupt_at: int = -1) -> None:
        """Nothing held yet."""
        super().__init__(interrupt_at)
        self._held: list[Output] = []

    def handle(self, topic, msg, wanted):
        """Hold the outputs."""
        self._held += super().handle(topic, msg, wanted)
        return []

    def finish(self):
        """The held outputs."""
        held, self._held = self._held, []
        return held


def test_outputs_held_to_the_end_are_written_and_fed_on_at_the_last_stamp(tmp_path):
    stamps = _write_images(tmp_path / 'in', 5)
    with BagWriter(tmp_path / 'out') as writer:
        stats = replay(
            [HoldingProcessor(), DoublingProcessor()],
            read_messages(tmp_path / 'in'),
            writer.write,
            {'/cam/image': 'image'},
        )
    assert stats.outputs == {'mean': 4, 'double': 4}
    written = list(read_messages(tmp_path / 'out'))
    assert [(m.topic, m.msg.data) for m in written] == [
        *(('mean', value) for value in (0, 1, 2, 4)),
        *(('double', value) for value in (0, 2, 4, 8)),
    ]
    assert {m.stamp_ns for m in written} == {stamps[-1]}


@pytest.mark.parametrize('processor', [MeanProcessor, HoldingProcessor])
def test_ctrl_c_leaves_a_valid_output_bag_with_the_outputs_until_then(tmp_path, processor):
    """Outputs written as they come (MeanProcessor) or held until then (HoldingProcessor)."""
    _write_images(tmp_path / 'in', 20)
    stats = _run(tmp_path / 'in', tmp_path / 'out', processor(interrupt_at=11))
    assert stats.interrupted
    assert [m.msg.data for m in read_messages(tmp_path / 'out')] == [0, 1, 2, 4, 5, 6, 7, 8, 9]


class DeferringProcessor(MeanProcessor):
    """MeanProcessor with work left until a message's outputs are out (Deferring)."""

    def __init__(self, events: list) -> None:
        """Record each run of the deferred work in ``events``; the second one fails."""
        super().__init__()
        self._events = events
        self._runs = 0

    def run_deferred(self):
        """Record the run."""
        self._runs += 1
        self._events.append(('deferred', self._runs))
        if self._runs == 2:
            raise InputError('deferred work failed')


def test_deferred_work_runs_once_each_message_s_outputs_are_written(tmp_path):
    # As the node publishes before it runs the deferred work; a failure there is counted.
    _write_images(tmp_path / 'in', 5)
    events = []
    with BagWriter(tmp_path / 'out') as writer:
        stats = replay(
            [DeferringProcessor(events)],
            read_messages(tmp_path / 'in'),
            writer.write,
            {'/cam/image': 'image'},
            on_output=lambda output, _stamp: events.append(('mean', output.msg.data)),
        )
    assert events == [
        *(('mean', 0), ('deferred', 1), ('mean', 1), ('deferred', 2)),
        *(('mean', 2), ('deferred', 3), ('deferred', 4), ('mean', 4), ('deferred', 5)),
    ]  # frame 3 is rejected by MeanProcessor, its deferred work runs all the same
    assert stats.errors == {'image: deferred work failed': 1, 'image: frame marked bad': 1}
    assert [m.msg.data for m in read_messages(tmp_path / 'out')] == [0, 1, 2, 4]


def test_on_demand_outputs_only_when_wanted(tmp_path):
    _write_images(tmp_path / 'in', 3)
    for wanted, expected in (
        (frozenset(), {'mean': 3}),
        (frozenset({'preview'}), {'mean': 3, 'preview': 3}),
    ):
        out = tmp_path / f'out_{len(wanted)}'
        with BagWriter(out) as writer:
            stats = replay(
                [MeanProcessor()],
                read_messages(tmp_path / 'in'),
                writer.write,
                {'/cam/image': 'image'},
                wanted=wanted,
            )
        assert stats.outputs == expected


def test_a_misspelt_wanted_or_echoed_topic_is_named(tmp_path, monkeypatch, capsys):
    _write_images(tmp_path / 'in', 3)
    monkeypatch.setattr(
        replay_module, 'processor_factory', lambda _node: lambda _p, _f: MeanProcessor()
    )
    replay = ['replay', 'mono_tracker', str(tmp_path / 'in'), '--quiet', '--out']
    assert main([*replay, str(tmp_path / 'a'), '--want', 'previw']) == 2
    expected = 'previw: not an on-demand output of mono_tracker (they have preview)'
    assert expected in capsys.readouterr().err
    assert main([*replay, str(tmp_path / 'b'), '--echo', 'men']) == 0
    assert '--echo men: nothing was produced on it (outputs: mean)' in capsys.readouterr().out


def test_echo_prints_each_output_timed_from_the_bags_first_message(tmp_path, monkeypatch, capsys):
    _write_images(tmp_path / 'in', 5)  # 33 ms apart; frame 3 is marked bad: no output
    monkeypatch.setattr(
        replay_module, 'processor_factory', lambda _node: lambda _p, _f: MeanProcessor()
    )
    argv = ['replay', 'mono_tracker', str(tmp_path / 'in'), '--quiet', '--out']
    assert main([*argv, str(tmp_path / 'out'), '--echo', 'mean']) == 0
    echoed = [line for line in capsys.readouterr().out.splitlines() if line.startswith('t=')]
    assert [line[:33] for line in echoed] == [
        f't={seconds:8.3f} s  mean               ' for seconds in (0.0, 0.033, 0.066, 0.132)
    ]
    assert [line[33:].split('data=')[1][:3] for line in echoed] == ['0.0', '1.0', '2.0', '4.0']


def test_an_echoed_event_is_one_line_of_its_fields():
    factory = RosbagsMessages(typestore())
    expression = 'face_tracking_msgs/msg/ExpressionEvent'
    onset = factory.make(expression, label='smile', event=0, confidence=0.9, duration=0.0)
    offset = factory.make(expression, label='smile', event=1, confidence=0.8, duration=1.25)
    identity = factory.make(
        'face_tracking_msgs/msg/IdentityEvent', identity='ann', distance=1.5, confidence=0.75
    )
    assert describe(onset) == 'ONSET  smile      confidence 0.90 duration 0.00 s'
    assert describe(offset) == 'OFFSET smile      confidence 0.80 duration 1.25 s'
    assert describe(identity) == 'ann          distance 1.50 confidence 0.75'


def test_a_node_named_twice_is_refused_before_any_work(tmp_path, capsys):
    _write_images(tmp_path / 'in', 3)
    argv = ['replay', 'mono_tracker,expression_recognizer, mono_tracker', str(tmp_path / 'in')]
    with pytest.raises(SystemExit) as exit_info:
        main([*argv, '--out', str(tmp_path / 'out')])
    assert exit_info.value.code == 2
    assert (
        "node mono_tracker named more than once in 'mono_tracker,expression_recognizer, "
        "mono_tracker': a node runs once"
    ) in capsys.readouterr().err
    assert not (tmp_path / 'out').exists()


def test_a_tracker_fed_one_camera_of_a_pair_is_refused(tmp_path, capsys):
    """A mono bag's image fed the stereo_tracker's left port by type: nothing paired, exit 0."""
    mono = str(Path(__file__).resolve().parents[1] / 'bags' / 'mono_test' / 'subject_00_seq_00')
    assert main(['replay', 'stereo_tracker', mono, '--out', str(tmp_path / 'a')]) == 2
    assert capsys.readouterr().err == (
        f"error: {mono}: no topic for the stereo_tracker's right/image_raw (left/image_raw reads "
        "image; matched by a name ending in it, else give --remap INPUT=TOPIC); the bag's "
        'images: image\n'
    )
    assert not (tmp_path / 'a').exists()


def test_a_tracker_whose_camera_info_the_bag_holds_under_other_names_is_refused(tmp_path, capsys):
    """Two CameraInfo topics, neither chosen by name or type: the tracker read none.

    It held every image and said 'no calibration on camera_info yet' of a bag that has two.
    """
    stereo = str(REPO / 'bags' / 'stereo_train' / 'subject_00_seq_00')
    argv = ['replay', 'mono_tracker', stereo, '--remap', 'image=left/image_raw', '--quiet']
    assert main([*argv, '--out', str(tmp_path / 'a')]) == 2
    assert capsys.readouterr().err == (
        f"error: {stereo}: no topic for the mono_tracker's camera_info (image reads "
        'left/image_raw; matched by a name ending in it, else give --remap INPUT=TOPIC); the '
        "bag's camera_info topics: left/camera_info, right/camera_info\n"
    )
    assert not (tmp_path / 'a').exists()
    remapped = [*argv, '--remap', 'camera_info=left/camera_info', '--out', str(tmp_path / 'b')]
    assert main(remapped) == 0
    assert 'read: 10 camera_info, 10 image' in capsys.readouterr().out


def _problem_lines(stats: replay_module.ReplayStats) -> list[str]:
    """The summary's lines after its heading of input problems."""
    lines = stats.summary(Path('o'))
    heading = (
        'input problems, each kind as its first message (the live node reports these on'
        ' /diagnostics):'
    )
    return lines[lines.index(heading) + 1 :]


def test_a_summary_counts_messages_alike_but_for_their_numbers_as_one_problem():
    """A camera that repeats every stamp made one line per image: each text names its stamp."""
    stats = replay_module.ReplayStats()
    for i in range(25):
        stats.count_error(f'image: image stamp {i}.5 s repeats the previous image stamp')
    for _ in range(3):
        stats.count_error('image: unsupported image encoding 16UC1')
    stats.count_error('image: unsupported image encoding mono16')
    stats.count_error('camera_info: K holds NaN')
    assert _problem_lines(stats) == [
        '  25x image: image stamp 0.5 s repeats the previous image stamp',
        '  3x image: unsupported image encoding 16UC1',
        '  1x image: unsupported image encoding mono16',
        '  1x camera_info: K holds NaN',
    ]


def test_a_summary_lists_ten_kinds_of_problem_and_counts_the_rest():
    stats = replay_module.ReplayStats()
    names = 'abcdefghijklmn'  # 14 kinds: topic names differ by letters, not numbers
    for count, name in enumerate(names, start=1):
        for _ in range(count):
            stats.count_error(f'image_{name}: unsupported image encoding')
    problems = _problem_lines(stats)
    assert problems[:10] == [
        f'  {14 - k}x image_{names[13 - k]}: unsupported image encoding' for k in range(10)
    ]
    assert problems[10:] == ['  ... 4 other kinds of problem (10 messages)']  # 4 + 3 + 2 + 1
    stats = replay_module.ReplayStats()
    for name in names[:11]:  # 11 kinds of one message each
        stats.count_error(f'image_{name}: unsupported image encoding')
    assert _problem_lines(stats)[10:] == ['  ... 1 other kind of problem (1 message)']
