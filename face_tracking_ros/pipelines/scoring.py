"""A tracked bag scored against the synthetic truth its source bag carries.

The tracker's outputs, written by a replay of a synthetic bag
(:func:`face_tracking_ros.replay.replay_bag`), are matched to the bag's truth frames by stamp
and scored: the mono tracker's FaceStates by
:func:`~face_tracking_ros.tracking.accuracy.tracking_accuracy`, the stereo tracker's meshes by
:func:`~face_tracking_ros.tracking.stereo_evaluation.evaluate_stereo` in the rig of the bag's
camera_info. ``face-tracking track`` prints either score; the learning pipeline's tracking of
raw stereo bags (:mod:`.stereo_meshes`) prints the stereo one.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np

from face_tracking_ros.data import default_model_path
from face_tracking_ros.errors import BagError, InputError
from face_tracking_ros.geometry.camera import PinholeCamera, StereoRig
from face_tracking_ros.io.bags import bag_topics, read_messages, topic_has_word
from face_tracking_ros.io.conversions import CAMERA_INFO_TYPE, camera_from_info
from face_tracking_ros.io.series import TruthSeries, load_states, load_truth
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.tracking.accuracy import TrackingAccuracy, tracking_accuracy
from face_tracking_ros.tracking.result import TrackStatus
from face_tracking_ros.tracking.stereo_evaluation import StereoEvaluation, evaluate_stereo


def score_stereo_against_truth(
    bag: Path, out: Path, truth: TruthSeries | None = None
) -> StereoEvaluation:
    """Stereo-tracked meshes in ``out`` against the truth in ``bag`` (issue 5's figures).

    The errors are over the frames from the first tracked one on: before it there is no
    estimate (the published nodes are zeros); a frame lost later counts with the last estimate,
    which is what the node publishes.

    Args:
        bag: the bag tracked, holding truth and the stereo camera_info.
        out: the tracker's output bag.
        truth: the truth of ``bag`` when read already; None: read here (:func:`load_truth`).

    Raises:
        BagError: if no frame was tracked.
    """
    states = load_states(out)
    truth = load_truth(bag) if truth is None else truth
    est, ref = _matching_frames(states.stamps, truth.stamps, bag, out)
    tracked = states.status[est] == TrackStatus.TRACKING
    if not tracked.any():
        msg = f'{out}: no frame was tracked'
        raise BagError(msg)
    since = int(np.argmax(tracked))
    est, ref = est[since:], ref[since:]
    nodes = states.nodes[est]
    return evaluate_stereo(
        nodes,
        truth.nodes[ref][:, : nodes.shape[1]],
        stereo_rig(bag),
        mesh_topology(nodes.shape[1]),
        states.status[est],
    )


def stereo_rig(bag: Path) -> StereoRig:
    """The rig of a stereo bag, from the first valid left and right camera_info.

    A camera_info topic is the left (right) camera's if its name has the word ``left``
    (``right``; :func:`~face_tracking_ros.io.bags.topic_has_word`): not ``/cleft_palate/...``.

    Raises:
        BagError: if the bag lacks them.
        InputError: if they do not form a rectified rig.
    """
    cameras: dict[str, PinholeCamera | None] = {
        topic: None for topic, kind in bag_topics(bag).items() if kind == CAMERA_INFO_TYPE
    }
    for message in read_messages(bag, topics=list(cameras)):
        if cameras[message.topic] is None:
            with contextlib.suppress(InputError):  # e.g. an all-zero K: the tracker skips it too
                cameras[message.topic] = camera_from_info(message.msg)
        if all(cameras.values()):
            break
    left, right = (
        next((c for t, c in cameras.items() if topic_has_word(t, side) and c is not None), None)
        for side in ('left', 'right')
    )
    if left is None or right is None:
        msg = f'{bag}: no valid left and right camera_info to build the stereo rig'
        raise BagError(msg)
    return StereoRig(left, right)


def _matching_frames(
    stamps: np.ndarray, truth_stamps: np.ndarray, bag: Path, out: Path
) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the output frames and of the truth frames with the same stamps.

    Raises:
        BagError: if no output frame has a truth frame of the same stamp.
    """
    index = {int(stamp): i for i, stamp in enumerate(truth_stamps)}
    rows = [(i, index[int(s)]) for i, s in enumerate(stamps) if int(s) in index]
    if not rows:
        msg = f'{out}: no output frame has a truth frame of the same stamp in {bag}'
        raise BagError(msg)
    est, ref = np.array(rows).T
    return est, ref


def score_against_truth(bag: Path, out: Path, model_file: Path | None) -> TrackingAccuracy:
    """Accuracy of the mono FaceState outputs in ``out`` against the truth in ``bag``."""
    model = load_model(model_file or default_model_path())
    states, truth = load_states(out), load_truth(bag)
    est, ref = _matching_frames(states.stamps, truth.stamps, bag, out)
    return tracking_accuracy(
        model,
        states.status[est],
        states.omega[est],
        states.t[est],
        states.alpha[est],
        states.nodes[est],
        truth.nodes[ref][:, : model.num_nodes],
    )
