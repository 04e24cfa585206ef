"""The synthetic benchmark of issue 7 on a small scenario of the real synthetic population."""

from __future__ import annotations

import numpy as np
import pytest
from recognition_streams import truth_model

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.recognition.benchmark import (
    BenchmarkConfig,
    identity_with_track_error,
    run_benchmark,
    synthetic_sequences,
    tracking_noise,
)
from face_tracking_ros.recognition.identity import IdentityConfig
from face_tracking_ros.synthetic.faces import FacePopulation


def test_small_scenario_reaches_the_targets_with_the_true_model() -> None:
    model = truth_model(FacePopulation('default', 0), 19)
    config = BenchmarkConfig(subjects=3, strangers=2, duration=13.0)

    report = run_benchmark(model, config)

    assert report.identity.windows == 3 * 13
    assert report.identity.open_set >= 0.95
    assert report.identity.rejection >= 0.9
    assert report.expression.clear >= 0.92
    assert report.events_from_half_rise.f1 >= 0.9
    assert np.mean(report.events_from_half_rise.latencies) <= 0.15
    separation = report.separation
    assert separation.row('identity', 'sigma').accuracy >= 0.95
    assert separation.row('identity', 'alpha').accuracy <= 0.5
    assert separation.row('expression', 'alpha').accuracy >= 0.9
    assert separation.row('expression', 'sigma').balanced <= 0.3
    assert 'strangers rejected' in report.format()


def test_noise_free_sequences_carry_the_true_expressions() -> None:
    population = FacePopulation('default', 0)
    model = truth_model(population, 34)
    config = BenchmarkConfig(duration=4.0, node_noise=0.0)

    (sequence,) = synthetic_sequences(
        population, model, range(1), 1, True, config, np.random.default_rng(0)
    )

    # The model's A spans the true expressions: alpha maps back to the true displacement.
    smile = population.expression_basis_true[:, 0]
    frames = sequence.labels == 'smile'
    displacement = sequence.alpha[frames] @ model.action_basis.T
    np.testing.assert_allclose(
        displacement, np.outer(sequence.intensity[frames], smile), atol=1e-9
    )
    np.testing.assert_allclose(
        sequence.sigma, np.broadcast_to(sequence.sigma[0], sequence.sigma.shape), atol=1e-9
    )


def test_tracking_noise_has_the_requested_spread_and_memory() -> None:
    noise = tracking_noise(np.random.default_rng(1), 30_000, 2, 0.002, 30.0)

    assert noise.std() == pytest.approx(0.002, rel=0.03)
    lag_one = np.mean(noise[1:] * noise[:-1]) / noise.var()
    assert lag_one == pytest.approx(0.5 * np.exp(-1.0 / 9.0), abs=0.02)
    # The slow part starts from its stationary distribution: the first frame has the full spread.
    first = tracking_noise(np.random.default_rng(2), 2, 20_000, 0.002, 30.0)[0]
    assert first.std() == pytest.approx(0.002, rel=0.03)


def test_config_errors() -> None:
    with pytest.raises(ConfigError, match='subjects must be >= 2'):
        BenchmarkConfig(subjects=1)
    with pytest.raises(ConfigError, match='node_noise'):
        BenchmarkConfig(node_noise=-1.0)
    with pytest.raises(ConfigError, match='duration > 1 s'):
        BenchmarkConfig(duration=0.5)
    with pytest.raises(ConfigError, match='strangers must be >= 1, got 0'):
        BenchmarkConfig(strangers=0)
    with pytest.raises(ConfigError, match='training_sequences must be >= 1, got 0'):
        BenchmarkConfig(training_sequences=0)
    # The smallest scenario the ranges allow is accepted.
    smallest = dict(subjects=2, strangers=1, training_sequences=1, fps=0.5, node_noise=0.0)
    assert BenchmarkConfig(**smallest).fps == 0.5


def test_identity_with_track_error_trades_acceptance_for_rejection() -> None:
    track_std = np.array([0.6, 2.1, 2.3, 1.0]) * 1e-3

    tight = identity_with_track_error(track_std, IdentityConfig(min_std=0.001), trials=4)
    default = identity_with_track_error(track_std, IdentityConfig(), trials=4)

    assert default.open_set >= 0.95
    assert default.rejection >= 0.85
    assert tight.open_set < default.open_set
    assert tight.rejection >= default.rejection
