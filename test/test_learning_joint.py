"""The joint within/between-subject learner (issue 11) against the realistic population."""

from __future__ import annotations

from dataclasses import replace

from learning_population import training_set
import numpy as np
import pytest

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.learning.alignment import align_training_set
from face_tracking_ros.learning.evaluation import compare_with_truth, population_truth
from face_tracking_ros.learning.joint import JointConfig, _DeviationMoments, learn_joint
from face_tracking_ros.learning.seed import learn_seed
from face_tracking_ros.learning.training_set import TrainingSet


def test_exact_on_noise_free_face_frame_meshes():
    """Without noise or alignment error the within-subject model is exact."""
    training, population, alpha = training_set(
        'realistic', 19, subjects=5, sequences=1, frames=120, noise=0.0
    )
    truth_meshes = (
        np.array(
            [population.subject(s).neutral_nodes[:19].ravel() for s in training.subject_index]
        )
        + alpha @ population.truth(19).expression_basis.T
    )
    exact = training.with_meshes(truth_meshes.reshape(-1, 19, 3))
    result = learn_joint(exact)
    neutrals = np.array([population.subject(s).neutral_nodes[:19].ravel() for s in range(5)])
    assert np.abs(result.subject_neutral - neutrals).max() < 1e-12
    expressions = population.truth(19).expression_basis
    residual = expressions - result.model.action_basis @ (
        result.model.action_basis.T @ expressions
    )
    # Five of the six expression directions are kept; the weakest one is the residual.
    assert np.linalg.matrix_rank(residual, tol=1e-9) <= 1
    assert result.converged


@pytest.fixture(scope='module')
def realistic_world():
    training, population, alpha = training_set(
        'realistic', 19, subjects=11, sequences=1, frames=160
    )
    truth = population_truth(population, 19, range(11), alpha, samples=300)
    return align_training_set(training), truth, alpha


def test_keeps_identity_out_of_the_expression_subspace(realistic_world):
    training, truth, _ = realistic_world
    joint_model = learn_joint(training).model
    joint = compare_with_truth(joint_model, truth)
    seed = compare_with_truth(learn_seed(training).model, truth)
    assert joint.action_share > 0.99
    assert joint.action_similarity > 0.98
    assert seed.action_share < 0.6  # the §3.4 loop mixes leftover identity into A (issue 11)
    # S is the top-2 principal subspace of the subjects' true neutral faces (aligned likewise),
    # close to the population's: eleven subjects are enough to separate its top-2 axes.
    assert joint.shape_sample_similarity > 0.99
    assert joint.shape_similarity > 0.93


def _mislabel(training: TrainingSet, alpha: np.ndarray, share: float) -> TrainingSet:
    rng = np.random.default_rng(7)
    flip = (alpha.max(axis=1) > 0.5) & (rng.random(len(alpha)) < share)
    return replace(training, neutral=training.neutral | flip)


def test_robust_label_weights_resist_expressive_frames_labelled_neutral(realistic_world):
    training, _, alpha = realistic_world
    reference = training.subject_means(training.flat(), training.neutral)
    mislabelled = _mislabel(training, alpha, 0.3)
    assert mislabelled.neutral.sum() > 1.2 * training.neutral.sum()

    def neutral_error_mm(config: JointConfig) -> float:
        result = learn_joint(mislabelled, config)
        return 1000.0 * float(np.sqrt(np.mean((result.subject_neutral - reference) ** 2)))

    robust = neutral_error_mm(JointConfig())
    trusting = neutral_error_mm(JointConfig(robust_scale=None))
    assert robust < 0.3
    assert trusting > 1.5 * robust


def test_converged_neutrals_solve_the_robust_neutral_half_step(realistic_world):
    """At convergence every neutral solves the module notes' neutral half-step.

    Its part along A is the kappa-weighted mean of A^T X over the subject's neutral-labelled
    frames, kappa = lambda c / (1 + lambda c), with c the Cauchy label weights.
    """
    training, _, _ = realistic_world
    config = JointConfig(tolerance=1e-13, neutral_tolerance=1e-11, max_iterations=1000)
    result = learn_joint(training, config)
    action_basis, weight = result.model.action_basis, config.neutral_weight
    projection = training.flat() @ action_basis
    along = projection - (result.subject_neutral @ action_basis)[training.subject_index]
    neutral = training.neutral
    c = neutral.astype(float)
    for _ in range(200):  # c and alpha = A^T (X - neutral_s) / (1 + lambda c) at their fixed point
        norms = np.linalg.norm(along / (1.0 + weight * c)[:, None], axis=1)
        k = config.robust_scale * np.median(norms[neutral])
        c = np.where(neutral, 1.0 / (1.0 + (norms / k) ** 2), 0.0)
    kappa = weight * c / (1.0 + weight * c)

    assert result.converged
    assert c[neutral].min() < 0.1 < 0.9 < c[neutral].max()  # the weights differ: kappa matters
    for s in range(training.num_subjects):
        rows = training.subject_index == s
        expected = kappa[rows] @ projection[rows] / kappa[rows].sum()
        np.testing.assert_allclose(result.subject_neutral[s] @ action_basis, expected, atol=1e-7)


def test_a_loose_a_tolerance_leaves_the_stop_to_the_rms_move_of_the_neutrals(realistic_world):
    """With the A test met from iteration 2 on, the loop ends at the first neutral RMS move < 1 um.

    The defaults never reach this case (A's 1e-6 ends the loop after the neutrals settle), so
    the neutrals' measure, metres RMS per coordinate, is pinned here against the moves between
    the neutral faces of runs cut after k - 1 and k iterations.
    """
    training, _, _ = realistic_world

    def neutrals_after(iterations: int) -> np.ndarray:
        cut = JointConfig(neutral_tolerance=0.0, max_iterations=iterations)
        return learn_joint(training, cut).subject_neutral

    after = np.array([neutrals_after(k) for k in range(1, 7)])
    moves = np.sqrt(np.mean(np.diff(after, axis=0) ** 2, axis=(1, 2)))
    stop = 2 + int(np.argmax(moves < 1e-6))
    result = learn_joint(training, JointConfig(tolerance=1.0, neutral_tolerance=1e-6))
    assert moves[0] > 5e-6  # measured 6.6 um: not the A test (met since iteration 2) ends it
    assert stop == 4  # moves measured 6.6, 2.2, 0.97 um
    assert (result.iterations, result.converged) == (stop, True)


def test_model_records_method_and_prior(realistic_world):
    training, _, _ = realistic_world
    result = learn_joint(training)
    model = result.model
    assert model.method == 'joint'
    assert model.metadata['neutral_weight'] == JointConfig().neutral_weight
    assert result.iterations <= 20
    assert np.allclose(model.mean_shape, result.subject_neutral.mean(axis=0))
    assert np.allclose(model.sigma_prior_covariance, np.cov(result.subject_sigma.T, bias=True))


@pytest.mark.parametrize(
    ('config', 'match', 'error'),
    [
        (
            JointConfig(neutral_weight=0.0),
            r'neutral_weight must be positive, got 0\.0',
            ConfigError,
        ),
        (JointConfig(p=11), r'at least p \+ 1 = 12 subjects are needed', ConfigError),
        (JointConfig(max_iterations=0), r'max_iterations must be at least 1, got 0', ConfigError),
    ],
)
def test_bad_configuration(realistic_world, config, match, error):
    training, _, _ = realistic_world
    with pytest.raises(error, match=match):
        learn_joint(training, config)


def test_what_differs_between_a_subjects_sequences_stays_out_of_the_expression_subspace():
    """A constant error per sequence (a stereo tracker's depth error at its frame 1) is not A."""
    training, population, alpha = training_set('default', 34, subjects=8, sequences=2, frames=80)
    truth = population_truth(population, 34, range(8), alpha, samples=300)
    rng = np.random.default_rng(7)
    errors = rng.normal(scale=0.001, size=(training.sequence_of_frame.max() + 1, 34, 3))
    tracked = align_training_set(
        training.with_meshes(training.meshes + errors[training.sequence_of_frame])
    )
    clean = compare_with_truth(learn_joint(align_training_set(training)).model, truth)
    per_sequence = compare_with_truth(learn_joint(tracked).model, truth)
    pooled = learn_joint(tracked, JointConfig(neutral_per_sequence=False)).model
    assert per_sequence.action_similarity > clean.action_similarity - 0.005
    assert compare_with_truth(pooled, truth).action_similarity < 0.9  # measured 0.74


def test_the_deviation_moment_from_sufficient_statistics_is_the_direct_sum():
    """A's PCA matrix, kept as statistics taken once, equals the weighted sum over the frames."""
    training, _, _ = training_set('default', 19, subjects=4, sequences=2, frames=30)
    frames = training.flat()
    rng = np.random.default_rng(3)
    sequences = len(training.sequence_subject)
    origins = frames.mean(axis=0) + rng.normal(scale=0.002, size=(sequences, frames.shape[1]))
    weights = np.where(training.neutral, rng.uniform(0.1, 1.0, len(frames)), 1.0)
    moments = _DeviationMoments.of(training, frames, training.sequence_means(frames))
    deviations = frames - origins[training.sequence_of_frame]
    direct = (deviations * weights[:, None]).T @ deviations / weights.sum()
    assert np.allclose(moments.moment(origins, weights), direct, rtol=1e-10, atol=0.0)
