"""The training meshes of a bag: its subjects' meshes, neutral flags, labels and true alpha.

A bag holds one of:

* ``face_tracking_msgs/FaceTruth`` (synthetic truth, default topic ``truth/face``): nodes in the
  camera frame, subject id and expression label per frame; frames labelled 'neutral' are the
  neutral frames of §3.4;
* ``face_tracking_msgs/FaceMesh`` or ``FaceState`` (a tracker's meshes): subject, label and
  alpha come from a truth bag (matched by header stamp) when given; otherwise the subject is
  :attr:`~.learn_options.LearnOptions.subject` or the bag's name (its
  :func:`~face_tracking_ros.io.bags.recording_name`), and the first
  ``neutral_frames`` frames of each bag are taken as neutral. Frames the tracker did not track
  are left out, and so are those with nodes it judged covered by an occluder
  (``FaceState.occluded``: such a node was not measured, so the mesh does not show the face's
  expression there).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from face_tracking_ros.errors import BagError, ConfigError, InputError
from face_tracking_ros.io.bags import read_usable, recording_name
from face_tracking_ros.io.conversions import (
    STATE_TYPE,
    TRUTH_TYPE,
    TruthSample,
    occluded_nodes,
    points_to_array,
    stamp_to_ns,
    truth_from_msg,
)
from face_tracking_ros.io.series import read_converted
from face_tracking_ros.learning.training_set import MeshSequence
from face_tracking_ros.model.topology import SUPPORTED_NODE_COUNTS
from face_tracking_ros.pipelines.bag_reads import AFRESH, BagReads
from face_tracking_ros.pipelines.learn_options import LearnOptions, subject_of
from face_tracking_ros.replay import bag_spelling
from face_tracking_ros.tracking.result import TrackStatus
from face_tracking_ros.wording import counted

MESH_TYPES = ('face_tracking_msgs/msg/FaceMesh', STATE_TYPE)
TRUTH_TOPIC = 'truth/face'
STATE_TOPIC = 'face/state'
TRACKED = int(TrackStatus.TRACKING)  # FaceState.STATUS_TRACKING
UNTRACKED = 'untracked'  # a frame left out of learning: not TRACKING
OCCLUDED = 'occluded'  # a frame left out of learning: nodes covered by an occluder
DEFAULT_TOPICS = (TRUTH_TOPIC, 'face/mesh_raw', STATE_TOPIC)


@dataclass(frozen=True)
class BagMeshes:
    """Meshes of one subject read from one bag.

    Attributes:
        sequence: the meshes, neutral flags and labels.
        alpha: (F, E) true alpha when the bag holds truth, else None.
        sigma: the subject's true sigma when the bag holds truth, else None.
    """

    sequence: MeshSequence
    alpha: np.ndarray | None
    sigma: np.ndarray | None = None


class _Frame(NamedTuple):
    """One tracked frame of a bag: its subject, message index, (N, 3) nodes (m) and truth."""

    subject: str
    index: int
    nodes: np.ndarray
    sample: TruthSample | None


def read_bag_meshes(
    bag: Path,
    options: LearnOptions,
    truth_bag: Path | None,
    name: str,
    say: Callable[[str], None] = print,
    reads: BagReads = AFRESH,
) -> list[BagMeshes]:
    """The meshes of one bag, one entry per subject found in it.

    Args:
        bag: a bag of FaceTruth, FaceMesh or FaceState messages.
        options: the run's options (topic, subject, neutral frames, nodes).
        truth_bag: for mesh bags, a bag whose ``truth/face`` messages give the subject, label and
            alpha of the mesh with the same header stamp (e.g. the synthetic bag a tracker ran
            on); None: the meshes carry their own truth (FaceTruth) or have none.
        name: the recording name the subject id is taken from without truth
            (:func:`~.learn_options.subject_of`): the raw bag's, for the meshes tracked from
            it.
        say: where the notes on what was left out or taken as neutral go, line by line.
        reads: how the bags' topics and truth are read: learn reads each bag's once a run
            (:meth:`~.bag_reads.BagReads.once`).

    Raises:
        BagError: if a bag lacks the topic, holds no message on it, or the truth bag has no
            truth for a mesh's stamp.
        InputError: naming the bag, topic and message index of a malformed message.
    """
    topics = reads.topics(bag)
    topic = _checked_mesh_topic(bag, topics, options)
    frames, left_out = _tracked_frames(bag, topics, topic, options, truth_bag, name, reads.truth)
    if left_out[UNTRACKED]:
        untracked = counted(left_out[UNTRACKED], 'frame')
        say(f'{bag}: {untracked} the tracker did not track (initialising or lost) left out')
    if left_out[OCCLUDED]:
        occluded = counted(left_out[OCCLUDED], 'frame')
        say(f'{bag}: {occluded} with nodes covered by an occluder (FaceState.occluded) left out')
    if not frames:
        skipped, seen = left_out.total(), ' with every node seen' if left_out[OCCLUDED] else ''
        msg = (
            f'{bag}: none of the {counted(skipped, "frame")} on {topic} was tracked{seen}'
            if skipped
            else f'{bag}: no message on {topic}'
        )
        raise BagError(msg)
    by_subject: dict[str, list[_Frame]] = {}
    for frame in frames:
        by_subject.setdefault(frame.subject, []).append(frame)
    return [_bag_meshes(bag, topic, items, options, say) for items in by_subject.values()]


def bag_subjects(
    bag: Path,
    options: LearnOptions,
    truth_bag: Path | None,
    truth_meshes: bool,
    reads: BagReads = AFRESH,
) -> set[str]:
    """The subjects :func:`read_bag_meshes` finds in a bag's meshes, known without reading them.

    Those of ``truth_bag``'s truth (it may hold more: a stamp without a mesh, or an untracked
    one), else those of the bag's FaceTruth messages where its meshes are these, else the one
    its name gives (:func:`~.learn_options.subject_of`).

    Args:
        bag: the bag given (a raw stereo bag: the meshes are yet to be tracked from it).
        options: the run's options (topic, subject, subject pattern).
        truth_bag: the bag labelling its meshes, as for :func:`read_bag_meshes`; None: none.
        truth_meshes: whether its meshes may be its FaceTruth messages (it holds truth and is
            not tracked).
        reads: how the bags' topics and truth are read, as for :func:`read_bag_meshes`.

    Raises:
        BagError, InputError: for truth that :func:`read_bag_meshes` would refuse (a missing
            topic, a malformed message), or a bag of truth without the mesh topic.
        ConfigError: if ``options.subject_pattern`` does not match the bag's name.
    """
    if truth_bag is not None:
        return {sample.subject_id for sample in reads.truth(truth_bag, TRUTH_TOPIC)}
    topic = _own_truth_topic(bag, options, truth_meshes, reads)
    if topic is not None:
        return {sample.subject_id for sample in reads.truth(bag, topic)}
    return {subject_of(recording_name(bag), options)}


def subject_from_name(
    bag: Path,
    options: LearnOptions,
    truth_bag: Path | None,
    truth_meshes: bool,
    reads: BagReads = AFRESH,
) -> bool:
    """Whether the subject of a bag's meshes is the one its name gives (no truth labels them).

    As :func:`bag_subjects` finds it (same arguments): only then do ``options.subject`` and
    ``options.subject_pattern`` (:func:`~.learn_options.subject_of`) name it, and
    ``options.neutral_frames`` mark its neutral frames.

    Raises:
        BagError: for a bag of truth without the mesh topic.
    """
    return truth_bag is None and _own_truth_topic(bag, options, truth_meshes, reads) is None


def _own_truth_topic(
    bag: Path, options: LearnOptions, truth_meshes: bool, reads: BagReads
) -> str | None:
    """The bag's mesh topic if its meshes are its own FaceTruth messages; else None.

    They may be only where ``truth_meshes`` (it holds truth and is not tracked); the topics are
    read by ``reads``.

    Raises:
        BagError: for such a bag without the mesh topic (:func:`_checked_mesh_topic`).
    """
    if not truth_meshes:
        return None
    topics = reads.topics(bag)
    topic = _checked_mesh_topic(bag, topics, options)
    return topic if topics[topic] == TRUTH_TYPE else None


def mesh_topic(topics: dict[str, str], options: LearnOptions) -> str | None:
    """The bag's mesh topic: ``options.topic``, else the first of DEFAULT_TOPICS it has.

    As the bag spells it (a recorder's names are absolute: '/face/mesh_raw'); None if it has none.
    """
    wanted = [options.topic] if options.topic else DEFAULT_TOPICS
    spelt = [bag_spelling(name, topics) for name in wanted]
    return next((name for name in spelt if name in topics), None)


def mesh_from_message(msg: Any, msgtype: str) -> tuple[int, np.ndarray, TruthSample | None]:
    """Header stamp (ns), (N, 3) nodes (m) and, for FaceTruth, the truth of one mesh message.

    A candidate for :mod:`face_tracking_ros.io.conversions`.

    Raises:
        InputError: naming the field of a NaN or malformed value.
    """
    if msgtype == TRUTH_TYPE:
        truth = truth_from_msg(msg)
        return truth.stamp_ns, truth.nodes, truth
    field = 'FaceMesh.points' if msgtype == MESH_TYPES[0] else 'FaceState.nodes'
    points = msg.points if msgtype == MESH_TYPES[0] else msg.nodes
    return stamp_to_ns(msg.header.stamp), points_to_array(points, field), None


def _checked_mesh_topic(bag: Path, topics: dict[str, str], options: LearnOptions) -> str:
    """The bag's mesh topic (:func:`mesh_topic`).

    Raises:
        BagError: if the bag has none, or it is of another type than a mesh's.
    """
    topic = mesh_topic(topics, options)
    if topic is None:
        wanted = options.topic or ' or '.join(DEFAULT_TOPICS)
        msg = f'{bag}: no topic {wanted} in bag (topics: {", ".join(sorted(topics)) or "none"})'
        raise BagError(msg)
    msgtype = topics[topic]
    if msgtype != TRUTH_TYPE and msgtype not in MESH_TYPES:
        msg = f'{bag}: topic {topic} has type {msgtype}; expected FaceTruth, FaceMesh or FaceState'
        raise BagError(msg)
    return topic


def _tracked_frames(
    bag: Path,
    topics: dict[str, str],
    topic: str,
    options: LearnOptions,
    truth_bag: Path | None,
    name: str,
    truth_of: Callable[[Path, str], Sequence[TruthSample]],
) -> tuple[list[_Frame], Counter[str]]:
    """The frames of ``topic`` to learn from, with their truth, and how many were left out, why.

    Left out (:func:`_left_out`): those its FaceStates, or the face/state beside its FaceMeshes,
    say were not tracked (:data:`UNTRACKED`) or had nodes covered by an occluder
    (:data:`OCCLUDED`).

    The truth of a frame is its FaceTruth message's, else the truth bag's of its stamp; its
    subject is the truth's, else the one named by ``name`` (:func:`~.learn_options.subject_of`).
    Truth is read by ``truth_of``, meshes of FaceTruth too.

    Raises:
        BagError: if the truth bag has no truth for a mesh's stamp.
        InputError: naming the bag, topic and message index of a malformed message.
    """
    msgtype = topics[topic]
    truth = _by_stamp(truth_of(truth_bag, TRUTH_TOPIC)) if truth_bag is not None else {}
    # A FaceState says itself whether to leave it out; a FaceMesh by its bag's face/state.
    beside = _left_out_stamps(bag, topics) if msgtype == MESH_TYPES[0] else {}
    frames: list[_Frame] = []
    skipped: Counter[str] = Counter()
    for index, (msg, (stamp_ns, nodes, sample)) in enumerate(
        _mesh_messages(bag, topic, msgtype, truth_of)
    ):
        why = _left_out(msg) if msgtype == MESH_TYPES[1] else beside.get(stamp_ns)
        if why is not None:
            skipped[why] += 1
            continue
        if truth_bag is not None:
            sample = truth.get(stamp_ns)
            if sample is None:
                msg = f'{truth_bag}: no {TRUTH_TOPIC} message stamped {stamp_ns} ns for {bag}'
                raise BagError(msg)
        subject = sample.subject_id if sample else subject_of(name, options)
        frames.append(_Frame(subject, index, nodes, sample))
    # Beside a face/state, every frame it leaves out counts, with a mesh or not: a tracker
    # publishes none while INITIALIZING (before its first fit, or after a reset).
    return frames, Counter(beside.values()) if beside else skipped


def _left_out(state: Any) -> str | None:
    """Why a FaceState's frame is no training mesh (:data:`UNTRACKED`, :data:`OCCLUDED`), or None.

    Not tracked: its mesh is none (zeros before the first initialisation) or the last one
    tracked, not the face. Occluded: a node covered by an occluder was not measured (the stereo
    tracker moved it with the head's rigid motion, the mono tracker's face model placed it), so
    the mesh does not show the face's expression there. A FaceState written before
    the field existed has no flags (:func:`~face_tracking_ros.io.conversions.occluded_nodes`).
    """
    if state.status != TRACKED:
        return UNTRACKED
    return OCCLUDED if occluded_nodes(state).any() else None


def _left_out_stamps(bag: Path, topics: dict[str, str]) -> dict[int, str]:
    """Header stamps of the frames a tracker's output bag leaves out, and why.

    Its face/state messages that :func:`_left_out` gives a reason for.
    """
    state_topic = bag_spelling(STATE_TOPIC, topics)
    if topics.get(state_topic) != MESH_TYPES[1]:
        return {}
    left_out = (
        (stamp_to_ns(message.msg.header.stamp), _left_out(message.msg))
        for message in read_usable(bag, [state_topic])
    )
    return {stamp: why for stamp, why in left_out if why is not None}


def _mesh_messages(
    bag: Path, topic: str, msgtype: str, truth_of: Callable[[Path, str], Sequence[TruthSample]]
) -> Iterable[tuple[Any, tuple[int, np.ndarray, TruthSample | None]]]:
    """Each mesh message of ``topic`` (of ``msgtype``) and its :func:`mesh_from_message`.

    FaceTruth is read by ``truth_of`` (the message is then None: only a FaceState's is used).
    """
    if msgtype == TRUTH_TYPE:
        return [(None, (truth.stamp_ns, truth.nodes, truth)) for truth in truth_of(bag, topic)]
    return read_converted(bag, topic, lambda msg: mesh_from_message(msg, msgtype))


def _by_stamp(samples: Iterable[TruthSample]) -> dict[int, TruthSample]:
    """Truth samples by header stamp."""
    return {sample.stamp_ns: sample for sample in samples}


def _bag_meshes(
    bag: Path, topic: str, items: list[_Frame], options: LearnOptions, say: Callable[[str], None]
) -> BagMeshes:
    """One subject's meshes of a bag; neutral frames from labels, else the first K frames.

    ``items`` are the subject's frames, all with truth or all without; the first K are by
    message index (``say`` notes it when they are all of them). With truth, the subject's true
    sigma is its first frame's.
    """
    subject = items[0].subject
    counts = {len(item.nodes) for item in items}
    if len(counts) > 1:
        msg = f'{bag}: {topic} meshes of subject {subject!r} have node counts {sorted(counts)}'
        raise InputError(msg)
    meshes = _select_nodes(np.array([item.nodes for item in items]), options, f'{bag}: {topic}')
    samples = [item.sample for item in items if item.sample is not None]
    if not samples:
        neutral = np.array([item.index for item in items]) < options.neutral_frames
        if neutral.all():
            say(
                f'{bag}: {options.named("neutral_frames")} {options.neutral_frames} covers all '
                f'its {counted(len(items), "frame")}: all are taken as neutral, none shows an '
                'expression'
            )
        return BagMeshes(MeshSequence(subject, meshes, neutral, None, str(bag)), None)
    labels = tuple(str(sample.label) for sample in samples)
    alpha = np.array([sample.alpha for sample in samples])
    return BagMeshes(
        MeshSequence.labelled(subject, meshes, labels, str(bag)), alpha, samples[0].sigma
    )


def _select_nodes(meshes: np.ndarray, options: LearnOptions, where: str) -> np.ndarray:
    """Keep the first ``options.nodes`` nodes (the 19-node mesh is a prefix of the 34-node one)."""
    if meshes.shape[1] not in SUPPORTED_NODE_COUNTS:
        msg = f'{where}: meshes have {meshes.shape[1]} nodes; supported: {SUPPORTED_NODE_COUNTS}'
        raise InputError(msg)
    num_nodes = options.nodes
    if num_nodes is None:
        return meshes
    if num_nodes > meshes.shape[1]:
        msg = (
            f'{where}: {options.named("nodes")} {num_nodes} but the meshes have only '
            f'{meshes.shape[1]} nodes'
        )
        raise ConfigError(msg)
    return meshes[:, :num_nodes]
