"""face-tracking learn on raw stereo bags tracks them with the stereo tracker, then learns."""

from __future__ import annotations

import json

import pytest

from face_tracking_ros.cli.main import main
from face_tracking_ros.io.bags import bag_topics
from face_tracking_ros.model.model_file import load_model

from conftest import REPO

BAGS = sorted((REPO / 'bags' / 'stereo_train').glob('subject_*'))


def test_stereo_images_are_tracked_then_learned(tmp_path):
    argv = [
        'learn', *map(str, BAGS), '--from-images', '--simulate-clicks', '1.0', '--p', '1',
        '--q', '2', '--compare', '--out', str(tmp_path / 'model.npz'), '--report',
        str(tmp_path / 'report.json'),
    ]  # fmt: skip
    assert main(argv) == 0
    meshes = sorted((tmp_path / 'report_meshes').glob('subject_*_seq_00'))
    assert [m.name for m in meshes] == [b.name for b in BAGS]
    assert bag_topics(meshes[0])['face/mesh_raw'] == 'face_tracking_msgs/msg/FaceMesh'
    model = load_model(tmp_path / 'model.npz')
    assert (model.num_nodes, model.p, model.q) == (34, 1, 2)
    report = json.loads((tmp_path / 'report.json').read_text())
    assert report['frames'] == 30
    assert report['subjects'] == ['subject_00', 'subject_01', 'subject_02']


def test_raw_stereo_bag_without_initialisation_is_refused(tmp_path, capsys):
    argv = ['learn', str(BAGS[0]), '--from-images', '--out', str(tmp_path / 'm.npz'),
            '--report', str(tmp_path / 'r.json')]  # fmt: skip
    assert main(argv) == 2
    assert 'give its initialisation with --init-dir' in capsys.readouterr().err


@pytest.fixture(autouse=True)
def _bags_exist():
    assert len(BAGS) == 3, 'the committed stereo sample bags are missing'
