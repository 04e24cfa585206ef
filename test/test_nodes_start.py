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
    assert 'invalid parameter tracker.epsilon = 1.5' in output
    assert 'Traceback' not in output
