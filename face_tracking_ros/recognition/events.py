"""Expression events: onsets and offsets from per-frame posteriors, with hysteresis.

An expression (any label but 'neutral') starts when its posterior has stayed at or above
``on_threshold`` for ``min_duration`` seconds, and ends when it has stayed below
``off_threshold`` (< ``on_threshold``: the hysteresis band) for ``min_duration`` seconds. At most
one expression is active at a time: a new one can start once the active one has ended. Events are
plain values for the node to publish as face_tracking_msgs/ExpressionEvent.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import IntEnum
import math

import numpy as np

from face_tracking_ros.errors import ConfigError, FieldError
from face_tracking_ros.recognition.expression import NEUTRAL, ExpressionScores


class EventKind(IntEnum):
    """Kind of an expression event; values match ExpressionEvent.EVENT_*."""

    ONSET = 0
    OFFSET = 1


@dataclass(frozen=True)
class ExpressionEvent:
    """The onset or offset of an expression of one face.

    Attributes:
        stamp: time of the frame at which the event was detected, s.
        label: expression label.
        kind: onset or offset.
        confidence: in [0, 1]; at onset the label's posterior, at offset one minus it.
        alpha: (q,) action parameters of the frame that triggered the event.
        duration: 0 at onset; at offset the time since the matching onset, s.
    """

    stamp: float
    label: str
    kind: EventKind
    confidence: float
    alpha: np.ndarray
    duration: float


@dataclass(frozen=True)
class EventConfig:
    """Hysteresis thresholds and the minimum duration of expression events.

    Attributes:
        on_threshold: posterior an expression must reach to start, in (0, 1].
        off_threshold: posterior below which the active expression ends, in [0, on_threshold).
        min_duration: seconds a threshold must stay crossed before the event is emitted, >= 0.
    """

    on_threshold: float = 0.6
    off_threshold: float = 0.35
    min_duration: float = 0.05

    def __post_init__(self) -> None:
        """Validate the ranges.

        Raises:
            ConfigError: naming the parameter out of range.
        """
        if not 0.0 < self.on_threshold <= 1.0:
            msg = f'on_threshold must be in (0, 1], got {self.on_threshold}'
            raise FieldError(msg, 'on_threshold', 'in (0, 1]')
        if not 0.0 <= self.off_threshold < self.on_threshold:
            expected = f'in [0, on_threshold={self.on_threshold})'
            msg = f'off_threshold must be {expected}, got {self.off_threshold}'
            raise FieldError(msg, 'off_threshold', expected)
        if not 0.0 <= self.min_duration < math.inf:
            msg = f'min_duration must be >= 0 s and finite, got {self.min_duration}'
            raise FieldError(msg, 'min_duration', '>= 0 s and finite')


class ExpressionEventDetector:
    """Turns a stream of :class:`ExpressionScores` of one face into events."""

    def __init__(self, labels: tuple[str, ...], config: EventConfig) -> None:
        """Start with no active expression.

        Args:
            labels: the classifier's labels, in the order of its probabilities.
            config: thresholds and minimum duration.

        Raises:
            ConfigError: if the labels hold no expression besides 'neutral'.
        """
        if not set(labels) - {NEUTRAL}:
            msg = f'expression events need a label besides {NEUTRAL!r}, got {labels}'
            raise ConfigError(msg)
        self._labels = labels
        self._config = config
        self._active: str | None = None
        self._onset_stamp = 0.0
        self._pending: str | None = None
        self._pending_since = 0.0
        self._last: ExpressionScores | None = None  # the last frame's scores

    @property
    def active(self) -> str | None:
        """The expression currently on, or None."""
        return self._active

    def reset(self) -> None:
        """Forget the state without emitting events (new face or restarted tracker)."""
        self._active = None
        self._pending = None

    def end(self, stamp: float) -> list[ExpressionEvent]:
        """The face is no longer tracked: the active expression, if any, ends at ``stamp``.

        Its offset carries the last frame's alpha and, as confidence, one minus the last
        frame's posterior of the expression; then the state is forgotten.
        """
        events = []
        if self._active is not None and self._last is not None:
            at_loss = replace(self._last, stamp=stamp)
            events.append(self._offset(at_loss, self._active_posterior(at_loss)))
        self.reset()
        return events

    def update(self, scores: ExpressionScores) -> list[ExpressionEvent]:
        """Process one frame.

        Returns:
            The events detected at this frame: none, an onset, an offset, or both (an offset
            and then an onset when ``min_duration`` is 0 and the expression changes at once).
        """
        self._last = scores
        events = []
        if self._active is not None:
            posterior = self._active_posterior(scores)
            if self._held(posterior < self._config.off_threshold, NEUTRAL, scores.stamp):
                events.append(self._offset(scores, posterior))
                self._active = None
        if self._active is None:
            label, posterior = self._best_expression(scores.probabilities)
            if self._held(posterior >= self._config.on_threshold, label, scores.stamp):
                self._active = label
                self._onset_stamp = scores.stamp
                events.append(_event(scores, label, EventKind.ONSET, posterior, 0.0))
        return events

    def _active_posterior(self, scores: ExpressionScores) -> float:
        """The posterior of the active expression at the frame of ``scores``."""
        return float(scores.probabilities[self._labels.index(self._active)])

    def _offset(self, scores: ExpressionScores, posterior: float) -> ExpressionEvent:
        """The active expression's offset at the frame of ``scores``, its posterior there given."""
        duration = scores.stamp - self._onset_stamp
        return _event(scores, self._active, EventKind.OFFSET, 1.0 - posterior, duration)

    def _held(self, crossed: bool, target: str, stamp: float) -> bool:
        """Whether the change to ``target`` has been wanted for ``min_duration`` (then cleared)."""
        if not crossed:
            self._pending = None
            return False
        if self._pending != target:
            self._pending = target
            self._pending_since = stamp
        if stamp - self._pending_since < self._config.min_duration:
            return False
        self._pending = None
        return True

    def _best_expression(self, probabilities: np.ndarray) -> tuple[str, float]:
        """The most probable non-neutral label and its posterior."""
        candidates = [i for i, label in enumerate(self._labels) if label != NEUTRAL]
        best = max(candidates, key=lambda i: probabilities[i])
        return self._labels[best], float(probabilities[best])


def _event(
    scores: ExpressionScores, label: str, kind: EventKind, confidence: float, duration: float
) -> ExpressionEvent:
    """An event detected at the frame of ``scores``."""
    return ExpressionEvent(
        stamp=scores.stamp,
        label=label,
        kind=kind,
        confidence=confidence,
        alpha=scores.alpha,
        duration=duration,
    )
