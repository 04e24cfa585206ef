"""Least-squares fit of the face model (eq. 1-3) to measured 3-D nodes.

Given nodes Y_i in the camera frame (from the stereo tracker), find the pose (omega, t) and the
parameters (sigma, alpha) minimising the MAP cost

    sum_i w_i ||R(omega) (mean_shape_i + S_i sigma + A_i alpha) + t - Y_i||^2 / s^2
        + sigma^T C_sigma^-1 sigma + alpha^T C_alpha^-1 alpha

with s the node noise and C the Gaussian prior covariances of §4.1 stored in the model. It starts
from the weighted rigid Procrustes pose of the mean shape and is solved by
``scipy.optimize.least_squares`` with the analytic Jacobian of eq. 1 and 3.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cholesky, solve_triangular
from scipy.optimize import least_squares

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.procrustes import rigid_align
from face_tracking_ros.geometry.rotation import matrix_to_omega, rodrigues, rotate_with_jacobian
from face_tracking_ros.model.face_model import FaceModel


@dataclass(frozen=True)
class MeshFit:
    """The model parameters best explaining a set of 3-D nodes.

    Attributes:
        omega: (3,) rotation vector of the face frame in the camera frame (eq. 1), rad.
        t: (3,) translation of the face frame in the camera frame (eq. 1), m.
        sigma: (p,) shape parameters of eq. 3, m.
        alpha: (q,) action parameters of eq. 3, m.
        nodes_cam: (N, 3) the fitted model nodes in the camera frame, m.
        node_errors: (N,) distance of each fitted node from the measured one, m.
        rms: weighted RMS of node_errors, m.
    """

    omega: np.ndarray
    t: np.ndarray
    sigma: np.ndarray
    alpha: np.ndarray
    nodes_cam: np.ndarray
    node_errors: np.ndarray
    rms: float


def fit_model_to_nodes(
    model: FaceModel,
    nodes_cam: np.ndarray,
    weights: np.ndarray | None = None,
    noise: float = 0.001,
) -> MeshFit:
    """MAP fit of pose, sigma and alpha to measured nodes (eq. 1 and 3, §4.1 prior).

    Args:
        model: the face model.
        nodes_cam: (N, 3) measured nodes in the camera frame, m.
        weights: (N,) node weights (default: the §3.3 Procrustes weights of the topology,
            rigid parts 0.9, lips and brows 0.1, edge 0.5).
        noise: node noise s, m: the balance between the data and the prior.

    Returns:
        The fit.

    Raises:
        InputError: if nodes_cam is not a finite (N, 3) array for the model's N, or noise <= 0.
    """
    nodes_cam = np.asarray(nodes_cam, dtype=float)
    if nodes_cam.shape != (model.num_nodes, 3) or not np.all(np.isfinite(nodes_cam)):
        msg = f'nodes_cam must be finite ({model.num_nodes}, 3), got shape {nodes_cam.shape}'
        raise InputError(msg)
    if not noise > 0:
        msg = f'noise must be > 0, got {noise}'
        raise InputError(msg)
    w = model.topology.alignment_weights() if weights is None else np.asarray(weights, float)
    mean = model.mean_shape.reshape(-1, 3)
    start = rigid_align(mean, nodes_cam, w)
    p, q = model.p, model.q
    basis = np.concatenate([model.shape_basis, model.action_basis], axis=1).reshape(
        model.num_nodes, 3, p + q
    )
    # Whitening of the prior: sigma^T C^-1 sigma = ||L^-1 sigma||^2 with C = L L^T.
    whiten = [
        _inverse_cholesky(model.sigma_prior_covariance),
        _inverse_cholesky(model.alpha_prior_covariance),
    ]
    prior = np.zeros((p + q, p + q))
    prior[:p, :p], prior[p:, p:] = whiten
    sqrt_w = np.sqrt(w)[:, None] / noise

    def shape_of(params: np.ndarray) -> np.ndarray:
        return mean + basis @ params[6:]

    def residuals(params: np.ndarray) -> np.ndarray:
        rotated, _ = rotate_with_jacobian(params[:3], shape_of(params))
        data = sqrt_w * (rotated + params[3:6] - nodes_cam)
        return np.concatenate([data.ravel(), prior @ params[6:]])

    def jacobian(params: np.ndarray) -> np.ndarray:
        _, d_omega = rotate_with_jacobian(params[:3], shape_of(params))
        rotation, _ = rodrigues(params[:3])
        data = np.concatenate(
            [
                d_omega,
                np.broadcast_to(np.eye(3), (model.num_nodes, 3, 3)),
                np.einsum('ab,nbk->nak', rotation, basis),
            ],
            axis=2,
        )
        data = sqrt_w[:, :, None] * data
        return np.vstack(
            [data.reshape(3 * model.num_nodes, -1), np.hstack([np.zeros((p + q, 6)), prior])]
        )

    x0 = np.concatenate([matrix_to_omega(start.rotation), start.t, np.zeros(p + q)])
    solution = least_squares(residuals, x0, jac=jacobian, method='lm', xtol=1e-12, ftol=1e-12)
    params = solution.x
    rotated, _ = rotate_with_jacobian(params[:3], shape_of(params))
    fitted = rotated + params[3:6]
    errors = np.linalg.norm(fitted - nodes_cam, axis=1)
    return MeshFit(
        omega=params[:3],
        t=params[3:6],
        sigma=params[6 : 6 + p],
        alpha=params[6 + p :],
        nodes_cam=fitted,
        node_errors=errors,
        rms=float(np.sqrt(np.sum(w * errors**2) / np.sum(w))),
    )


def _inverse_cholesky(covariance: np.ndarray) -> np.ndarray:
    """L^-1 for covariance = L L^T; an empty (0, 0) array for an empty covariance."""
    if covariance.size == 0:
        return np.zeros((0, 0))
    lower = cholesky(covariance, lower=True)
    return solve_triangular(lower, np.eye(covariance.shape[0]), lower=True)
