"""Synthetic parameter streams for the recognition tests: sigma clusters and labelled alpha.

Stand-ins for tracked parameters: every subject has a true sigma and a personal scale of each
expression; every frame's estimate adds the benchmark's tracking noise (white plus AR(1)).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.io.bags import BagWriter
from face_tracking_ros.io.conversions import array_to_points, make_header, pose_msg
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.recognition.benchmark import tracking_noise
from face_tracking_ros.recognition.expression import EXPRESSION_LABELS
from face_tracking_ros.recognition.sequences import ParameterSequence
from face_tracking_ros.synthetic.faces import FacePopulation

FPS = 30.0
TRUTH = 'truth/face'
FACE_TRUTH = 'face_tracking_msgs/msg/FaceTruth'


@dataclass(frozen=True)
class ExpressionWorld:
    """Expression displacements in alpha space (q dims, metres) per non-neutral label."""

    directions: dict[str, np.ndarray]

    @classmethod
    def make(cls, rng: np.random.Generator, q: int, amplitude: float = 0.012) -> ExpressionWorld:
        """Random distinct directions; surprise = brow_raise + jaw_open as on a real face."""
        base = {}
        for label in ('smile', 'jaw_open', 'brow_raise', 'frown', 'pucker'):
            direction = rng.normal(size=q)
            base[label] = amplitude * direction / np.linalg.norm(direction)
        base['surprise'] = 0.8 * (base['brow_raise'] + base['jaw_open'])
        return cls(directions=base)


@dataclass(frozen=True)
class LabelledStream:
    """One sequence: stamps (M,) s, parameters (M, d), labels (M,) str, intensity (M,)."""

    times: np.ndarray
    values: np.ndarray
    labels: np.ndarray
    intensity: np.ndarray


def expression_stream(
    rng: np.random.Generator,
    world: ExpressionWorld,
    duration: float,
    noise_std: float = 0.001,
    subject_scale: float = 0.2,
) -> LabelledStream:
    """A sequence alternating neutral stretches and expressions with smooth onsets and offsets."""
    frames = int(round(duration * FPS))
    times = np.arange(frames) / FPS
    labels = np.full(frames, 'neutral', dtype=object)
    intensity = np.zeros(frames)
    alpha = np.zeros((frames, len(next(iter(world.directions.values())))))
    scales = {k: 1.0 + subject_scale * rng.uniform(-1, 1) for k in world.directions}
    t = rng.uniform(0.3, 1.0)  # a track starts on a neutral face (the calibration period)
    while True:
        label = EXPRESSION_LABELS[1 + rng.integers(len(EXPRESSION_LABELS) - 1)]
        rise, hold, fall = rng.uniform(0.15, 0.3), rng.uniform(0.5, 1.2), rng.uniform(0.15, 0.3)
        if t + rise + hold + fall > duration:
            break
        peak = rng.uniform(0.6, 1.0)
        u = times - t
        ramp_up = np.clip(u / rise, 0.0, 1.0)
        ramp_down = np.clip((rise + hold + fall - u) / fall, 0.0, 1.0)
        course = peak * np.minimum(_smoothstep(ramp_up), _smoothstep(ramp_down))
        if label == 'jaw_open':  # talking: the jaw oscillates at ~4 Hz while open
            course *= 0.7 + 0.3 * np.cos(2 * np.pi * 4.0 * np.clip(u, 0.0, None))
        active = course > 0.0
        labels[active] = label
        intensity[active] = course[active]
        alpha += course[:, None] * (scales[label] * world.directions[label])[None, :]
        t += rise + hold + fall + rng.uniform(0.4, 1.2)
    alpha += tracking_noise(rng, frames, alpha.shape[1], noise_std, FPS)
    return LabelledStream(
        times=times, values=alpha, labels=labels.astype(str), intensity=intensity
    )


def sigma_population(
    rng: np.random.Generator, subjects: int, stds: tuple[float, ...]
) -> np.ndarray:
    """(subjects, p) true sigma drawn from N(0, diag(stds**2)), metres."""
    return rng.normal(size=(subjects, len(stds))) * np.asarray(stds)[None, :]


def sigma_stream(
    rng: np.random.Generator, sigma_true: np.ndarray, duration: float, noise_std: float
) -> np.ndarray:
    """(M, p) tracked sigma estimates of one subject over ``duration`` seconds."""
    frames = int(round(duration * FPS))
    return sigma_true[None, :] + tracking_noise(rng, frames, len(sigma_true), noise_std, FPS)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    """3x^2 - 2x^3 on [0, 1]."""
    return x * x * (3.0 - 2.0 * x)


def parameter_sequence(
    rng: np.random.Generator,
    world: ExpressionWorld,
    subject_id: str,
    sigma_true: np.ndarray,
    duration: float,
    alpha_noise: float = 0.0015,
    sigma_noise: float = 0.002,
) -> ParameterSequence:
    """A labelled sequence of one subject: expression stream plus noisy sigma estimates."""
    stream = expression_stream(rng, world, duration, noise_std=alpha_noise)
    return ParameterSequence(
        subject_id=subject_id,
        times=stream.times,
        sigma=sigma_stream(rng, sigma_true, duration, sigma_noise),
        alpha=stream.values,
        labels=stream.labels,
        intensity=stream.intensity,
    )


def truth_model(population: FacePopulation, num_nodes: int = 34) -> FaceModel:
    """A FaceModel whose S and A orthonormally span the population's true bases."""
    truth = population.truth(num_nodes)
    shape_basis = np.linalg.qr(truth.identity_basis)[0]
    action_basis = truth.expression_span()
    p, q = shape_basis.shape[1], action_basis.shape[1]
    return FaceModel(
        node_names=truth.node_names,
        mean_shape=truth.mean_shape,
        shape_basis=shape_basis,
        action_basis=action_basis,
        shape_eigenvalues=np.ones(p),
        action_eigenvalues=np.ones(q),
        sigma_prior_covariance=np.eye(p),
        alpha_prior_covariance=np.eye(q),
        method='truth',
    )


def write_truth_bag(
    path: Path, population: FacePopulation, subject: int, seed: int, duration: float = 12.0
) -> None:
    """A bag of FaceTruth at 30 fps: expressions with onsets/offsets, a slowly moving head."""
    rng = np.random.default_rng(seed)
    stream = expression_stream(rng, ExpressionWorld.make(rng, 1), duration, noise_std=0.0)
    person = population.subject(subject)
    factory = RosbagsMessages(typestore())
    with BagWriter(path) as bag:
        for m, (time, label, level) in enumerate(
            zip(stream.times, stream.labels, stream.intensity, strict=True)
        ):
            weights = {label: level} if label != 'neutral' else {}
            omega = 0.1 * np.sin([time, 0.7 * time, 0.3 * time])
            t = np.array([0.02 * np.sin(time), 0.0, 0.6])
            nodes = population.nodes(person, weights) @ rodrigues(omega)[0].T + t
            stamp_ns = 10**9 + m * 33_333_333
            msg = factory.make(
                FACE_TRUTH,
                header=make_header(factory, stamp_ns, 'camera'),
                subject_id=person.subject_id,
                pose=pose_msg(factory, omega, t),
                omega=omega,
                alpha=population.alpha(weights),
                sigma=person.sigma_true,
                node_names=list(population.node_names),
                nodes=array_to_points(factory, nodes),
                expression_label=str(label),
                expression_intensity=float(level),
            )
            bag.write(TRUTH, FACE_TRUTH, msg, stamp_ns)
