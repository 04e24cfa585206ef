"""Eq. 3 of FaceModel: X = mean_shape + S sigma + A alpha, node-major, against hand-made bases."""

from __future__ import annotations

import numpy as np

from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.topology import mesh_topology

NODES = 19


def _unit(node: int, axis: int) -> np.ndarray:
    """(3N,) basis vector moving one coordinate of one node (node-major flattening)."""
    column = np.zeros(3 * NODES)
    column[3 * node + axis] = 1.0
    return column


def _model() -> FaceModel:
    """Identity modes move node 2's y and node 7's x; expression modes node 5's z and 11's y."""
    shape_basis = np.column_stack([_unit(2, 1), _unit(7, 0)])
    action_basis = np.column_stack([_unit(5, 2), _unit(11, 1)])
    return FaceModel.from_prior_covariances(
        node_names=mesh_topology(NODES).node_names,
        mean_shape=mesh_topology(NODES).reference_shape.ravel(),
        shape_basis=shape_basis,
        action_basis=action_basis,
        sigma_prior_covariance=np.diag([1e-4, 4e-5]),
        alpha_prior_covariance=np.diag([9e-5, 1e-5]),
        method='seed',
    )


def test_eq3_adds_each_mode_to_its_node_and_coordinate():
    model = _model()
    mean = mesh_topology(NODES).reference_shape
    sigma, alpha = np.array([0.01, -0.004]), np.array([0.003, -0.002])
    expected = mean.copy()
    expected[2, 1] += 0.01
    expected[7, 0] -= 0.004
    expected[5, 2] += 0.003
    expected[11, 1] -= 0.002
    np.testing.assert_allclose(model.shape(sigma, alpha), expected, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(model.shape(), mean)
    neutral = model.identity_shape(sigma)
    np.testing.assert_allclose(neutral[[2, 7]], expected[[2, 7]], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(neutral[[5, 11]], mean[[5, 11]])
    expression = model.shape(alpha=alpha)
    np.testing.assert_allclose(expression[[5, 11]], expected[[5, 11]], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(expression[[2, 7]], mean[[2, 7]])
    np.testing.assert_array_equal(model.mean_shape, mean.ravel())  # not changed in place


def test_the_node_shaped_bases_are_the_derivatives_of_each_node():
    model = _model()
    action, shape = model.action_basis_nodes(), model.shape_basis_nodes()
    assert action.shape == (NODES, 3, 2) and shape.shape == (NODES, 3, 2)
    expected_action = np.zeros((NODES, 3, 2))
    expected_action[5, 2, 0] = expected_action[11, 1, 1] = 1.0
    expected_shape = np.zeros((NODES, 3, 2))
    expected_shape[2, 1, 0] = expected_shape[7, 0, 1] = 1.0
    np.testing.assert_array_equal(action, expected_action)
    np.testing.assert_array_equal(shape, expected_shape)


def test_eigenvalues_are_the_prior_covariances_diagonals():
    model = _model()
    np.testing.assert_array_equal(model.shape_eigenvalues, [1e-4, 4e-5])
    np.testing.assert_array_equal(model.action_eigenvalues, [9e-5, 1e-5])
    assert (model.num_nodes, model.p, model.q) == (NODES, 2, 2)
