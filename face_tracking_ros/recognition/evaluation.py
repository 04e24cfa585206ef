"""Scoring recognition against truth: accuracies, events, the separation experiment (§4.5).

Conventions of every score here:

- Identity is decided on consecutive, non-overlapping windows of ``IdentityConfig.window``
  seconds (1 s) of a held-out sequence; closed-set accuracy counts the most likely enrolled person,
  open-set accuracy counts the decision including rejection (a rejected genuine face is wrong),
  and the rejection rate is measured on sequences of people who are not enrolled.
- Expression accuracy is per frame, on "clear" frames: neutral frames and frames whose expression
  intensity is at least ``min_intensity`` (the first and last moments of an onset or offset,
  where the face is still nearly neutral, have no well-defined answer); the accuracy over all
  frames is reported too.
- Events: a truth expression is a run of frames with the same non-neutral label; its onset is the
  first frame of the run whose intensity reaches ``onset_level`` times the run's peak intensity
  (0: the label's first frame, the very start of the rise; 0.5: the half-rise point, the usual
  definition of a response's onset time). A detected onset matches a truth expression of the
  same label if it falls between ``onset - tolerance`` and the run's end; each is matched at most
  once (the earliest). Latency is detected minus truth onset.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
import itertools

import numpy as np
from sklearn.calibration import CalibratedClassifierCV
from sklearn.discriminant_analysis import (
    LinearDiscriminantAnalysis,
    QuadraticDiscriminantAnalysis,
)
from sklearn.linear_model import LogisticRegression
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.recognition.events import (
    EventConfig,
    EventKind,
    ExpressionEvent,
    ExpressionEventDetector,
)
from face_tracking_ros.recognition.expression import (
    EXPRESSION_LABELS,
    NEUTRAL,
    ExpressionClassifier,
    ExpressionRecognizer,
    ExpressionTrainingConfig,
    train_expression_classifier,
    training_features,
)
from face_tracking_ros.recognition.identity import (
    UNKNOWN,
    IdentityConfig,
    IdentityGallery,
)
from face_tracking_ros.recognition.sequences import PARAMETERS, Parameter, ParameterSequence

# --- identity


@dataclass(frozen=True)
class IdentityAccuracy:
    """Identity scores over 1-s windows.

    Attributes:
        closed_set: share of genuine windows whose most likely person is right.
        open_set: share of genuine windows decided right, rejection counting as wrong.
        rejection: share of windows of non-enrolled people rejected as unknown (NaN if none).
        windows: number of genuine windows scored.
    """

    closed_set: float
    open_set: float
    rejection: float
    windows: int


def enroll_sequences(
    sequences: list[ParameterSequence], config: IdentityConfig, parameter: Parameter = 'sigma'
) -> IdentityGallery:
    """A gallery with every subject of ``sequences`` enrolled from its decision-window means.

    Each person is enrolled from the means of the consecutive ``config.window`` windows of its
    sequences (:func:`decision_windows`), i.e. from samples of the very statistic that is
    classified, so C_k is the spread of a window mean (per-frame noise averaged as in a decision)
    plus the floor.

    Raises:
        ConfigError: if there are no sequences, or a subject has no full window.
    """
    if not sequences:
        msg = 'no sequences to enrol identities from'
        raise ConfigError(msg)
    gallery = IdentityGallery.empty(sequences[0].values(parameter).shape[1])
    for subject in sorted({s.subject_id for s in sequences}):
        mine = [s for s in sequences if s.subject_id == subject]
        means = [
            values.mean(axis=0) for _, values in decision_windows(mine, config.window, parameter)
        ]
        if not means:
            msg = f'{subject!r} has no full {config.window} s window to enrol from'
            raise ConfigError(msg)
        gallery = gallery.enroll(subject, np.array(means), config)
    return gallery


def decision_windows(
    sequences: list[ParameterSequence], length: float, parameter: Parameter = 'sigma'
) -> Iterator[tuple[str, np.ndarray]]:
    """Consecutive non-overlapping windows ``(subject_id, (W, d) values)`` of ``length`` s.

    A window without frames (the track lost for ``length`` or more) is left out.
    """
    for sequence in sequences:
        elapsed = sequence.times - sequence.times[0]
        frame_period = float(np.median(np.diff(sequence.times))) if len(elapsed) > 1 else 0.0
        index = np.floor(elapsed / length).astype(int)
        full = int(np.floor((elapsed[-1] + frame_period) / length + 1e-9))
        values = sequence.values(parameter)
        for k in range(full):  # a last, partial window is left out
            if np.any(index == k):
                yield sequence.subject_id, values[index == k]


def identity_accuracy(
    gallery: IdentityGallery,
    genuine: list[ParameterSequence],
    impostors: list[ParameterSequence],
    config: IdentityConfig,
    parameter: Parameter = 'sigma',
) -> IdentityAccuracy:
    """Score the gallery on held-out sequences of enrolled and of non-enrolled people.

    A share of no window is NaN.
    """
    decisions = [
        (subject, gallery.classify(values, config))
        for subject, values in decision_windows(genuine, config.window, parameter)
    ]
    rejected = [
        gallery.classify(values, config).identity == UNKNOWN
        for _, values in decision_windows(impostors, config.window, parameter)
    ]
    return IdentityAccuracy(
        closed_set=_share([d.nearest == s for s, d in decisions]),
        open_set=_share([d.identity == s for s, d in decisions]),
        rejection=_share(rejected),
        windows=len(decisions),
    )


def _share(outcomes: list[bool]) -> float:
    """The share of true outcomes; NaN for none."""
    return float(np.mean(outcomes)) if outcomes else float('nan')


def compare_identity_classifiers(
    train: list[ParameterSequence],
    genuine: list[ParameterSequence],
    impostors: list[ParameterSequence],
    config: IdentityConfig,
) -> dict[str, IdentityAccuracy]:
    """The measurement behind the choice of identity rule: Gaussian/Mahalanobis versus SVM.

    The SVM (scikit-learn SVC, RBF kernel, Platt probabilities, on standardised sigma frames)
    classifies a window's mean sigma and rejects it when its top probability falls below the
    ``1 - acceptance`` quantile of the top probabilities of the training windows (the same nominal
    acceptance as the Gaussian rule).

    Returns:
        ``{'mahalanobis': ..., 'svm': ...}``.
    """
    gallery = enroll_sequences(train, config)
    scores = {'mahalanobis': identity_accuracy(gallery, genuine, impostors, config)}
    x = np.vstack([s.sigma for s in train])
    y = np.concatenate([[s.subject_id] * len(s.times) for s in train])
    calibrated = CalibratedClassifierCV(SVC(random_state=0), ensemble=False)
    svm = make_pipeline(StandardScaler(), calibrated).fit(x, y)

    def top(sequences: list[ParameterSequence]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Subjects, predicted labels and top probabilities of the windows of sequences."""
        pairs = list(decision_windows(sequences, config.window))
        if not pairs:
            return np.array([]), np.array([]), np.array([])
        means = np.array([values.mean(axis=0) for _, values in pairs])
        probabilities = svm.predict_proba(means)
        return (
            np.array([subject for subject, _ in pairs]),
            svm.classes_[np.argmax(probabilities, axis=1)],
            probabilities.max(axis=1),
        )

    threshold = np.quantile(top(train)[2], 1.0 - config.acceptance)
    subjects, predicted, confidence = top(genuine)
    _, _, impostor_confidence = top(impostors)
    scores['svm'] = IdentityAccuracy(
        closed_set=float(np.mean(predicted == subjects)),
        open_set=float(np.mean((predicted == subjects) & (confidence >= threshold))),
        rejection=float(np.mean(impostor_confidence < threshold))
        if len(impostor_confidence)
        else float('nan'),
        windows=len(subjects),
    )
    return scores


# --- expressions


@dataclass(frozen=True)
class ExpressionAccuracy:
    """Per-frame expression scores.

    Attributes:
        clear: accuracy on clear frames (neutral, or intensity >= min_intensity).
        all_frames: accuracy on every frame.
        balanced: mean per-label recall on clear frames (chance = 1 / number of labels).
        labels: the labels of the confusion matrix (those of the truth and the classifier).
        confusion: (L, L) counts of clear frames, rows truth, columns prediction.
    """

    clear: float
    all_frames: float
    balanced: float
    labels: tuple[str, ...]
    confusion: np.ndarray


def expression_accuracy(
    classifier: ExpressionClassifier,
    sequences: list[ParameterSequence],
    min_intensity: float = 0.3,
    parameter: Parameter = 'alpha',
) -> ExpressionAccuracy:
    """Score the classifier's most probable label against the truth labels, frame by frame."""
    truth, predicted, clear = [], [], []
    for sequence in sequences:
        probabilities = classifier.sequence_probabilities(
            sequence.times, sequence.values(parameter)
        )
        truth.append(sequence.labels)
        predicted.append(np.asarray(classifier.labels)[np.argmax(probabilities, axis=1)])
        clear.append((sequence.labels == NEUTRAL) | (sequence.intensity >= min_intensity))
    return _accuracy(np.concatenate(truth), np.concatenate(predicted), np.concatenate(clear))


def compare_expression_classifiers(
    train: list[ParameterSequence],
    test: list[ParameterSequence],
    config: ExpressionTrainingConfig,
) -> dict[str, float]:
    """The measurement behind the choice of expression classifier: clear-frame accuracy of each.

    Candidates, all on the same standardised window features of alpha
    (:func:`~face_tracking_ros.recognition.expression.training_features`, test frames too, so
    with the truth-labelled neutral baseline and only clear frames): the linear softmax that
    :func:`train_expression_classifier` fits ('logistic'), an RBF SVM ('svm', Gokturk et al.),
    linear and quadratic discriminants ('lda', 'qda').
    """
    x_train, y_train = training_features(train, config)
    x_test, y_test = training_features(test, config)
    candidates = {
        'logistic': LogisticRegression(C=config.regularisation, max_iter=5000),
        'svm': SVC(C=10.0),
        'lda': LinearDiscriminantAnalysis(),
        'qda': QuadraticDiscriminantAnalysis(reg_param=0.01),
    }
    return {
        name: float(
            np.mean(
                make_pipeline(StandardScaler(), model).fit(x_train, y_train).predict(x_test)
                == y_test
            )
        )
        for name, model in candidates.items()
    }


# --- events


@dataclass(frozen=True)
class Segment:
    """A truth expression: label, onset and end stamps, s."""

    label: str
    onset: float
    end: float


@dataclass(frozen=True)
class EventScore:
    """Detected onsets against truth expressions.

    Attributes:
        true_positives: matched onsets.
        false_positives: detected onsets matching no truth expression.
        false_negatives: truth expressions with no matched onset.
        latencies: (true_positives,) detected minus truth onset, s.
    """

    true_positives: int
    false_positives: int
    false_negatives: int
    latencies: np.ndarray

    @property
    def precision(self) -> float:
        """TP / (TP + FP); 1 when nothing was detected."""
        detected = self.true_positives + self.false_positives
        return self.true_positives / detected if detected else 1.0

    @property
    def recall(self) -> float:
        """TP / (TP + FN); 1 when there was nothing to detect."""
        expected = self.true_positives + self.false_negatives
        return self.true_positives / expected if expected else 1.0

    @property
    def f1(self) -> float:
        """Harmonic mean of precision and recall."""
        total = self.precision + self.recall
        return 2.0 * self.precision * self.recall / total if total else 0.0


def truth_segments(sequence: ParameterSequence, onset_level: float = 0.0) -> list[Segment]:
    """The truth expressions of a sequence (runs of one non-neutral label), see module notes."""
    segments = []
    for label, run in itertools.groupby(
        range(len(sequence.labels)), key=sequence.labels.__getitem__
    ):
        frames = np.fromiter(run, dtype=int)
        peak = sequence.intensity[frames].max()
        reached = frames[sequence.intensity[frames] >= onset_level * peak]
        if label != NEUTRAL and peak > 0.0:
            segments.append(
                Segment(
                    label, float(sequence.times[reached[0]]), float(sequence.times[frames[-1]])
                )
            )
    return segments


def detect_events(
    classifier: ExpressionClassifier, sequence: ParameterSequence, config: EventConfig
) -> list[ExpressionEvent]:
    """Run the online recogniser and event detector over a sequence, frame by frame."""
    recognizer = ExpressionRecognizer(classifier)
    detector = ExpressionEventDetector(classifier.labels, config)
    events: list[ExpressionEvent] = []
    for stamp, alpha in zip(sequence.times, sequence.alpha, strict=True):
        events.extend(detector.update(recognizer.update(float(stamp), alpha)))
    return events


def score_events(
    events: list[ExpressionEvent], segments: list[Segment], tolerance: float = 0.3
) -> EventScore:
    """Match detected onsets to truth expressions (see module notes)."""
    onsets = [event for event in events if event.kind == EventKind.ONSET]
    used = [False] * len(onsets)
    latencies = []
    for segment in segments:
        for i, event in enumerate(onsets):
            if (
                not used[i]
                and event.label == segment.label
                and segment.onset - tolerance <= event.stamp <= segment.end
            ):
                used[i] = True
                latencies.append(event.stamp - segment.onset)
                break
    return EventScore(
        true_positives=len(latencies),
        false_positives=used.count(False),
        false_negatives=len(segments) - len(latencies),
        latencies=np.array(latencies),
    )


def merge_scores(scores: list[EventScore]) -> EventScore:
    """Pool the counts and latencies of several sequences."""
    return EventScore(
        true_positives=sum(s.true_positives for s in scores),
        false_positives=sum(s.false_positives for s in scores),
        false_negatives=sum(s.false_negatives for s in scores),
        latencies=np.concatenate([s.latencies for s in scores]) if scores else np.array([]),
    )


# --- the separation experiment (§4.5)


@dataclass(frozen=True)
class SeparationRow:
    """One cell pair of the separation table: a task recognised from one parameter vector."""

    task: str
    parameter: Parameter
    accuracy: float
    balanced: float
    chance: float


@dataclass(frozen=True)
class SeparationTable:
    """Identity and expression recognised from sigma and from alpha (seed §4.5).

    If the subspaces are well separated, identity is recognised from sigma and expression from
    alpha, while the crossed rows stay near chance.
    """

    rows: tuple[SeparationRow, ...]

    def row(self, task: str, parameter: Parameter) -> SeparationRow:
        """The row of ``task`` ('identity' or 'expression') from ``parameter``."""
        return next(r for r in self.rows if r.task == task and r.parameter == parameter)

    def format(self) -> str:
        """The table as text, percentages."""
        lines = [f'{"task":<11}{"from":<7}{"accuracy":>10}{"balanced":>10}{"chance":>8}']
        lines += [
            f'{r.task:<11}{r.parameter:<7}{100 * r.accuracy:>9.1f}%{100 * r.balanced:>9.1f}%'
            f'{100 * r.chance:>7.1f}%'
            for r in self.rows
        ]
        return '\n'.join(lines)


def separation_experiment(
    train: list[ParameterSequence],
    test: list[ParameterSequence],
    identity_config: IdentityConfig,
    expression_config: ExpressionTrainingConfig,
) -> SeparationTable:
    """Recognise identity and expression each from sigma and from alpha (seed §4.5).

    Identity: every subject of ``train`` is enrolled (:func:`enroll_sequences`) from the chosen
    parameter and held-out ``test`` sequences of the same subjects are classified in 1-s windows,
    closed set (chance 1 / subjects). Expression: the classifier of :mod:`.expression` is trained
    on ``train`` from the chosen parameter and scored per clear frame on ``test`` (accuracy, and
    balanced accuracy whose chance level is 1 / labels).

    Raises:
        ConfigError: if a test subject is not in the training sequences.
    """
    unknown = {s.subject_id for s in test} - {s.subject_id for s in train}
    if unknown:
        msg = f'test subjects {sorted(unknown)} have no training sequences to enrol from'
        raise ConfigError(msg)
    rows = []
    for parameter in PARAMETERS:
        gallery = enroll_sequences(train, identity_config, parameter)
        identity = identity_accuracy(gallery, test, [], identity_config, parameter)
        chance = 1.0 / len(gallery)
        rows.append(
            SeparationRow('identity', parameter, identity.closed_set, identity.closed_set, chance)
        )
    for parameter in PARAMETERS:
        classifier = train_expression_classifier(train, expression_config, parameter)
        expression = expression_accuracy(
            classifier, test, expression_config.min_intensity, parameter
        )
        chance = 1.0 / len(expression.labels)
        rows.append(
            SeparationRow('expression', parameter, expression.clear, expression.balanced, chance)
        )
    return SeparationTable(rows=tuple(rows))


def _accuracy(truth: np.ndarray, predicted: np.ndarray, clear: np.ndarray) -> ExpressionAccuracy:
    """Accuracies and confusion matrix of per-frame labels."""
    labels = tuple(label for label in EXPRESSION_LABELS if label in set(truth) | set(predicted))
    index = {label: i for i, label in enumerate(labels)}
    confusion = np.zeros((len(labels), len(labels)), dtype=np.int64)
    np.add.at(
        confusion, ([index[t] for t in truth[clear]], [index[p] for p in predicted[clear]]), 1
    )
    present = confusion.sum(axis=1) > 0
    recall = np.diag(confusion)[present] / confusion.sum(axis=1)[present]
    return ExpressionAccuracy(
        clear=float(np.mean(truth[clear] == predicted[clear])),
        all_frames=float(np.mean(truth == predicted)),
        balanced=float(recall.mean()),
        labels=labels,
        confusion=confusion,
    )
