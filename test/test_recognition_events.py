"""Expression events: hysteresis and minimum duration on scripted posteriors, F1 and latency."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from recognition_streams import ExpressionWorld, parameter_sequence

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.recognition.evaluation import (
    Segment,
    detect_events,
    merge_scores,
    score_events,
    truth_segments,
)
from face_tracking_ros.recognition.events import (
    EventConfig,
    EventKind,
    ExpressionEvent,
    ExpressionEventDetector,
)
from face_tracking_ros.recognition.expression import (
    ExpressionScores,
    ExpressionTrainingConfig,
    train_expression_classifier,
)

LABELS = ('neutral', 'smile', 'frown')
FPS = 10.0


def run(smile: list[float], config: EventConfig, frown: list[float] | None = None) -> list:
    """Events of a detector fed posteriors of smile (and frown) at 10 fps; alpha = frame index."""
    frown = frown or [0.0] * len(smile)
    detector = ExpressionEventDetector(LABELS, config)
    events = []
    for m, (s, f) in enumerate(zip(smile, frown, strict=True)):
        probabilities = np.array([1.0 - s - f, s, f])
        scores = ExpressionScores(m / FPS, probabilities, '', 0.0, np.array([float(m)]))
        events.extend(detector.update(scores))
    return events


def test_onset_and_offset_after_the_minimum_duration() -> None:
    config = EventConfig(on_threshold=0.6, off_threshold=0.4, min_duration=0.2)
    smile = [0.1, 0.5, 0.7, 0.8, 0.9, 0.9, 0.9, 0.3, 0.2, 0.1, 0.1]

    events = run(smile, config)

    assert [(e.kind, e.label, e.stamp) for e in events] == [
        (EventKind.ONSET, 'smile', pytest.approx(0.4)),
        (EventKind.OFFSET, 'smile', pytest.approx(0.9)),
    ]
    onset, offset = events
    assert onset.confidence == pytest.approx(0.9)
    assert onset.duration == 0.0
    np.testing.assert_array_equal(onset.alpha, [4.0])
    assert offset.confidence == pytest.approx(0.9)
    assert offset.duration == pytest.approx(0.5)


def test_event_kinds_are_the_message_constants() -> None:
    message = typestore().types['face_tracking_msgs/msg/ExpressionEvent']
    assert (
        (EventKind.ONSET, EventKind.OFFSET)
        == (message.EVENT_ONSET, message.EVENT_OFFSET)
        == (0, 1)
    )


def test_hysteresis_band_neither_starts_nor_ends_an_expression() -> None:
    config = EventConfig(on_threshold=0.6, off_threshold=0.4, min_duration=0.0)
    below_on = [0.5, 0.55, 0.59, 0.45, 0.5]
    inside_band = [0.7, 0.45, 0.55, 0.41, 0.5, 0.45]

    assert run(below_on, config) == []
    assert [e.kind for e in run(inside_band, config)] == [EventKind.ONSET]


def test_blips_shorter_than_the_minimum_duration_are_ignored() -> None:
    config = EventConfig(min_duration=0.2)
    blip = [0.1, 0.9, 0.9, 0.1, 0.1]
    dip = [0.9, 0.9, 0.9, 0.9, 0.1, 0.1, 0.9, 0.9]

    assert run(blip, config) == []
    assert [e.kind for e in run(dip, config)] == [EventKind.ONSET]
    # Two blips 0.3 s apart are two blips, not one crossing held since the first.
    assert run([0.1, 0.9, 0.9, 0.1, 0.9, 0.9, 0.1], config) == []
    dips = [0.9, 0.9, 0.9, 0.9, 0.1, 0.1, 0.9, 0.1, 0.1, 0.9, 0.9]
    assert [e.kind for e in run(dips, config)] == [EventKind.ONSET]


def test_a_change_of_expression_ends_one_and_starts_the_other() -> None:
    config = EventConfig(min_duration=0.0)
    smile = [0.9, 0.9, 0.2, 0.0]
    frown = [0.0, 0.0, 0.7, 0.9]

    events = run(smile, config, frown)

    assert [(e.kind, e.label, e.stamp) for e in events] == [
        (EventKind.ONSET, 'smile', 0.0),
        (EventKind.OFFSET, 'smile', pytest.approx(0.2)),
        (EventKind.ONSET, 'frown', pytest.approx(0.2)),
    ]


def test_reset_forgets_the_active_expression() -> None:
    detector = ExpressionEventDetector(LABELS, EventConfig(min_duration=0.0))
    detector.update(ExpressionScores(0.0, np.array([0.1, 0.9, 0.0]), '', 0.0, np.zeros(1)))
    assert detector.active == 'smile'

    detector.reset()

    assert detector.active is None


def test_config_errors() -> None:
    with pytest.raises(ConfigError, match='on_threshold'):
        EventConfig(on_threshold=0.0)
    with pytest.raises(ConfigError, match='off_threshold'):
        EventConfig(on_threshold=0.5, off_threshold=0.5)
    with pytest.raises(ConfigError, match='min_duration'):
        EventConfig(min_duration=-0.1)
    with pytest.raises(ConfigError, match='need a label besides'):
        ExpressionEventDetector(('neutral',), EventConfig())


def test_scoring_counts_and_latency() -> None:
    def onset(stamp: float, label: str) -> ExpressionEvent:
        return ExpressionEvent(stamp, label, EventKind.ONSET, 1.0, np.zeros(1), 0.0)

    segments = [Segment('smile', 1.0, 2.0), Segment('frown', 3.0, 4.0), Segment('smile', 5.0, 6.0)]
    events = [onset(1.1, 'smile'), onset(1.5, 'smile'), onset(3.2, 'smile'), onset(5.05, 'smile')]

    score = score_events(events, segments)

    assert (score.true_positives, score.false_positives, score.false_negatives) == (2, 2, 1)
    np.testing.assert_allclose(score.latencies, [0.1, 0.05])
    assert score.f1 == pytest.approx(2 * 0.5 * (2 / 3) / (0.5 + 2 / 3))
    missed = score_events([onset(1.1, 'frown')], segments[:1])
    assert (missed.precision, missed.recall, missed.f1) == (0.0, 0.0, 0.0)


def test_truth_segments_follow_labels_and_onset_level() -> None:
    rng = np.random.default_rng(20)
    sequence = parameter_sequence(rng, ExpressionWorld.make(rng, 3), 's', np.zeros(2), 10.0)

    starts = truth_segments(sequence)
    half = truth_segments(sequence, onset_level=0.5)

    runs = np.flatnonzero(
        (sequence.labels != 'neutral') & np.r_[True, sequence.labels[1:] != sequence.labels[:-1]]
    )
    assert [s.onset for s in starts] == list(sequence.times[runs])
    ends = np.flatnonzero(
        (sequence.labels != 'neutral') & np.r_[sequence.labels[1:] != sequence.labels[:-1], True]
    )
    assert [s.end for s in starts] == list(sequence.times[ends])
    # A labelled run that never rises above zero intensity is no expression.
    assert truth_segments(replace(sequence, intensity=np.zeros(len(sequence.times)))) == []
    assert len(half) == len(starts)
    for early, late in zip(starts, half, strict=True):
        assert early.label == late.label
        assert early.onset < late.onset < late.end == early.end
        run = (sequence.times >= early.onset) & (sequence.times <= early.end)
        peak = sequence.intensity[run].max()
        m = int(np.searchsorted(sequence.times, late.onset))
        assert sequence.intensity[m] >= 0.5 * peak > sequence.intensity[m - 1]


def test_events_on_synthetic_streams_reach_f1_and_latency_targets() -> None:
    rng = np.random.default_rng(21)
    world = ExpressionWorld.make(rng, 5)
    sequences = [parameter_sequence(rng, world, 's', np.zeros(2), 20.0) for _ in range(8)]
    classifier = train_expression_classifier(sequences[:5], ExpressionTrainingConfig())

    scores = [
        score_events(detect_events(classifier, s, EventConfig()), truth_segments(s, 0.5))
        for s in sequences[5:]
    ]

    total = merge_scores(scores)
    assert total.true_positives >= 20
    assert total.f1 >= 0.9
    assert np.mean(total.latencies) <= 0.15
