"""Every processing node starts with its default parameters, runs, and stops cleanly on SIGINT."""

from __future__ import annotations

import signal
import time

from bag_processes import finish, start_node
import pytest

UP_S = 4.0
NODES = ('mono_tracker', 'stereo_tracker', 'expression_recognizer', 'identity_recognizer')


@pytest.mark.parametrize('node', NODES)
def test_node_starts_with_defaults_and_stops_on_sigint(node):
    process = start_node(node)
    time.sleep(UP_S)
    running = process.poll() is None
    code, output = finish(process, stop=signal.SIGINT)
    assert running, f'{node} exited at start-up:\n{output}'
    assert code == 0, output
    assert 'Traceback' not in output, output


def test_node_with_a_bad_parameter_says_so_and_exits_2():
    process = start_node('mono_tracker', **{'tracker.epsilon': 1.5})
    code, output = finish(process)
    assert code == 2
    # with its description: the node's parameter descriptions are gone with it
    expected = 'invalid parameter tracker.epsilon = 1.5: drift-monitoring weight epsilon of eq. 6'
    assert f'{expected}, in [0, 1] (seed: 0.2).\n' in output
    assert 'Traceback' not in output


def test_a_renamed_node_names_itself_in_its_start_up_error():
    """The error line carries the name and namespace given on the command line.

    It said ``[mono_tracker]`` whatever the node was renamed to, where every later line of a
    node that starts says the name it runs under.
    """
    remaps = ('__node:=face_cam', '__ns:=/robot')
    code, output = finish(start_node('mono_tracker', remaps, **{'tracker.epsilon': 1.5}))
    assert code == 2
    assert '[robot.face_cam]: invalid parameter tracker.epsilon = 1.5' in output
    assert 'mono_tracker' not in output


def test_a_parameter_without_a_value_is_one_error_line_and_exit_code_2():
    """``-p output:=`` (an empty string is ``-p "output:=''"``): rcl cannot parse it.

    It was rclpy.init's RCLError traceback, exit code 1.
    """
    code, output = finish(start_node('bag_recorder', output=''))
    assert code == 2
    assert "Couldn't parse parameter override rule: '-p output:='" in output
    assert 'Traceback' not in output and ', at /' not in output


def test_an_empty_list_parameter_is_one_error_line_and_exit_code_2(tmp_path):
    """``-p topics:=[]``: rclpy cannot type it when the node declares what it was given.

    It was a ValueError traceback ('Cannot declare a statically typed parameter with default
    value of type PARAMETER_NOT_SET'), exit code 1.
    """
    code, output = finish(start_node('bag_recorder', output=str(tmp_path / 'bag'), topics=[]))
    assert code == 2
    assert 'a parameter is given as an empty list ([]), which rclpy cannot type' in output
    assert 'Traceback' not in output
    assert not (tmp_path / 'bag').exists()


@pytest.mark.parametrize('delay_s', [0.8, 1.2, 1.6])
def test_a_stop_signal_while_a_node_starts_ends_it_cleanly(delay_s):
    """SIGTERM (a launch system, a CI runner) while the node is still being built.

    rclpy's own handler shut the context down under the building node: 'Failed to create
    publisher: publisher's context is invalid', a traceback and exit 1 at 0.5-1.8 s.
    """
    process = start_node('expression_recognizer')
    time.sleep(delay_s)
    code, output = finish(process, stop=signal.SIGTERM)
    assert code == 0, output
    assert 'Traceback' not in output, output
