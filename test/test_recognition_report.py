"""``face-tracking recognition-report`` on tracker-like output bags paired with truth bags."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
import shutil

import numpy as np
import pytest
from recognition_streams import truth_model, write_truth_bag

from face_tracking_ros.cli import main as cli
from face_tracking_ros.cli.recognition_report import tracked_sequence
from face_tracking_ros.cli.train_expressions import truth_sequences
from face_tracking_ros.errors import BagError, ConfigError
from face_tracking_ros.io.bags import BagWriter, read_messages
from face_tracking_ros.io.conversions import make_header, stamp_to_ns
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.provenance import KEY as PROVENANCE_KEY
from face_tracking_ros.io.provenance import Provenance
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.recognition.benchmark import (
    BenchmarkConfig,
    synthetic_sequences,
    tracking_noise,
)
from face_tracking_ros.recognition.evaluation import (
    detect_events,
    merge_scores,
    score_events,
    truth_segments,
)
from face_tracking_ros.recognition.events import EventConfig
from face_tracking_ros.recognition.expression import (
    ExpressionClassifier,
    ExpressionTrainingConfig,
    train_expression_classifier,
)
from face_tracking_ros.synthetic.faces import FacePopulation

FACE_STATE = 'face_tracking_msgs/msg/FaceState'
LOST_EVERY = 10  # every 10th frame of the fake tracker is LOST


def write_state_bag(path: Path, truth: Path, model, seed: int) -> None:
    """A fake tracker output: the model fitted to the truth nodes plus parameter noise."""
    (sequence,) = truth_sequences(truth, model=model)
    rng = np.random.default_rng(seed)
    frames = len(sequence.times)
    sigma = sequence.sigma + tracking_noise(rng, frames, model.p, 0.001, 30.0)
    alpha = sequence.alpha + tracking_noise(rng, frames, model.q, 0.001, 30.0)
    stamps = [m.stamp_ns for m in read_messages(truth, topics=['truth/face'])]
    factory = RosbagsMessages(typestore())
    with BagWriter(path) as bag:
        for m, stamp_ns in enumerate(stamps):
            msg = factory.make(
                FACE_STATE,
                header=make_header(factory, stamp_ns, 'camera'),
                status=2 if m % LOST_EVERY == 0 else 1,
                sigma=sigma[m],
                alpha=alpha[m],
            )
            bag.write('face/state', FACE_STATE, msg, stamp_ns)


@pytest.fixture(scope='module')
def pairs(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Truth and fake-tracked bags: people 0-2 twice (enrol, test), people 3-4 once.

    The classifier is trained on noisy truth of people 5-7 playing the training scripts.
    """
    root = tmp_path_factory.mktemp('report')
    population = FacePopulation('default', 0)
    model = truth_model(population, 34)
    made: dict[str, list[str]] = {'enrol': [], 'test': [], 'strangers': []}
    plan = [(i, 'enrol') for i in range(3)] + [(i, 'test') for i in range(3)]
    plan += [(i, 'strangers') for i in (3, 4)]
    for k, (person, role) in enumerate(plan):
        truth, tracked = root / f'truth_{k}', root / f'tracked_{k}'
        write_truth_bag(truth, population, person, seed=60 + k, duration=6.0)
        write_state_bag(tracked, truth, model, seed=k)
        made[role].append(f'{tracked}={truth}')
    scenario = BenchmarkConfig(duration=20.0, node_noise=0.001)
    rng = np.random.default_rng(7)
    training = synthetic_sequences(population, model, range(5, 8), 1, True, scenario, rng)
    train_expression_classifier(training, ExpressionTrainingConfig()).save(root / 'classifier.npz')
    made['classifier'] = [str(root / 'classifier.npz')]
    return made


def test_report_on_tracked_bags(pairs: dict, capsys: pytest.CaptureFixture) -> None:
    status = cli.main(
        [
            'recognition-report',
            '--enrol', *pairs['enrol'],
            '--test', *pairs['test'],
            '--strangers', *pairs['strangers'],
            '--classifier', pairs['classifier'][0],
        ]
    )  # fmt: skip

    out = capsys.readouterr().out
    assert status == 0
    assert 'identity after 1 s (15 windows): 100.0 % closed set, 100.0 % with rejection' in out
    assert 'strangers rejected 100.0 %' in out
    clear = float(out.split('expressions: ')[1].split(' %')[0])
    assert clear >= 90.0
    assert 'identity   sigma      100.0%' in out
    # Events scored with onsets at the label's start, then at half its rise (alpha level 0.5):
    # here F1 1.000 for both, latencies 159 and 49 ms.
    scored = [
        tracked_sequence(*map(Path, p.split('='))) for p in pairs['test'] + pairs['strangers']
    ]
    classifier = ExpressionClassifier.load(pairs['classifier'][0], scored[0].alpha.shape[1])
    events = [detect_events(classifier, s, EventConfig()) for s in scored]
    for level, name in ((0.0, 'label start'), (0.5, 'half rise')):
        segments = [truth_segments(sequence, level) for sequence in scored]
        score = merge_scores(list(map(score_events, events, segments)))
        latency = 1000 * np.mean(score.latencies)
        assert (
            f'events (onset at {name}): F1 {score.f1:.3f}, mean onset latency {latency:.0f} ms\n'
            in out
        )


def test_report_without_strangers_says_so(pairs: dict, capsys: pytest.CaptureFixture) -> None:
    argv = ['recognition-report', '--enrol', *pairs['enrol'], '--test', *pairs['test'],
            '--classifier', pairs['classifier'][0]]  # fmt: skip
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert '100.0 % with rejection; no strangers' in out and 'nan' not in out


def test_tracked_sequence_keeps_tracking_frames_matched_by_stamp(pairs: dict) -> None:
    tracked, truth = (Path(p) for p in pairs['test'][0].split('='))

    sequence = tracked_sequence(tracked, truth)

    truth_stamps = [m.stamp_ns for m in read_messages(truth, topics=['truth/face'])]
    kept = [s for m, s in enumerate(truth_stamps) if m % LOST_EVERY]
    np.testing.assert_allclose(sequence.times, np.array(kept) / 1e9)
    assert sequence.subject_id == 'subject_00'
    labels = {
        stamp_to_ns(m.msg.header.stamp): m.msg.expression_label
        for m in read_messages(truth, topics=['truth/face'])
    }
    assert list(sequence.labels) == [labels[s] for s in kept]


def test_errors(pairs: dict, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    tracked, truth = (Path(p) for p in pairs['test'][0].split('='))
    other_truth = Path(pairs['strangers'][0].split('=')[1])
    with BagWriter(tmp_path / 'later') as bag:
        factory = RosbagsMessages(typestore())
        state = factory.make(FACE_STATE, header=make_header(factory, 5, 'c'), status=1)
        bag.write('face/state', FACE_STATE, state, 5)
    with pytest.raises(BagError, match='no TRACKING face/state frame has a truth frame'):
        tracked_sequence(tmp_path / 'later', other_truth)
    with pytest.raises(BagError, match='no topic face/state'):
        tracked_sequence(truth, truth)
    classifier = ['--classifier', pairs['classifier'][0]]  # required: not the error here
    with pytest.raises(SystemExit) as refused:
        cli.main(['recognition-report', '--enrol', str(tracked), '--test', 'x=y', *classifier])
    assert refused.value.code == 2
    expected = f'argument --enrol: expected TRACKED=TRUTH bag paths, got {str(tracked)!r}'
    assert expected in capsys.readouterr().err
    # A track that records the bag it was tracked from, paired with another's truth (which
    # starts at the same stamp, as synthetic bags do: every frame would pair).
    provenance = Provenance.of(truth, ['mono_tracker'], {})
    with BagWriter(tmp_path / 'recorded') as bag:
        bag.set_custom_data(PROVENANCE_KEY, provenance.text())
        for message in read_messages(tracked, topics=['face/state']):
            bag.write(message.topic, message.msgtype, message.msg, message.stamp_ns)
    paired = tracked_sequence(tracked, truth).times  # the frames of the bag it copies
    assert np.array_equal(tracked_sequence(tmp_path / 'recorded', truth).times, paired)
    with pytest.raises(ConfigError, match=f'was tracked from {truth}, not from {other_truth}'):
        tracked_sequence(tmp_path / 'recorded', other_truth)
    # Another bag of the same name (in another directory) is another bag; a link is the same.
    namesake = tmp_path / 'elsewhere' / truth.name
    shutil.copytree(other_truth, namesake)
    with pytest.raises(ConfigError, match=f'was tracked from {truth}, not from {namesake}'):
        tracked_sequence(tmp_path / 'recorded', namesake)
    (tmp_path / 'link').symlink_to(truth)
    assert np.array_equal(tracked_sequence(tmp_path / 'recorded', tmp_path / 'link').times, paired)
    # A classifier trained on another model's alpha than the one the track names (the default).
    bound = tmp_path / 'bound.npz'
    loaded = ExpressionClassifier.load(pairs['classifier'][0], 6)
    replace(loaded, model='0123456789abcdef').save(bound)
    pair = f'{tmp_path / "recorded"}={truth}'
    argv = ['recognition-report', '--enrol', pair, '--test', pair, '--classifier', str(bound)]
    assert cli.main(argv) == 2
    assert 'was made with another face model' in capsys.readouterr().err
    # A test bag shorter than a decision window, and one of another model's q.
    with BagWriter(tmp_path / 'short') as bag, BagWriter(tmp_path / 'narrow') as narrow:
        for k, message in enumerate(read_messages(tracked, topics=['face/state'])):
            if k < 20:
                bag.write(message.topic, message.msgtype, message.msg, message.stamp_ns)
            state = message.msg
            state.alpha = state.alpha[:-1]
            narrow.write(message.topic, message.msgtype, state, message.stamp_ns)
    enrol = [
        'recognition-report',
        '--enrol',
        *pairs['enrol'],
        '--classifier',
        pairs['classifier'][0],
    ]
    assert cli.main([*enrol, '--test', f'{tmp_path / "short"}={truth}']) == 2
    assert 'no TRACKING stretch of the --test bags spans a 1-s window' in capsys.readouterr().err
    assert cli.main([*enrol, '--test', f'{tmp_path / "narrow"}={truth}']) == 2
    assert f'{tmp_path / "narrow"}: sigma and alpha of p=' in capsys.readouterr().err
    # The bag named is the one unlike the first bag, wherever it is given.
    first = pairs['enrol'][0].split('=')[0]
    odd = [pairs['enrol'][0], f'{tmp_path / "narrow"}={truth}', '--test', *pairs['test']]
    assert cli.main(['recognition-report', '--enrol', *odd, *enrol[-2:]]) == 2
    assert capsys.readouterr().err == (
        f'error: {tmp_path / "narrow"}: sigma and alpha of p=4, q=5, {first} p=4, q=6: the bags '
        'were tracked with different face models\n'
    )


def test_test_subject_never_enrolled_is_refused_before_any_figure(
    pairs: dict, capsys: pytest.CaptureFixture
) -> None:
    stranger = pairs['strangers'][0]
    argv = ['recognition-report', '--enrol', *pairs['enrol'], '--test', pairs['test'][0],
            stranger, '--classifier', pairs['classifier'][0]]  # fmt: skip

    assert cli.main(argv) == 2

    captured = capsys.readouterr()
    assert captured.out == ''  # no identity or expression figures of a run that fails
    assert captured.err == (
        f"error: {stranger.split('=')[0]}: --test subject 'subject_03' is none of the --enrol "
        "pairs' (subject_00, subject_01, subject_02): give people never enrolled with "
        '--strangers\n'
    )


def test_a_report_that_fails_at_its_separation_table_prints_no_figure(
    pairs: dict, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """Enrolment truth relabelled all neutral: no expression to train the table's classifier."""
    enrol = []
    for pair in pairs['enrol']:
        tracked, truth = pair.split('=')
        neutral = tmp_path / Path(truth).name
        with BagWriter(neutral) as bag:
            for message in read_messages(truth, topics=['truth/face']):
                message.msg.expression_label, message.msg.expression_intensity = 'neutral', 0.0
                bag.write(message.topic, message.msgtype, message.msg, message.stamp_ns)
        enrol.append(f'{tracked}={neutral}')
    argv = ['recognition-report', '--enrol', *enrol, '--test', *pairs['test'],
            '--classifier', pairs['classifier'][0]]  # fmt: skip

    assert cli.main(argv) == 2

    captured = capsys.readouterr()
    assert captured.out == ''  # not the identity and expression lines of a report cut short
    assert captured.err == (
        'error: training data hold only the label neutral; need neutral and an expression\n'
    )
