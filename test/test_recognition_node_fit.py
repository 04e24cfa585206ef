"""Fitting omega, t, sigma, alpha of a model to 3-D nodes (eq. 1, 3)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from recognition_streams import truth_model

from face_tracking_ros.data import default_model_path
from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.recognition.node_fit import NodeFitProblem, fit_model_to_nodes
from face_tracking_ros.synthetic.faces import FacePopulation


def posed(model, sigma, alpha, omega, t) -> np.ndarray:
    """(F, N, 3) camera-frame meshes of eq. 1 and 3."""
    shapes = model.mean_shape + sigma @ model.shape_basis.T + alpha @ model.action_basis.T
    shapes = shapes.reshape(len(sigma), -1, 3)
    return np.array([x @ rodrigues(o)[0].T + d for x, o, d in zip(shapes, omega, t, strict=True)])


@pytest.mark.parametrize('num_nodes', [19, 34])
def test_parameters_of_model_meshes_are_recovered(num_nodes: int) -> None:
    rng = np.random.default_rng(30)
    model = truth_model(FacePopulation('default', 0), num_nodes)
    frames = 40
    sigma = rng.normal(size=(frames, model.p)) * 0.03
    alpha = rng.normal(size=(frames, model.q)) * 0.01
    omega = rng.uniform(-0.5, 0.5, size=(frames, 3))
    t = rng.normal(size=(frames, 3)) * 0.05 + [0.0, 0.0, 0.6]

    fit = fit_model_to_nodes(model, posed(model, sigma, alpha, omega, t))

    np.testing.assert_allclose(fit.sigma, sigma, atol=1e-6)
    np.testing.assert_allclose(fit.alpha, alpha, atol=1e-6)
    np.testing.assert_allclose(fit.omega, omega, atol=1e-6)
    np.testing.assert_allclose(fit.t, t, atol=1e-6)
    assert np.all(fit.rms < 1e-6)


def test_rms_measures_what_the_model_cannot_explain() -> None:
    rng = np.random.default_rng(31)
    model = truth_model(FacePopulation('default', 0))
    nodes = posed(
        model,
        np.zeros((200, model.p)),
        np.zeros((200, model.q)),
        np.zeros((200, 3)),
        np.tile([0.0, 0.0, 0.6], (200, 1)),
    )
    noise = 0.001

    fit = fit_model_to_nodes(model, nodes + rng.normal(scale=noise, size=nodes.shape))

    # 3N - 6 - p - q of the 3N residual degrees of freedom remain: rms^2 ~ noise^2 (3N - D) / N.
    dof = 3 * model.num_nodes - 6 - model.p - model.q
    expected = noise * np.sqrt(dof / model.num_nodes)
    assert np.sqrt(np.mean(fit.rms**2)) == pytest.approx(expected, rel=0.05)


def test_the_procrustes_start_is_exact_on_the_posed_mean_shape() -> None:
    model = truth_model(FacePopulation('default', 0))
    omega, t = np.array([[0.3, -0.2, 0.1]]), np.array([[0.01, -0.02, 0.6]])
    nodes = posed(model, np.zeros((1, model.p)), np.zeros((1, model.q)), omega, t)

    start = fit_model_to_nodes(model, nodes, max_iterations=0)

    assert start.iterations == 0
    np.testing.assert_allclose(start.omega, omega, atol=1e-12)
    np.testing.assert_allclose(start.t, t, atol=1e-12)
    np.testing.assert_allclose(np.hstack([start.sigma, start.alpha]), 0.0, atol=1e-12)
    assert start.rms[0] < 1e-12


def test_input_errors() -> None:
    model = truth_model(FacePopulation('default', 0), 19)
    with pytest.raises(InputError, match=r'\(F >= 1, 19, 3\)'):
        fit_model_to_nodes(model, np.zeros((2, 34, 3)))
    with pytest.raises(InputError, match='NaN'):
        fit_model_to_nodes(model, np.full((1, 19, 3), np.nan))


def test_zero_weight_nodes_are_ignored_by_the_fit() -> None:
    rng = np.random.default_rng(32)
    model = truth_model(FacePopulation('default', 0))
    sigma, alpha = rng.normal(size=(1, model.p)) * 0.03, rng.normal(size=(1, model.q)) * 0.01
    nodes = posed(model, sigma, alpha, np.array([[0.1, -0.2, 0.05]]), np.array([[0, 0, 0.6]]))
    corrupted = nodes.copy()
    corrupted[0, :4] += 0.02
    weights = np.ones(model.num_nodes)
    weights[:4] = 0.0

    fit = fit_model_to_nodes(model, corrupted, weights=weights)

    np.testing.assert_allclose(fit.alpha, alpha, atol=1e-6)
    np.testing.assert_allclose(fit.sigma, sigma, atol=1e-6)
    assert fit.rms[0] > 0.005  # rms counts every node, the corrupted ones too
    with pytest.raises(InputError, match='weights'):
        fit_model_to_nodes(model, nodes, weights=-weights)
    # Checked before the Procrustes start (which refuses some too), so also with a given start.
    for bad in (-weights, np.full(model.num_nodes, np.nan), np.ones(model.num_nodes + 1)):
        with pytest.raises(
            InputError, match=r'weights must be finite and >= 0 with shape \(34,\)'
        ):
            fit_model_to_nodes(model, nodes, weights=bad, start=fit)


def test_a_start_from_the_previous_frames_fit_reaches_the_same_fit() -> None:
    rng = np.random.default_rng(33)
    model = truth_model(FacePopulation('default', 0))
    sigma = np.repeat(rng.normal(size=(1, model.p)) * 0.03, 2, axis=0)  # one person
    alpha = rng.normal(size=(1, model.q)) * 0.01 + [[0.0], [0.001]]
    omega = np.array([[0.1, -0.2, 0.05], [0.11, -0.19, 0.05]])  # two frames 0.8 deg apart
    t = np.array([[0.0, 0.0, 0.6], [0.002, 0.0, 0.6]])
    meshes = posed(model, sigma, alpha, omega, t) + rng.normal(scale=0.001, size=(2, 34, 3))
    previous = fit_model_to_nodes(model, meshes[:1])

    cold = fit_model_to_nodes(model, meshes[1:], tolerance=1e-7)  # the stereo tracker's
    warm = fit_model_to_nodes(model, meshes[1:], tolerance=1e-7, start=previous)

    for name in ('omega', 't', 'sigma', 'alpha', 'rms'):
        np.testing.assert_allclose(getattr(warm, name), getattr(cold, name), atol=1e-8)
    # Both take 4 iterations here, so their counts cannot show the start is used; a start at
    # the solution can: Gauss-Newton's first step from it is below the tolerance (a cold start
    # would take the 4 again).
    assert fit_model_to_nodes(model, meshes[1:], tolerance=1e-7, start=cold).iterations == 1
    with pytest.raises(InputError, match='start fit has 1 frames'):
        fit_model_to_nodes(model, meshes, start=previous)
    fewer = replace(previous, alpha=previous.alpha[:, 1:])
    parameters = model.p + model.q
    with pytest.raises(
        InputError, match=f'1 frames and {parameters - 1} parameters, the fit 1 and {parameters}'
    ):
        fit_model_to_nodes(model, meshes[:1], start=fewer)


def test_the_alpha_prior_gives_the_most_probable_alpha_of_noisy_nodes() -> None:
    # The packaged model's alpha prior (its smallest mode 2.3 mm) against nodes 2 mm off per
    # coordinate, as the stereo tracker's are on rendered free head motion (its fit_node_noise).
    rng = np.random.default_rng(34)
    model = load_model(default_model_path())
    frames, noise = 400, 0.002
    covariance = model.alpha_prior_covariance
    alpha = rng.multivariate_normal(np.zeros(model.q), covariance, size=frames)
    sigma = rng.multivariate_normal(np.zeros(model.p), model.sigma_prior_covariance, frames)
    omega = rng.uniform(-0.4, 0.4, size=(frames, 3))
    t = rng.normal(size=(frames, 3)) * 0.05 + [0.0, 0.0, 0.6]
    nodes = posed(model, sigma, alpha, omega, t)
    nodes += rng.normal(scale=noise, size=nodes.shape)

    plain = fit_model_to_nodes(model, nodes)
    prior = fit_model_to_nodes(model, nodes, alpha_precision=noise**2 * np.linalg.inv(covariance))

    plain_error = np.mean((plain.alpha - alpha) ** 2, axis=0)
    prior_error = np.mean((prior.alpha - alpha) ** 2, axis=0)
    # Per mode of variance l, the least-squares error is about noise^2 and the posterior's
    # l noise^2 / (l + noise^2): the small modes gain most (measured, in noise^2: the smallest
    # mode's 0.92 -> 0.53, 0.58 of it against 0.57 expected; the largest's 0.98 -> 0.94).
    variances = np.diag(covariance)
    smallest, largest = np.argmin(variances), np.argmax(variances)
    posterior = variances / (variances + noise**2)
    gain = prior_error / plain_error
    assert gain[smallest] == pytest.approx(posterior[smallest], rel=0.15)
    assert gain[largest] == pytest.approx(posterior[largest], rel=0.05)
    assert np.sum(prior_error) < np.sum(plain_error)
    with pytest.raises(InputError, match='positive definite'):
        fit_model_to_nodes(model, nodes[:1], alpha_precision=-np.eye(model.q))
    with pytest.raises(InputError, match=r'symmetric \(5, 5\) matrix, got \(4, 4\)'):
        fit_model_to_nodes(model, nodes[:1], alpha_precision=np.eye(4))


def test_a_prepared_problem_fits_as_the_function_does() -> None:
    # A tracker's fits: one prepared problem (weights, prior) warm-started frame after frame.
    rng = np.random.default_rng(39)
    model = load_model(default_model_path())
    frames = 6
    alpha = rng.multivariate_normal(np.zeros(model.q), model.alpha_prior_covariance, frames)
    sigma = np.tile(rng.normal(size=model.p) * 0.03, (frames, 1))
    omega = np.cumsum(rng.normal(scale=0.02, size=(frames, 3)), axis=0)
    t = np.array([0.0, 0.0, 0.6]) + np.cumsum(rng.normal(scale=0.002, size=(frames, 3)), axis=0)
    nodes = posed(model, sigma, alpha, omega, t)
    nodes += rng.normal(scale=0.002, size=nodes.shape)
    weights = rng.uniform(0.2, 1.0, model.num_nodes)
    precision = 0.002**2 * np.linalg.inv(model.alpha_prior_covariance)
    problem = NodeFitProblem.of(model, weights, precision)
    prepared = function = None
    for mesh in nodes:
        prepared = problem.fit(mesh[None], 1e-5, start=prepared)
        function = fit_model_to_nodes(
            model, mesh[None], 1e-5, weights=weights, start=function, alpha_precision=precision
        )
        for name in ('omega', 't', 'sigma', 'alpha', 'rms'):
            np.testing.assert_array_equal(getattr(prepared, name), getattr(function, name))
        assert prepared.iterations == function.iterations
    # The last frame's fit: nodes 2 mm off per coordinate leave 3.1 mm RMS (3.5 less the fitted
    # parameters' share); alpha's errors 0.7e-3 to 3.2e-3 (the prior's deviations 2.3e-3 to 0.015).
    assert 0.0028 < prepared.rms[0] < 0.0034
    np.testing.assert_allclose(prepared.alpha[0], alpha[-1], atol=4e-3)
    with pytest.raises(InputError, match='weights'):
        NodeFitProblem.of(model, -weights)
    with pytest.raises(InputError, match='positive definite'):
        NodeFitProblem.of(model, alpha_precision=-np.eye(model.q))
    with pytest.raises(InputError, match='NaN'):
        problem.fit(np.full((1, model.num_nodes, 3), np.nan))
