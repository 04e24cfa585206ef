"""``face-tracking recognition-report``: identity, expression and event figures on tracked bags.

Each input is a pair ``TRACKED=TRUTH``: a tracker's output bag (FaceState on ``face/state``, as
written by ``face-tracking track``) and the synthetic bag it tracked (FaceTruth on
``truth/face``); frames are matched by stamp and only frames the tracker reports as TRACKING are
used. People of the ``--enrol`` pairs are enrolled from their tracked sigma; ``--test`` pairs
(the same people, other sequences) and ``--strangers`` pairs (people never enrolled) are
classified in 1-s windows; expressions are recognised with the ``--classifier`` file on the test
and stranger pairs; the separation table (§4.5) is computed on tracked parameters, enrolling and
training on the ``--enrol`` pairs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from face_tracking_ros.errors import BagError, ConfigError
from face_tracking_ros.io.bags import NS_PER_S, read_usable
from face_tracking_ros.io.conversions import stamp_to_ns, truth_from_msg
from face_tracking_ros.io.provenance import other_source, tracked_with
from face_tracking_ros.io.series import read_converted, require_parameters
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.recognition.evaluation import (
    detect_events,
    enroll_sequences,
    expression_accuracy,
    identity_accuracy,
    merge_scores,
    score_events,
    separation_experiment,
    truth_segments,
)
from face_tracking_ros.recognition.events import EventConfig
from face_tracking_ros.recognition.expression import ExpressionClassifier, ExpressionTrainingConfig
from face_tracking_ros.recognition.identity import IdentityConfig
from face_tracking_ros.recognition.sequences import ParameterSequence

STATE_TOPIC = 'face/state'
TRUTH_TOPIC = 'truth/face'
STATUS_TRACKING = 1


def register(parser: argparse.ArgumentParser) -> None:
    """Register the ``recognition-report`` subcommand's options."""
    parser.description = (
        'Score identity (enrolled from tracked sigma), expressions, expression '
        'events and the separation table on tracker output bags paired with their truth bags.'
    )
    pair = {'type': _pair, 'nargs': '+', 'metavar': 'TRACKED=TRUTH'}
    parser.add_argument('--enrol', required=True, help='pairs to enrol and train on', **pair)
    parser.add_argument('--test', required=True, help='other sequences of those people', **pair)
    parser.add_argument('--strangers', default=[], help='people never enrolled', **pair)
    parser.add_argument('--classifier', required=True, type=Path, help='expression classifier')
    parser.add_argument(
        '--model',
        type=Path,
        help='face model the bags were tracked with, for the check that the classifier was '
        'trained on it (default: the one their metadata names)',
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    """Print the report, once all of it is computed (a run that fails prints no figure).

    Raises:
        BagError: if a bag is unreadable, lacks its topic or no frame pairs up.
        ConfigError: if a tracked bag was tracked from another bag than its truth, or the bags
            with different face models or another than ``--model``, or a ``--test`` subject
            is none of the ``--enrol`` pairs'.
        ModelFileError: if the classifier does not match the tracked alpha or their model.
    """
    enrol, test, strangers = (
        [tracked_sequence(tracked, truth) for tracked, truth in pairs]
        for pairs in (args.enrol, args.test, args.strangers)
    )
    tracked_bags = [tracked for tracked, _ in [*args.enrol, *args.test, *args.strangers]]
    _check_one_model(tracked_bags, [*enrol, *test, *strangers])
    _check_enrolled([tracked for tracked, _ in args.test], test, enrol)
    model = tracked_with(tracked_bags, args.model)
    fingerprint = load_model(model).fingerprint if model is not None else None
    classifier = ExpressionClassifier.load(args.classifier, enrol[0].alpha.shape[1], fingerprint)
    identity_config = IdentityConfig()
    report = [
        _identity_line(enrol, test, strangers, identity_config),
        *_expression_lines(classifier, test + strangers),
        separation_experiment(enrol, test, identity_config, ExpressionTrainingConfig()).format(),
    ]
    print('\n'.join(report))


def _identity_line(
    enrol: list[ParameterSequence],
    test: list[ParameterSequence],
    strangers: list[ParameterSequence],
    config: IdentityConfig,
) -> str:
    """The identity line: decisions on ``test`` and ``strangers`` by a gallery of ``enrol``.

    Raises:
        BagError: if no TRACKING stretch of the test bags spans a decision window.
    """
    identity = identity_accuracy(enroll_sequences(enrol, config), test, strangers, config)
    rejected = (
        f'strangers rejected {100 * identity.rejection:.1f} %' if strangers else 'no strangers'
    )
    if not identity.windows:
        msg = (
            f'no TRACKING stretch of the --test bags spans a {config.window:.0f}-s '
            'window: no identity decision to score'
        )
        raise BagError(msg)
    return (
        f'identity after {config.window:.0f} s ({identity.windows} windows): '
        f'{100 * identity.closed_set:.1f} % closed set, {100 * identity.open_set:.1f} % with '
        f'rejection; {rejected}'
    )


def _expression_lines(
    classifier: ExpressionClassifier, scored: list[ParameterSequence]
) -> list[str]:
    """The expression lines: per-frame accuracy, then events at two onset definitions."""
    accuracy = expression_accuracy(classifier, scored)
    lines = [
        f'expressions: {100 * accuracy.clear:.1f} % clear frames, '
        f'{100 * accuracy.all_frames:.1f} % all frames, {100 * accuracy.balanced:.1f} % balanced'
    ]
    events = [detect_events(classifier, s, EventConfig()) for s in scored]
    for level, name in ((0.0, 'label start'), (0.5, 'half rise')):
        score = merge_scores(
            [
                score_events(e, truth_segments(s, level))
                for e, s in zip(events, scored, strict=True)
            ]
        )
        latency = (
            f'mean onset latency {1000 * np.mean(score.latencies):.0f} ms'
            if len(score.latencies)
            else 'no onset found'
        )
        lines.append(f'events (onset at {name}): F1 {score.f1:.3f}, {latency}')
    return lines


def _check_enrolled(
    bags: list[Path], test: list[ParameterSequence], enrol: list[ParameterSequence]
) -> None:
    """Check, before any figure, that every ``--test`` subject is enrolled.

    The identity line and the separation table score test sequences of enrolled people; an
    unenrolled one would count as a wrong decision (and the table refused it only at the end).

    Raises:
        ConfigError: naming the first test bag whose subject no ``--enrol`` pair shows.
    """
    enrolled = sorted({sequence.subject_id for sequence in enrol})
    for bag, sequence in zip(bags, test, strict=True):
        if sequence.subject_id not in enrolled:
            msg = (
                f"{bag}: --test subject {sequence.subject_id!r} is none of the --enrol pairs' "
                f'({", ".join(enrolled)}): give people never enrolled with --strangers'
            )
            raise ConfigError(msg)


def _check_one_model(bags: list[Path], sequences: list[ParameterSequence]) -> None:
    """Check that every track has the sigma and alpha dimensions of the first.

    Raises:
        BagError: naming the first bag whose p or q differs from the first bag's.
    """
    first = (sequences[0].sigma.shape[1], sequences[0].alpha.shape[1])
    for bag, sequence in zip(bags, sequences, strict=True):
        dims = (sequence.sigma.shape[1], sequence.alpha.shape[1])
        if dims != first:
            msg = (
                f'{bag}: sigma and alpha of p={dims[0]}, q={dims[1]}, {bags[0]} p={first[0]}, '
                f'q={first[1]}: the bags were tracked with different face models'
            )
            raise BagError(msg)


def tracked_sequence(tracked: Path, truth: Path) -> ParameterSequence:
    """Tracked sigma and alpha of a tracker output bag with the labels of its truth bag.

    Raises:
        BagError: if a bag cannot be read, lacks its topic, no TRACKING frame has truth, or the
            states carry no sigma or alpha.
        ConfigError: if ``tracked`` records that it was tracked from another bag than ``truth``.
    """
    source = other_source(tracked, truth)
    if source is not None:
        msg = f'{tracked}={truth}: {tracked} was tracked from {source}, not from {truth}'
        raise ConfigError(msg)
    labels = {}
    subject = ''
    for _, sample in read_converted(truth, TRUTH_TOPIC, truth_from_msg):
        labels[sample.stamp_ns] = (sample.label, sample.intensity)
        subject = sample.subject_id
    frames = [
        message.msg
        for message in read_usable(tracked, topics=[STATE_TOPIC])
        if message.msg.status == STATUS_TRACKING
        and stamp_to_ns(message.msg.header.stamp) in labels
    ]
    if not frames:
        msg = f'{tracked}: no TRACKING {STATE_TOPIC} frame has a truth frame in {truth}'
        raise BagError(msg)
    require_parameters(tracked, {'sigma': len(frames[0].sigma), 'alpha': len(frames[0].alpha)})
    stamps = [stamp_to_ns(frame.header.stamp) for frame in frames]
    return ParameterSequence(
        subject_id=subject,
        times=np.array(stamps, dtype=float) / NS_PER_S,
        sigma=np.array([frame.sigma for frame in frames], dtype=float),
        alpha=np.array([frame.alpha for frame in frames], dtype=float),
        labels=np.array([labels[stamp][0] for stamp in stamps]),
        intensity=np.array([labels[stamp][1] for stamp in stamps]),
    )


def _pair(text: str) -> tuple[Path, Path]:
    """Parse ``TRACKED=TRUTH``."""
    tracked, separator, truth = text.partition('=')
    if not separator or not tracked or not truth:
        msg = f'expected TRACKED=TRUTH bag paths, got {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return Path(tracked), Path(truth)
