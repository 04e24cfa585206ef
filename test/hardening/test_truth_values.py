"""A NaN in a truth bag is named with the bag, topic, message and stamp, not dumped.

Before, ``track`` (scoring, simulated clicks), ``train-expressions`` and ``learn`` printed the
field's 102 values without naming the bag.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from face_tracking_ros.cli.main import main
from face_tracking_ros.io.bags import BagWriter, read_messages

MONO = Path(__file__).resolve().parents[2] / 'bags' / 'mono_test' / 'subject_00_seq_00'


def _nan_truth(path: Path, index: int) -> Path:
    """A copy of the sample mono bag with a NaN in node 3 of truth/face message ``index``."""
    count = 0
    with BagWriter(path) as writer:
        for message in read_messages(MONO):
            if message.topic == 'truth/face':
                if count == index:
                    message.msg.nodes[3].x = float('nan')
                count += 1
            writer.write(message.topic, message.msgtype, message.msg, message.stamp_ns)
    return path


def _expected(bag: Path, index: int) -> str:
    stamp = next(
        m.msg.header.stamp for i, m in enumerate(read_messages(bag, ['truth/face'])) if i == index
    )
    return (
        f'error: {bag}: truth/face message {index} (stamp {stamp.sec}.{stamp.nanosec:09d} s): '
        'FaceTruth.nodes holds NaN or Inf: 1 of 102 values, the first (nan) at [3, 0]\n'
    )


@pytest.mark.parametrize(
    'command',
    [
        ['train-expressions', '--out', '{tmp}/classifier.npz'],
        ['learn', '--out', '{tmp}/model.npz', '--report', '{tmp}/learn.json'],
    ],
)
def test_training_on_a_truth_bag_with_a_nan_names_the_message(tmp_path, capsys, command):
    bag = _nan_truth(tmp_path / 'nan', 4)
    argv = [command[0], str(bag), *(arg.format(tmp=tmp_path) for arg in command[1:])]
    assert main(argv) == 2
    assert capsys.readouterr().err == _expected(bag, 4)


def test_tracking_a_truth_bag_with_a_nan_names_the_message(tmp_path, capsys):
    first = _nan_truth(tmp_path / 'first', 0)
    track = ['track', '--simulate-clicks', '1', '--quiet']
    assert main([*track, str(first), '--out', str(tmp_path / 'a')]) == 2  # the clicks' frame
    assert capsys.readouterr().err == _expected(first, 0)
    later = _nan_truth(tmp_path / 'later', 4)
    assert main([*track, str(later), '--out', str(tmp_path / 'b')]) == 2  # the scoring
    assert capsys.readouterr().err == _expected(later, 4)
    assert len(list(read_messages(tmp_path / 'b', ['face/state']))) > 0  # the track is kept
