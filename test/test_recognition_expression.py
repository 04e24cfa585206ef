"""Expression features and classifier: exact features, accuracy, online = batch, file, errors."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from recognition_streams import ExpressionWorld, parameter_sequence
from sklearn.linear_model import LogisticRegression

from face_tracking_ros.errors import ConfigError, InputError, ModelFileError
from face_tracking_ros.recognition.archive import load_archive, save_archive
from face_tracking_ros.recognition.evaluation import expression_accuracy
from face_tracking_ros.recognition.expression import (
    BASELINE_MEMORY,
    CLASSIFIER_FORMAT_VERSION,
    CLASSIFIER_KIND,
    EXPRESSION_LABELS,
    ExpressionClassifier,
    ExpressionRecognizer,
    ExpressionTrainingConfig,
    NeutralBaseline,
    train_expression_classifier,
)
from face_tracking_ros.recognition.features import (
    sequence_features,
    subtract_baselines,
    window_features,
)
from face_tracking_ros.recognition.sequences import ParameterSequence
from face_tracking_ros.synthetic.faces import EXPRESSIONS

Q = 5
CONFIG = ExpressionTrainingConfig()


@pytest.fixture(scope='module')
def data() -> tuple[list[ParameterSequence], list[ParameterSequence]]:
    """Six training and three test sequences of 20 s, alpha noise 1.5 mm."""
    rng = np.random.default_rng(10)
    world = ExpressionWorld.make(rng, Q)
    sequences = [parameter_sequence(rng, world, f's{i}', np.zeros(2), 20.0) for i in range(9)]
    return sequences[:6], sequences[6:]


@pytest.fixture(scope='module')
def classifier(data: tuple) -> ExpressionClassifier:
    return train_expression_classifier(data[0], CONFIG)


def test_labels_are_those_of_the_synthetic_world() -> None:
    assert EXPRESSION_LABELS == EXPRESSIONS


def test_window_features_of_a_line_are_exact() -> None:
    times = np.array([0.0, 0.1, 0.2, 0.3])
    values = np.stack([2.0 * times + 1.0, -times], axis=1)

    features = window_features(times, values)

    np.testing.assert_allclose(features, [1.6, -0.3, 1.3, -0.15, 2.0, -1.0], atol=1e-12)
    np.testing.assert_array_equal(window_features(times[:1], values[:1]), [1.0, 0.0] * 2 + [0, 0])


def test_sequence_features_are_causal_and_windowed() -> None:
    rng = np.random.default_rng(11)
    times = np.arange(20) / 30.0
    values = rng.normal(size=(20, 3))

    features = sequence_features(times, values, 0.1)
    changed_future = values.copy()
    changed_future[12:] += 5.0

    np.testing.assert_array_equal(
        sequence_features(times, changed_future, 0.1)[:12], features[:12]
    )
    np.testing.assert_allclose(features[10], window_features(times[8:11], values[8:11]))


def test_held_out_accuracy_over_seven_classes(
    data: tuple, classifier: ExpressionClassifier
) -> None:
    accuracy = expression_accuracy(classifier, data[1], CONFIG.min_intensity)

    assert classifier.labels == EXPRESSION_LABELS
    assert accuracy.clear >= 0.92
    assert accuracy.balanced >= 0.9
    assert accuracy.confusion.sum() == sum(
        np.count_nonzero((s.labels == 'neutral') | (s.intensity >= 0.3)) for s in data[1]
    )
    assert accuracy.clear == pytest.approx(np.trace(accuracy.confusion) / accuracy.confusion.sum())
    predicted = [
        np.asarray(classifier.labels)[
            np.argmax(classifier.sequence_probabilities(s.times, s.alpha), 1)
        ]
        for s in data[1]
    ]
    right = np.concatenate([p == s.labels for p, s in zip(predicted, data[1], strict=True)])
    assert accuracy.all_frames == pytest.approx(np.mean(right))
    assert accuracy.all_frames < accuracy.clear  # faint frames, not scored as clear, are harder


def test_without_baseline_the_online_recognizer_equals_vectorised_features(data: tuple) -> None:
    config = ExpressionTrainingConfig(calibration=0.0)
    classifier = train_expression_classifier(data[0], config)
    sequence = data[1][0]
    recognizer = ExpressionRecognizer(classifier)

    online = [recognizer.update(t, a) for t, a in zip(sequence.times, sequence.alpha, strict=True)]

    features = sequence_features(sequence.times, sequence.alpha, config.window)
    np.testing.assert_allclose(
        [s.probabilities for s in online], classifier.probabilities(features), atol=1e-12
    )
    np.testing.assert_array_equal(online[-1].alpha, sequence.alpha[-1])


def test_neutral_baseline_cancels_a_constant_alpha_offset(
    data: tuple, classifier: ExpressionClassifier
) -> None:
    sequence = data[1][0]
    offset = np.random.default_rng(12).normal(scale=0.01, size=Q)  # identity leaking into alpha

    shifted = classifier.sequence_probabilities(sequence.times, sequence.alpha + offset)

    reference = classifier.sequence_probabilities(sequence.times, sequence.alpha)
    np.testing.assert_allclose(shifted, reference, atol=1e-9)
    uncalibrated = train_expression_classifier(data[0], ExpressionTrainingConfig(calibration=0.0))
    moved = uncalibrated.sequence_probabilities(sequence.times, sequence.alpha + offset)
    assert (
        np.abs(moved - uncalibrated.sequence_probabilities(sequence.times, sequence.alpha)).max()
        > 0.5
    )


def test_the_calibration_takes_the_first_calibration_seconds_inclusive(
    classifier: ExpressionClassifier,
) -> None:
    rng = np.random.default_rng(14)
    times = 100.0 + np.arange(11) / 30.0  # frame 9 is 0.3 s (CONFIG.calibration) after frame 0
    alpha = rng.normal(scale=0.01, size=(11, Q))
    alpha[9] += 0.05  # not neutral: it does not refine the baseline once calibration is over

    online = classifier.sequence_probabilities(times, alpha)

    baseline = alpha[:10].mean(axis=0)  # frames 0 to 9
    features = sequence_features(times, alpha, classifier.window)[10]
    expected = classifier.probabilities(subtract_baselines(features[None], baseline[None]))[0]
    assert times[9] - times[0] == pytest.approx(CONFIG.calibration, abs=1e-12)  # the boundary
    assert online[9, classifier.labels.index('neutral')] < 0.9
    np.testing.assert_allclose(online[10], expected, atol=1e-12)


def test_frames_classified_neutral_after_the_calibration_refine_the_baseline(
    classifier: ExpressionClassifier,
) -> None:
    """Frames 10 and 11 (after the 0.3 s calibration) are neutral: the baseline is their mean too.

    Without the refinement (the calibration's mean alone) frame 12 differs by 8e-4.
    """
    rng = np.random.default_rng(15)
    times = 100.0 + np.arange(13) / 30.0
    alpha = rng.normal(scale=0.002, size=(13, Q))

    online = classifier.sequence_probabilities(times, alpha)

    assert online[10:12, classifier.labels.index('neutral')].min() >= 0.9
    features = sequence_features(times, alpha, classifier.window)[12]
    baseline = alpha[:12].mean(axis=0)
    expected = classifier.probabilities(subtract_baselines(features[None], baseline[None]))[0]
    np.testing.assert_allclose(online[12], expected, rtol=0, atol=1e-12)


def test_the_neutral_baseline_is_a_running_mean_forgetting_beyond_its_memory() -> None:
    baseline = NeutralBaseline(2)
    for value in (1.0, 2.0, 6.0):
        baseline.add(np.array([value, -value]))
    np.testing.assert_allclose(baseline.value, [3.0, -3.0], rtol=1e-15)
    baseline.reset()
    for _ in range(BASELINE_MEMORY):
        baseline.add(np.array([1.0, 0.0]))
    baseline.add(np.array([1.0 + BASELINE_MEMORY, 0.0]))  # weighs 1 / BASELINE_MEMORY: +1
    np.testing.assert_allclose(baseline.value, [2.0, 0.0], rtol=1e-12)


def test_a_new_track_restarts_window_and_baseline(classifier: ExpressionClassifier) -> None:
    rng = np.random.default_rng(13)
    times = np.arange(60) / 30.0
    first, second = rng.normal(scale=0.01, size=(2, 60, Q))
    recognizer = ExpressionRecognizer(classifier)
    for t, a in zip(times, first, strict=True):
        recognizer.update(t, a)

    replayed = [recognizer.update(t, a).probabilities for t, a in zip(times, second, strict=True)]

    np.testing.assert_array_equal(replayed, classifier.sequence_probabilities(times, second))


def test_two_labels_give_the_logistic_probabilities(data: tuple) -> None:
    sequences = [
        ParameterSequence(s.subject_id, s.times, s.sigma, s.alpha, labels, s.intensity)
        for s in data[0]
        for labels in [np.where(np.isin(s.labels, ['smile', 'neutral']), s.labels, 'neutral')]
    ]
    config = ExpressionTrainingConfig(min_intensity=0.0, calibration=0.0)

    classifier = train_expression_classifier(sequences, config)

    x = np.vstack([sequence_features(s.times, s.alpha, config.window) for s in sequences])
    y = np.concatenate([s.labels for s in sequences])
    z = (x - x.mean(axis=0)) / x.std(axis=0)
    reference = LogisticRegression(C=config.regularisation, max_iter=5000).fit(z, y)
    assert classifier.labels == ('neutral', 'smile')
    np.testing.assert_allclose(classifier.probabilities(x), reference.predict_proba(z), atol=1e-6)


def test_file_round_trip(tmp_path: Path, data: tuple, classifier: ExpressionClassifier) -> None:
    path = tmp_path / 'expressions.npz'

    classifier.save(path)
    loaded = ExpressionClassifier.load(path, Q)

    assert loaded.labels == classifier.labels
    assert loaded.window == classifier.window
    sequence = data[1][0]
    np.testing.assert_array_equal(
        loaded.sequence_probabilities(sequence.times, sequence.alpha),
        classifier.sequence_probabilities(sequence.times, sequence.alpha),
    )


def test_a_classifier_of_one_model_is_refused_with_another(
    tmp_path: Path, classifier: ExpressionClassifier
) -> None:
    """Alpha of another model of the same q means other expressions: the file records its model."""
    path = tmp_path / 'expressions.npz'
    replace(classifier, model='0123456789abcdef').save(path)

    assert ExpressionClassifier.load(path, Q, '0123456789abcdef').model == '0123456789abcdef'
    with pytest.raises(ModelFileError, match='train-expressions --model'):
        ExpressionClassifier.load(path, Q, 'fedcba9876543210')
    classifier.save(path)  # trained on the true alpha: no model recorded, none refused
    assert ExpressionClassifier.load(path, Q, 'fedcba9876543210').model is None


def test_file_errors(tmp_path: Path, classifier: ExpressionClassifier) -> None:
    path = tmp_path / 'expressions.npz'
    classifier.save(path)
    with pytest.raises(ModelFileError, match=r'trained for q=5 .* the model has q=7'):
        ExpressionClassifier.load(path, 7)
    archive = load_archive(path, CLASSIFIER_KIND, CLASSIFIER_FORMAT_VERSION)
    header = {key: archive.header[key] for key in ('q', 'window', 'calibration', 'labels')}
    save_archive(
        path,
        CLASSIFIER_KIND,
        CLASSIFIER_FORMAT_VERSION,
        {**header, 'labels': [*header['labels'][:-1], 'wink']},
        archive.arrays,
    )
    with pytest.raises(
        ModelFileError, match='unknown expression label wink; known labels are neutral'
    ):
        ExpressionClassifier.load(path, Q)
    save_archive(path, CLASSIFIER_KIND, CLASSIFIER_FORMAT_VERSION, header, {})
    with pytest.raises(ModelFileError, match="misses the array 'feature_mean'"):
        ExpressionClassifier.load(path, Q)
    np.savez(path, header=np.array('{not json'), weights=np.zeros(3))
    with pytest.raises(ModelFileError, match='not valid JSON'):
        ExpressionClassifier.load(path, Q)
    np.savez(path, header=np.array({'kind': 'x'}, dtype=object))
    with pytest.raises(ModelFileError, match='not a readable pickle-free .npz'):
        ExpressionClassifier.load(path, Q)


def test_training_errors(data: tuple) -> None:
    sequence = data[0][0]

    def relabelled(labels: np.ndarray) -> list[ParameterSequence]:
        return [
            ParameterSequence(
                's', sequence.times, sequence.sigma, sequence.alpha, labels, sequence.intensity
            )
        ]

    with pytest.raises(ConfigError, match='no training sequences'):
        train_expression_classifier([], CONFIG)
    wink = np.where(sequence.labels == 'smile', 'wink', sequence.labels)
    with pytest.raises(
        ConfigError, match='unknown expression label wink; known labels are neutral'
    ):
        train_expression_classifier(relabelled(wink), CONFIG)
    no_neutral = np.where(sequence.labels == 'neutral', 'smile', sequence.labels)
    with pytest.raises(ConfigError, match="lack 'neutral'"):
        train_expression_classifier(relabelled(no_neutral), CONFIG)
    with pytest.raises(ConfigError, match="of 's' has no neutral frame for its baseline"):
        train_expression_classifier([*data[0][1:], *relabelled(no_neutral)], CONFIG)
    with pytest.raises(ConfigError, match='need neutral and an expression'):
        train_expression_classifier(relabelled(np.full(len(wink), 'neutral')), CONFIG)
    with pytest.raises(ConfigError, match='window'):
        ExpressionTrainingConfig(window=0.0)
    with pytest.raises(ConfigError, match='calibration'):
        ExpressionTrainingConfig(calibration=-1.0)
    with pytest.raises(ConfigError, match='min_intensity'):
        ExpressionTrainingConfig(min_intensity=1.0)
    with pytest.raises(ConfigError, match='regularisation'):
        ExpressionTrainingConfig(regularisation=0.0)


def test_input_errors(classifier: ExpressionClassifier) -> None:
    with pytest.raises(InputError, match=r'expected \(M, 15\) expression features'):
        classifier.probabilities(np.zeros((2, 14)))
    with pytest.raises(InputError, match='increase strictly'):
        sequence_features(np.zeros(3), np.zeros((3, Q)), 0.1)
    with pytest.raises(InputError, match=r'finite \(5,\) parameter vector'):
        ExpressionRecognizer(classifier).update(0.0, np.zeros(4))
    for bad in (
        {'feature_scale': np.where(np.arange(3 * Q) == 2, 0.0, classifier.feature_scale)},
        {'window': 0.0},
        {'calibration': -0.1},
    ):
        with pytest.raises(InputError, match='classifier feature_scale must be positive'):
            replace(classifier, **bad)
    with pytest.raises(InputError, match='alpha has shape'):
        ParameterSequence(
            's',
            np.arange(3.0),
            np.zeros((3, 2)),
            np.zeros((2, Q)),
            np.array(['neutral'] * 3),
            np.zeros(3),
        )
