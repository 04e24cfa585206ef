"""Tests of synthetic scenes, bags and the ``face-tracking synth`` command."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
import re

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest

from face_tracking_ros.cli import synth
from face_tracking_ros.cli.main import main
from face_tracking_ros.errors import ConfigError
from face_tracking_ros.geometry.rotation import omega_to_quaternion, rodrigues
from face_tracking_ros.io.bags import read_messages
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.synthetic.motion import ExpressionScript, ExpressionSegment
from face_tracking_ros.synthetic.recording import TRUTH_TOPIC, record
from face_tracking_ros.synthetic.scenes import (
    SceneConfig,
    SequenceRenderer,
    SyntheticFrame,
    _LightPath,
    _OccluderPass,
)

SMALL = {'width': 160, 'height': 120, 'focal': 150.0, 'frames': 3, 'fps': 15.0}
SMALL_VIEW = {'width': 160, 'height': 120, 'focal': 150.0, 'fps': 10.0}


@pytest.fixture(scope='module')
def stereo_frames() -> list[SyntheticFrame]:
    config = SceneConfig(kind='stereo', motion='free', seed=2, **{**SMALL, 'frames': 6})
    return list(SequenceRenderer(config, 0).frames(0))


def test_stereo_truth_satisfies_the_rectified_epipolar_constraint(stereo_frames):
    config = SceneConfig(kind='stereo', seed=2, **SMALL)
    cameras = config.cameras()
    for frame in stereo_frames:
        nodes = frame.truth.nodes_camera
        left, right = cameras['left'].project(nodes), cameras['right'].project(nodes)
        np.testing.assert_allclose(left[:, 1], right[:, 1], atol=1e-9)  # same row
        disparity = left[:, 0] - right[:, 0]
        np.testing.assert_allclose(disparity, config.focal * config.baseline / nodes[:, 2])
        assert frame.images['left'].shape == (120, 160) and frame.images['left'].dtype == np.uint8


@pytest.mark.parametrize('baseline', [0.03, 0.30])
def test_rigs_of_the_whole_baseline_range_film_the_face_in_both_cameras(baseline):
    # The working volume is centred between the cameras: a 0.30 m rig sees the face too.
    config = SceneConfig(kind='stereo', seed=2, baseline=baseline, frames=1)
    cameras = config.cameras()
    frame = next(SequenceRenderer(config, 0).frames(0))
    nodes = frame.truth.nodes_camera
    left, right = cameras['left'].project(nodes), cameras['right'].project(nodes)
    np.testing.assert_allclose(left[:, 0] - right[:, 0], 600.0 * baseline / nodes[:, 2])
    assert 0 < right[:, 0].min() and left[:, 0].max() < 640
    assert frame.truth.visible['left'][:19].all() and frame.truth.visible['right'][:19].all()


def test_frame_truth_is_eq3_with_true_bases_posed_by_eq1(stereo_frames):
    population = FacePopulation('default', seed=2)
    subject = population.subject(0)
    for frame in stereo_frames:
        truth = frame.truth
        rotation, _ = rodrigues(truth.omega)
        posed = population.nodes(subject, truth.alpha) @ rotation.T + truth.t
        np.testing.assert_allclose(truth.nodes_camera, posed, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(truth.sigma, subject.sigma_true)
        assert frame.stamp_ns == 1_700_000_000 * 10**9 + round(frame.index * 1e9 / 15.0)
        assert set(truth.visible) == {'left', 'right'} and truth.visible['left'].shape == (34,)


def _bag_bytes(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob('*')) if p.is_file()
    }


def test_same_seed_gives_byte_identical_bags(tmp_path):
    config = SceneConfig(kind='mono', sequences=2, seed=5, **SMALL)
    record(config, tmp_path / 'a')
    record(config, tmp_path / 'b')
    first, second = _bag_bytes(tmp_path / 'a'), _bag_bytes(tmp_path / 'b')
    assert len(first) == 4  # two bags, each metadata.yaml + one .mcap
    assert first == second
    record(SceneConfig(kind='mono', sequences=2, seed=6, **SMALL), tmp_path / 'c')
    assert _bag_bytes(tmp_path / 'c') != first


def test_bags_round_trip_through_rosbags_and_the_mcap_reader(tmp_path):
    frames: list[SyntheticFrame] = []
    config = SceneConfig(kind='stereo', seed=1, **SMALL)
    [bag] = record(config, tmp_path, on_frame=frames.append)
    assert bag.frames == 3 and bag.path.name == 'subject_00_seq_00'
    messages = list(read_messages(bag.path))
    topics = {m.topic for m in messages}
    assert topics == {
        'left/image_raw', 'left/camera_info', 'right/image_raw', 'right/camera_info', TRUTH_TOPIC
    }  # fmt: skip
    truths = [m.msg for m in messages if m.topic == TRUTH_TOPIC]
    images = [m.msg for m in messages if m.topic == 'right/image_raw']
    infos = [m.msg for m in messages if m.topic == 'right/camera_info']
    for frame, truth, image, info in zip(frames, truths, images, infos, strict=True):
        expected = frame.truth
        assert (
            truth.subject_id == 'subject_00'
            and truth.header.frame_id == 'left_camera_optical_frame'
        )
        np.testing.assert_array_equal(truth.omega, expected.omega)
        np.testing.assert_array_equal(truth.alpha, expected.alpha)
        np.testing.assert_array_equal(truth.sigma, expected.sigma)
        nodes = np.array([(p.x, p.y, p.z) for p in truth.nodes])
        np.testing.assert_array_equal(nodes, expected.nodes_camera)
        quaternion = [truth.pose.orientation.x, truth.pose.orientation.y,
                      truth.pose.orientation.z, truth.pose.orientation.w]  # fmt: skip
        np.testing.assert_allclose(quaternion, omega_to_quaternion(expected.omega))
        assert truth.expression_label == expected.label
        assert truth.expression_intensity == expected.intensity
        assert (image.encoding, image.height, image.width, image.step) == ('mono8', 120, 160, 160)
        np.testing.assert_array_equal(image.data.reshape(120, 160), frame.images['right'])
        assert info.p[3] == pytest.approx(-150.0 * 0.11)
    mcap_truths = []
    with next(bag.path.glob('*.mcap')).open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages():
            if channel.topic == TRUTH_TOPIC:
                mcap_truths.append((message.log_time, decoded))
    assert [t for t, _ in mcap_truths] == [f.stamp_ns for f in frames]
    for (_, decoded), frame in zip(mcap_truths, frames, strict=True):
        assert decoded.expression_label == frame.truth.label
        np.testing.assert_array_equal(decoded.sigma, frame.truth.sigma)


def test_synth_command_writes_bags_and_a_contact_sheet(tmp_path, capsys):
    status = main([
        'synth', '--kind', 'mono', '--frames', '2', '--size', '160x120', '--focal', '150',
        '--motion', 'free', '--seed', '3', '--out', str(tmp_path / 'bags'),
    ])  # fmt: skip
    assert status == 0
    assert (tmp_path / 'bags' / 'subject_00_seq_00' / 'metadata.yaml').is_file()
    assert '1 bag, 2 frames (2 images) in ' in capsys.readouterr().out


@pytest.mark.parametrize(
    ('arguments', 'message'),
    [
        (['--subjects', '0'], 'subjects must be >= 1, got 0'),
        (['--frames', '0'], 'frames must be >= 1, got 0'),
        (['--fps', '0'], r'fps must be in \(0, 120\]'),
        (
            ['--texture', 'missing.png', '--texture-nodes', 'missing.json'],
            'texture file not found',
        ),
        (['--texture', 'missing.png'], 'needs its node positions'),
        (['--baseline', '0.31'], r'baseline must be in \[0.03, 0.3\] m, got 0.31'),
        (['--baseline', '0.02'], r'baseline must be in \[0.03, 0.3\] m, got 0.02'),
        (['--distortion', '0.1,0.2'], 'distortion must be 5 finite plumb_bob coefficients'),
        (['--toe-in', '12'], r'toe_in_deg must be in \[0, 10\], got 12.0'),
        (
            ['--kind', 'mono', '--focal', '1e12', '--frames', '1'],
            r'focal must be in \[28.0, 36668\] px for an image 640 px wide \(a horizontal field '
            r'of view of 170 down to 1 degrees\), got 1000000000000.0',
        ),
        (['--focal', 'nan'], r'focal must be in \[28.0, 36668\] px .*, got nan'),
        (['--size', '2x2', '--focal', '2', '--frames', '1'], r'size must be in \[32, 4096\] px'),
        (['--size', '5000x480', '--frames', '1'], r'a side, got 5000x480'),
    ],
)
def test_bad_arguments_give_clear_errors(tmp_path, capsys, arguments, message):
    status = main(['synth', '--out', str(tmp_path), *arguments])
    assert status == 2
    err = capsys.readouterr().err
    assert err.startswith('error: ')
    assert re.search(message, err)


@pytest.mark.parametrize(
    ('name', 'message'),
    [
        ('sheets', r'--contact-sheet \S*sheets is a directory, not a file'),
        ('sheet.txt', r'--contact-sheet \S*sheet.txt: OpenCV writes no image format of its '),
        ('sheet', r'--contact-sheet \S*sheet: .* of its extension \(none\)'),
        ('notes.txt/sheet.png', r'--contact-sheet \S*sheet.png: \S*notes.txt is a file, not a'),
    ],
)
def test_a_contact_sheet_that_cannot_be_written_is_refused_before_rendering(
    tmp_path, capsys, monkeypatch, name, message
):
    (tmp_path / 'sheets').mkdir()
    (tmp_path / 'notes.txt').write_text('kept')
    rendered = []  # (the bags and the sheet, which take seconds to render)
    monkeypatch.setattr(synth, 'record', lambda *args, **kwargs: rendered.append('bags') or [])
    sheet = np.zeros((4, 4), np.uint8)
    monkeypatch.setattr(synth, 'contact_sheet', lambda config: rendered.append('sheet') or sheet)
    argv = ['synth', '--out', str(tmp_path / 'bags'), '--contact-sheet', str(tmp_path / name)]

    status = main(argv)

    assert status == 2
    err = capsys.readouterr().err
    assert re.fullmatch(f'error: {message}.*\n', err)
    assert not rendered
    assert (tmp_path / 'notes.txt').read_text() == 'kept'


def test_scene_config_rejects_bad_values():
    with pytest.raises(ConfigError, match="unknown kind 'fisheye'"):
        SceneConfig(kind='fisheye')
    with pytest.raises(ConfigError, match="unknown motion 'dance'"):
        SceneConfig(motion='dance')
    with pytest.raises(ConfigError, match="unknown population preset 'huge'"):
        SceneConfig(population='huge')
    with pytest.raises(ConfigError, match="unknown image encoding 'yuv422'"):
        SceneConfig(encoding='yuv422')
    with pytest.raises(ConfigError, match='seed must be >= 0'):
        SceneConfig(seed=-1)
    # A stereo backdrop 1e12 px * 0.11 m / 2.5 m away hung OpenCV's warp: refused before.
    with pytest.raises(ConfigError, match=r'focal must .* got 1000000000000.0'):
        SceneConfig(kind='stereo', focal=1e12)
    with pytest.raises(ConfigError, match=r'focal must be in \[5.6, 7333\] px for an image 128'):
        SceneConfig(width=128, height=96, focal=5.5)
    for focal in (28.0, 36668.0):  # the bounds the message gives are accepted
        SceneConfig(focal=focal)
    with pytest.raises(ConfigError, match=r'baseline must be in \[0.03, 0.3\] m, got nan'):
        SceneConfig(baseline=float('nan'))
    with pytest.raises(ConfigError, match='sequence index must be >= 0'):
        next(SequenceRenderer(SceneConfig(**SMALL), 0).frames(-1))


def test_a_face_smaller_than_a_pixel_renders_as_the_background():
    # A wide field of view on a small image: the face spans 0.4 px and covers no pixel centre.
    config = SceneConfig(kind='mono', motion='static', width=32, height=32, focal=2.0, frames=1)

    frame = next(SequenceRenderer(config, 0).frames(0))

    assert frame.images['image'].shape == (32, 32)
    assert not frame.truth.visible['image'].any()


def test_a_toed_in_rig_turns_each_raw_camera_towards_the_other():
    cameras = SceneConfig(toe_in_deg=3.0).cameras()
    axes = {name: camera.r[:, 2] for name, camera in cameras.items()}  # raw optical axes
    assert axes['left'][0] == pytest.approx(np.sin(np.radians(3.0)))  # towards +x, the right
    assert axes['right'][0] == pytest.approx(-np.sin(np.radians(3.0)))
    assert all(camera.needs_rectification for camera in cameras.values())
    assert not any(camera.needs_rectification for camera in SceneConfig().cameras().values())


def test_the_key_light_comes_from_the_upper_front_within_40_degrees_of_the_axis():
    lights = [_LightPath.random(np.random.default_rng(seed)) for seed in range(200)]
    bases = np.array([light.base for light in lights])
    azimuth = np.arctan2(bases[:, 0], -bases[:, 2])  # towards +x, the subject's left
    elevation = np.arcsin(-bases[:, 1])  # y is down
    np.testing.assert_allclose(np.linalg.norm(bases, axis=1), 1.0)
    assert -0.7 <= azimuth.min() < -0.6 and 0.6 < azimuth.max() <= 0.7
    assert 0.2 <= elevation.min() < 0.25 and 0.65 < elevation.max() <= 0.7
    # The sway turns the light about the camera's y axis by at most 15 degrees.
    light = lights[0]
    directions = np.array([light.at(t).direction for t in np.linspace(0.0, 60.0, 601)])
    np.testing.assert_allclose(directions[:, 1], light.base[1])
    turn = np.arccos(
        np.clip(
            directions[:, [0, 2]] @ light.base[[0, 2]] / np.linalg.norm(light.base[[0, 2]]) ** 2,
            -1.0,
            1.0,
        )
    )
    assert np.radians(14.0) < turn.max() <= np.radians(15.0) + 1e-9


def test_an_occluder_passes_15_cm_in_front_of_the_face_once_mid_sequence():
    config = SceneConfig(kind='mono', motion='static', occlusion=True, frames=40, **SMALL_VIEW)
    renderer = SequenceRenderer(config, 0)
    sequence = renderer._sequence(0)
    occluder = sequence.occluder
    passes = [_OccluderPass.random(np.random.default_rng(seed), config) for seed in range(100)]
    for name, values, low, high in (
        ('start', [p.start for p in passes], 0.25 * 4.0 - 0.75, 0.75 * 4.0 - 0.75),
        ('height', [p.height for p in passes], 0.0, 0.08),
        ('width', [p.size[0] for p in passes], 0.03, 0.05),
        ('length', [p.size[1] for p in passes], 0.05, 0.08),
    ):
        spread = 0.1 * (high - low)  # 100 draws come this close to both ends
        assert low <= min(values) < low + spread and high - spread < max(values) <= high, name
    assert {p.duration for p in passes} == {1.5}  # min(1.5 s, half the 4 s sequence)
    camera = config.cameras()['image']
    pose = renderer._pose(sequence.trajectory, sequence.script, 0.0)
    assert occluder.at(occluder.start - 0.01, camera, pose) == ()
    assert occluder.at(occluder.start + 1.51, camera, pose) == ()
    [middle] = occluder.at(occluder.start + 0.75, camera, pose)
    depth = pose.t[2] - 0.15
    expected = camera.project(np.array([[pose.t[0], pose.t[1] + occluder.height, depth]]))[0]
    np.testing.assert_allclose(middle.centre, expected)
    np.testing.assert_allclose(middle.axes, np.array(occluder.size) * 150.0 / depth)
    # Rendered: the still face is covered in mid-pass and shows only sensor noise before it.
    before, during = (
        renderer._frame(sequence, index).images['image'].astype(float)
        for index in (0, round(10.0 * (occluder.start + 0.75)))
    )
    after = renderer._frame(sequence, 39).images['image'].astype(float)
    assert (after - before).std() < 6.0 < (during - before).std()


def test_a_sequence_rendered_with_a_given_script_and_occluder_pass():
    config = SceneConfig(kind='mono', motion='static', occlusion=True, frames=15, **SMALL_VIEW)
    renderer = SequenceRenderer(config, 0)
    smile = ExpressionSegment('smile', 0.2, 0.3, 0.4, 0.1, 0.8)

    smiling = list(renderer.frames(0, script=ExpressionScript((smile,))))
    early, late = (list(renderer.frames(0, occluder_pass=(start, 0.25))) for start in (0.0, 1.0))

    labels = [frame.truth.label for frame in smiling]
    assert labels == ['neutral'] * 3 + ['smile'] * 7 + ['neutral'] * 5
    assert [frame.truth.intensity for frame in smiling[5:8]] == [0.8] * 3  # its apex
    # The same head, light and noise: the images differ only while either pass is on (at 0.0,
    # 0.1, 0.2 s and 1.0, 1.1, 1.2 s), not elsewhere, to the bit.
    differs = [
        not np.array_equal(one.images['image'], other.images['image'])
        for one, other in zip(early, late, strict=True)
    ]
    assert differs == [True] * 3 + [False] * 7 + [True] * 3 + [False] * 2
    with pytest.raises(ConfigError, match='an occluder pass needs a scene with occlusion'):
        next(SequenceRenderer(replace(config, occlusion=False), 0).frames(0, occluder_pass=(0, 1)))
    with pytest.raises(ConfigError, match='must last more than 0 s, got 0.0'):
        next(renderer.frames(0, occluder_pass=(0.5, 0.0)))


def test_motion_blur_averages_the_poses_over_half_the_frame_period():
    config = SceneConfig(kind='mono', motion='free', motion_blur=True, seed=3, **SMALL)
    renderer = SequenceRenderer(config, 0)
    sequence = renderer._sequence(0)
    frame = renderer._frame(sequence, 2)
    time, half = 2 / 15.0, 0.25 / 15.0  # the exposure is half the 1/15 s frame period
    poses = [
        renderer._pose(sequence.trajectory, sequence.script, t)
        for t in (time - half, time, time + half)
    ]
    image, _ = renderer.renderer.render_with_visibility(
        config.cameras()['image'],
        poses,
        sequence.backgrounds['image'],
        sequence.light.at(time),
        (),
        rng=np.random.default_rng((*sequence.seeds, 2, 0)),
    )
    np.testing.assert_array_equal(frame.images['image'], image)
    np.testing.assert_array_equal(frame.truth.nodes_camera, poses[1].camera_nodes())
