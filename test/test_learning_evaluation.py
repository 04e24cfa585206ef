"""Evaluation measures (truth comparison, LOO, identity fit, recognition) and report plots."""

from __future__ import annotations

from dataclasses import replace

from learning_population import training_set
import numpy as np
import pytest
from scipy.linalg import subspace_angles
from scipy.spatial.transform import Rotation

from face_tracking_ros.learning.alignment import align_training_set
from face_tracking_ros.learning.evaluation import (
    compare_with_truth,
    comparison_table,
    evaluate,
    expression_accuracy,
    fit_identity,
    identity_accuracy,
    leave_one_out,
    population_truth,
    rigid_motion_basis,
    sigma_silhouette,
)
from face_tracking_ros.learning.methods import make_learner
from face_tracking_ros.learning.plots import (
    plot_comparison,
    plot_convergence,
    plot_sigma_scatter,
)
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.synthetic.faces import FacePopulation

PNG = b'\x89PNG\r\n\x1a\n'


def _model(mean: np.ndarray, shape_basis: np.ndarray, action_basis: np.ndarray) -> FaceModel:
    p, q = shape_basis.shape[1], action_basis.shape[1]
    return FaceModel(
        node_names=mesh_topology(len(mean) // 3).node_names,
        mean_shape=mean,
        shape_basis=shape_basis,
        action_basis=action_basis,
        shape_eigenvalues=np.ones(p),
        action_eigenvalues=np.ones(q),
        sigma_prior_covariance=np.eye(p),
        alpha_prior_covariance=np.eye(q),
    )


def test_rigid_motion_basis_spans_small_rigid_motions():
    shape = mesh_topology(34).reference_shape
    basis = rigid_motion_basis(shape.ravel())
    assert basis.shape == (102, 6)
    assert np.allclose(basis.T @ basis, np.eye(6), atol=1e-12)
    moved = shape @ Rotation.from_rotvec([1e-4, -2e-4, 3e-4]).as_matrix().T + [1e-3, 0, -2e-3]
    displacement = (moved - shape).ravel()
    residual = displacement - basis @ (basis.T @ displacement)
    # Only the second-order part of the rotation is left (|omega| ~ 4e-4 rad).
    assert np.linalg.norm(residual) < 1e-5 * np.linalg.norm(displacement)


@pytest.fixture(scope='module')
def truth():
    return population_truth(FacePopulation('realistic'), 34, range(6), samples=300)


def test_truth_compared_with_itself_is_perfect(truth):
    expressions, _, _ = np.linalg.svd(truth.expression_basis, full_matrices=False)
    mean = FacePopulation('realistic').mean_shape
    model = _model(mean, truth.identity_axes[:, :2], expressions[:, :5])
    comparison = compare_with_truth(model, truth)
    # Not exactly 1: the truth axes keep a trace of rigid motion that the comparison removes.
    assert comparison.shape_similarity == pytest.approx(1.0, abs=5e-4)
    assert comparison.action_share == pytest.approx(1.0, abs=1e-9)
    # Six training subjects do not share the population's top-2 axes exactly.
    assert 0.5 < comparison.shape_sample_similarity < 1.0


def test_identity_in_the_action_basis_is_detected(truth):
    mean = FacePopulation('realistic').mean_shape
    identity = truth.identity_axes
    expressions, _, _ = np.linalg.svd(truth.expression_basis, full_matrices=False)
    outside = identity[:, 2:7] - expressions @ (expressions.T @ identity[:, 2:7])
    model = _model(mean, identity[:, :2], np.linalg.qr(outside)[0])
    comparison = compare_with_truth(model, truth)
    assert comparison.action_share < 0.05
    assert comparison.action_similarity < 0.05


def test_fit_identity_recovers_sigma_under_rigid_motion():
    rng = np.random.default_rng(3)
    bases, _ = np.linalg.qr(rng.normal(size=(57, 4)))
    model = _model(mesh_topology(19).reference_shape.ravel(), bases[:, :2], bases[:, 2:])
    sigma = np.array([0.012, -0.007])
    moved = model.identity_shape(sigma) @ Rotation.from_rotvec([0.2, -0.1, 0.3]).as_matrix().T
    fitted, rms = fit_identity(model, moved + [0.1, 0.0, 0.6])
    assert np.allclose(fitted, sigma, atol=1e-9)
    assert rms < 1e-9
    off_model = model.identity_shape(sigma) + 0.002 * bases[:, 2].reshape(-1, 3)
    _, rms = fit_identity(model, off_model)
    # The off-model displacement stays, except for its small rigid-motion part.
    assert 0.8 * 0.002 / np.sqrt(19) < rms <= 0.002 / np.sqrt(19)


def test_recognition_measures_on_separable_data():
    rng = np.random.default_rng(4)
    subjects = np.repeat(np.arange(3), 40)
    sequences = np.tile(np.repeat([0, 1], 20), 3)
    sigma = np.eye(3)[subjects][:, :2] * 0.01 + rng.normal(scale=0.0005, size=(120, 2))
    assert sigma_silhouette(sigma, subjects) > 0.8
    assert identity_accuracy(sigma, subjects, sequences) == 1.0
    assert identity_accuracy(sigma, subjects, np.zeros(120, int)) == 1.0
    drifting = sigma + np.tile(np.repeat([0.0, 0.02], 20), 3)[:, None]  # 2nd half moves away
    assert identity_accuracy(drifting, subjects, np.zeros(120, int)) < 0.7
    labels = np.array(['neutral', 'smile', 'frown', 'surprise'])[np.arange(120) % 4]
    alpha = np.eye(4)[np.arange(120) % 4] * 0.01 + rng.normal(scale=0.001, size=(120, 4))
    assert expression_accuracy(alpha, labels, subjects) == 1.0
    shuffled = rng.permutation(labels)
    assert expression_accuracy(alpha, shuffled, subjects) < 0.5
    # Two subjects: leaving out the one that smiles leaves only neutral frames to learn from.
    pair = subjects[:80]
    one_sided = np.where(pair == 0, 'neutral', labels[:80])
    assert np.isnan(expression_accuracy(alpha[:80], one_sided, pair))
    # Two labels are enough to tell apart.
    two = np.isin(labels, ['neutral', 'smile'])
    assert expression_accuracy(alpha[two], labels[two], subjects[two]) == 1.0


@pytest.fixture(scope='module')
def small_world():
    training, population, alpha = training_set('default', 19, subjects=5, sequences=2, frames=200)
    return align_training_set(training), population_truth(
        population, 19, range(5), alpha, samples=300
    )


def test_leave_one_out_figures(small_world):
    training, _ = small_world
    learner = make_learner('joint', 2, 4)
    full = learner(training)
    loo = leave_one_out(training, learner, full)
    assert loo.shape_similarity.shape == (5,)
    assert np.all((loo.shape_similarity > 0.5) & (loo.shape_similarity <= 1.0 + 1e-12))
    assert np.all(loo.action_similarity > 0.95)
    assert np.all((loo.mean_variation_percent > 0.0) & (loo.mean_variation_percent < 10.0))
    # Held-out neutral RMS is the identity fit of that subject's aligned neutral mesh.
    model = learner(training.without_subject(2)).model
    neutral = training.subject_means(training.flat(), training.neutral)[2].reshape(-1, 3)
    assert loo.neutral_rms_mm[2] == pytest.approx(1000.0 * fit_identity(model, neutral)[1])
    # The similarities are the mean squared cosine of the principal angles between the model
    # learned without the subject and the full one (§3.4), and the mean shape moves by a share
    # of the full mean's size (its nodes' distance from their centroid, as a vector).
    for similarity, held_out, every in (
        (loo.shape_similarity, model.shape_basis, full.model.shape_basis),
        (loo.action_similarity, model.action_basis, full.model.action_basis),
    ):
        expected = np.mean(np.cos(subspace_angles(held_out, every)) ** 2)
        assert similarity[2] == pytest.approx(expected, rel=1e-9)
    full_mean = full.model.mean_shape.reshape(-1, 3)
    size = np.linalg.norm(full_mean - full_mean.mean(axis=0))
    moved = np.linalg.norm(model.mean_shape - full.model.mean_shape)
    assert loo.mean_variation_percent[2] == pytest.approx(100.0 * moved / size, rel=1e-9)


def test_calibrated_expression_accuracy_removes_each_subjects_offset(small_world):
    """A per-subject alpha offset misleads the raw expression accuracy, not the calibrated one.

    Each subject's mean alpha over its neutral-labelled frames takes the offset out exactly.
    """
    training, _ = small_world
    learner = make_learner('joint', 2, 4)
    result = learner(training)
    plain = evaluate(training, learner, result)[0]
    offsets = np.random.default_rng(7).normal(scale=0.05, size=(training.num_subjects, 4))
    shifted = replace(result, frame_alpha=result.frame_alpha + offsets[training.subject_index])
    offset = evaluate(training, learner, shifted)[0]
    assert plain.expression_accuracy_calibrated > 0.85  # 7 labels: 1/7 by chance
    assert offset.expression_accuracy < 0.2  # 0.0955: the offsets (5 cm) swamp alpha (1 cm)
    assert offset.expression_accuracy_calibrated == plain.expression_accuracy_calibrated


def test_evaluate_table_and_plots(small_world, tmp_path):
    training, truth = small_world
    evaluations, results = {}, {}
    for method in ('joint', 'seed'):
        learner = make_learner(method, 2, 4)
        evaluation, loo, result = evaluate(training, learner, truth=truth)
        evaluations[method], results[method] = evaluation, result
        assert evaluation.method == method
        assert evaluation.iterations == result.iterations
        assert evaluation.loo_neutral_rms_mm == pytest.approx(
            np.sqrt(np.mean(loo.neutral_rms_mm**2))
        )
        assert evaluation.identity_accuracy == 1.0  # 0.2 by chance (5 subjects)
        assert evaluation.as_dict()['truth']['action_share'] == evaluation.truth.action_share
    assert evaluations['joint'].truth.action_share > evaluations['seed'].truth.action_share
    table = comparison_table(evaluations)
    assert table.splitlines()[0].split() == ['joint', 'seed']
    assert 'share of A in true expr. span' in table
    no_truth = {
        name: e.__class__(**{**e.__dict__, 'truth': None}) for name, e in evaluations.items()
    }
    assert 'true' not in comparison_table(no_truth)
    paths = [
        plot_sigma_scatter(
            results['joint'].frame_sigma,
            training.subject_index,
            training.subject_ids,
            tmp_path / 'sigma.png',
        ),
        plot_comparison(evaluations, tmp_path / 'comparison.png'),
        plot_convergence(results, tmp_path / 'convergence.png'),
    ]
    for path in paths:
        assert path.read_bytes()[:8] == PNG
