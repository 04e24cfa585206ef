"""``face-tracking train-expressions`` on small labelled truth bags."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from recognition_streams import ExpressionWorld, expression_stream, truth_model

from face_tracking_ros.cli import main as cli
from face_tracking_ros.cli.train_expressions import truth_sequences
from face_tracking_ros.errors import BagError
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.io.bags import BagWriter
from face_tracking_ros.io.conversions import array_to_points, make_header, pose_msg
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.model.model_file import save_model
from face_tracking_ros.recognition.evaluation import expression_accuracy
from face_tracking_ros.recognition.expression import ExpressionClassifier
from face_tracking_ros.synthetic.faces import ACTIVE_EXPRESSIONS, FacePopulation

TRUTH = 'truth/face'
FACE_TRUTH = 'face_tracking_msgs/msg/FaceTruth'


def write_truth_bag(path: Path, population: FacePopulation, subject: int, seed: int) -> None:
    """A 12 s bag of FaceTruth at 30 fps: expressions with onsets/offsets, a slowly moving head."""
    rng = np.random.default_rng(seed)
    stream = expression_stream(rng, ExpressionWorld.make(rng, 1), 12.0, noise_std=0.0)
    person = population.subject(subject)
    factory = RosbagsMessages(typestore())
    with BagWriter(path) as bag:
        for m, (time, label, level) in enumerate(
            zip(stream.times, stream.labels, stream.intensity, strict=True)
        ):
            weights = {label: level} if label != 'neutral' else {}
            omega = 0.1 * np.sin([time, 0.7 * time, 0.3 * time])
            t = np.array([0.02 * np.sin(time), 0.0, 0.6])
            nodes = population.nodes(person, weights) @ rodrigues(omega)[0].T + t
            stamp_ns = 10**9 + m * 33_333_333
            msg = factory.make(
                FACE_TRUTH,
                header=make_header(factory, stamp_ns, 'camera'),
                subject_id=person.subject_id,
                pose=pose_msg(factory, omega, t),
                omega=omega,
                alpha=population.alpha(weights),
                sigma=person.sigma_true,
                node_names=list(population.node_names),
                nodes=array_to_points(factory, nodes),
                expression_label=str(label),
                expression_intensity=float(level),
            )
            bag.write(TRUTH, FACE_TRUTH, msg, stamp_ns)


@pytest.fixture(scope='module')
def bags(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Three truth bags of three subjects (the last one held out)."""
    root = tmp_path_factory.mktemp('truth_bags')
    population = FacePopulation('default', 0)
    paths = [root / f'subject_{i}' for i in range(3)]
    for i, path in enumerate(paths):
        write_truth_bag(path, population, i, seed=40 + i)
    return paths


def test_train_on_model_alpha_of_truth_bags(
    bags: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    model = truth_model(FacePopulation('default', 0), 19)
    save_model(model, tmp_path / 'model.npz')
    out = tmp_path / 'expressions.npz'

    status = cli.main(
        [
            'train-expressions',
            *map(str, bags[:2]),
            '--out',
            str(out),
            '--model',
            str(tmp_path / 'model.npz'),
        ]
    )

    assert status == 0
    assert f'q={model.q}' in capsys.readouterr().out
    classifier = ExpressionClassifier.load(out, model.q)
    held_out = truth_sequences(bags[2], model=model)
    assert expression_accuracy(classifier, held_out).clear >= 0.9


def test_true_alpha_sequences_carry_the_messages(bags: list[Path]) -> None:
    (sequence,) = truth_sequences(bags[0])

    assert sequence.subject_id == 'subject_00'
    assert sequence.alpha.shape == (360, len(ACTIVE_EXPRESSIONS))
    np.testing.assert_allclose(sequence.times[1] - sequence.times[0], 1 / 30, atol=1e-9)
    smile = sequence.labels == 'smile'
    np.testing.assert_allclose(sequence.alpha[smile, 0], sequence.intensity[smile])


def test_errors_are_reported(bags: list[Path], tmp_path: Path, capsys) -> None:
    model = truth_model(FacePopulation('default', 0), 34)
    with pytest.raises(BagError, match='no topic face/truth'):
        truth_sequences(bags[0], topic='face/truth', model=model)
    status = cli.main(['train-expressions', str(tmp_path / 'nobag'), '--out', str(tmp_path / 'x')])
    assert status == cli.EXIT_ERROR
    assert 'cannot read bag' in capsys.readouterr().err
    status = cli.main(
        ['train-expressions', str(bags[0]), '--out', str(tmp_path / 'x'), '--window', '0']
    )
    assert status == cli.EXIT_ERROR
    assert 'window must be > 0' in capsys.readouterr().err
