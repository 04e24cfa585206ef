"""The §3.4 learner (and its §4.3 eigenvalue-weighted option) against the synthetic population."""

from __future__ import annotations

from learning_population import training_set
import numpy as np
import pytest

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.learning.alignment import align_training_set
from face_tracking_ros.learning.evaluation import (
    TrueSubspaces,
    compare_with_truth,
    population_truth,
)
from face_tracking_ros.learning.seed import (
    SeedConfig,
    check_dimensions,
    check_iterations,
    choose_dimension,
    learn_seed,
)
from face_tracking_ros.learning.subspace import subspace_similarity
from face_tracking_ros.learning.training_set import TrainingSet


@pytest.fixture(scope='module')
def default_world() -> tuple[TrainingSet, TrueSubspaces]:
    """Noise-free 'default' world: 4 identity modes orthogonal to the 6 expressions."""
    training, population, alpha = training_set(
        'default', 34, subjects=8, sequences=1, frames=150, noise=0.0
    )
    return align_training_set(training), population_truth(population, 34, range(8), alpha, 300)


def test_recovers_well_separated_subspaces_when_p_and_q_match_the_world(default_world):
    training, truth = default_world
    result = learn_seed(training, SeedConfig(p=4, q=6))
    comparison = compare_with_truth(result.model, truth)
    assert comparison.shape_similarity > 0.995
    # Not 1: expressions tilt the Procrustes alignment slightly differently on each face.
    assert comparison.action_share > 0.95
    assert result.converged and result.iterations <= 20
    assert result.history[-1] < 1e-6
    assert result.model.method == 'seed'


def test_p_chosen_by_explained_variance(default_world):
    training, _ = default_world
    result = learn_seed(training, SeedConfig(p=None, explained_variance=0.999))
    assert result.model.p == 4
    assert choose_dimension(np.array([0.5, 0.3, 0.15, 0.05]), 0.8) == 2
    assert choose_dimension(np.array([0.5, 0.3, 0.15, 0.05]), 0.81) == 3
    assert choose_dimension(np.array([0.5, 0.3]), 0.99) == 2


def test_model_prior_and_parameters_are_consistent(default_world):
    training, _ = default_world
    result = learn_seed(training)
    model = result.model
    assert (model.p, model.q) == (2, 5)
    sigma = (result.subject_neutral - model.mean_shape) @ model.shape_basis
    assert np.allclose(result.subject_sigma, sigma)
    assert np.allclose(model.sigma_prior_covariance, sigma.T @ sigma / len(sigma))
    assert np.allclose(model.shape_eigenvalues, np.diag(model.sigma_prior_covariance))
    assert np.allclose(model.mean_shape, result.subject_neutral.mean(axis=0))
    expected_alpha = (
        training.flat() - model.mean_shape - sigma[training.subject_index] @ model.shape_basis.T
    ) @ model.action_basis
    assert np.allclose(result.frame_alpha, expected_alpha)
    # alpha's prior is its second moment about zero over the training frames (result.py).
    np.testing.assert_allclose(
        model.alpha_prior_covariance,
        result.frame_alpha.T @ result.frame_alpha / len(training.meshes),
        rtol=1e-9,
        atol=1e-15,
    )
    assert np.allclose(model.action_eigenvalues, np.diag(model.alpha_prior_covariance))
    assert result.frame_sigma.shape == (len(training.meshes), 2)
    assert model.metadata['subjects'] == list(training.subject_ids)
    assert model.metadata['iterations'] == result.iterations


def residual_moment(training: TrainingSet, model) -> np.ndarray:
    """(3N, 3N) second moment of the frames' deviations from the mean shape, off S (step 4)."""
    off_shape = np.eye(3 * training.num_nodes) - model.shape_basis @ model.shape_basis.T
    residual = (training.flat() - model.mean_shape) @ off_shape
    return residual.T @ residual / len(residual)


def test_action_basis_is_the_leading_eigenvectors_of_the_residual_moment(default_world):
    training, _ = default_world
    model = learn_seed(training).model  # q = 5 of the world's 6 expressions

    variances, vectors = np.linalg.eigh(residual_moment(training, model))

    assert subspace_similarity(model.action_basis, vectors[:, -model.q :]) == pytest.approx(
        1.0, abs=1e-10
    )
    assert variances[-model.q - 1] < 0.5 * variances[-model.q]  # a well-defined subspace


def test_eigenvalue_weighted_alpha_is_the_map_coding_of_section_4_3(default_world):
    training, _ = default_world
    model = learn_seed(training, SeedConfig(eigenvalue_weighted=True)).model
    moment = residual_moment(training, model)
    action_variances = np.linalg.eigvalsh(moment)[::-1][: model.q]
    # Probabilistic PCA's noise: the residual variance A leaves, per remaining dimension.
    noise = (np.trace(moment) - action_variances.sum()) / (len(moment) - model.q)
    coding = np.hstack([model.shape_basis, model.action_basis])
    priors = np.concatenate([model.shape_eigenvalues, action_variances])
    deviations = training.flat() - model.mean_shape

    coefficients = np.linalg.solve(
        coding.T @ coding + np.diag(noise / priors), coding.T @ deviations.T
    ).T

    alpha = coefficients[:, model.p :]
    assert noise > 1e-4 * action_variances[-1]  # q = 5 < 6 expressions: the priors act
    np.testing.assert_allclose(
        model.alpha_prior_covariance, alpha.T @ alpha / len(alpha), rtol=1e-7, atol=1e-15
    )


def test_smallest_allowed_dimensions_and_iterations_are_accepted(default_world):
    training, _ = default_world
    check_dimensions(training, 1, 1)
    check_dimensions(training, None, 3 * training.num_nodes - 1)
    check_iterations(1)


def test_eigenvalue_weighted_option_converges_to_a_close_model(default_world):
    training, _ = default_world
    plain = learn_seed(training, SeedConfig(p=4, q=6))
    weighted = learn_seed(training, SeedConfig(p=4, q=6, eigenvalue_weighted=True))
    assert weighted.model.method == 'seed-weighted'
    assert weighted.converged and weighted.iterations <= 20
    # On a world with orthogonal subspaces and no noise the weighting changes almost nothing.
    assert subspace_similarity(weighted.model.action_basis, plain.model.action_basis) > 0.999


@pytest.mark.parametrize(
    ('config', 'match'),
    [
        (SeedConfig(p=8), r'8 subjects cannot give an identity subspace of p = 8'),
        (SeedConfig(p=0), r'p must be at least 1'),
        (SeedConfig(q=0), r'q must be between 1 and 101, got 0'),
        (SeedConfig(q=102), r'q must be between 1 and 101, got 102'),
        (SeedConfig(max_iterations=0), r'max_iterations must be at least 1, got 0'),
    ],
)
def test_bad_dimensions(default_world, config, match):
    training, _ = default_world
    with pytest.raises(ConfigError, match=match):
        learn_seed(training, config)


def test_q_beyond_the_training_meshes_is_refused_naming_q_and_their_count():
    """30 meshes (3 subjects x 10 frames) give at most 30 expression modes, whatever 3N is."""
    training, _, _ = training_set('default', 34, subjects=3, sequences=1, frames=10, noise=0.0)
    with pytest.raises(ConfigError) as refused:
        learn_seed(training, SeedConfig(p=2, q=31))
    assert str(refused.value) == (
        'q = 31 expression modes cannot come from 30 training meshes: at most 30'
    )
    assert learn_seed(training, SeedConfig(p=2, q=30)).model.action_basis.shape == (102, 30)
