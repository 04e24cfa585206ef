"""A topic is the left (right) camera's by the word left (right) in its name, not a part of one.

The simulated clicks, the stereo scoring's rig and the overlay's image topic choose their
camera by :func:`~face_tracking_ros.io.bags.topic_has_word`, as the stereo tracker's inputs do:
a ``/cleft_palate/...`` or ``/leftover/...`` topic is no left camera's. Where the tracker's
left camera is given (``--left-info-topic``), the clicks are in that camera whatever its name.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from face_tracking_ros.cli.main import main
from face_tracking_ros.errors import BagError
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import BagWriter, read_messages, topic_has_word
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.pipelines import stereo_meshes
from face_tracking_ros.pipelines.learn_options import LearnOptions
from face_tracking_ros.pipelines.scoring import stereo_rig
from face_tracking_ros.synthetic.clicks import clicks_from_bag
from face_tracking_ros.tracking.initialisation import load_init_file
from face_tracking_ros.visualization.video import image_topic

from repo_root import REPO

STEREO = REPO / 'bags' / 'stereo_train' / 'subject_00_seq_00'
DECOY = PinholeCamera.ideal(320, 240, focal=150.0)  # the bag's cameras: 320x240, focal 300


def _renamed(source: Path, target: Path, names: dict[str, str], decoys: tuple[str, ...]) -> Path:
    """``target``: the first message of each of ``names``' topics of ``source`` (old -> new name).

    Written first, the ``decoys`` (camera_info topics) hold :data:`DECOY`, and image topics
    (their names ending in image_raw) the first left image.
    """
    first = {}
    for message in read_messages(source, topics=list(names)):
        first.setdefault(message.topic, message)
    factory = RosbagsMessages(typestore())
    with BagWriter(target) as bag:
        left = first['left/camera_info']
        for decoy in decoys:
            if decoy.endswith('image_raw'):
                image = first['left/image_raw']
                bag.write(decoy, image.msgtype, image.msg, image.stamp_ns)
            else:
                info = conversions.camera_to_info(factory, left.msg.header, DECOY)
                bag.write(decoy, left.msgtype, info, left.stamp_ns)
        for topic, message in first.items():
            bag.write(names[topic], message.msgtype, message.msg, message.stamp_ns)
    return target


@pytest.fixture(scope='module')
def cleft(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The stereo bag's first frame, with a camera_info and an image on /cleft_palate first."""
    names = {t: t for t in ('left/camera_info', 'right/camera_info', 'truth/face')}
    names['left/image_raw'] = 'left/image_raw'
    decoys = ('/cleft_palate/camera_info', '/cleft_palate/image_raw')
    return _renamed(STEREO, tmp_path_factory.mktemp('cleft') / 'bag', names, decoys)


@pytest.mark.parametrize(
    ('topic', 'expected'),
    [
        ('/stereo/left/image_raw', True),
        ('cam_left', True),
        ('Left_Camera/camera_info', True),
        ('/cleft_palate/camera_info', False),
        ('/leftover/camera_info', False),
        ('/lefty', False),
    ],
)
def test_left_is_a_word_of_the_name(topic, expected):
    assert topic_has_word(topic, 'left') is expected


def test_the_clicks_are_in_the_left_camera_not_a_cleft_one(cleft):
    clicks, reference = clicks_from_bag(cleft, 0.0), clicks_from_bag(STEREO, 0.0)
    assert clicks.node_names == reference.node_names
    np.testing.assert_array_equal(clicks.points, reference.points)
    assert np.ptp(clicks.points[:, 0]) == pytest.approx(62.1, abs=0.1)  # px; the decoy's: 31


def test_the_scoring_rig_is_the_left_and_right_cameras_not_a_cleft_one(cleft):
    rig, reference = stereo_rig(cleft), stereo_rig(STEREO)
    np.testing.assert_array_equal(rig.left.p, reference.left.p)
    assert rig.baseline == pytest.approx(reference.baseline)
    assert rig.baseline > 0.05  # m


def test_the_overlay_draws_on_the_left_images_not_cleft_ones(cleft):
    assert image_topic(cleft) == 'left/image_raw'


def test_without_a_left_word_clicks_take_the_first_camera_info_and_the_rig_is_refused(tmp_path):
    names = {
        'left/camera_info': '/leftover/camera_info',
        'right/camera_info': '/right/camera_info',
        'truth/face': 'truth/face',
    }
    bag = _renamed(STEREO, tmp_path / 'bag', names, ())
    np.testing.assert_array_equal(
        clicks_from_bag(bag, 0.0).points, clicks_from_bag(STEREO, 0.0).points
    )  # /leftover/ comes first by name: its (left) camera
    with pytest.raises(BagError, match='no valid left and right camera_info to build the stereo'):
        stereo_rig(bag)


SIDES = {  # the unsided bag's topics: /cam_b/ is the left camera, /cam_a/ (first by name) right
    'left/image_raw': '/cam_b/image_raw',
    'right/image_raw': '/cam_a/image_raw',
    'left/camera_info': '/cam_b/camera_info',
    'right/camera_info': '/cam_a/camera_info',
}


@pytest.fixture(scope='module')
def unsided(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The stereo bag's first pair, its topics named without a side (:data:`SIDES`)."""
    names = {**SIDES, 'truth/face': 'truth/face'}
    return _renamed(STEREO, tmp_path_factory.mktemp('unsided') / 'bag', names, ())


def test_track_clicks_in_the_camera_given_as_the_left_one(unsided, tmp_path):
    """Simulated clicks go where the tracker reads its left camera, not the first camera_info."""
    out = tmp_path / 'tracked'
    argv = ['track', str(unsided), '--simulate-clicks', '0', '--out', str(out), '--quiet',
            '--left-topic', SIDES['left/image_raw'], '--right-topic', SIDES['right/image_raw'],
            '--left-info-topic', SIDES['left/camera_info'],
            '--right-info-topic', SIDES['right/camera_info']]  # fmt: skip
    main(argv)
    clicks = load_init_file(out.parent / f'{out.name}.init.json')
    np.testing.assert_array_equal(clicks.points, clicks_from_bag(STEREO, 0.0).points)


def test_learn_clicks_in_the_camera_given_as_the_left_one(unsided, tmp_path):
    options = LearnOptions(
        bags=(unsided,),
        out=tmp_path / 'm.npz',
        report=tmp_path / 'r.json',
        from_images=True,
        simulate_clicks=0.0,
        left_topic=SIDES['left/image_raw'],
        right_topic=SIDES['right/image_raw'],
        left_info_topic=SIDES['left/camera_info'],
        right_info_topic=SIDES['right/camera_info'],
    )
    checked = stereo_meshes.checked_stereo_bags(options)
    initialisation = stereo_meshes.stereo_initialisations(checked, options)[unsided].initialisation
    assert checked[unsided].initialisation is None and initialisation is not None
    clicks = load_init_file(initialisation['init_file'])
    np.testing.assert_array_equal(clicks.points, clicks_from_bag(STEREO, 0.0).points)
    reference = clicks_from_bag(unsided, 0.0)  # by name alone: the first camera_info, the right
    assert np.mean(reference.points[:, 0] - clicks.points[:, 0]) < -5.0  # px of disparity
    with pytest.raises(BagError, match=f'{unsided}: no CameraInfo topic /nope to click in'):
        clicks_from_bag(unsided, 0.0, camera_info='/nope')
