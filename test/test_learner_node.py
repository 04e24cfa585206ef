"""The learner node learns from bags, writes the model and serves it latched on face/model."""

from __future__ import annotations

from dataclasses import fields
import shutil
import signal
import time

from bag_processes import finish, start_node
from face_tracking_msgs.msg import FaceModel
import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from face_tracking_ros.cli import learn as learn_command
from face_tracking_ros.cli.main import build_parser
from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io import conversions
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.nodes.learner import LearnerConfig, learn_options
from face_tracking_ros.nodes.processor_node import QOS_PROFILES
from face_tracking_ros.pipelines.learn import learn_from_bags
from face_tracking_ros.pipelines.learn_options import LearnOptions
from face_tracking_ros.processing.base import QosClass

from repo_root import REPO

WAIT_S = 90.0


def test_model_reaches_a_subscriber_that_starts_after_it_was_published(ros_context, tmp_path):
    output = tmp_path / 'model.npz'
    process = start_node(
        'learner', bag_dir=REPO / 'bags' / 'stereo_train', output=output, method='seed', p=1
    )
    try:
        deadline = time.monotonic() + WAIT_S
        while not output.exists():  # learned and written: the message is out before we listen
            assert process.poll() is None, finish(process)[1]
            assert time.monotonic() < deadline, 'the learner wrote no model'
            time.sleep(0.2)
        time.sleep(1.0)
        node = Node('late_tracker', context=ros_context)
        executor = SingleThreadedExecutor(context=ros_context)
        executor.add_node(node)
        received = []
        node.create_subscription(
            FaceModel, 'face/model', received.append, QOS_PROFILES[QosClass.LATCHED]
        )
        while not received:
            assert time.monotonic() < deadline, 'no model on face/model'
            executor.spin_once(timeout_sec=0.1)
        executor.shutdown()
        node.destroy_node()
    finally:
        code, log = finish(process, stop=signal.SIGINT)
    assert code == 0, log
    published = conversions.model_from_msg(received[0])
    written = load_model(output)
    assert published.method == written.method == 'seed'
    assert published.node_names == written.node_names
    np.testing.assert_array_equal(published.shape_basis, written.shape_basis)
    assert output.with_suffix('.json').exists()


def test_tracker_params_reach_the_stereo_tracking_of_learn():
    config = LearnerConfig(bags=('a', 'b'), tracker_params=('retroactive_depths=false', 'x=1'))
    options = learn_options(config)
    assert [str(bag) for bag in options.bags] == ['a', 'b']
    assert options.tracker_params == ('retroactive_depths=false', 'x=1')
    assert learn_options(LearnerConfig(bags=('a',))).tracker_params == ()
    automatic = LearnerConfig(bags=('a',), auto_init=True, from_images=True)
    options = learn_options(automatic)
    assert options.auto_init and options.from_images
    assert (options.left_topic, options.right_topic, options.left_info_topic) == (None, None, None)
    topics = LearnerConfig(bags=('a',), left_topic='/c0', right_topic='/c1', right_info_topic='/i')
    options = learn_options(topics)
    given = (
        options.left_topic,
        options.right_topic,
        options.left_info_topic,
        options.right_info_topic,
    )
    assert given == ('/c0', '/c1', None, '/i')


def test_the_node_learns_by_default_as_face_tracking_learn_does():
    """Both keep their own defaults (p, q, method...); docs/learning.md gives --p 2 --q 5."""
    argv = ['learn', 'a', '--out', 'face_model.npz', '--report', 'face_model.json']
    command = learn_command.learn_options(build_parser().parse_args(argv))
    node = learn_options(LearnerConfig(bags=('a',)))
    names = [field.name for field in fields(LearnOptions)]
    differ = {name for name in names if getattr(command, name) != getattr(node, name)}
    assert differ == {'compare', 'named'}  # the node evaluates only its method; its names
    assert (command.p, command.q, command.method, command.neutral_frames) == (2, 5, 'joint', 0)


def test_the_learning_pipeline_names_the_nodes_parameters_not_the_commands_options(tmp_path):
    """Its messages said face-tracking learn's --out, --init-dir... to a user of parameters."""
    bag = REPO / 'bags' / 'stereo_train' / 'subject_00_seq_00'
    model, notes = tmp_path / 'm.npz', tmp_path / 'notes.npz'
    notes.write_text('notes')
    same = {'left_topic': 'left/image_raw', 'right_topic': 'left/image_raw'}
    cases = [
        ({'output': str(notes)}, f'parameter output {notes} exists and is not a face model ('),
        (
            {'report': str(model)},
            f'parameter output and parameter report are both {model}: the report would',
        ),
        ({'subject_pattern': '('}, "parameter subject_pattern '(': not a regular expression"),
        (
            {'from_images': True},
            f'{bag} holds raw stereo images: give its initialisation with parameter init_dir (a '
            'subject_00_seq_00.yaml node-name -> pixel file), parameter auto_init (the optional '
            'landmark detector) or, for synthetic bags, parameter simulate_clicks',
        ),
        ({'from_images': True, 'init_dir': str(tmp_path)}, f'in parameter init_dir {tmp_path},'),
        (
            {'from_images': True, **same},
            'parameter left_topic and parameter right_topic are both left/image_raw',
        ),
    ]
    for given, expected in cases:
        config = LearnerConfig(bags=(str(bag),), **{'output': str(model), **given})
        with pytest.raises(ConfigError) as error:
            learn_from_bags(learn_options(config), say=lambda _: None)
        assert expected in str(error.value) and '--' not in str(error.value), given


def test_a_bag_it_cannot_read_is_one_error_line_and_exit_code_2(tmp_path):
    code, output = finish(start_node('learner', bags=[str(tmp_path / 'nope')]))
    assert code == 2
    assert f'{tmp_path}/nope: cannot read bag' in output and 'Traceback' not in output


def test_a_learner_parameter_out_of_range_is_named_before_any_work():
    process = start_node('learner', bags=['no_such_bag'], method='jiont')
    code, output = finish(process)
    assert code == 2
    assert 'invalid parameter method = ' in output and "'jiont'" in output
    assert 'usage:' not in output and 'Traceback' not in output


def test_a_run_whose_report_is_in_bag_dir_learns_again_past_its_meshes(tmp_path, capsys):
    """bag_dir took every sub-directory for a bag: the second run read the first's meshes.

    The meshes of raw stereo bags go beside the report (<report name>_meshes/, clicks in
    <report name>_meshes_clicks/): written in bag_dir, the second run stopped at 'm_meshes: not
    a rosbag2 bag (...); it holds 3 bags'. An empty directory (a drive's lost+found) is no
    bag either.
    """
    recordings = tmp_path / 'recordings'
    bags = sorted((REPO / 'bags' / 'stereo_train').glob('subject_*'))
    for bag in bags:
        shutil.copytree(bag, recordings / bag.name)
    (recordings / 'lost+found').mkdir()
    output = recordings / 'm.npz'
    config = LearnerConfig(
        bag_dir=str(recordings),
        output=str(output),
        from_images=True,
        simulate_clicks=0.0,
        method='seed',
        p=1,
    )
    for _ in range(2):
        options = learn_options(config)
        assert [bag.name for bag in options.bags] == [bag.name for bag in bags]
        assert learn_from_bags(options, say=lambda _: None) == output  # as the node publishes it
        assert load_model(output).method == 'seed'
    skipped = f'parameter bag_dir: {recordings}: skipped lost+found (sub-directories without'
    first, second = capsys.readouterr().out.splitlines()
    assert first.startswith(skipped) and first.endswith('metadata.yaml or .mcap files)')
    assert second == first.replace('lost+found', 'lost+found, m_meshes, m_meshes_clicks')
