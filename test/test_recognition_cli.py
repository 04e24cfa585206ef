"""``face-tracking train-expressions`` on small labelled truth bags."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from recognition_streams import truth_model, write_truth_bag

from face_tracking_ros.cli import main as cli
from face_tracking_ros.cli.train_expressions import truth_sequences
from face_tracking_ros.errors import BagError
from face_tracking_ros.io.bags import BagWriter
from face_tracking_ros.io.conversions import CAMERA_INFO_TYPE, make_header
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.model.model_file import load_model, save_model
from face_tracking_ros.recognition.evaluation import expression_accuracy
from face_tracking_ros.recognition.expression import (
    ExpressionClassifier,
    ExpressionTrainingConfig,
)
from face_tracking_ros.synthetic.faces import ACTIVE_EXPRESSIONS, FacePopulation


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
    printed = capsys.readouterr().out
    assert f'(alpha of {tmp_path / "model.npz"}, q={model.q})' in printed
    # The frames trained on: the neutral ones and the expressions above the intensity cut.
    sequences = [s for bag in bags[:2] for s in truth_sequences(bag, model=model)]
    kept = sum(
        np.sum((s.labels == 'neutral') | (s.intensity >= ExpressionTrainingConfig().min_intensity))
        for s in sequences
    )
    assert kept < sum(len(s.labels) for s in sequences)
    assert f'trained on {kept} frames of 2 sequences' in printed
    classifier = ExpressionClassifier.load(out, model.q)
    assert classifier.model == model.fingerprint  # bound: a recogniser of another model refuses it
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
    assert 'window must be > 1e-06 s, got 0.0' in capsys.readouterr().err
    # --out naming the model (or any file that is not a classifier) is not written over.
    save_model(model, tmp_path / 'model.npz')
    argv = ['train-expressions', str(bags[0]), '--model', str(tmp_path / 'model.npz')]
    assert cli.main([*argv, '--out', str(tmp_path / 'model.npz')]) == cli.EXIT_ERROR
    assert 'exists and is not an expression classifier' in capsys.readouterr().err
    assert load_model(tmp_path / 'model.npz').fingerprint == model.fingerprint


def test_topic_of_another_type_is_refused(tmp_path: Path, capsys) -> None:
    bag = tmp_path / 'camera'
    factory = RosbagsMessages(typestore())
    with BagWriter(bag) as writer:
        info = factory.make(CAMERA_INFO_TYPE, header=make_header(factory, 10**9, 'left'))
        writer.write('left/camera_info', CAMERA_INFO_TYPE, info, 10**9)
    out = tmp_path / 'expressions.npz'

    status = cli.main(
        ['train-expressions', str(bag), '--out', str(out), '--topic', 'left/camera_info']
    )

    assert status == cli.EXIT_ERROR
    error = capsys.readouterr().err
    assert error == (
        f'error: {bag}: topic left/camera_info has type {CAMERA_INFO_TYPE}; '
        'expected face_tracking_msgs/msg/FaceTruth\n'
    )
    assert not out.exists()
