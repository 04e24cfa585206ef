"""The issue 7 targets measured on the synthetic world: true parameters plus tracking noise.

Scenario: subjects of a :class:`~face_tracking_ros.synthetic.faces.FacePopulation` play the
expression scripts of :mod:`face_tracking_ros.synthetic.motion` (training scripts for enrolment
and training, random test scripts otherwise). Every frame's true 34 nodes get tracking noise (per
node coordinate: half white, half slowly varying AR(1) with a 0.3 s time constant, total standard
deviation ``node_noise``) and are projected onto the face model under test
(:func:`~face_tracking_ros.recognition.node_fit.fit_model_to_nodes`), giving the sigma and alpha a
tracker with that model would report if its node error were that noise. The head pose does not
enter: the projection is invariant to it.

- Identity: the ``subjects`` enrolled people are enrolled from their training sequences; their
  held-out test sequences and those of ``strangers`` other people are classified in 1-s windows.
- Expressions: the classifier is trained on the enrolled people's training sequences and scored
  on the strangers' test sequences (held-out subjects and sequences), per frame and as events.
- The separation table (§4.5) uses the enrolled people's training and test sequences.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.recognition.evaluation import (
    EventScore,
    ExpressionAccuracy,
    IdentityAccuracy,
    SeparationTable,
    compare_expression_classifiers,
    compare_identity_classifiers,
    detect_events,
    expression_accuracy,
    merge_scores,
    score_events,
    separation_experiment,
    truth_segments,
)
from face_tracking_ros.recognition.events import EventConfig
from face_tracking_ros.recognition.expression import (
    ExpressionTrainingConfig,
    train_expression_classifier,
)
from face_tracking_ros.recognition.identity import UNKNOWN, IdentityConfig, IdentityGallery
from face_tracking_ros.recognition.node_fit import fit_model_to_nodes
from face_tracking_ros.recognition.sequences import ParameterSequence
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.synthetic.motion import ExpressionScript

NOISE_TIME_CONSTANT = 0.3  # s, of the slowly varying half of the tracking noise


@dataclass(frozen=True)
class BenchmarkConfig:
    """The synthetic scenario.

    Attributes:
        preset: population preset, 'default' or 'realistic'.
        seed: seed of the population and of every script and noise draw.
        subjects: number of enrolled people (11 in issue 7), >= 2.
        strangers: number of people never enrolled, >= 1.
        training_sequences: training sequences per enrolled person, >= 1.
        duration: length of every sequence, s, > 1.
        fps: frame rate, Hz, > 0.
        node_noise: standard deviation of the tracking noise per node coordinate, m, >= 0.
    """

    preset: str = 'default'
    seed: int = 0
    subjects: int = 11
    strangers: int = 11
    training_sequences: int = 2
    duration: float = 20.0
    fps: float = 30.0
    node_noise: float = 0.0015

    def __post_init__(self) -> None:
        """Validate the ranges.

        Raises:
            ConfigError: naming the parameter out of range.
        """
        counts = {
            'subjects': (self.subjects, 2),
            'strangers': (self.strangers, 1),
            'training_sequences': (self.training_sequences, 1),
        }
        for name, (value, least) in counts.items():
            if value < least:
                msg = f'benchmark {name} must be >= {least}, got {value}'
                raise ConfigError(msg)
        if not (self.duration > 1.0 and self.fps > 0.0 and self.node_noise >= 0.0):
            msg = (
                f'benchmark needs duration > 1 s, fps > 0 and node_noise >= 0, got '
                f'{self.duration}, {self.fps}, {self.node_noise}'
            )
            raise ConfigError(msg)


@dataclass(frozen=True)
class RecognitionReport:
    """Every figure of issue 7 on one scenario.

    Attributes:
        identity: the Gaussian identity rule (enrolled test windows and strangers).
        identity_svm: the SVM alternative on the same windows.
        expression: per-frame accuracy on held-out subjects.
        expression_candidates: clear-frame accuracy of each candidate classifier.
        events_from_label_start: events scored with the truth onset at the label's first frame.
        events_from_half_rise: events scored with the truth onset at half the peak intensity.
        separation: the §4.5 table.
    """

    identity: IdentityAccuracy
    identity_svm: IdentityAccuracy
    expression: ExpressionAccuracy
    expression_candidates: dict[str, float]
    events_from_label_start: EventScore
    events_from_half_rise: EventScore
    separation: SeparationTable

    def format(self) -> str:
        """The report as text."""
        rows = [
            ('identity (Mahalanobis + chi-square)', self.identity),
            ('identity (RBF SVM, probability cut)', self.identity_svm),
        ]
        lines = [
            f'{name}: {100 * a.closed_set:.1f} % closed set, {100 * a.open_set:.1f} % with '
            f'rejection, strangers rejected {100 * a.rejection:.1f} % ({a.windows} windows)'
            for name, a in rows
        ]
        lines.append(
            f'expressions (held-out subjects): {100 * self.expression.clear:.1f} % clear frames, '
            f'{100 * self.expression.all_frames:.1f} % all frames, '
            f'{100 * self.expression.balanced:.1f} % balanced'
        )
        lines.append(
            'classifier candidates: '
            + ', '.join(f'{k} {100 * v:.1f} %' for k, v in self.expression_candidates.items())
        )
        for name, score in (
            ('label start', self.events_from_label_start),
            ('half rise', self.events_from_half_rise),
        ):
            latency = score.latencies if len(score.latencies) else np.array([np.nan])
            lines.append(
                f'events (onset at {name}): F1 {score.f1:.3f} (P {score.precision:.3f}, '
                f'R {score.recall:.3f}), onset latency mean {1000 * np.mean(latency):.0f} ms, '
                f'90th percentile {1000 * np.percentile(latency, 90):.0f} ms'
            )
        return '\n'.join([*lines, self.separation.format()])


def tracking_noise(
    rng: np.random.Generator, frames: int, dim: int, std: float, fps: float
) -> np.ndarray:
    """(frames, dim) noise: half white, half AR(1) with a 0.3 s time constant; total std ``std``.

    The AR(1) part x_m = phi x_{m-1} + e_m (phi = exp(-1 / (0.3 s * fps))) is run by
    :func:`scipy.signal.lfilter` from its stationary distribution.
    """
    half = std / np.sqrt(2.0)
    phi = float(np.exp(-1.0 / (NOISE_TIME_CONSTANT * fps)))
    drive = rng.normal(scale=half * np.sqrt(1.0 - phi**2), size=(frames, dim))
    drive[0] = rng.normal(scale=half, size=dim)
    slow = lfilter([1.0], [1.0, -phi], drive, axis=0)
    return rng.normal(scale=half, size=(frames, dim)) + slow


def synthetic_sequences(
    population: FacePopulation,
    model: FaceModel,
    subject_indices: range,
    count: int,
    training: bool,
    config: BenchmarkConfig,
    rng: np.random.Generator,
) -> list[ParameterSequence]:
    """Noisy sigma and alpha of ``count`` sequences of each subject, with truth labels.

    Args:
        population: the synthetic people.
        model: the face model whose parameters are reported (its nodes are taken by name).
        subject_indices: which people of the population.
        count: sequences per person.
        training: training scripts (neutral first, each expression in turn) or random test ones.
        config: duration, frame rate and noise.
        rng: source of the scripts and noise.
    """
    times = np.arange(int(round(config.duration * config.fps))) / config.fps
    names = population.node_names
    rows = np.array([[3 * names.index(n) + k for k in range(3)] for n in model.node_names])
    sequences = []
    for index in subject_indices:
        subject = population.subject(index)
        for k in range(count):
            script = (
                ExpressionScript.training(config.duration, first=k)
                if training
                else ExpressionScript.random(config.duration, rng)
            )
            states = [script.state(float(t)) for t in times]
            weights = np.array([state.alpha for state in states])
            flat = subject.neutral_nodes.ravel() + weights @ population.expression_basis_true.T
            noisy = flat[:, rows.ravel()] + tracking_noise(
                rng, len(times), rows.size, config.node_noise, config.fps
            )
            fit = fit_model_to_nodes(model, noisy.reshape(len(times), -1, 3))
            sequences.append(
                ParameterSequence(
                    subject_id=subject.subject_id,
                    times=times,
                    sigma=fit.sigma,
                    alpha=fit.alpha,
                    labels=np.array([state.label for state in states]),
                    intensity=np.array([state.intensity for state in states]),
                )
            )
    return sequences


def identity_with_track_error(
    track_std: np.ndarray,
    config: IdentityConfig,
    preset: str = 'default',
    subjects: int = 11,
    strangers: int = 25,
    trials: int = 20,
    seed: int = 0,
) -> IdentityAccuracy:
    """Identity when every track carries its own constant sigma error (a tracker fixing sigma).

    The §3.5 tracker estimates sigma once per track and holds it, so an enrolled mean and a later
    probe of the same person differ by two independent per-track errors, which per-frame
    averaging cannot remove. Here, in the population's true identity basis, every enrolment and
    every probe is a person's sigma_true plus one draw of N(0, diag(track_std**2)); each trial
    enrols ``subjects`` random people from one track each and probes them and ``strangers``
    others once.

    Args:
        track_std: (K,) per-track error standard deviation of each true identity mode, m.
        config: the identity rule under test.
        preset: population preset.
        subjects: enrolled people per trial.
        strangers: people never enrolled per trial.
        trials: number of random galleries.
        seed: seed of the draws.
    """
    population = FacePopulation(preset, seed)
    rng = np.random.default_rng(seed)
    right, rejected = [], []
    for _ in range(trials):
        people = rng.choice(10 * (subjects + strangers), subjects + strangers, replace=False)
        sigma = np.array([population.subject(int(i)).sigma_true for i in people])
        enrolled = sigma[:subjects] + rng.normal(size=(subjects, len(track_std))) * track_std
        probes = sigma + rng.normal(size=sigma.shape) * track_std
        gallery = IdentityGallery.empty(len(track_std))
        for k in range(subjects):
            gallery = gallery.enroll(str(k), enrolled[k][None], config)
        decisions = [gallery.classify(probe, config).identity for probe in probes]
        right += [decision == str(k) for k, decision in enumerate(decisions[:subjects])]
        rejected += [decision == UNKNOWN for decision in decisions[subjects:]]
    return IdentityAccuracy(
        closed_set=float('nan'),  # not scored: only decisions with rejection matter here
        open_set=float(np.mean(right)),
        rejection=float(np.mean(rejected)),
        windows=len(right),
    )


def run_benchmark(model: FaceModel, config: BenchmarkConfig) -> RecognitionReport:
    """Measure identity, expression, event and separation figures on the scenario.

    The recognisers run with their default tunables (:class:`IdentityConfig`,
    :class:`ExpressionTrainingConfig`, :class:`EventConfig`).

    Args:
        model: the face model under test (19 or 34 nodes; its nodes are taken by name).
        config: the scenario.
    """
    identity_config = IdentityConfig()
    expression_config = ExpressionTrainingConfig()
    event_config = EventConfig()
    population = FacePopulation(config.preset, config.seed)
    rng = np.random.default_rng(config.seed)
    enrolled = range(config.subjects)
    others = range(config.subjects, config.subjects + config.strangers)
    train = synthetic_sequences(
        population, model, enrolled, config.training_sequences, True, config, rng
    )
    test = synthetic_sequences(population, model, enrolled, 1, False, config, rng)
    strangers = synthetic_sequences(population, model, others, 1, False, config, rng)
    identities = compare_identity_classifiers(train, test, strangers, identity_config)
    classifier = train_expression_classifier(train, expression_config)
    events = [detect_events(classifier, s, event_config) for s in strangers]
    return RecognitionReport(
        identity=identities['mahalanobis'],
        identity_svm=identities['svm'],
        expression=expression_accuracy(classifier, strangers, expression_config.min_intensity),
        expression_candidates=compare_expression_classifiers(train, strangers, expression_config),
        events_from_label_start=merge_scores(
            [score_events(e, truth_segments(s)) for e, s in zip(events, strangers, strict=True)]
        ),
        events_from_half_rise=merge_scores(
            [
                score_events(e, truth_segments(s, onset_level=0.5))
                for e, s in zip(events, strangers, strict=True)
            ]
        ),
        separation=separation_experiment(train, test, identity_config, expression_config),
    )
