"""Time series read from bags: a tracker's FaceState outputs and the synthetic world's truth.

Plots, overlays, accuracy reports and benchmarks read whole sequences as arrays, one row per
frame, through these two loaders. A damaged bag gives its readable messages, with a warning
(:func:`~face_tracking_ros.io.bags.read_usable`): the outputs of a track cut off stay usable.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from face_tracking_ros.errors import BagError, InputError
from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import bag_topics, read_usable, stamp_to_ns
from face_tracking_ros.tracking.result import TrackStatus

T = TypeVar('T')


@dataclass(frozen=True)
class StateSeries:
    """A tracker's estimates over a sequence (FaceState messages), F frames.

    Attributes:
        stamps: (F,) image stamps, ns.
        status: (F,) TrackStatus values.
        omega: (F, 3) rotation vectors, rad.
        t: (F, 3) translations, m.
        alpha: (F, q) action parameters.
        sigma: (F, p) shape parameters.
        nodes: (F, N, 3) nodes in the camera frame, m.
        image_points: (F, N, 2) node projections, px.
        mean_residual: (F,) mean photometric residual, grey levels.
        iterations: (F,) solver iterations.
        occluded: (F, N) bool, nodes judged covered by an occluder (FaceState.occluded); False
            where not judged.
    """

    stamps: np.ndarray
    status: np.ndarray
    omega: np.ndarray
    t: np.ndarray
    alpha: np.ndarray
    sigma: np.ndarray
    nodes: np.ndarray
    image_points: np.ndarray
    mean_residual: np.ndarray
    iterations: np.ndarray
    occluded: np.ndarray


@dataclass(frozen=True)
class TruthSeries:
    """The synthetic world's truth over a sequence (FaceTruth messages), F frames.

    Attributes:
        stamps: (F,) image stamps, ns.
        subject_id: the subject of the sequence.
        omega: (F, 3) true rotation vectors, rad.
        t: (F, 3) true translations, m.
        alpha: (F, E) true expression coefficients.
        sigma: (F, K) true identity coefficients.
        nodes: (F, N, 3) true nodes in the camera frame, m.
        labels: (F,) expression labels.
        intensity: (F,) expression intensities in [0, 1].
    """

    stamps: np.ndarray
    subject_id: str
    omega: np.ndarray
    t: np.ndarray
    alpha: np.ndarray
    sigma: np.ndarray
    nodes: np.ndarray
    labels: np.ndarray
    intensity: np.ndarray


def load_states(bag: Path) -> StateSeries:
    """The FaceState series of a bag (its only FaceState topic); of a damaged bag, those readable.

    Raises:
        BagError: if the bag has no or several FaceState topics, or none of its states can be
            read.
    """
    topic = _only_topic(bag, conversions.STATE_TYPE)
    rows = [m.msg for m in read_usable(bag, topics=[topic])]
    if not rows:
        msg = f'{bag}: topic {topic} holds no FaceState message'
        raise BagError(msg)
    where = f'{bag}: {topic}'
    status = np.array([r.status for r in rows], dtype=int)
    unknown = np.flatnonzero(~np.isin(status, [int(s) for s in TrackStatus]))
    if len(unknown):
        msg = f'{where} message {unknown[0]}: FaceState.status {status[unknown[0]]} is unknown'
        raise BagError(msg)

    def stacked(field: str, values: list[np.ndarray]) -> np.ndarray:
        return _stacked(values, where, f'FaceState.{field}')

    image_points = stacked('image_points', [_points(r.image_points)[:, :2] for r in rows])
    occluded = stacked('occluded', [conversions.occluded_nodes(r) for r in rows]) == 1
    return StateSeries(
        stamps=np.array([stamp_to_ns(r.header.stamp) for r in rows], dtype=np.int64),
        status=status,
        omega=stacked('omega', [r.omega for r in rows]),
        t=np.array([[r.pose.position.x, r.pose.position.y, r.pose.position.z] for r in rows]),
        alpha=stacked('alpha', [r.alpha for r in rows]),
        sigma=stacked('sigma', [r.sigma for r in rows]),
        nodes=stacked('nodes', [_points(r.nodes) for r in rows]),
        image_points=image_points,
        mean_residual=np.array([r.mean_residual for r in rows], dtype=float),
        iterations=np.array([r.iterations for r in rows], dtype=int),
        occluded=occluded if occluded.size else np.zeros(image_points.shape[:2], dtype=bool),
    )


def _stacked(values: list[np.ndarray], where: str, field: str) -> np.ndarray:
    """One row per message; an empty field (a frame without that estimate) is a NaN row.

    Raises:
        BagError: naming a message whose field has another non-empty shape than the others.
    """
    shapes = [np.shape(value) for value in values]
    given = [i for i, value in enumerate(values) if np.size(value)]
    if not given:
        return np.array(values, dtype=float)
    first = shapes[given[0]]
    odd = next((i for i in given if shapes[i] != first), None)
    if odd is not None:
        msg = f'{where} message {odd}: {field} has shape {shapes[odd]}, message {given[0]} {first}'
        raise BagError(msg)
    rows = np.full((len(values), *first), np.nan)
    rows[given] = [values[i] for i in given]
    return rows


def load_truth(bag: Path) -> TruthSeries:
    """The FaceTruth series of a synthetic bag.

    Raises:
        BagError: if the bag has no FaceTruth topic or it is empty.
        InputError: naming the bag, topic and message of a NaN (:func:`read_converted`).
    """
    topic = _only_topic(bag, conversions.TRUTH_TYPE)
    return truth_series(read_truth(bag, topic), f'{bag}: topic {topic}')


def read_truth(bag: Path, topic: str) -> list[conversions.TruthSample]:
    """The truth samples of a bag's FaceTruth ``topic``, in record order.

    Raises:
        BagError: if the bag lacks the topic.
        InputError: naming the bag, topic and message index of a malformed message.
    """
    return [sample for _, sample in read_converted(bag, topic, conversions.truth_from_msg)]


def truth_series(samples: Sequence[conversions.TruthSample], where: str) -> TruthSeries:
    """The FaceTruth series of samples read already, one row per sample.

    Args:
        samples: the truth of the frames, in record order.
        where: the bag and topic they were read from, for the message.

    Raises:
        BagError: if there are none.
    """
    if not samples:
        msg = f'{where} holds no FaceTruth message'
        raise BagError(msg)
    return TruthSeries(
        stamps=np.array([s.stamp_ns for s in samples], dtype=np.int64),
        subject_id=samples[0].subject_id,
        omega=np.array([s.omega for s in samples]),
        t=np.array([s.t for s in samples]),
        alpha=np.array([s.alpha for s in samples]),
        sigma=np.array([s.sigma for s in samples]),
        nodes=np.array([s.nodes for s in samples]),
        labels=np.array([s.label for s in samples]),
        intensity=np.array([s.intensity for s in samples]),
    )


def read_converted(bag: Path, topic: str, convert: Callable[[Any], T]) -> Iterator[tuple[Any, T]]:
    """Each message of ``topic`` (one with a header) and its conversion, in record order.

    Of a damaged bag, the readable messages (:func:`~face_tracking_ros.io.bags.read_usable`).

    Args:
        bag: bag directory.
        topic: the topic to read.
        convert: a reader of :mod:`~face_tracking_ros.io.conversions`, e.g. ``truth_from_msg``.

    Raises:
        InputError: for a message ``convert`` refuses (a NaN, a malformed field), naming the
            bag, the topic, the message's index and header stamp, and what is wrong with it.
    """
    for index, message in enumerate(read_usable(bag, topics=[topic])):
        try:
            converted = convert(message.msg)
        except InputError as error:
            stamp = message.msg.header.stamp
            where = f'{bag}: {topic} message {index} (stamp {stamp.sec}.{stamp.nanosec:09d} s)'
            raise InputError(f'{where}: {error}') from None
        yield message.msg, converted


def require_parameters(bag: Path, lengths: dict[str, int]) -> None:
    """Check that a tracker output's states carry the parameters to recognise from.

    Args:
        bag: the tracker output, for the message.
        lengths: parameter name ('sigma', 'alpha') -> its length in the states.

    Raises:
        BagError: if one is empty, as in a stereo_tracker output tracked without a model.
    """
    empty = [name for name, length in lengths.items() if length == 0]
    if empty:
        msg = (
            f'{bag}: its face/state carries no {" or ".join(empty)} (a stereo_tracker output '
            'tracked without a face model: give one, --model or model_file; or one in which no '
            'pair was tracked)'
        )
        raise BagError(msg)


def has_truth(bag: Path) -> bool:
    """True if the bag has a FaceTruth topic."""
    return holds_truth(bag_topics(bag))


def holds_truth(topics: Mapping[str, str]) -> bool:
    """True if a bag's topics (name -> type) include a FaceTruth topic."""
    return conversions.TRUTH_TYPE in topics.values()


def _only_topic(bag: Path, msgtype: str) -> str:
    """The one topic of ``msgtype`` in the bag."""
    topics = [topic for topic, kind in bag_topics(bag).items() if kind == msgtype]
    if len(topics) != 1:
        found = ', '.join(topics) or 'none'
        msg = f'{bag}: expected one {msgtype} topic, found {found}'
        raise BagError(msg)
    return topics[0]


def _points(points: list) -> np.ndarray:
    """(N, 3) array of geometry_msgs/Point (NaN-free by construction of the writers)."""
    return np.array([(p.x, p.y, p.z) for p in points], dtype=float).reshape(-1, 3)
