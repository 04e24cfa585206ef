"""Tests of the synthetic population's own face model (true_model.py), against its truth."""

from __future__ import annotations

import numpy as np
import pytest

from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.synthetic.true_model import true_face_model


def test_the_default_true_model_holds_the_top_4_identity_axes_and_their_variances():
    population = FacePopulation('default', seed=3)
    model = true_face_model(population)
    truth = population.truth(34)
    axes, variances = truth.identity_principal_axes()
    assert model.node_names == truth.node_names and model.method == 'truth'
    np.testing.assert_array_equal(model.mean_shape, population.mean_shape)
    assert model.shape_basis.shape == (102, 4)
    # the same axes (up to sign) with the true variances as a diagonal prior
    np.testing.assert_allclose(np.abs(axes[:, :4].T @ model.shape_basis), np.eye(4), atol=1e-9)
    np.testing.assert_allclose(model.sigma_prior_covariance, np.diag(variances[:4]), atol=1e-15)
    # default preset: 4.5, 3.0, 1.75, 1.25 mm RMS per node over 34 nodes
    rms_mm = 1000.0 * np.sqrt(np.diag(model.sigma_prior_covariance) / 34)
    np.testing.assert_allclose(rms_mm, [4.5, 3.0, 1.75, 1.25], rtol=1e-9)


@pytest.mark.parametrize(('num_nodes', 'p'), [(34, 2), (19, 4)])
def test_the_true_action_basis_spans_the_expressions_with_a_half_intensity_prior(num_nodes, p):
    population = FacePopulation('realistic', seed=1)
    model = true_face_model(population, num_nodes, p)
    displacements = population.truth(num_nodes).expression_basis  # (3N, 6), full intensity
    assert model.shape_basis.shape == (3 * num_nodes, p)
    assert true_face_model(population).shape_basis.shape == (102, 4)  # 4 of the 13 by default
    assert model.action_basis.shape == (3 * num_nodes, 6)
    np.testing.assert_allclose(model.action_basis.T @ model.action_basis, np.eye(6), atol=1e-12)
    in_span = model.action_basis @ (model.action_basis.T @ displacements)
    np.testing.assert_allclose(in_span, displacements, atol=1e-12)
    # intensities of std 0.5: the prior's trace is 0.25 times the squared displacements
    covariance = model.alpha_prior_covariance
    assert np.trace(covariance) == pytest.approx(0.25 * np.sum(displacements**2), rel=1e-12)
    np.testing.assert_allclose(model.action_eigenvalues, np.diag(covariance))
