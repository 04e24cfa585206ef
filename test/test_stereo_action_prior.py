"""The stereo tracker's face-model term (tracking.action_prior) against its definition."""

from __future__ import annotations

import numpy as np
import pytest
from recognition_streams import truth_model

from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.tracking.action_prior import ALPHA_DAMPING, ActionPrior

MODEL = truth_model(FacePopulation('default', 0))
RNG = np.random.default_rng(40)
SIGMA = RNG.normal(size=MODEL.p) * 0.03


def _mesh(alpha: np.ndarray, omega: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, 3) camera-frame nodes of eq. 1 and 3."""
    shape = MODEL.mean_shape + MODEL.shape_basis @ SIGMA + MODEL.action_basis @ alpha
    return shape.reshape(-1, 3) @ rodrigues(omega)[0].T + t


FIRST = _mesh(np.zeros(MODEL.q), np.array([0.05, -0.1, 0.02]), np.array([0.0, 0.01, 0.6]))
WEIGHTS = np.full(MODEL.num_nodes, 1e8)


def test_no_motion_costs_exactly_nothing() -> None:
    prior, theta = ActionPrior.build(MODEL, FIRST, WEIGHTS)
    evaluation = prior.evaluate(FIRST, prior.point(theta))
    hessian, gradient = prior.normal_equations(evaluation)
    assert evaluation.cost == 0.0 and not np.any(gradient)
    assert np.array_equal(evaluation.point.theta, theta)
    assert np.allclose(hessian, hessian.T) and np.linalg.eigvalsh(hessian).min() > -1e-3


def test_model_motion_is_free_and_other_motion_costs_lambda() -> None:
    prior, theta = ActionPrior.build(MODEL, FIRST, WEIGHTS)
    # A head turn and an expression: the model explains them, the cost stays ~0.
    alpha = RNG.normal(size=MODEL.q) * 0.01
    moved = _mesh(alpha, np.array([0.1, 0.05, 0.0]), np.array([0.01, 0.0, 0.62]))
    point = prior.point(theta)
    for _ in range(5):  # each fit is a warm-started Gauss-Newton step, as frame to frame
        point = prior.fit(moved, point)
    evaluation = prior.evaluate(moved, point)
    assert evaluation.cost < 1e-6 * WEIGHTS[0] * 1e-6
    np.testing.assert_allclose(evaluation.point.theta[6:], alpha, atol=1e-4)
    # One node pushed off the face by 1 mm: most of it is off the model, so it costs about
    # lambda (1 mm)^2, and the gradient (d cost / dX = 2 g) matches finite differences.
    pushed = moved.copy()
    pushed[5] += [0.0, 0.0, 0.001]
    evaluation = prior.evaluate(pushed, evaluation.point)
    hessian, gradient = prior.normal_equations(evaluation)
    refit = evaluation.point
    assert 0.5 * WEIGHTS[0] * 1e-6 < evaluation.cost < WEIGHTS[0] * 1e-6
    step = 1e-6
    for k in (15, 16, 17, 40):
        plus, minus = pushed.ravel().copy(), pushed.ravel().copy()
        plus[k] += step
        minus[k] -= step
        numeric = (
            prior.evaluate(plus.reshape(-1, 3), refit).cost
            - prior.evaluate(minus.reshape(-1, 3), refit).cost
        ) / (2 * step)
        assert abs(2 * gradient[k] - numeric) < 0.02 * abs(2 * gradient[15]) + 1e-3
    # Gauss-Newton on the term alone puts the node back on the model in one step.
    back = pushed.ravel() - np.linalg.lstsq(hessian, gradient, rcond=None)[0]
    assert prior.evaluate(back.reshape(-1, 3), refit).cost < 1e-3 * evaluation.cost


def test_moved_term_follows_the_refined_first_nodes() -> None:
    prior, theta = ActionPrior.build(MODEL, FIRST, WEIGHTS)
    shift = np.zeros_like(FIRST)
    shift[25:, 2] = RNG.normal(scale=0.005, size=FIRST.shape[0] - 25)  # face-edge depths
    moved = prior.moved(shift)
    # The moved frame-1 mesh costs (almost exactly) nothing in the moved term, a lot in the
    # original one, since a depth change of single nodes is off the model.
    evaluation = moved.evaluate(FIRST + shift, moved.point(theta))
    _, gradient = moved.normal_equations(evaluation)
    assert evaluation.cost < 1e-12 and np.abs(gradient).max() < 1e-3
    original = prior.evaluate(FIRST + shift, prior.point(theta))
    assert original.cost > 0.1 * WEIGHTS[0] * np.sum(shift**2)
    # A head turn and an expression of the moved mesh stay free.
    alpha = RNG.normal(size=MODEL.q) * 0.01
    first_rotation = rodrigues(np.array([0.05, -0.1, 0.02]))[0]
    omega = np.array([0.1, 0.05, 0.0])
    turned = _mesh(alpha, omega, np.array([0.01, 0.0, 0.62]))
    turned = turned + (shift @ first_rotation) @ rodrigues(omega)[0].T  # the shift, face frame
    point = moved.point(theta)
    for _ in range(5):
        point = moved.fit(turned, point)
    assert moved.evaluate(turned, point).cost < 1e-6 * WEIGHTS[0] * 1e-6


def test_compiled_terms_equal_the_numpy_expressions() -> None:
    prior, theta = ActionPrior.build(MODEL, FIRST, WEIGHTS)
    moved = _mesh(RNG.normal(size=MODEL.q) * 0.01, np.array([0.08, 0.02, 0.01]), np.zeros(3))
    theta = theta + RNG.normal(size=theta.size) * 1e-3
    point = prior.point(theta)
    omega, t, alpha = theta[:3], theta[3:6], theta[6:]
    rotation, d_rotation = rodrigues(omega)
    shape = prior.base + prior.action_basis @ alpha
    np.testing.assert_allclose(point.shape, shape, rtol=0, atol=1e-15)
    np.testing.assert_allclose(point.nodes, shape @ rotation.T + t, rtol=0, atol=1e-15)
    # dM / d(omega, t, alpha) and the weighted normal matrices of eq. 1 and 3.
    jacobian = np.concatenate(
        [
            np.einsum('kab,nb->nak', d_rotation, shape),
            np.broadcast_to(np.eye(3), (len(shape), 3, 3)),
            np.einsum('ab,nbq->naq', rotation, prior.action_basis),
        ],
        axis=2,
    ).reshape(len(prior.row_weights), -1)
    weighted = jacobian * prior.row_weights[:, None]
    normal = jacobian.T @ weighted
    scale = np.abs(normal).max()  # sums cancel: compared to rounding of the largest entry
    np.testing.assert_allclose(point.weighted, weighted, rtol=0, atol=1e-15 * WEIGHTS[0])
    np.testing.assert_allclose(point.normal, normal, rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(
        np.diag(point.damped_normal), np.diag(normal) * (1.0 + ALPHA_DAMPING), rtol=1e-13
    )
    # The refit, the cost and the normal equations at the moved nodes.
    motion = moved - prior.first_nodes
    difference = (motion - (point.nodes - prior.first_model)).ravel()
    step = np.linalg.solve(point.damped_normal, weighted.T @ difference)
    evaluation = prior.evaluate(moved, point)
    np.testing.assert_allclose(evaluation.point.theta, theta + step, rtol=1e-12, atol=1e-15)
    refit = evaluation.point
    difference = (motion - (refit.nodes - prior.first_model)).ravel()
    np.testing.assert_array_equal(evaluation.difference, difference)
    assert evaluation.cost == pytest.approx(difference @ (prior.row_weights * difference), 1e-13)
    hessian, gradient = prior.normal_equations(evaluation)
    expected = np.diag(prior.row_weights) - refit.weighted @ np.linalg.solve(
        refit.normal, refit.weighted.T
    )
    np.testing.assert_allclose(hessian, expected, rtol=0, atol=1e-9 * WEIGHTS[0])
    np.testing.assert_array_equal(gradient, prior.row_weights * difference)
