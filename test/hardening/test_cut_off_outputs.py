"""Output bags cut off (a track killed, a full disk): the commands use their readable messages.

A bag cut off has its MCAP file without its end (the summary) and no ``metadata.yaml``, which
rosbags writes at the close. Each command that reads an output bag (plot, enroll, overlay,
recognition-report, learn, train-expressions) gives what it gives for a complete bag of the
messages read before the cut, and one warning on stderr names the bag, says it is cut off and
how many messages were read; a bag cut before any message it needs is refused, named.
"""

from __future__ import annotations

from pathlib import Path
import warnings

from cut_bags import cut_copy, read_until_damage, readable_copy
import numpy as np
import pytest

from face_tracking_ros.cli.main import main
from face_tracking_ros.errors import BagError, DamagedBagWarning, FaceTrackingWarning, warnings_to
from face_tracking_ros.io.bags import read_usable
from face_tracking_ros.io.series import load_states
from face_tracking_ros.pipelines.learn_options import LearnOptions
from face_tracking_ros.pipelines.mesh_bags import read_bag_meshes
from face_tracking_ros.recognition.expression import ExpressionClassifier
from face_tracking_ros.recognition.identity import IdentityGallery

from repo_root import REPO

MONO = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
CLASSIFIER = REPO / 'face_tracking_ros' / 'data' / 'default_expressions.npz'
CUT_AT = 0.5  # of the MCAP file's bytes: 14 of the 30 states read (a chunk per frame)


@pytest.fixture(scope='module')
def tracked(tmp_path_factory) -> Path:
    """The sample bag tracked with its inputs recorded: 9.6 MB, 31 MCAP chunks of 30 frames."""
    out = tmp_path_factory.mktemp('tracked') / 'subject_00_seq_00'
    track = ['track', str(MONO), '--simulate-clicks', '1', '--record-inputs', '--out', str(out)]
    assert main([*track, '--quiet']) == 0
    return out


@pytest.fixture(scope='module')
def cut(tracked, tmp_path_factory) -> tuple[Path, Path]:
    """The track cut off at half, without metadata.yaml, and a complete bag of what it gives."""
    root = tmp_path_factory.mktemp('cut')
    cut = cut_copy(tracked, root / 'subject_00_seq_00', CUT_AT, keep_metadata=False)
    return cut, readable_copy(cut, root / 'readable')


def _states_read(bag: Path) -> int:
    """How many face/state messages a cut bag gives before its damage."""
    return sum(message.topic == 'face/state' for message in read_until_damage(bag)[0])


def _warning(bag: Path, count: int, topic: str = 'face/state') -> str:
    """The line that says ``bag`` is cut off and ``count`` messages on ``topic`` were read."""
    mcap_file = next(bag.glob('*.mcap'))
    return (
        f'warning: {bag} is cut off: using the {count} messages on {topic} read before the cut '
        f'({mcap_file}: damaged MCAP file, {count} messages recovered before: the file ends part '
        'way (truncated))\n'
    )


def test_the_cut_keeps_part_of_the_track(cut):
    bag, _ = cut
    read = _states_read(bag)
    assert 5 <= read <= 25, read  # states on both sides of the cut
    assert not (bag / 'metadata.yaml').exists()


def test_plot_draws_the_states_read_before_the_cut(cut, tmp_path, capsys):
    """It refused the bag: 'error: ...: damaged MCAP file, 14 messages recovered before'."""
    bag, readable = cut
    assert main(['plot', str(bag), '--png', str(tmp_path / 'cut.png')]) == 0
    captured = capsys.readouterr()
    assert captured.err == _warning(bag, _states_read(bag))
    assert main(['plot', str(readable), '--png', str(tmp_path / 'readable.png')]) == 0
    assert capsys.readouterr().err == ''  # a complete bag: no warning
    assert (tmp_path / 'cut.png').read_bytes() == (tmp_path / 'readable.png').read_bytes()


def test_the_states_of_a_cut_bag_are_its_first_states(tracked, cut):
    bag, _ = cut
    with pytest.warns(DamagedBagWarning, match=f'{bag} is cut off: using the') as said:
        states = load_states(bag)
    assert len(said) == 1
    whole = load_states(tracked)
    read = _states_read(bag)
    assert len(states.stamps) == read
    for field in ('stamps', 'status', 'omega', 't', 'alpha', 'sigma', 'nodes', 'image_points'):
        np.testing.assert_array_equal(getattr(states, field), getattr(whole, field)[:read])


def test_enroll_enrols_the_sigma_read_before_the_cut(cut, tmp_path, capsys):
    bag, readable = cut
    galleries = tmp_path / 'cut.npz', tmp_path / 'readable.npz'
    assert main(['enroll', str(bag), '--name', 'ann', '--gallery', str(galleries[0])]) == 0
    captured = capsys.readouterr()
    assert captured.err == _warning(bag, _states_read(bag))
    assert main(['enroll', str(readable), '--name', 'ann', '--gallery', str(galleries[1])]) == 0
    said = capsys.readouterr()
    assert said.err == ''
    assert captured.out.replace(str(galleries[0]), '') == said.out.replace(str(galleries[1]), '')
    enrolled, expected = (IdentityGallery.load(gallery, 2) for gallery in galleries)
    np.testing.assert_array_equal(enrolled.means, expected.means)
    np.testing.assert_array_equal(enrolled.covariances, expected.covariances)


def test_overlay_draws_the_frames_tracked_before_the_cut(cut, tmp_path, capsys):
    bag, _ = cut
    read = _states_read(bag)
    assert main(['overlay', str(MONO), str(bag), '--video', str(tmp_path / 'v.gif')]) == 0
    captured = capsys.readouterr()
    assert f'wrote {read} frames to ' in captured.out
    assert captured.err == _warning(bag, read)


def test_recognition_report_scores_the_frames_read_before_the_cut(cut, capsys):
    """Enrolled from and tested on the same cut track: one warning, not one per use."""
    bag, readable = cut
    reports = []
    for tracked in (bag, readable):
        pairs = f'{tracked}={MONO}'
        report = ['recognition-report', '--enrol', pairs, '--test', pairs]
        assert main([*report, '--classifier', str(CLASSIFIER)]) == 0
        reports.append(capsys.readouterr())
    assert reports[0].err == _warning(bag, _states_read(bag))
    assert reports[1].err == ''
    assert reports[0].out == reports[1].out


def test_learn_reads_the_meshes_before_the_cut(cut, tmp_path):
    """The face/mesh_raw meshes, and beside them the face/state that says which were tracked."""
    bag, readable = cut
    options = LearnOptions(bags=(bag,), out=tmp_path / 'm.npz', report=tmp_path / 'r.json')
    name = 'subject_00_seq_00'
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter('default')
        meshes = read_bag_meshes(bag, options, None, name, say=lambda _: None)
    lines = [f'warning: {warning.message}\n' for warning in said]
    read = _states_read(bag)
    assert lines == [_warning(bag, read), _warning(bag, read, 'face/mesh_raw')]
    expected = read_bag_meshes(readable, options, None, name, say=lambda _: None)
    assert [m.sequence.subject_id for m in meshes] == [m.sequence.subject_id for m in expected]
    for got, want in zip(meshes, expected, strict=True):
        assert len(got.sequence.meshes) == read
        np.testing.assert_array_equal(got.sequence.meshes, want.sequence.meshes)


def test_train_expressions_trains_on_the_truth_before_the_cut(tmp_path, capsys):
    """A synthetic bag cut off (a synth killed): the truth frames read before the cut."""
    bag = cut_copy(MONO, tmp_path / 'subject_00_seq_00', CUT_AT, keep_metadata=False)
    readable = readable_copy(bag, tmp_path / 'readable')
    read = sum(message.topic == 'truth/face' for message in read_until_damage(bag)[0])
    outputs = []
    for source, out in ((bag, tmp_path / 'cut.npz'), (readable, tmp_path / 'readable.npz')):
        assert main(['train-expressions', str(source), '--out', str(out)]) == 0
        outputs.append(capsys.readouterr())
    assert outputs[0].err == _warning(bag, read, 'truth/face')
    assert outputs[1].err == ''
    assert outputs[0].out.replace('cut.npz', '') == outputs[1].out.replace('readable.npz', '')
    trained, expected = (
        ExpressionClassifier.load(tmp_path / f'{name}.npz', 6) for name in ('cut', 'readable')
    )
    assert trained.labels == expected.labels
    np.testing.assert_array_equal(trained.weights, expected.weights)


def test_a_bag_cut_before_what_a_command_needs_is_refused_named(tracked, cut, tmp_path, capsys):
    """Nothing readable at all, or none of the messages needed: an error naming the bag."""
    early = cut_copy(tracked, tmp_path / 'early', 0.005, keep_metadata=False)  # in chunk 1
    assert read_until_damage(early)[0] == []
    assert main(['plot', str(early), '--png', str(tmp_path / 'p.png')]) == 2
    mcap_file = next(early.glob('*.mcap'))
    assert capsys.readouterr().err == (
        f'error: {mcap_file}: damaged MCAP file, 0 messages recovered before: the file ends part '
        'way (truncated)\n'
    )
    bag, _ = cut  # a track holds no truth: nothing to train on
    assert main(['train-expressions', str(bag), '--out', str(tmp_path / 'c.npz')]) == 2
    assert capsys.readouterr().err == (
        f'error: {bag}: no message on truth/face could be read, nothing to use: '
        f'{next(bag.glob("*.mcap"))}: damaged MCAP file, 0 messages recovered before: the file '
        'ends part way (truncated)\n'
    )
    assert not (tmp_path / 'p.png').exists() and not (tmp_path / 'c.npz').exists()
    with pytest.raises(BagError, match=f'{early}: no message on image could be read'):
        list(read_usable(early, ['image']))


def test_the_package_s_warnings_go_to_the_one_told_others_as_python_shows_them():
    """The command line prints them as 'warning: ...', a node logs them (the learner)."""
    told: list[str] = []
    with pytest.warns(RuntimeWarning) as shown, warnings_to(told.append):
        warnings.warn('a bag used in part', FaceTrackingWarning, stacklevel=1)
        warnings.warn('a library speaks', RuntimeWarning, stacklevel=1)
    assert told == ['a bag used in part']
    assert [(w.category, str(w.message)) for w in shown] == [(RuntimeWarning, 'a library speaks')]
