"""The training faces' size: a stereo baseline off by a factor, seen across subjects.

A rectified rig whose camera_info gives k times the true baseline triangulates every face k
times its size, k times as far (seed §3.3's stereo meshes); the tracker refuses a face outside
0.7-1.5 times the adult reference face (``tracker.init.min_face_scale``), which a baseline 25 %
off passes: one face cannot tell it from a larger one. Across several subjects it shows: their
median size moves by k, while the median of adult faces stays near 1. The synthetic populations'
neutral faces read 0.86-1.14 (the realistic one's standard deviation 5.3 %, the default's 3-4 %);
the median of 3 of them, drawn 300 000 times from seeds 0-5 of each, exceeded 1.12 in at most
2e-4 of the draws and fell below 1 / 1.12 in at most 1e-3, the same faces times 1.25 fell below
1.12 in at most 1.9e-3 (4 subjects: 1e-5, 7e-5 and 1.3e-4). :func:`face_size_warning` says so
above :data:`SET_SCALE_BOUND` or below its inverse, from :data:`MIN_SUBJECTS` subjects on.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from face_tracking_ros.io.bags import recording_name
from face_tracking_ros.learning.training_set import MeshSequence
from face_tracking_ros.model.topology import SUPPORTED_NODE_COUNTS, Group, mesh_topology
from face_tracking_ros.tracking.stereo_init import face_scale
from face_tracking_ros.wording import counted

SET_SCALE_BOUND = 1.12  # the subjects' median face size warned above, and below its inverse
MIN_SUBJECTS = 3  # fewest subjects whose median size is judged


def subject_scales(sequences: Sequence[MeshSequence]) -> dict[str, float]:
    """Each subject's face size, in sizes of the adult reference face (:func:`face_scale`).

    The median over the subject's neutral frames (every frame if none is labelled neutral) of
    the size its inner nodes span; frames without a finite mesh are left out, and so are
    subjects without one or with meshes of a node count without a reference face.
    """
    frames: dict[str, list[np.ndarray]] = {}
    for sequence in sequences:
        meshes = sequence.meshes[sequence.neutral] if sequence.neutral.any() else sequence.meshes
        frames.setdefault(sequence.subject_id, []).extend(meshes)
    scales = {subject: _median_scale(meshes) for subject, meshes in frames.items()}
    return {subject: scale for subject, scale in scales.items() if np.isfinite(scale)}


def _median_scale(meshes: list[np.ndarray]) -> float:
    """The median face size of ``meshes`` (N, 3) with finite nodes; NaN if none."""
    finite = [mesh for mesh in meshes if np.isfinite(mesh).all()]
    if not finite or finite[0].shape[0] not in SUPPORTED_NODE_COUNTS:
        return float('nan')
    topology = mesh_topology(finite[0].shape[0])
    inner = ~topology.group_mask(Group.EDGE)
    return float(np.median([face_scale(topology, mesh, inner) for mesh in finite]))


def face_size_warning(
    scales: Mapping[str, float], baselines: Callable[[], Mapping[Path, tuple[float, float]]]
) -> str | None:
    """The warning of a training set whose faces are too large or too small together; else None.

    Args:
        scales: each subject's face size (:func:`subject_scales`).
        baselines: reads, by raw stereo bag tracked for the set, its right camera's P[0,3]
            (-fx B) and baseline B, m (named with the values that would make the faces
            adult-sized); called only when the warning is made.

    Returns:
        From :data:`MIN_SUBJECTS` subjects on, when their median size is above
        :data:`SET_SCALE_BOUND` or below its inverse: the median, the range and what to check.
    """
    if len(scales) < MIN_SUBJECTS:
        return None
    values = np.array(list(scales.values()))
    scale = float(np.median(values))
    if 1.0 / SET_SCALE_BOUND <= scale <= SET_SCALE_BOUND:
        return None
    return (
        f"warning: the {counted(len(values), 'subject')}' faces read {scale:.2f} times the size "
        f'of an adult face (median; each {values.min():.2f}-{values.max():.2f}), where adults '
        f'stay within {1 / SET_SCALE_BOUND:.2f}-{SET_SCALE_BOUND:.2f}: a stereo baseline '
        f'{scale:.2f} times the true one reads so. {_adult_baselines(scale, baselines())}. A set '
        'of children, or of large faces only, reads so too: learning goes on'
    )


def _adult_baselines(scale: float, baselines: Mapping[Path, tuple[float, float]]) -> str:
    """The baselines that would make faces read ``scale`` adult-sized, one per rig of the bags."""
    if not baselines:
        return f'B / {scale:.2f} (P[0,3] / {scale:.2f}) would make them adult-sized'
    rigs: dict[tuple[float, float], list[str]] = {}
    for bag, rig in baselines.items():
        rigs.setdefault(rig, []).append(recording_name(bag))
    return '; '.join(
        f"The right camera_info's P[0,3] = {tx:.4g} (-fx B) gives B = {b:.4g} m "
        f'({", ".join(names)}): B = {b / scale:.3g} m (P[0,3] = {tx / scale:.4g}) would make '
        'them adult-sized'
        for (tx, b), names in rigs.items()
    )
