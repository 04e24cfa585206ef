"""Expression recognition from the action parameters alpha and their dynamics (seed §2.5, §4.5).

Features (:mod:`.features`): for every frame, alpha, its mean and its slope over a causal window
of ``window`` seconds (default 1/6 s, five frames at 30 fps), standardised. Classifier: a
multinomial logistic regression (linear softmax) over the labels of :data:`EXPRESSION_LABELS`
present in the training data, fitted by scikit-learn and persisted as its arrays (weights,
intercepts, standardisation), never pickled: ``P(label | x) = softmax(W z + b)`` with
``z = (x - feature_mean) / feature_scale``.

Why this classifier: measured with
:func:`face_tracking_ros.recognition.evaluation.compare_expression_classifiers` in
:func:`~face_tracking_ros.recognition.benchmark.run_benchmark` on held-out subjects (nodes with
1.5 mm tracking noise projected onto the model; default preset with the true bases / realistic
preset with a learned p = 4 seed model / realistic preset with a learned p = 4 joint model, both
learned with q = 5 from 11 subjects' true meshes with 0.5 mm noise, two 380-frame training
sequences each), the linear softmax scored 99.5 / 95.1 / 96.9 % of clear frames, an RBF SVM (the
classifier of Gokturk et al., cited in §2.5) 98.9 / 94.7 / 96.3 %, a quadratic discriminant
99.3 / 95.2 / 96.8 % and a linear discriminant 93.7 / 89.6 / 90.9 %. The softmax is as accurate
as the best (within 0.1 point), gives calibrated posteriors (the event confidences) and persists
as two small arrays; the SVM needs its support vectors and a calibration step for probabilities.

Neutral baseline: alpha is taken relative to the face's own neutral alpha (class
:class:`NeutralBaseline`): the mean alpha of the first ``calibration`` seconds of the track (the
face is assumed neutral then, as when a tracker starts), then refined with every frame the
classifier finds neutral with posterior >= :data:`REFINE_POSTERIOR`, as a running mean with a
memory of :data:`BASELINE_MEMORY` frames (so it follows slow tracker drift). In training, the
baseline of a sequence is the mean alpha of its neutral-labelled frames. A learned model whose
action basis also carries identity (too few shape modes for the population, issue 11) gives every
face its own constant alpha offset: on held-out subjects of the realistic synthetic population
with that learned p = 4, q = 5 seed model, the baseline lifts the clear-frame accuracy from
72.2 % to 93.8 % and the event F1 (onset at half rise) from 0.60 to 0.94. ``calibration`` 0 turns
the baseline off.

Frames labelled with an expression whose intensity is below ``min_intensity`` (the first and last
moments of an onset or offset, where the face is still almost neutral) are left out of training.
"""

from __future__ import annotations

from dataclasses import dataclass
import os

import numpy as np
from scipy.special import softmax
from sklearn.linear_model import LogisticRegression
from sklearn.preprocessing import StandardScaler

from face_tracking_ros.errors import ConfigError, InputError
from face_tracking_ros.recognition.archive import load_archive, model_header, save_archive
from face_tracking_ros.recognition.features import (
    STAMP_TOLERANCE,
    SlidingWindow,
    sequence_features,
    subtract_baselines,
)
from face_tracking_ros.recognition.sequences import Parameter, ParameterSequence
from face_tracking_ros.recognition.validation import check_shapes
from face_tracking_ros.wording import listed

EXPRESSION_LABELS = ('neutral', 'smile', 'jaw_open', 'brow_raise', 'frown', 'pucker', 'surprise')
NEUTRAL = EXPRESSION_LABELS[0]
CLASSIFIER_KIND = 'expression_classifier'
CLASSIFIER_FORMAT_VERSION = 1
REFINE_POSTERIOR = 0.9  # neutral posterior above which a frame refines the neutral baseline
BASELINE_MEMORY = 300  # frames the baseline's running mean remembers (10 s at 30 Hz)


@dataclass(frozen=True)
class ExpressionTrainingConfig:
    """Tunables of expression training.

    Attributes:
        window: length of the causal feature window, s, > :data:`.features.STAMP_TOLERANCE`.
        calibration: length of the neutral calibration period at the start of a track, s, >= 0
            (0: no baseline).
        min_intensity: expression frames below this intensity are not trained on, in [0, 1).
        regularisation: inverse strength C of the L2 penalty of the logistic regression on
            standardised features, > 0.
    """

    window: float = 1.0 / 6.0
    calibration: float = 0.3
    min_intensity: float = 0.3
    regularisation: float = 10.0

    def __post_init__(self) -> None:
        """Validate the ranges.

        Raises:
            ConfigError: naming the parameter out of range.
        """
        if not self.window > STAMP_TOLERANCE:
            msg = f'expression feature window must be > {STAMP_TOLERANCE} s, got {self.window}'
            raise ConfigError(msg)
        if not self.calibration >= 0.0:
            msg = f'neutral calibration must be >= 0 s, got {self.calibration}'
            raise ConfigError(msg)
        if not 0.0 <= self.min_intensity < 1.0:
            msg = f'min_intensity must be in [0, 1), got {self.min_intensity}'
            raise ConfigError(msg)
        if not self.regularisation > 0.0:
            msg = f'regularisation C must be > 0, got {self.regularisation}'
            raise ConfigError(msg)


@dataclass(frozen=True)
class ExpressionClassifier:
    """A trained expression classifier: linear softmax on standardised window features.

    Attributes:
        labels: K class labels, a subset of :data:`EXPRESSION_LABELS` holding 'neutral'.
        q: dimension of the parameter vector it was trained on (the model's q for alpha).
        window: feature window, s.
        calibration: neutral calibration period at the start of a track, s (0: none).
        feature_mean: (3q,) mean of the training features.
        feature_scale: (3q,) positive standard deviation of the training features.
        weights: (K, 3q) weights W of the softmax.
        intercepts: (K,) intercepts b of the softmax.
        model: fingerprint of the face model whose alpha it was trained on
            (:attr:`~face_tracking_ros.model.face_model.FaceModel.fingerprint`); None: not known
            (e.g. trained on the true alpha of synthetic bags).
    """

    labels: tuple[str, ...]
    q: int
    window: float
    calibration: float
    feature_mean: np.ndarray
    feature_scale: np.ndarray
    weights: np.ndarray
    intercepts: np.ndarray
    model: str | None = None

    def __post_init__(self) -> None:
        """Check labels and array shapes.

        Raises:
            InputError: if an array disagrees with q and the labels or labels are invalid.
        """
        _check_labels(self.labels, InputError)
        k, f = len(self.labels), 3 * self.q
        check_shapes(
            'expression classifier',
            self,
            {'feature_mean': (f,), 'feature_scale': (f,), 'weights': (k, f), 'intercepts': (k,)},
        )
        if not (
            np.all(self.feature_scale > 0.0)
            and self.window > STAMP_TOLERANCE
            and self.calibration >= 0.0
        ):
            msg = (
                f'classifier feature_scale must be positive, window > {STAMP_TOLERANCE} s, '
                'calibration >= 0'
            )
            raise InputError(msg)

    def probabilities(self, features: np.ndarray) -> np.ndarray:
        """(M, K) label posteriors of (M, 3q) window features."""
        features = np.asarray(features, dtype=float)
        if features.ndim != 2 or features.shape[1] != 3 * self.q:
            msg = f'expected (M, {3 * self.q}) expression features, got {features.shape}'
            raise InputError(msg)
        z = (features - self.feature_mean) / self.feature_scale
        return softmax(z @ self.weights.T + self.intercepts, axis=1)

    def sequence_probabilities(self, times: np.ndarray, values: np.ndarray) -> np.ndarray:
        """(M, K) posteriors of every frame of a track of (M,) stamps and (M, q) parameters.

        The track starts at the first frame; the frames go through :class:`ExpressionRecognizer`
        one by one, so the result is exactly what the online recogniser reports.
        """
        recognizer = ExpressionRecognizer(self)
        return np.array(
            [
                recognizer.update(float(stamp), value).probabilities
                for stamp, value in zip(times, values, strict=True)
            ]
        ).reshape(len(times), len(self.labels))

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the classifier atomically (pickle-free npz, see :mod:`.archive`)."""
        save_archive(
            path,
            CLASSIFIER_KIND,
            CLASSIFIER_FORMAT_VERSION,
            {
                'labels': list(self.labels),
                'q': self.q,
                'window': self.window,
                'calibration': self.calibration,
                **model_header(self.model),
            },
            {
                'feature_mean': self.feature_mean,
                'feature_scale': self.feature_scale,
                'weights': self.weights,
                'intercepts': self.intercepts,
            },
        )

    @classmethod
    def load(
        cls, path: str | os.PathLike[str], q: int, model: str | None = None
    ) -> ExpressionClassifier:
        """Read a classifier written by :meth:`save` for a model with q action parameters.

        Args:
            path: the classifier file.
            q: the model's q.
            model: the model's fingerprint; a classifier trained on another model's alpha is
                refused. None: not checked.

        Raises:
            ModelFileError: naming the file if it is missing, corrupt, of another format version,
                has unknown labels, or was trained for another q (both q named) or another model.
        """
        archive = load_archive(path, CLASSIFIER_KIND, CLASSIFIER_FORMAT_VERSION)
        file_q = archive.field('q', int)
        if file_q != q:
            archive.fail(
                f'classifier was trained for q={file_q} action parameters, the model has q={q} '
                '(train it on this model: face-tracking train-expressions --model)'
            )
        recorded = archive.model(
            model, 'train it on the alpha of this model: face-tracking train-expressions --model'
        )
        labels = tuple(archive.field('labels', list))
        window = float(archive.field('window', float))
        calibration = float(archive.field('calibration', float))
        k, f = len(labels), 3 * q
        arrays = {
            'feature_mean': archive.array('feature_mean', (f,)),
            'feature_scale': archive.array('feature_scale', (f,)),
            'weights': archive.array('weights', (k, f)),
            'intercepts': archive.array('intercepts', (k,)),
        }
        try:
            return cls(
                labels=labels,
                q=q,
                window=window,
                calibration=calibration,
                **arrays,
                model=recorded,
            )
        except InputError as error:
            problem = str(error)
        archive.fail(problem)


def training_features(
    sequences: list[ParameterSequence],
    config: ExpressionTrainingConfig,
    parameter: Parameter = 'alpha',
) -> tuple[np.ndarray, np.ndarray]:
    """Features and labels of the frames trained on.

    Each sequence's features are taken relative to its neutral baseline (the mean of its
    neutral-labelled frames) unless ``config.calibration`` is 0. Expression frames below
    ``config.min_intensity`` are left out.

    Args:
        sequences: labelled sequences (truth labels and intensities).
        config: window, calibration and intensity cut.
        parameter: 'alpha' (expression recognition) or 'sigma' (the separation experiment).

    Returns:
        ``(x, y)``: (M, 3d) features and (M,) labels.

    Raises:
        ConfigError: if there are no sequences, a label is not in :data:`EXPRESSION_LABELS`,
            'neutral' is missing from a sequence that needs a baseline, or from all of them.
    """
    if not sequences:
        msg = 'no training sequences for the expression classifier'
        raise ConfigError(msg)
    _check_labels(tuple(set(np.concatenate([s.labels for s in sequences]))), ConfigError)
    features, labels = [], []
    for sequence in sequences:
        values = sequence.values(parameter)
        x = sequence_features(sequence.times, values, config.window)
        if config.calibration > 0.0:
            neutral = sequence.labels == NEUTRAL
            if not np.any(neutral):
                msg = f'sequence of {sequence.subject_id!r} has no neutral frame for its baseline'
                raise ConfigError(msg)
            baseline = values[neutral].mean(axis=0)
            x = subtract_baselines(x, np.broadcast_to(baseline, values.shape))
        keep = (sequence.labels == NEUTRAL) | (sequence.intensity >= config.min_intensity)
        features.append(x[keep])
        labels.append(sequence.labels[keep])
    return np.vstack(features), np.concatenate(labels)


def train_expression_classifier(
    sequences: list[ParameterSequence],
    config: ExpressionTrainingConfig,
    parameter: Parameter = 'alpha',
) -> ExpressionClassifier:
    """Fit the classifier to labelled sequences (features of :func:`training_features`).

    Raises:
        ConfigError: for the training data errors of :func:`training_features`, or if no
            expression frame passes the intensity cut.
    """
    x, y = training_features(sequences, config, parameter)
    present = tuple(label for label in EXPRESSION_LABELS if label in set(y))
    if len(present) < 2:
        msg = (
            f'training data hold only the {listed("label", present)}; need neutral and an '
            'expression'
        )
        raise ConfigError(msg)
    scaler = StandardScaler().fit(x)
    scale = np.where(scaler.scale_ > 0.0, scaler.scale_, 1.0)
    regression = LogisticRegression(C=config.regularisation, max_iter=5000)
    regression.fit((x - scaler.mean_) / scale, y)
    order = [list(regression.classes_).index(label) for label in present]
    weights, intercepts = regression.coef_, regression.intercept_
    if len(present) == 2:  # scikit-learn stores one logit for two classes: softmax([0, w z + b])
        weights = np.vstack([np.zeros_like(weights), weights])
        intercepts = np.concatenate([[0.0], intercepts])
    return ExpressionClassifier(
        labels=present,
        q=x.shape[1] // 3,
        window=config.window,
        calibration=config.calibration,
        feature_mean=scaler.mean_,
        feature_scale=scale,
        weights=weights[order],
        intercepts=intercepts[order],
    )


@dataclass(frozen=True)
class ExpressionScores:
    """The classifier's output for one frame.

    Attributes:
        stamp: s.
        probabilities: (K,) posteriors of the classifier's labels.
        label: most probable label.
        confidence: its posterior.
        alpha: (q,) action parameters of the frame.
    """

    stamp: float
    probabilities: np.ndarray
    label: str
    confidence: float
    alpha: np.ndarray


class NeutralBaseline:
    """The neutral alpha of one tracked face (see the module notes).

    Calibrated on the first ``calibration`` seconds of the track, then refined with the frames
    classified neutral, as a running mean that forgets with a memory of ``BASELINE_MEMORY`` frames.
    """

    def __init__(self, dim: int) -> None:
        """Start with a zero baseline."""
        self.value = np.zeros(dim)
        self._count = 0

    def reset(self) -> None:
        """Back to a zero baseline (new track)."""
        self.value[:] = 0.0
        self._count = 0

    def add(self, alpha: np.ndarray) -> None:
        """Take one neutral frame's alpha into the running mean."""
        self._count += 1
        self.value += (alpha - self.value) / min(self._count, BASELINE_MEMORY)


class ExpressionRecognizer:
    """Online per-frame expression posteriors of one tracked face."""

    def __init__(self, classifier: ExpressionClassifier) -> None:
        """Start with an empty feature window and no neutral baseline."""
        self._classifier = classifier
        self._window = SlidingWindow(classifier.window, classifier.q)
        self._baseline = NeutralBaseline(classifier.q)
        self._neutral = classifier.labels.index(NEUTRAL)

    @property
    def labels(self) -> tuple[str, ...]:
        """The classifier's labels, in the order of the probabilities."""
        return self._classifier.labels

    def update(self, stamp: float, alpha: np.ndarray) -> ExpressionScores:
        """Classify the frame at ``stamp`` with action parameters alpha (q,).

        A stamp not later than the previous one starts a new track (window and baseline).

        Raises:
            InputError: if alpha is not a finite (q,) vector.
        """
        if self._window.push(stamp, alpha):
            self._baseline.reset()
        alpha = self._window.values[-1]
        calibration = self._classifier.calibration
        calibrating = self._window.elapsed <= calibration + STAMP_TOLERANCE
        if calibration > 0.0 and calibrating:
            self._baseline.add(alpha)
        features = subtract_baselines(self._window.features()[None], self._baseline.value[None])
        probabilities = self._classifier.probabilities(features)[0]
        if (
            calibration > 0.0
            and not calibrating
            and probabilities[self._neutral] >= REFINE_POSTERIOR
        ):
            self._baseline.add(alpha)
        best = int(np.argmax(probabilities))
        return ExpressionScores(
            stamp=stamp,
            probabilities=probabilities,
            label=self.labels[best],
            confidence=float(probabilities[best]),
            alpha=alpha,
        )


def _check_labels(labels: tuple[str, ...], error: type[Exception]) -> None:
    """Raise ``error`` for labels outside :data:`EXPRESSION_LABELS` or without 'neutral'."""
    unknown = sorted(str(label) for label in set(labels) - set(EXPRESSION_LABELS))
    if unknown:
        known = ', '.join(EXPRESSION_LABELS)
        msg = f'unknown expression {listed("label", unknown)}; known labels are {known}'
        raise error(msg)
    if NEUTRAL not in labels:
        msg = f'expression labels {labels} lack {NEUTRAL!r}'
        raise error(msg)
