"""A bag given twice to a command that pools its bags: refused before anything is read.

Its frames counted twice without a word: train-expressions 'trained on 12 frames of 2
sequences' from one 6-frame bag, learn read 18 meshes from one of 6, enroll doubled the
estimates of a person.
"""

from __future__ import annotations

import pytest

from face_tracking_ros.cli.main import main


@pytest.mark.parametrize(
    'command',
    [
        ['enroll', '--name', 'anna', '--gallery', '{tmp}/gallery.npz'],
        ['train-expressions', '--out', '{tmp}/classifier.npz'],
        ['learn', '--out', '{tmp}/model.npz', '--report', '{tmp}/report.json'],
    ],
)
def test_a_bag_given_twice_is_refused_naming_it(tmp_path, capsys, command):
    bag = tmp_path / 'anna_1'
    bag.mkdir()
    (bag / 'anna_1.mcap').write_bytes(b'')  # never opened
    same = [str(bag), str(tmp_path / '.' / 'anna_1'), str(bag / 'anna_1.mcap')]
    argv = [part.format(tmp=tmp_path) for part in command]
    for other in same[1:]:
        assert main([*argv, str(bag), other]) == 2
        assert capsys.readouterr().err == (
            f'error: bag {bag} given twice (also as {other}): its frames would count twice\n'
        )
    assert not {path.name for path in tmp_path.iterdir()} - {'anna_1'}  # nothing written
