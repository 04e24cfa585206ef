"""Which bag topics feed the stereo tracker: found by name, by side, by --remap or given."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from face_tracking_ros.cli.main import main
from face_tracking_ros.errors import ConfigError
from face_tracking_ros.pipelines.bag_inputs import (
    check_stereo_topics,
    clicked_camera_topic,
    stereo_remaps,
)

from repo_root import REPO

IMAGE, INFO = 'sensor_msgs/msg/Image', 'sensor_msgs/msg/CameraInfo'
# stereo_image_proc's outputs: two images a side, so the side alone does not choose.
PROC = {
    '/stereo/left/image_rect': IMAGE,
    '/stereo/left/image_rect_color': IMAGE,
    '/stereo/right/image_rect': IMAGE,
    '/stereo/right/image_rect_color': IMAGE,
    '/stereo/left/camera_info': INFO,
    '/stereo/right/camera_info': INFO,
}
RECT = {'left/image_raw': '/stereo/left/image_rect', 'right/image_raw': '/stereo/right/image_rect'}


def _options(**given: str) -> SimpleNamespace:
    names = ('left_topic', 'right_topic', 'left_info_topic', 'right_info_topic')
    return SimpleNamespace(**{name: given.get(name) for name in names})


def test_remapped_inputs_count_where_the_side_does_not_choose():
    with pytest.raises(ConfigError, match="no topic for the stereo tracker's left/image_raw, ri"):
        check_stereo_topics(Path('b'), PROC, _options(), compressed=False)
    check_stereo_topics(Path('b'), PROC, _options(), compressed=False, remaps=RECT)  # no error


def test_the_side_then_remaps_then_options_choose():
    topics = {'/cam_left/image': IMAGE, '/cam_right/image': IMAGE, '/x/right/image': IMAGE}
    found = stereo_remaps(topics, _options(), compressed=False)
    assert found == {'left/image_raw': '/cam_left/image'}  # two with 'right': neither
    remapped = stereo_remaps(topics, _options(), False, {'left/image_raw': '/x/right/image'})
    assert remapped == {'left/image_raw': '/x/right/image'}
    given = stereo_remaps(topics, _options(left_topic='/a'), False, {'left/image_raw': '/b'})
    assert given == {'left/image_raw': '/a'}


def test_a_side_is_a_word_of_the_name_not_part_of_one():
    topics = {'/cam/left/image': IMAGE, '/cam/bright/image': IMAGE, '/cam/right_eye/image': IMAGE}
    assert stereo_remaps(topics, _options(), compressed=False) == {
        'left/image_raw': '/cam/left/image',
        'right/image_raw': '/cam/right_eye/image',
    }


def test_the_mono_camera_info_option_on_a_stereo_bag_is_named(tmp_path, capsys):
    stereo = REPO / 'bags' / 'stereo_train' / 'subject_00_seq_00'
    argv = ['track', str(stereo), '--simulate-clicks', '1', '--out', str(tmp_path / 'o')]
    assert main([*argv, '--camera-info-topic', 'left/camera_info']) == 2
    assert 'error: --camera-info-topic left/camera_info is for the mono tracker; the stereo' in (
        capsys.readouterr().err
    )
    assert list(tmp_path.iterdir()) == []


def test_the_clicks_are_in_the_stereo_trackers_left_camera_and_the_mono_trackers_only_one():
    read = {'/cam_b/camera_info': 'left/camera_info', '/cam_a/camera_info': 'right/camera_info'}
    assert clicked_camera_topic(read, 'stereo_tracker') == '/cam_b/camera_info'
    assert clicked_camera_topic(read, 'mono_tracker') is None  # no topic feeds its camera_info
    assert clicked_camera_topic({'/cam/info': 'camera_info'}, 'mono_tracker') == '/cam/info'
