"""Training meshes drawn from the synthetic FacePopulation, for the learning tests and benchmark.

Each sequence is one subject with an almost still head (the seed's training protocol, §3.3):
neutral stretches alternate with labelled expression episodes (smooth onset, hold, offset), the
head drifts by about a degree and a few millimetres, and every node gets white noise. Frames are
returned in the camera frame, as a tracker or the truth topic would give them.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from face_tracking_ros.learning.training_set import NEUTRAL_LABEL, MeshSequence, TrainingSet
from face_tracking_ros.synthetic.faces import ACTIVE_EXPRESSIONS, FacePopulation

FPS = 30.0
CAMERA_DISTANCE = 0.6  # m


def expression_course(rng: np.random.Generator, frames: int) -> tuple[np.ndarray, tuple[str, ...]]:
    """Intensities (frames, E) and labels of alternating neutral stretches and expressions."""
    alpha = np.zeros((frames, len(ACTIVE_EXPRESSIONS)))
    labels = [NEUTRAL_LABEL] * frames
    f = int(rng.integers(10, 25))
    while True:
        rise, hold, fall = (int(round(FPS * rng.uniform(*span))) for span in _EPISODE)
        if f + rise + hold + fall > frames:
            break
        which = int(rng.integers(len(ACTIVE_EXPRESSIONS)))
        peak = rng.uniform(0.6, 1.0)
        ramp = np.concatenate(
            [np.linspace(0, 1, rise + 1)[1:], np.ones(hold), np.linspace(1, 0, fall + 1)[:-1]]
        )
        alpha[f : f + len(ramp), which] = peak * np.sin(0.5 * np.pi * ramp) ** 2
        for k in range(f, f + len(ramp)):
            labels[k] = ACTIVE_EXPRESSIONS[which]
        f += len(ramp) + int(rng.integers(8, 30))
    return alpha, tuple(labels)


_EPISODE = ((0.15, 0.3), (0.5, 1.2), (0.15, 0.3))  # rise, hold, fall durations, s


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
    result = []
    alphas = []
    for index in range(subjects):
        subject = population.subject(index)
        for k in range(sequences):
            alpha, labels = expression_course(rng, frames)
            nodes = subject.neutral_nodes + (alpha @ population.expression_basis_true.T).reshape(
                frames, -1, 3
            )
            nodes = nodes[:, :num_nodes] + rng.normal(scale=noise, size=(frames, num_nodes, 3))
            drift = np.cumsum(rng.normal(scale=0.002, size=(frames, 3)), axis=0)
            rotation = Rotation.from_rotvec(
                np.radians(rng.normal(scale=1.0, size=3)) + np.radians(0.3) * np.tanh(drift)
            ).as_matrix()
            t = np.array([0.0, 0.0, CAMERA_DISTANCE]) + rng.normal(scale=0.01, size=3)
            t = t + 0.3 * np.tanh(drift) * 0.01
            camera = np.einsum('fab,fnb->fna', rotation, nodes) + t[:, None, :]
            neutral = np.array([label == NEUTRAL_LABEL for label in labels])
            result.append(
                MeshSequence(
                    subject.subject_id, camera, neutral, labels, f'{subject.subject_id}/{k}'
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
