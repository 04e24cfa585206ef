"""Tests of the 3-D model fit (eq. 1-3) used by the stereo tracker."""

from __future__ import annotations

import numpy as np
import pytest

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.tracking.mesh_fit import fit_model_to_nodes


def _model(p: int = 2, q: int = 3, prior_std: float = 0.02) -> FaceModel:
    """A random orthonormal-basis model on the 34-node reference face."""
    rng = np.random.default_rng(7)
    topology = mesh_topology(34)
    bases, _ = np.linalg.qr(rng.normal(size=(102, p + q)))
    return FaceModel(
        node_names=topology.node_names,
        mean_shape=topology.reference_shape.ravel().copy(),
        shape_basis=bases[:, :p],
        action_basis=bases[:, p:],
        shape_eigenvalues=np.full(p, prior_std**2),
        action_eigenvalues=np.full(q, prior_std**2),
        sigma_prior_covariance=np.eye(p) * prior_std**2,
        alpha_prior_covariance=np.eye(q) * prior_std**2,
    )


def _pose_nodes(model: FaceModel, omega, t, sigma, alpha) -> np.ndarray:
    rotation, _ = rodrigues(np.asarray(omega, float))
    return model.shape(sigma, alpha) @ rotation.T + np.asarray(t, float)


def test_fit_recovers_pose_and_parameters_exactly_without_noise() -> None:
    model = _model()
    omega, t = np.array([0.1, -0.2, 0.05]), np.array([0.02, -0.01, 0.65])
    sigma, alpha = np.array([0.012, -0.006]), np.array([0.004, 0.0, -0.008])
    fit = fit_model_to_nodes(model, _pose_nodes(model, omega, t, sigma, alpha), noise=1e-5)
    assert np.allclose(fit.omega, omega, atol=1e-5)
    assert np.allclose(fit.t, t, atol=1e-6)
    assert np.allclose(fit.sigma, sigma, atol=1e-5)
    assert np.allclose(fit.alpha, alpha, atol=1e-5)
    assert fit.rms < 1e-6 and fit.node_errors.shape == (34,)


def test_fit_with_noise_is_within_the_noise_and_prior_shrinks() -> None:
    model = _model()
    rng = np.random.default_rng(3)
    truth = _pose_nodes(model, [0.0, 0.3, 0.0], [0.0, 0.0, 0.7], [0.01, 0.01], [0.01, 0, 0])
    measured = truth + rng.normal(0, 0.0005, truth.shape)
    fit = fit_model_to_nodes(model, measured, noise=0.0005)
    assert np.sqrt(np.mean(np.sum((fit.nodes_cam - truth) ** 2, axis=1))) < 0.0005
    # 3-D residual of isotropic 0.5 mm noise: about sqrt(3) * 0.5 mm less the fitted dofs.
    assert 0.0007 < fit.rms < 0.001
    # A tight prior (tiny covariance relative to the noise) pulls sigma and alpha to zero.
    tight = fit_model_to_nodes(_model(prior_std=1e-5), measured, noise=0.0005)
    assert np.abs(tight.sigma).max() < 1e-4 and np.abs(tight.alpha).max() < 1e-4


def test_fit_rejects_bad_input() -> None:
    model = _model()
    with pytest.raises(InputError, match=r'finite \(34, 3\)'):
        fit_model_to_nodes(model, np.zeros((19, 3)))
    with pytest.raises(InputError, match='noise must be > 0'):
        fit_model_to_nodes(model, model.shape(), noise=0.0)
