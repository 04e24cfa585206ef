"""Expression recognition from the action parameters alpha and their dynamics (seed §2.5, §4.5).

Features (:mod:`.features`): for every frame, alpha, its mean and its slope over a causal window
of ``window`` seconds (default 1/6 s, five frames at 30 fps), standardised. Classifier: a
multinomial logistic regression (linear softmax) over the labels of :data:`EXPRESSION_LABELS`
present in the training data, fitted by scikit-learn and persisted as its arrays (weights,
intercepts, standardisation), never pickled: ``P(label | x) = softmax(W z + b)`` with
``z = (x - feature_mean) / feature_scale``.

Why this classifier: measured with
:func:`face_tracking_ros.recognition.evaluation.compare_expression_classifiers` on held-out
sequences, the linear softmax is as accurate as an RBF SVM (the classifier of Gokturk et al.,
cited in §2.5), a quadratic discriminant and a linear discriminant within about one percentage
point, while giving calibrated posteriors (the event confidences) and persisting as two small
arrays; the SVM needs its support vectors and an extra calibration step for probabilities.

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
from face_tracking_ros.recognition.archive import load_archive, save_archive
from face_tracking_ros.recognition.features import SlidingWindow, sequence_features
from face_tracking_ros.recognition.sequences import Parameter, ParameterSequence
from face_tracking_ros.recognition.validation import check_shapes

EXPRESSION_LABELS = ('neutral', 'smile', 'jaw_open', 'brow_raise', 'frown', 'pucker', 'surprise')
NEUTRAL = EXPRESSION_LABELS[0]
CLASSIFIER_KIND = 'expression_classifier'
CLASSIFIER_FORMAT_VERSION = 1


@dataclass(frozen=True)
class ExpressionTrainingConfig:
    """Tunables of expression training.

    Attributes:
        window: length of the causal feature window, s, > 0.
        min_intensity: expression frames below this intensity are not trained on, in [0, 1).
        regularisation: inverse strength C of the L2 penalty of the logistic regression on
            standardised features, > 0.
    """

    window: float = 1.0 / 6.0
    min_intensity: float = 0.3
    regularisation: float = 10.0

    def __post_init__(self) -> None:
        """Validate the ranges.

        Raises:
            ConfigError: naming the parameter out of range.
        """
        if not self.window > 0.0:
            msg = f'expression feature window must be > 0 s, got {self.window}'
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
        feature_mean: (3q,) mean of the training features.
        feature_scale: (3q,) positive standard deviation of the training features.
        weights: (K, 3q) weights W of the softmax.
        intercepts: (K,) intercepts b of the softmax.
    """

    labels: tuple[str, ...]
    q: int
    window: float
    feature_mean: np.ndarray
    feature_scale: np.ndarray
    weights: np.ndarray
    intercepts: np.ndarray

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
        if not np.all(self.feature_scale > 0.0) or not self.window > 0.0:
            msg = 'classifier feature_scale and window must be positive'
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
        """(M, K) posteriors of every frame of a sequence of (M,) stamps and (M, q) parameters."""
        return self.probabilities(sequence_features(times, values, self.window))

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the classifier atomically (pickle-free npz, see :mod:`.archive`)."""
        save_archive(
            path,
            CLASSIFIER_KIND,
            CLASSIFIER_FORMAT_VERSION,
            {'labels': list(self.labels), 'q': self.q, 'window': self.window},
            {
                'feature_mean': self.feature_mean,
                'feature_scale': self.feature_scale,
                'weights': self.weights,
                'intercepts': self.intercepts,
            },
        )

    @classmethod
    def load(cls, path: str | os.PathLike[str], q: int) -> ExpressionClassifier:
        """Read a classifier written by :meth:`save` for a model with q action parameters.

        Raises:
            ModelFileError: naming the file if it is missing, corrupt, of another format version,
                has unknown labels, or was trained for another q (both q named).
        """
        archive = load_archive(path, CLASSIFIER_KIND, CLASSIFIER_FORMAT_VERSION)
        file_q = archive.field('q', int)
        if file_q != q:
            archive.fail(
                f'classifier was trained for q={file_q} action parameters, the model has q={q}'
            )
        labels = tuple(archive.field('labels', list))
        window = float(archive.field('window', float))
        k, f = len(labels), 3 * q
        arrays = {
            'feature_mean': archive.array('feature_mean', (f,)),
            'feature_scale': archive.array('feature_scale', (f,)),
            'weights': archive.array('weights', (k, f)),
            'intercepts': archive.array('intercepts', (k,)),
        }
        try:
            return cls(labels=labels, q=q, window=window, **arrays)
        except InputError as error:
            problem = str(error)
        archive.fail(problem)


def train_expression_classifier(
    sequences: list[ParameterSequence],
    config: ExpressionTrainingConfig,
    parameter: Parameter = 'alpha',
) -> ExpressionClassifier:
    """Fit the classifier to labelled sequences.

    Args:
        sequences: labelled training sequences (truth labels and intensities).
        config: window, intensity cut and regularisation.
        parameter: 'alpha' (expression recognition) or 'sigma' (the separation experiment).

    Raises:
        ConfigError: if there are no sequences, a label is not in :data:`EXPRESSION_LABELS`,
            'neutral' is missing, or no expression frame passes the intensity cut.
    """
    if not sequences:
        msg = 'no training sequences for the expression classifier'
        raise ConfigError(msg)
    _check_labels(tuple(set(np.concatenate([s.labels for s in sequences]))), ConfigError)
    features, labels = [], []
    for sequence in sequences:
        keep = (sequence.labels == NEUTRAL) | (sequence.intensity >= config.min_intensity)
        values = sequence.values(parameter)
        features.append(sequence_features(sequence.times, values, config.window)[keep])
        labels.append(sequence.labels[keep])
    x, y = np.vstack(features), np.concatenate(labels)
    present = tuple(label for label in EXPRESSION_LABELS if label in set(y))
    if len(present) < 2:
        msg = f'training data hold only the label(s) {present}; need neutral and an expression'
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
        q=values.shape[1],
        window=config.window,
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


class ExpressionRecognizer:
    """Online per-frame expression posteriors of one tracked face."""

    def __init__(self, classifier: ExpressionClassifier) -> None:
        """Start with an empty feature window."""
        self._classifier = classifier
        self._window = SlidingWindow(classifier.window, classifier.q)

    @property
    def labels(self) -> tuple[str, ...]:
        """The classifier's labels, in the order of the probabilities."""
        return self._classifier.labels

    def reset(self) -> None:
        """Forget the feature window (new face or restarted tracker)."""
        self._window.clear()

    def update(self, stamp: float, alpha: np.ndarray) -> ExpressionScores:
        """Classify the frame at ``stamp`` with action parameters alpha (q,).

        A stamp not later than the previous one restarts the window.

        Raises:
            InputError: if alpha is not a finite (q,) vector.
        """
        self._window.push(stamp, alpha)
        probabilities = self._classifier.probabilities(self._window.features()[None, :])[0]
        best = int(np.argmax(probabilities))
        return ExpressionScores(
            stamp=stamp,
            probabilities=probabilities,
            label=self.labels[best],
            confidence=float(probabilities[best]),
            alpha=self._window.values[-1],
        )


def _check_labels(labels: tuple[str, ...], error: type[Exception]) -> None:
    """Raise ``error`` for labels outside :data:`EXPRESSION_LABELS` or without 'neutral'."""
    unknown = sorted(str(label) for label in set(labels) - set(EXPRESSION_LABELS))
    if unknown:
        msg = f'unknown expression label(s) {unknown}; known labels are {EXPRESSION_LABELS}'
        raise error(msg)
    if NEUTRAL not in labels:
        msg = f'expression labels {labels} lack {NEUTRAL!r}'
        raise error(msg)
