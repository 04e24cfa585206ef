"""The two-stage rigid alignment of the training meshes (seed §3.3).

Stage 1 aligns each subject's meshes to that subject's neutral mesh (the generalised-Procrustes
mean of its neutral-labelled frames); stage 2 aligns the subjects' neutral meshes together by
generalised Procrustes and moves every frame of a subject with its subject's transform. Both
stages use the weighted Procrustes of :mod:`face_tracking_ros.geometry.procrustes` (eyes, eye
corners and nose 0.9, face edge 0.5, lips and brows 0.1). The pose of the common mean is fixed
by the topology's reference face, and the result is translated so that the mean's eye-centre
midpoint is the origin, as the face frame of :mod:`face_tracking_ros.model.topology` requires.
"""

from __future__ import annotations

import numpy as np

from face_tracking_ros.geometry.procrustes import generalized_procrustes, rigid_align
from face_tracking_ros.learning.training_set import TrainingSet
from face_tracking_ros.model.topology import Group, mesh_topology


def align_training_set(training: TrainingSet) -> TrainingSet:
    """Two-stage alignment of §3.3: each subject to its neutral mesh, then all subjects together.

    Args:
        training: meshes in any per-frame rigid frame (e.g. the camera frame), metres.

    Returns:
        The same frames with meshes (F, N, 3) in the common face frame, metres.
    """
    topology = mesh_topology(training.num_nodes)
    weights = topology.alignment_weights()
    frames = [np.flatnonzero(training.subject_index == s) for s in range(training.num_subjects)]
    neutral_meshes = np.stack(
        [
            generalized_procrustes(training.meshes[mine[training.neutral[mine]]], weights).mean
            for mine in frames
        ]
    )
    together = generalized_procrustes(neutral_meshes, weights, reference=topology.reference_shape)
    # The face frame's origin: between the eyes of the subjects' mean neutral.
    origin = together.mean[topology.group_mask(Group.EYE)].mean(axis=0)
    aligned = np.empty_like(training.meshes)
    for s, mine in enumerate(frames):
        # Each frame onto its subject's neutral, then (one transform per subject) onto the rest.
        to_neutral = rigid_align(training.meshes[mine], neutral_meshes[s], weights).aligned
        aligned[mine] = to_neutral @ together.rotation[s].T + (together.t[s] - origin)
    return training.with_meshes(aligned)
