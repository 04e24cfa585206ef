"""``face-tracking train-expressions``: train the expression classifier from labelled bags.

Reads the ground truth (face_tracking_msgs/FaceTruth) of synthetic or hand-labelled bags: the
expression label and intensity of every frame, and either the true alpha carried by the message
or, with ``--model``, the alpha of that face model obtained by fitting the model to the truth
nodes (:func:`face_tracking_ros.recognition.node_fit.fit_model_to_nodes`), which is what a
tracker running that model reports. The trained classifier is written as a pickle-free file that
the expression recogniser loads; it checks that the file's q matches its model and, for a
classifier trained with ``--model``, that it is that model (the file records its fingerprint).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from face_tracking_ros.errors import BagError, ConfigError
from face_tracking_ros.io.atomic import check_output_path, check_replaceable
from face_tracking_ros.io.bags import NS_PER_S, bag_topics, check_distinct_bags
from face_tracking_ros.io.conversions import TRUTH_TYPE, truth_from_msg
from face_tracking_ros.io.series import read_converted
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.recognition.archive import load_archive
from face_tracking_ros.recognition.evaluation import expression_accuracy
from face_tracking_ros.recognition.expression import (
    CLASSIFIER_FORMAT_VERSION,
    CLASSIFIER_KIND,
    ExpressionTrainingConfig,
    train_expression_classifier,
    training_features,
)
from face_tracking_ros.recognition.node_fit import fit_model_to_nodes
from face_tracking_ros.recognition.sequences import ParameterSequence
from face_tracking_ros.wording import counted

TRUTH_TOPIC = 'truth/face'


def register(parser: argparse.ArgumentParser) -> None:
    """Register the ``train-expressions`` subcommand's options."""
    defaults = ExpressionTrainingConfig()
    parser.description = (
        'Train the expression classifier (alpha and its short-term dynamics -> '
        'neutral, smile, jaw_open, brow_raise, frown, pucker, surprise) from the FaceTruth '
        'messages of labelled bags and write it as a pickle-free .npz file.'
    )
    parser.add_argument('bags', nargs='+', type=Path, metavar='BAG', help='labelled bags')
    parser.add_argument('--out', required=True, type=Path, help='classifier file to write')
    parser.add_argument(
        '--model',
        type=Path,
        help='face model file: train on the alpha of this model, fitted to the truth nodes '
        '(what a tracker with this model reports); default: the true alpha of the messages',
    )
    parser.add_argument('--topic', default=TRUTH_TOPIC, help='FaceTruth topic (%(default)s)')
    parser.add_argument(
        '--window', type=float, default=defaults.window, help='feature window, s (%(default).3f)'
    )
    parser.add_argument(
        '--calibration',
        type=float,
        default=defaults.calibration,
        help='neutral calibration period at the start of each sequence, s; 0: none (%(default)s)',
    )
    parser.add_argument(
        '--min-intensity',
        type=float,
        default=defaults.min_intensity,
        help='expression frames below this intensity are not trained on (%(default)s)',
    )
    parser.add_argument(
        '--regularisation',
        type=float,
        default=defaults.regularisation,
        help='inverse L2 penalty C of the logistic regression (%(default)s)',
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    """Train, report the training accuracy and write the classifier.

    Raises:
        BagError: if a bag is unreadable or has no FaceTruth on the topic.
        ConfigError: for bad options, labels unknown to the classifier, or truth nodes that
            lack nodes of the model.
        ModelFileError: if the model file is unusable.
    """
    config = ExpressionTrainingConfig(
        window=args.window,
        calibration=args.calibration,
        min_intensity=args.min_intensity,
        regularisation=args.regularisation,
    )
    check_distinct_bags(args.bags)
    check_output_path(args.out, '--out', parent_made=False)
    check_replaceable(
        args.out,
        '--out',
        'an expression classifier',
        lambda path: load_archive(path, CLASSIFIER_KIND, CLASSIFIER_FORMAT_VERSION),
    )
    model = load_model(args.model) if args.model is not None else None
    sequences = [seq for bag in args.bags for seq in truth_sequences(bag, args.topic, model)]
    classifier = train_expression_classifier(sequences, config)
    if model is not None:  # bound to the model: the recogniser refuses it with another
        classifier = replace(classifier, model=model.fingerprint)
    classifier.save(args.out)
    accuracy = expression_accuracy(classifier, sequences, config.min_intensity)
    labels, counts = np.unique(training_features(sequences, config)[1], return_counts=True)
    source = f'alpha of {args.model}' if model is not None else 'true alpha'
    trained = f'{counted(sum(counts), "frame")} of {counted(len(sequences), "sequence")}'
    print(f'trained on {trained}', end=' ')
    # (expression frames below --min-intensity are not trained on, nor counted here)
    print(f'({source}, q={classifier.q})')
    print(
        'frames per label: ' + ', '.join(f'{k} {n}' for k, n in zip(labels, counts, strict=True))
    )
    print(f'training accuracy: {100 * accuracy.clear:.1f} % on clear frames')
    print(f'wrote {args.out}')


def truth_sequences(
    bag: Path, topic: str = TRUTH_TOPIC, model: FaceModel | None = None
) -> list[ParameterSequence]:
    """The labelled parameter sequences of a bag's FaceTruth messages, one per subject.

    Args:
        bag: bag directory.
        topic: FaceTruth topic.
        model: if given, sigma and alpha are those of this model fitted to the truth nodes;
            otherwise the true sigma and alpha of the messages.

    Raises:
        BagError: if the bag cannot be read, has no message on ``topic`` or ``topic`` is not
            a FaceTruth topic.
        ConfigError: if the truth lacks nodes of the model.
    """
    msgtype = bag_topics(bag).get(topic, TRUTH_TYPE)  # (a missing topic: read_messages says so)
    if msgtype != TRUTH_TYPE:
        msg = f'{bag}: topic {topic} has type {msgtype}; expected {TRUTH_TYPE}'
        raise BagError(msg)
    by_subject: dict[str, list] = {}
    for msg, sample in read_converted(bag, topic, truth_from_msg):
        by_subject.setdefault(sample.subject_id, []).append((sample, tuple(msg.node_names)))
    if not by_subject:
        msg = f'{bag}: no FaceTruth message on {topic}'
        raise BagError(msg)
    sequences = []
    for subject, frames in by_subject.items():
        frames.sort(key=lambda frame: frame[0].stamp_ns)
        samples = [sample for sample, _ in frames]
        if model is None:
            sigma = np.array([s.sigma for s in samples])
            alpha = np.array([s.alpha for s in samples])
        else:
            nodes = np.array([s.nodes[_node_indices(model, names, bag)] for s, names in frames])
            fit = fit_model_to_nodes(model, nodes)
            sigma, alpha = fit.sigma, fit.alpha
        sequences.append(
            ParameterSequence(
                subject_id=subject,
                times=np.array([s.stamp_ns for s in samples], dtype=float) / NS_PER_S,
                sigma=sigma,
                alpha=alpha,
                labels=np.array([s.label for s in samples]),
                intensity=np.array([s.intensity for s in samples]),
            )
        )
    return sequences


def _node_indices(model: FaceModel, names: tuple[str, ...], bag: Path) -> list[int]:
    """Indices in the truth's node list of the model's nodes, in the model's order."""
    missing = [name for name in model.node_names if name not in names]
    if missing:
        msg = f'{bag}: the truth nodes lack the model nodes {missing}'
        raise ConfigError(msg)
    return [names.index(name) for name in model.node_names]
