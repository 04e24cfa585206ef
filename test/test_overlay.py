"""face-tracking overlay: a bag's frames with the tracked mesh, as the trackers saw them."""

from __future__ import annotations

from pathlib import Path
import shutil

from compressed_bags import compressed_copy
import cv2
import imageio.v3 as iio
import numpy as np
import pytest

from face_tracking_ros.cli.main import main
from face_tracking_ros.errors import ConfigError, InputError
from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import BagWriter, bag_topics, read_messages
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.series import load_states
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.tracking.result import TrackStatus
from face_tracking_ros.visualization.overlay import draw_mesh
from face_tracking_ros.visualization.video import overlay_frames, write_overlay_video

NODE_RGB = (255, 90, 30)  # draw_mesh's node dots; its edges take the status colour


@pytest.fixture(scope='module')
def turned(tmp_path_factory) -> tuple[Path, Path]:
    """Three raw 160x120 frames of a camera turned 8 degrees from its rectified frame, tracked."""
    root = tmp_path_factory.mktemp('turned')
    synth = ['synth', '--kind', 'mono', '--frames', '3', '--size', '160x120', '--focal', '150',
             '--motion', 'static', '--toe-in', '8', '--out', str(root)]  # fmt: skip
    assert main(synth) == 0
    bag = root / 'subject_00_seq_00'
    track = ['track', str(bag), '--simulate-clicks', '0', '--out', str(root / 'out'), '--quiet',
             '--param', 'tracker.pyramid_levels=3']  # fmt: skip
    assert main(track) == 0
    return bag, root / 'out'


def _black_edge_columns(frame: np.ndarray) -> int:
    """How many of the two outermost columns are black from top to bottom."""
    return sum(int(not frame[:, column].any()) for column in (0, -1))


def test_frames_are_rectified_before_the_mesh_is_drawn(turned, tmp_path):
    bag, out = turned
    states = load_states(out)
    assert states.occluded.shape == (3, 34) and not states.occluded.any()  # mono: none judged
    rectified = list(overlay_frames(bag, states))
    recorded = list(overlay_frames(bag, states, rectify=False))
    assert len(rectified) == len(recorded) == 3
    # Turned by 8 degrees (21 px at f = 150), the rectified view reaches past one side of what
    # the camera saw: that side is black; the recorded frames have none.
    assert all(_black_edge_columns(frame) == 1 for frame in rectified)
    assert all(_black_edge_columns(frame) == 0 for frame in recorded)
    assert write_overlay_video(bag, states, tmp_path / 'v.gif') == 3
    # The mesh is drawn where the states put the nodes, in either view: a dot on each node.
    for frames in (rectified, recorded):
        for frame, points in zip(frames, states.image_points, strict=True):
            columns, rows = np.round(points).astype(int).T
            assert np.all(frame[rows, columns] == NODE_RGB)


def test_the_mesh_is_drawn_on_its_nodes_and_edges_in_the_status_colour():
    """Dots of radius 2 px on the nodes, 1-px lines on the edges; none to a NaN node."""
    gray = np.full((40, 60), 50, np.uint8)
    nodes = np.array([[10.0, 10.0], [50.0, 10.0], [30.0, 30.0], [np.nan, np.nan]])
    edges = np.array([[0, 1], [1, 2], [2, 3]])
    tracking = draw_mesh(gray, nodes, edges, TrackStatus.TRACKING)
    assert np.all(tracking[[10, 10, 30], [10, 50, 30]] == NODE_RGB)
    # The edge (50, 10)-(30, 30) runs diagonally through pixel centres: (40, 20) is on it.
    np.testing.assert_array_equal(tracking[20, 40], (60, 220, 60))
    np.testing.assert_array_equal(
        draw_mesh(gray, nodes, edges, TrackStatus.LOST)[20, 40], [230, 50, 50]
    )
    # Nothing beyond the dots' reach of the valid nodes (3 px with the anti-aliasing): an edge to
    # the NaN node would run to (0, 0).
    rows, columns = np.nonzero(np.any(tracking != 50, axis=2))
    assert rows.min() >= 10 - 3 and rows.max() <= 30 + 3
    assert columns.min() >= 10 - 3 and columns.max() <= 50 + 3
    # A node held under an occluder (FaceState.occluded) is a ring of radius 3 px, not a dot.
    held = draw_mesh(gray, nodes, edges, TrackStatus.TRACKING, occluded=np.eye(4, dtype=bool)[2])
    assert np.all(held[[10, 10], [10, 50]] == NODE_RGB)
    assert np.all(held[[27, 33, 30, 30], [30, 30, 27, 33], 0] > 200)  # on the ring, anti-aliased
    assert np.all(held[31, 30] == 50) and np.all(tracking[31, 30] == NODE_RGB)  # inside it


def test_compressed_frames_are_drawn_like_raw_ones(turned, tmp_path):
    """image_transport's compressed topic beside the camera_info: found, decoded, rectified."""
    bag, out = turned
    copy = compressed_copy(bag, tmp_path / 'compressed')
    assert bag_topics(copy)['image/compressed'] == 'sensor_msgs/msg/CompressedImage'
    states = load_states(out)
    frames = zip(overlay_frames(bag, states), overlay_frames(copy, states), strict=True)
    for expected, frame in frames:
        np.testing.assert_array_equal(frame, expected)


def _with_last_image_halved(bag: Path, out: Path) -> Path:
    """``bag`` with its last image at half size (same stamp), as a bag of mixed sizes has."""
    messages = list(read_messages(bag))
    last = max(i for i, message in enumerate(messages) if message.topic == 'image')
    factory = RosbagsMessages(typestore())
    with BagWriter(out) as writer:
        for i, message in enumerate(messages):
            msg = message.msg
            if i == last:
                small = cv2.resize(conversions.image_to_gray(msg), None, fx=0.5, fy=0.5)
                msg = conversions.array_to_image(factory, msg.header, small)
            writer.write(message.topic, message.msgtype, msg, message.stamp_ns)
    return out


@pytest.mark.parametrize(
    ('rectify', 'match'),
    [(True, 'image 2 is 80x60 but camera_info says 160x120'),
     (False, 'image 2 is 80x60, the frames before it 160x120')],
)  # fmt: skip
def test_an_image_of_another_size_is_refused_and_the_video_so_far_kept(
    turned, tmp_path, rectify, match
):
    """Its state (tracked elsewhere) would be drawn on the wrong pixels: a clear error instead."""
    bag, out = turned
    mixed = _with_last_image_halved(bag, tmp_path / 'mixed')
    states = load_states(out)
    frames = overlay_frames(mixed, states, rectify=rectify)
    assert len([next(frames), next(frames)]) == 2
    with pytest.raises(InputError, match=match):
        next(frames)
    video = tmp_path / 'v.mp4'
    video.write_bytes(b'an earlier video')
    kept = rf'{match} \(the frames before it are in .*v\.partial\.mp4\)'
    with pytest.raises(InputError, match=kept):
        write_overlay_video(mixed, states, video, rectify=rectify)
    assert video.read_bytes() == b'an earlier video'  # not replaced by an incomplete one
    capture = cv2.VideoCapture(str(tmp_path / 'v.partial.mp4'))
    assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == 2  # the frames before it, readable
    with pytest.raises(InputError, match=match):
        write_overlay_video(mixed, states, tmp_path / 'v.gif', rectify=rectify)
    assert len(iio.imread(tmp_path / 'v.partial.gif', index=None)) == 2


def test_a_video_in_a_missing_directory_is_refused_before_any_work(turned, tmp_path):
    bag, out = turned
    for name in ('x.mp4', 'x.gif'):  # OpenCV's writer would drop every frame without a word
        with pytest.raises(ConfigError, match=f'video file .*{name}: no directory .*absent'):
            write_overlay_video(bag, load_states(out), tmp_path / 'absent' / name)


def test_a_bag_without_images_is_named_with_its_topics(turned, tmp_path, capsys):
    """It said 'choose the image topic (--image-topic) among none' (here: the two bags swapped)."""
    _, out = turned
    video = ['--video', str(tmp_path / 'v.mp4')]
    expected = (
        f'error: {out}: no sensor_msgs/msg/Image or CompressedImage topic to draw on (its topics: '
        f'{", ".join(bag_topics(out))})\n'
    )
    for more in ([], ['--image-topic', 'image']):
        assert main(['overlay', str(out), str(out), *video, *more]) == 2
        assert capsys.readouterr().err == expected
    assert not (tmp_path / 'v.mp4').exists()


def test_the_bags_given_the_other_way_round_are_named_swapped(turned, tmp_path, capsys):
    """It said only that the images bag has no FaceState topic."""
    bag, out = turned
    assert main(['overlay', str(out), str(bag), '--video', str(tmp_path / 'v.gif')]) == 2
    assert capsys.readouterr().err == (
        f'error: {bag}: expected one face_tracking_msgs/msg/FaceState topic, found none: the '
        'first argument is a tracking output and the second holds images: give the images bag '
        'first\n'
    )
    assert main(['overlay', str(bag), str(bag), '--video', str(tmp_path / 'v.gif')]) == 2
    assert capsys.readouterr().err.endswith('FaceState topic, found none\n')  # no images first
    other = tmp_path / 'other'  # neither images nor states first: not a tracking output
    with BagWriter(other) as writer:
        factory = RosbagsMessages(typestore())
        writer.write('level', 'std_msgs/msg/Float64', factory.make('std_msgs/msg/Float64'), 1)
    assert main(['overlay', str(other), str(bag), '--video', str(tmp_path / 'v.gif')]) == 2
    assert capsys.readouterr().err.endswith(
        f'{bag}: expected one face_tracking_msgs/msg/FaceState topic, found none\n'
    )
    missing = tmp_path / 'no_such_bag'  # the check for swapped bags keeps the states' error
    assert main(['overlay', str(missing), str(bag), '--video', str(tmp_path / 'v.gif')]) == 2
    assert capsys.readouterr().err.endswith(
        f'{bag}: expected one face_tracking_msgs/msg/FaceState topic, found none\n'
    )
    assert not (tmp_path / 'v.gif').exists()


def test_a_track_drawn_on_another_bag_than_its_own_says_so(turned, tmp_path, capsys):
    """Synthetic bags share their stamps: another bag's track was drawn on them without a word."""
    bag, out = turned
    other = shutil.copytree(bag, tmp_path / 'other')
    assert main(['overlay', str(other), str(out), '--video', str(tmp_path / 'v.gif')]) == 0
    assert capsys.readouterr().out == (
        f'wrote 3 frames to {tmp_path / "v.gif"}\n'
        f'note: {out} was tracked from {bag}, not from {other}: its meshes are drawn on the '
        'images of the same stamps\n'
    )
    assert main(['overlay', str(bag), str(out), '--video', str(tmp_path / 'w.gif')]) == 0
    assert capsys.readouterr().out == f'wrote 3 frames to {tmp_path / "w.gif"}\n'
