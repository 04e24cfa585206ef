"""``face-tracking enroll`` and ``plot`` on tracker outputs, and on outputs they cannot use."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
import json
from pathlib import Path
import shutil

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from zeroed_bags import zeroed_copy

from face_tracking_ros.cli.main import main
from face_tracking_ros.data import default_model_path
from face_tracking_ros.errors import ConfigError, ModelFileError
from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import BagWriter, bag_topics, read_messages
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.provenance import KEY as PROVENANCE_KEY
from face_tracking_ros.io.provenance import Provenance
from face_tracking_ros.io.series import load_states
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.model.model_file import load_model, save_model
from face_tracking_ros.processing.identity import make_identity_processor
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.recognition.identity import IdentityConfig, IdentityGallery
from face_tracking_ros.synthetic.clicks import clicks_from_bag, write_init_file
from face_tracking_ros.tracking.initialisation import Initialisation, load_init_file
from face_tracking_ros.tracking.result import TrackStatus

from repo_root import REPO

STATE = 'face_tracking_msgs/msg/FaceState'


def _states(
    path: Path,
    sigmas: np.ndarray,
    status: int = TrackStatus.TRACKING,
    model_file: str | None = None,
    alphas: np.ndarray | None = None,
) -> Path:
    """A tracker output bag: face/state with these (F, p) sigma, every frame of one status.

    With ``alphas``, (F, q), the states carry them too.

    With ``model_file``, its metadata says the mono_tracker made it with that model ('': the
    packaged default), as replay records it.
    """
    factory = RosbagsMessages(typestore())
    with BagWriter(path) as writer:
        if model_file is not None:
            parameters = {'model_file': model_file} if model_file else {}
            provenance = Provenance.of(path.with_name('raw'), ['mono_tracker'], parameters)
            writer.set_custom_data(PROVENANCE_KEY, provenance.text())
        for f, sigma in enumerate(sigmas):
            header = conversions.make_header(factory, 1000 + f, 'camera')
            alpha = np.zeros(0) if alphas is None else alphas[f]
            state = factory.make(STATE, header=header, status=status, sigma=sigma, alpha=alpha)
            writer.write('face/state', STATE, state, 1000 + f)
    return path


def test_a_tracked_identity_is_enrolled_and_a_model_less_track_refused(tmp_path, capsys):
    sigmas = np.random.default_rng(0).normal([0.01, -0.02], 0.001, (20, 2))
    gallery = tmp_path / 'gallery.npz'
    assert main(['enroll', str(_states(tmp_path / 'ann', sigmas)), '--name', 'ann',
                 '--gallery', str(gallery)]) == 0  # fmt: skip
    enrolled = IdentityGallery.load(gallery, 2)
    assert enrolled.names == ('ann',)
    np.testing.assert_allclose(enrolled.means[0], sigmas.mean(axis=0))
    floor = np.cov(sigmas, rowvar=False) + IdentityConfig().min_std ** 2 * np.eye(2)
    np.testing.assert_allclose(enrolled.covariances[0], floor)
    assert "enrolled 'ann' from 20 shape estimates" in capsys.readouterr().out
    assert main(['enroll', str(tmp_path / 'ann'), '--name', 'ann', '--gallery', str(gallery),
                 '--min-std', '0.01']) == 0  # fmt: skip
    out = capsys.readouterr().out  # the same name again: said to replace the entry
    assert "enrolled 'ann' (replacing the earlier 'ann') from 20 shape estimates" in out
    assert out.endswith(f'{gallery} holds ann\n')
    floor = np.cov(sigmas, rowvar=False) + 0.01**2 * np.eye(2)
    np.testing.assert_allclose(IdentityGallery.load(gallery, 2).covariances[0], floor)
    # A stereo_tracker's output without a face model: states without sigma.
    bare = _states(tmp_path / 'bare', np.zeros((5, 0)))
    assert main(['enroll', str(bare), '--name', 'bob', '--gallery', str(gallery)]) == 2
    assert f'{bare}: its face/state carries no sigma (a stereo' in capsys.readouterr().err
    assert IdentityGallery.load(gallery, 2).names == ('ann',)  # the gallery as it was
    # A file that cannot be written is the user's matter: a message, not a traceback.
    absent = tmp_path / 'absent' / 'gallery.npz'
    assert main(['enroll', str(tmp_path / 'ann'), '--name', 'ann', '--gallery', str(absent)]) == 2
    assert 'error: ' in (err := capsys.readouterr().err) and 'absent' in err


def test_tracking_frames_whose_sigma_has_a_nan_are_left_out_and_counted(tmp_path, capsys):
    """They were left out silently: enrolled from 5 of 6 TRACKING frames, no word of the 6th."""
    sigmas = np.random.default_rng(2).normal([0.01, -0.02], 0.001, (6, 2))
    sigmas[3, 1] = np.nan
    gallery = tmp_path / 'gallery.npz'
    bag = _states(tmp_path / 'ann', sigmas)
    assert main(['enroll', str(bag), '--name', 'ann', '--gallery', str(gallery)]) == 0
    out = capsys.readouterr().out
    assert "enrolled 'ann' from 5 shape estimates" in out
    assert ', leaving out 1 TRACKING frame whose sigma has a NaN or inf; ' in out
    kept = np.delete(sigmas, 3, axis=0)
    np.testing.assert_allclose(IdentityGallery.load(gallery, 2).means[0], kept.mean(axis=0))
    void = _states(tmp_path / 'void', np.full((2, 2), np.nan))
    assert main(['enroll', str(void), '--name', 'bea', '--gallery', str(gallery)]) == 2
    expected = f'no TRACKING frame whose sigma is finite (2 have a NaN or inf) in {void}: nothing'
    assert expected in capsys.readouterr().err


def test_a_track_enrolled_under_one_name_is_refused_under_another(tmp_path, capsys):
    """The same estimates under two names made recognition tie between them: refused, named."""
    sigmas = np.random.default_rng(1).normal([0.01, -0.02], 0.001, (20, 2))
    gallery = tmp_path / 'gallery.npz'
    enroll = ['--gallery', str(gallery)]
    assert main(['enroll', str(_states(tmp_path / 'ann', sigmas)), '--name', 'ann', *enroll]) == 0
    capsys.readouterr()
    # The same track copied, its frames in another order (the mean summed in another order).
    copy = _states(tmp_path / 'copy', sigmas[::-1])
    assert main(['enroll', str(copy), '--name', 'bea', *enroll]) == 2
    assert capsys.readouterr().err == (
        f"error: {copy}: these 20 shape estimates are the ones {gallery} holds as 'ann' (the "
        "same mean sigma): enrolled as 'bea' too, the identity_recognizer could not tell the "
        "two apart (they tie); enrol them as 'ann' to replace that entry, or enrol 'bea' from "
        'other recordings\n'
    )
    assert IdentityGallery.load(gallery, 2).names == ('ann',)  # the gallery as it was
    # Under its own name it replaces the entry; the estimates of another track are enrolled,
    # even 0.1 um from ann's (a lookalike is the recogniser's matter: acceptance, posteriors).
    assert main(['enroll', str(copy), '--name', 'ann', *enroll]) == 0
    other = _states(tmp_path / 'bea', sigmas + 1e-7)
    assert main(['enroll', str(other), '--name', 'bea', *enroll]) == 0
    assert IdentityGallery.load(gallery, 2).names == ('ann', 'bea')


def test_a_gallery_holds_the_sigma_of_the_model_the_bags_were_tracked_with(tmp_path, capsys):
    default = load_model(default_model_path())
    other = save_model(replace(default, shape_basis=-default.shape_basis), tmp_path / 'other.npz')
    sigmas = np.random.default_rng(0).normal([0.01, -0.02], 0.001, (20, 2))
    ann = _states(tmp_path / 'ann', sigmas, model_file=str(other))
    gallery = tmp_path / 'gallery.npz'
    enroll = ['enroll', str(ann), '--name', 'ann', '--gallery', str(gallery)]
    # Without --model, the model the bag's metadata names.
    assert main(enroll) == 0
    assert f'of the model {other} (fingerprint {load_model(other).fingerprint})' in (
        capsys.readouterr().out
    )
    assert IdentityGallery.load(gallery, 2).model == load_model(other).fingerprint
    assert main([*enroll, '--model', str(default_model_path())]) == 2
    assert f'{ann} was tracked with the face model {other}, not ' in capsys.readouterr().err
    bob = _states(tmp_path / 'bob', sigmas, model_file='')  # the packaged default
    assert main(['enroll', str(ann), str(bob), '--name', 'x', '--gallery', str(gallery)]) == 2
    assert 'tracked with different face models' in capsys.readouterr().err
    wide = _states(tmp_path / 'wide', np.zeros((5, 3)))
    assert main(['enroll', str(bob), str(wide), '--name', 'x', '--gallery', str(gallery)]) == 2
    assert f'different p ({bob} p=2, {wide} p=3)' in capsys.readouterr().err
    assert main(['enroll', str(bob), '--name', 'bob', '--gallery', str(gallery)]) == 2
    assert 'made with another face model' in capsys.readouterr().err
    # The recogniser refuses the gallery with another model than the one it was enrolled with.
    factory = RosbagsMessages(typestore())
    with pytest.raises(ModelFileError, match='enrol the people again with it'):
        make_identity_processor(OverrideParameters({'gallery_file': str(gallery)}), factory)
    with_model = {'gallery_file': str(gallery), 'model_file': str(other)}
    assert make_identity_processor(OverrideParameters(with_model), factory).gallery.names == (
        'ann',
    )
    # A model file changed since the bag was tracked.
    save_model(replace(default, shape_basis=default.shape_basis[:, ::-1]), other)
    assert main([*enroll[:-1], str(tmp_path / 'g2.npz')]) == 2
    assert 'which is gone or has changed since: give that model as --model' in (
        capsys.readouterr().err
    )


def test_a_model_less_track_is_not_plotted(tmp_path, capsys):
    bare = _states(tmp_path / 'bare', np.zeros((5, 0)))
    assert main(['plot', str(bare), '--png', str(tmp_path / 'p.png')]) == 2
    assert f'{bare}: its face/state carries no sigma or alpha (a stereo' in capsys.readouterr().err
    assert not (tmp_path / 'p.png').exists()


def test_a_track_is_plotted_against_the_truth_of_its_own_bag_only(tmp_path, capsys):
    """As learn and recognition-report, by the input bag the track's metadata records."""
    states = _states(tmp_path / 'states', np.zeros((3, 2)), model_file='', alphas=np.zeros((3, 1)))
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    own, other = shutil.copytree(mono, tmp_path / 'raw'), shutil.copytree(mono, tmp_path / 'o')
    plot = ['plot', str(states), '--png', str(tmp_path / 'p.png'), '--truth']
    assert main([*plot, str(other)]) == 2
    assert f'--truth {other}: {states} was tracked from {own}, not from {other}' in (
        capsys.readouterr().err
    )
    assert not (tmp_path / 'p.png').exists()
    assert main([*plot, str(own)]) == 0  # the bag the states record (tmp_path / 'raw')
    assert (tmp_path / 'p.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_track_that_tracks_no_image_ends_with_status_1(tmp_path, capsys):
    """A bag whose camera_info is missing: every image is held, none tracked."""
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    init = write_init_file(clicks_from_bag(mono, 0.0), tmp_path / 'init.json')
    uncalibrated = tmp_path / 'uncalibrated'
    with BagWriter(uncalibrated) as writer:
        for message in read_messages(mono, ['image', 'truth/face']):
            writer.write(message.topic, message.msgtype, message.msg, message.stamp_ns)
    argv = ['track', str(uncalibrated), '--init', str(init), '--out', str(tmp_path / 'o')]
    assert main([*argv, '--quiet']) == 1
    printed = capsys.readouterr().out
    assert 'no calibration on camera_info yet' in printed
    assert 'no image was tracked (the input problems or last_reason above say why)' in printed


def _copied(source: Path, bag: Path, kept: Callable[[str], bool]) -> Path:
    """A copy of ``source`` at ``bag`` declaring every topic, the messages of ``kept`` ones."""
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        store = typestore()
        connections = {
            topic: writer.add_connection(topic, msgtype, typestore=store)
            for topic, msgtype in bag_topics(source).items()
        }
        for message in read_messages(source):
            if kept(message.topic):
                data = store.serialize_cdr(message.msg, message.msgtype)
                writer.write(connections[message.topic], message.stamp_ns, data)
    return bag


def test_track_of_a_bag_without_images_names_the_empty_image_topic(tmp_path, capsys):
    """'read: none' and 'the input problems or last_reason above say why', which none did."""
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    init = write_init_file(clicks_from_bag(mono, 0.0), tmp_path / 'init.json')
    bag = _copied(mono, tmp_path / 'no_images', lambda topic: topic == 'camera_info')
    argv = ['track', str(bag), '--init', str(init), '--out', str(tmp_path / 'o'), '--quiet']
    assert main(argv) == 1
    printed = capsys.readouterr().out
    assert 'read: 30 camera_info\n' in printed
    expected = 'no image was tracked: the bag holds no message on image, the image topic the '
    assert f'{expected}mono_tracker reads\n' in printed


def test_track_of_a_stereo_bag_with_one_side_empty_names_that_side(tmp_path, capsys):
    """Left images and both camera_infos but no right image: every left image goes unpaired."""
    stereo = REPO / 'bags' / 'stereo_train' / 'subject_00_seq_00'
    bag = _copied(stereo, tmp_path / 'no_right', lambda topic: topic != 'right/image_raw')
    argv = ['track', str(bag), '--simulate-clicks', '0', '--out', str(tmp_path / 'o'), '--quiet']
    assert main(argv) == 1
    printed = capsys.readouterr().out
    assert 'unpaired_images 10' in printed
    expected = (
        'no pair was tracked: the bag holds no message on right/image_raw, one of the image '
        'topics the stereo_tracker reads, so no image on left/image_raw had its pair\n'
    )
    assert expected in printed


def test_track_of_a_truncated_bag_keeps_its_track_and_does_not_score_it(tmp_path, capsys):
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    cut = tmp_path / 'cut'
    shutil.copytree(mono, cut)
    mcap_file = next(cut.glob('*.mcap'))
    mcap_file.write_bytes(mcap_file.read_bytes()[: mcap_file.stat().st_size // 2])
    argv = ['track', str(cut), '--simulate-clicks', '0', '--out', str(tmp_path / 'o')]
    assert main([*argv, '--quiet']) == 1
    printed = capsys.readouterr().out
    assert 'not scored against the truth: the bag is damaged (above)' in printed
    states = [m.msg.status for m in read_messages(tmp_path / 'o', ['face/state'])]
    assert 5 < len(states) < 30 and set(states) == {TrackStatus.TRACKING}


def test_track_of_a_bag_zeroed_in_its_middle_tracks_the_rest_and_is_not_complete(tmp_path, capsys):
    """The messages under the zeros vanish silently in the reader; the summary counts them."""
    zeroed = tmp_path / 'zeroed'
    lost = zeroed_copy(REPO / 'bags' / 'mono_test' / 'subject_00_seq_00', zeroed)
    assert lost['image'] > 0
    out = tmp_path / 'o'
    argv = ['track', str(zeroed), '--simulate-clicks', '0', '--out', str(out), '--quiet']
    assert main(argv) == 1
    printed = capsys.readouterr().out
    short = ', '.join(
        f'{30 - lost[topic]} of the 30 messages on {topic}'
        for topic in ('camera_info', 'image')
        if lost[topic]
    )
    assert (
        f'input bag damaged, replayed its readable part: {zeroed}: damaged MCAP file, read only '
        f'{short} that its summary counts (the others are unreadable)'
    ) in printed
    assert 'not scored against the truth: the bag is damaged (above)' in printed
    provenance = Provenance.read(out)
    assert provenance is not None and not provenance.complete
    states = [m.msg.status for m in read_messages(out, ['face/state'])]
    assert states == [TrackStatus.TRACKING] * (30 - lost['image'])


def test_an_output_bag_of_inconsistent_states_is_named_not_a_traceback(tmp_path, capsys):
    factory = RosbagsMessages(typestore())
    odd = tmp_path / 'odd'
    with BagWriter(odd) as writer:
        for f, (status, sigma) in enumerate([(1, [0.0, 0.0]), (1, [0.0, 0.0, 0.0])]):
            header = conversions.make_header(factory, 1000 + f, 'camera')
            state = factory.make(STATE, header=header, status=status, sigma=np.array(sigma))
            writer.write('face/state', STATE, state, 1000 + f)
    assert main(['plot', str(odd), '--png', str(tmp_path / 'p.png')]) == 2
    expected = 'face/state message 1: FaceState.sigma has shape (3,), message 0 (2,)'
    assert expected in capsys.readouterr().err
    unknown = _states(tmp_path / 'unknown', np.zeros((3, 2)), status=77)
    assert main(['enroll', str(unknown), '--name', 'x', '--gallery', str(tmp_path / 'g.npz')]) == 2
    assert 'face/state message 0: FaceState.status 77 is unknown' in capsys.readouterr().err


def test_outputs_that_exist_or_options_out_of_range_are_refused_before_any_work(tmp_path, capsys):
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    taken = tmp_path / 'taken'
    taken.mkdir()
    assert main(['track', str(mono), '--simulate-clicks', '5', '--out', str(taken)]) == 2
    assert f'--out {taken} exists' in capsys.readouterr().err
    assert not (tmp_path / 'taken.init.json').exists()  # the clicks of a run that did not run
    states = _states(tmp_path / 'states', np.zeros((3, 2)))
    plot = ['plot', str(states), '--png']
    assert main([*plot, str(tmp_path / 'p.txt')]) == 2
    assert 'p.txt: give a file name ending in .png' in capsys.readouterr().err
    assert main([*plot, str(tmp_path / 'p.png'), '--truth', str(states)]) == 2
    assert f'--truth {states} holds no truth/face' in capsys.readouterr().err
    video = ['overlay', str(mono), str(states), '--video', str(tmp_path / 'v.mp4')]
    assert main([*video, '--every', '0']) == 2
    assert '--every must be >= 1, got 0' in capsys.readouterr().err


def test_simulated_clicks_need_a_noise_of_0_or_more_and_replace_only_earlier_clicks(
    tmp_path, capsys
):
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    out, clicks = tmp_path / 'o', tmp_path / 'o.init.json'
    track = ['track', str(mono), '--out', str(out), '--quiet', '--simulate-clicks']
    refused = '--simulate-clicks must be a finite number of pixels >= 0 (0: exact), got'
    for noise in ('-1', 'nan', 'inf'):
        assert main([*track, noise]) == 2
        assert f'{refused} {float(noise)}' in capsys.readouterr().err
    assert not out.exists() and not clicks.exists()
    clicks.write_text('notes')  # another file where the clicks would go
    assert main([*track, '0']) == 2
    assert (
        f'--simulate-clicks: {clicks} exists and is not an init file (init file {clicks} is not '
        'valid JSON'
    ) in capsys.readouterr().err
    assert clicks.read_text() == 'notes'
    exact = write_init_file(clicks_from_bag(mono, 0.0), clicks).read_text()
    assert main([*track, '1', '--model', str(clicks)]) == 2  # the track's input
    assert f'--simulate-clicks: {clicks} (where the clicks go) is an input of this track' in (
        capsys.readouterr().err
    )
    assert main([*track, '1', '--report', str(clicks)]) == 2  # written after the track
    assert f'--report {clicks} is an input of this track' in capsys.readouterr().err
    assert clicks.read_text() == exact and not out.exists()
    assert main([*track, '1']) == 0  # earlier clicks are replaced
    assert clicks.read_text() != exact and load_init_file(clicks).node_names


def test_a_track_refused_by_its_replay_writes_no_clicks(tmp_path, capsys):
    """The replay's own refusals came after OUT.init.json (and OUT's parent) were written."""
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    out = tmp_path / 'new' / 'o'
    track = ['track', str(mono), '--out', str(out), '--quiet', '--simulate-clicks', '1']
    cases = [
        (['--remap', 'imgae=/image'], "remap imgae=/image: 'imgae' is not an input of"),
        (['--remap', 'image=/nothere'], "topic '/nothere' for input 'image' must be"),
        (['--param', 'tracker.epsilon=2'], 'invalid parameter tracker.epsilon = 2.0'),
        (['--param', 'nosuch=1'], 'unknown parameter nosuch'),
        (['--param', 'tracker.epsilon'], "parameter 'tracker.epsilon' must be written name="),
        (['--param', '=2'], "parameter '=2' must be written name=value"),
        (['--want', 'face/nothing'], 'face/nothing: not an on-demand output of mono_tracker'),
    ]
    for argv, expected in cases:
        assert main([*track, *argv]) == 2
        assert f'error: {expected}' in capsys.readouterr().err, argv
    stereo = ['track', str(REPO / 'bags' / 'stereo_train' / 'subject_00_seq_00'), *track[2:]]
    assert main([*stereo, '--remap', 'left=/left/image_raw']) == 2
    assert "error: remap left=/left/image_raw: 'left' is not an input of stereo_tracker" in (
        capsys.readouterr().err
    )
    assert list(tmp_path.iterdir()) == []


def test_a_malformed_remap_is_refused_before_the_track_starts(tmp_path, capsys):
    """--remap is parsed once, before the other checks: mono or stereo, nothing printed."""
    for bag in ('mono_test', 'stereo_train'):
        argv = ['track', str(REPO / 'bags' / bag / 'subject_00_seq_00'), '--out',
                str(tmp_path / 'o'), '--simulate-clicks', '1', '--remap', 'image']  # fmt: skip
        assert main(argv) == 2
        printed = capsys.readouterr()
        assert printed.err == "error: remap 'image' must be written INPUT=TOPIC\n", bag
        assert printed.out == '', bag
    assert list(tmp_path.iterdir()) == []


def test_an_init_file_or_model_given_twice_is_refused_not_chosen_silently(tmp_path, capsys):
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    out = tmp_path / 'o'
    track = ['track', str(mono), '--out', str(out), '--quiet']
    cases = [
        (['--simulate-clicks', '1', '--param', 'init_file=a.yaml'], '--simulate-clicks', 'init'),
        (['--init', 'b.yaml', '--param', 'init_file=a.yaml'], '--init', 'init'),
        (['--auto-init', '--model', 'm.npz', '--param', 'model_file=n.npz'], '--model', 'model'),
    ]
    for argv, option, name in cases:
        assert main([*track, *argv]) == 2
        assert f'error: {option} and --param {name}_file=' in capsys.readouterr().err, argv
    assert list(tmp_path.iterdir()) == []


def test_a_camera_info_topic_without_messages_is_named_not_a_traceback(tmp_path, capsys):
    """ros2 bag record keeps a topic whose publisher never sent: declared, no message."""
    source = REPO / 'bags' / 'stereo_train' / 'subject_00_seq_00'
    bag = _copied(source, tmp_path / 'empty_info', lambda topic: topic != 'left/camera_info')
    out = tmp_path / 'o'
    assert main(['track', str(bag), '--simulate-clicks', '1', '--out', str(out)]) == 2
    expected = 'simulated clicks need a message on left/camera_info, which has none'
    assert expected in capsys.readouterr().err
    tracked = tmp_path / 'tracked'  # the same pairs, tracked with their calibration
    assert main(['track', str(source), '--simulate-clicks', '0', '--out', str(tracked)]) == 0
    video = ['overlay', str(bag), str(tracked), '--video', str(tmp_path / 'v.mp4')]
    assert main(video) == 0  # drawn as recorded: no calibration to rectify with
    assert 'wrote 10 frames' in capsys.readouterr().out


def test_a_calibration_the_clicks_cannot_use_is_named_with_its_bag_and_topic(tmp_path, capsys):
    """It said only 'invalid camera: K, P, D or R holds NaN or Inf', of no bag or topic."""
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    bag = tmp_path / 'nan_k'
    with BagWriter(bag) as writer:
        for message in read_messages(mono):
            msg = message.msg
            if message.topic == 'camera_info':
                msg = replace(msg, k=np.array([np.nan, *msg.k[1:]]))
            writer.write(message.topic, message.msgtype, msg, message.stamp_ns)
    assert main(['track', str(bag), '--simulate-clicks', '1', '--out', str(tmp_path / 'o')]) == 2
    assert capsys.readouterr().err == (
        f'error: {bag}: camera_info: invalid camera: K, P, D or R holds NaN or Inf\n'
    )
    assert not (tmp_path / 'o').exists()


def test_a_stereo_bag_whose_first_right_calibration_is_void_is_scored_with_the_next(
    tmp_path, capsys
):
    source = REPO / 'bags' / 'stereo_train' / 'subject_00_seq_00'
    bag = tmp_path / 'first_void'
    first = True
    with BagWriter(bag) as writer:
        for message in read_messages(source):
            msg = message.msg
            if message.topic == 'right/camera_info' and first:
                msg, first = replace(msg, k=np.zeros(9)), False  # refused by the tracker too
            writer.write(message.topic, message.msgtype, msg, message.stamp_ns)
    argv = ['track', str(bag), '--simulate-clicks', '0', '--out', str(tmp_path / 'o')]
    assert main([*argv, '--quiet']) == 0
    printed = capsys.readouterr().out
    assert '1x right/camera_info: camera_info has an all-zero K' in printed
    assert '9 frames, 100% tracked: 3-D node RMS' in printed


def test_a_frame_without_estimates_reads_as_nan_among_frames_with_them(tmp_path):
    """A stereo_tracker with a model publishes no alpha or sigma for a pair it could not fit."""
    sigmas = [np.array([0.01, 0.02]), np.zeros(0), np.array([0.03, 0.04])]
    states = load_states(_states(tmp_path / 'gap', sigmas))
    np.testing.assert_array_equal(states.sigma, [[0.01, 0.02], [np.nan, np.nan], [0.03, 0.04]])


def test_stereo_clicks_with_left_and_right_swapped_are_named(tmp_path, capsys):
    """Clicks named as the image shows them (the subject's left on the image's left).

    A face seen from behind fits them (its nose 9 mm behind its eyes; right clicks: 22-31 mm in
    front, on 72 synthetic subjects); they tracked 83 mm off as TRACKING.
    """
    bag = REPO / 'bags' / 'stereo_train' / 'subject_00_seq_00'
    clicks = clicks_from_bag(bag, 0.0)
    swapped = {'left': 'right', 'right': 'left'}
    names = tuple(
        '_'.join(swapped.get(part, part) for part in name.split('_')) for name in clicks.node_names
    )
    mirrored = write_init_file(Initialisation(names, clicks.points), tmp_path / 'mirrored.json')
    argv = ['track', str(bag), '--init', str(mirrored), '--out', str(tmp_path / 'o'), '--quiet']
    assert main(argv) == 1
    printed = capsys.readouterr().out
    assert (
        'initializing_pairs 10, tracking_pairs 0, lost_pairs 0' in printed
        and 'fit a face turned away from the camera' in printed
    )
    assert 'are left and right swapped?' in printed


def test_the_recognizer_node_refuses_an_enrolment_it_cannot_save(tmp_path):
    """No traceback from the node's service: the enrolment is refused, the gallery unchanged."""
    factory = RosbagsMessages(typestore())
    absent = tmp_path / 'absent' / 'gallery.npz'
    processor = make_identity_processor(OverrideParameters({'gallery_file': str(absent)}), factory)
    for f in range(10):
        header = conversions.make_header(factory, 10**9 + f * 10**8, 'camera')
        shape = factory.make(
            'face_tracking_msgs/msg/ShapeParams', header=header, sigma=[0.01, 0.0]
        )
        processor.handle('face/shape', shape, frozenset())
    assert processor.status()['gallery_file'].endswith(
        f'no directory {absent.parent}, enrolments cannot be saved'
    )
    with pytest.raises(ConfigError, match=r"cannot enrol 'ann': the gallery cannot be saved"):
        processor.enroll('ann', 1.0)
    assert processor.gallery.names == ()
    for duration in (np.nan, 1e-9, np.inf):  # (inf: the history would grow without bound)
        bad = {'max_enroll_duration': str(duration)}
        with pytest.raises(ConfigError, match='max_enroll_duration must be > 1e-06 s'):
            make_identity_processor(OverrideParameters(bad), factory)


def test_the_demo_does_not_empty_a_directory_it_did_not_make(tmp_path, capsys):
    """`demo --out DIR` deleted any existing DIR: a user's data directory went with it."""
    (tmp_path / 'data').mkdir()
    (tmp_path / 'data' / 'recording.mcap').write_bytes(b'mine')
    assert main(['demo', '--out', str(tmp_path / 'data')]) == 2
    assert 'exists and was not made by the demo: not emptied' in capsys.readouterr().err
    assert (tmp_path / 'data' / 'recording.mcap').read_bytes() == b'mine'


def test_a_model_given_as_a_parameter_is_the_one_clicked_and_scored(tmp_path, capsys):
    """The model of --param model_file (as of --model) is the one the clicks are made for.

    The clicks named the packaged 34-node model's nodes, which the 19-node model lacks: every
    image was refused.
    """
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    argv = ['track', str(mono), '--simulate-clicks', '1', '--out', str(tmp_path / 'o'), '--quiet',
            '--param', f'model_file={default_model_path(19)}']  # fmt: skip
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert 'node RMS' in printed and 'lacks' not in printed
    assert load_states(tmp_path / 'o').nodes.shape[1] == 19


def test_a_report_that_is_an_input_or_not_json_is_not_written_over(tmp_path, capsys):
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    model = tmp_path / 'model.npz'
    shutil.copy(default_model_path(34), model)
    track = ['track', str(mono), '--simulate-clicks', '1', '--model', str(model)]
    assert main([*track, '--out', str(tmp_path / 'a'), '--report', str(model)]) == 2
    assert f'--report {model} is an input of this track' in capsys.readouterr().err
    notes = tmp_path / 'notes.txt'
    notes.write_text('not a report')
    assert main([*track, '--out', str(tmp_path / 'b'), '--report', str(notes)]) == 2
    assert 'is not a JSON report: not written over' in capsys.readouterr().err
    assert notes.read_text() == 'not a report'
    assert load_model(model).num_nodes == 34


def test_a_report_goes_into_new_directories_as_the_tracked_bag_does(tmp_path):
    """The demo's layout: --out and --report in a directory the track makes."""
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    tracked = tmp_path / 'tracked'
    argv = ['track', str(mono), '--simulate-clicks', '1', '--quiet', '--out', str(tracked / 'o')]
    assert main([*argv, '--report', str(tracked / 'o.json')]) == 0
    report = json.loads((tracked / 'o.json').read_text())
    assert (report['frames'], report['tracked'], report['lost']) == (30, 30, 0)


def test_a_report_of_figures_a_track_cannot_give_is_json_with_nulls(tmp_path):
    """One frame: no drift, jitter or alpha range. The report said NaN, which is not JSON."""
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    one = tmp_path / 'one'
    with BagWriter(one) as writer:
        for message in read_messages(mono):
            if message.stamp_ns == 1_700_000_000 * 10**9:
                writer.write(message.topic, message.msgtype, message.msg, message.stamp_ns)
    argv = ['track', str(one), '--simulate-clicks', '0', '--quiet', '--out', str(tmp_path / 'o')]
    assert main([*argv, '--report', str(tmp_path / 'o.json')]) == 0

    def refuse(constant: str) -> None:
        raise ValueError(constant)

    report = json.loads((tmp_path / 'o.json').read_text(), parse_constant=refuse)
    assert (report['frames'], report['tracked']) == (1, 1)
    assert [report[key] for key in ('alpha_rms_percent', 'drift_deg', 'jitter_deg')] == [None] * 3
    assert 0 < report['node_rms_mm'] < 50


def test_an_init_file_naming_a_node_the_model_lacks_is_named_not_the_model(tmp_path, capsys):
    """It said 'the face model has 34 nodes but the initialisation names ...: model refused'."""
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    clicks = clicks_from_bag(mono, 1.0)
    names = tuple('nose_tipp' if name == 'nose_tip' else name for name in clicks.node_names)
    init = write_init_file(replace(clicks, node_names=names), tmp_path / 'clicks.json')
    assert main(['track', str(mono), '--init', str(init), '--out', str(tmp_path / 'o')]) == 2
    model = load_model(default_model_path(34))
    assert capsys.readouterr().err == (
        f'error: init file {init} names 1 node (nose_tipp) that the 34-node face model lacks '
        f'(misspelt? its nodes: {", ".join(model.node_names)})\n'
    )


def test_an_init_file_whose_sigma_is_of_another_length_is_named(tmp_path, capsys):
    """It said 'the initialisation holds 3 sigma values', naming no file."""
    mono = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    clicks = replace(clicks_from_bag(mono, 1.0), sigma=np.zeros(3))
    init = write_init_file(clicks, tmp_path / 'clicks.json')
    assert main(['track', str(mono), '--init', str(init), '--out', str(tmp_path / 'o')]) == 2
    assert capsys.readouterr().err == (
        f'error: init file {init} holds 3 sigma values, the face model p = 2\n'
    )
