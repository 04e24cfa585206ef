"""Training meshes drawn from the synthetic world, for the learning tests and benchmark.

The synthetic world's own pieces make the sequences: a :class:`FacePopulation` subject, the
seed's training script (:meth:`ExpressionScript.training`: neutral first, then the expressions in
turn) and a 'still' head trajectory (§3.3: subjects asked not to move). Nodes get white noise
(the issue-4 protocol: 0.5 mm) and are returned in the camera frame, as the truth topic has them.
No images are rendered, so this is fast.
"""

from __future__ import annotations

import numpy as np

from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.learning.training_set import NEUTRAL_LABEL, MeshSequence, TrainingSet
from face_tracking_ros.synthetic.faces import ACTIVE_EXPRESSIONS, FacePopulation
from face_tracking_ros.synthetic.motion import ExpressionScript, HeadTrajectory

FPS = 30.0
EXPRESSIONS_PER_SEQUENCE = 5


def mesh_sequences(
    population: FacePopulation,
    num_nodes: int = 19,
    subjects: int = 11,
    sequences: int = 2,
    frames: int = 380,
    noise: float = 0.0005,
    seed: int = 0,
) -> tuple[list[MeshSequence], np.ndarray]:
    """Noisy camera-frame mesh sequences of the first ``subjects`` subjects.

    Returns:
        The sequences (subject-major) and the true alpha (total frames, E) in the same order.
    """
    rng = np.random.default_rng(seed)
    times = np.arange(frames) / FPS
    result = []
    alphas = []
    for index in range(subjects):
        subject = population.subject(index)
        for k in range(sequences):
            first = (index + EXPRESSIONS_PER_SEQUENCE * k) % len(ACTIVE_EXPRESSIONS)
            script = ExpressionScript.training(frames / FPS, first=first)
            states = [script.state(time) for time in times]
            alpha = np.array([state.alpha for state in states])
            trajectory = HeadTrajectory.random('still', rng)
            nodes = [
                population.nodes(subject, state.alpha)[:num_nodes] for state in states
            ] + rng.normal(scale=noise, size=(frames, num_nodes, 3))
            camera = np.empty_like(nodes)
            for f, time in enumerate(times):
                omega, t = trajectory.pose(time)
                camera[f] = nodes[f] @ rodrigues(omega)[0].T + t
            labels = tuple(state.label for state in states)
            result.append(
                MeshSequence(
                    subject.subject_id,
                    camera,
                    np.array([label == NEUTRAL_LABEL for label in labels]),
                    labels,
                    f'{subject.subject_id}/{k}',
                )
            )
            alphas.append(alpha)
    return result, np.concatenate(alphas)


def training_set(
    preset: str = 'realistic', num_nodes: int = 19, **kwargs: int | float
) -> tuple[TrainingSet, FacePopulation, np.ndarray]:
    """A pooled training set of :func:`mesh_sequences`, its population and true alpha."""
    population = FacePopulation(preset)
    sequences, alpha = mesh_sequences(population, num_nodes, **kwargs)
    return TrainingSet.from_sequences(sequences), population, alpha
