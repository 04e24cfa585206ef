"""Projection of 3-D meshes onto a face model: omega, t, sigma and alpha of known nodes (eq. 1, 3).

Training the expression classifier on the alpha a *learned* model would report needs the truth
meshes of labelled sequences expressed in that model: per frame, the pose and parameters that
minimise the node distance

    sum_i || R(omega) (mean_i + S_i sigma + A_i alpha) + t - X_c^i ||^2

(eq. 1 with eq. 3). The fit alternates two exact block minimisations of that same cost: the rigid
pose by Procrustes (:func:`face_tracking_ros.geometry.procrustes.rigid_align`) given the shape,
and sigma and alpha by linear least squares on the nodes brought into the face frame given the
pose. The cost never increases; convergence is linear (the pose and the bases are coupled), so
the loop runs until no frame's RMS node distance changes by more than ``tolerance`` (1 nm: on
exact model meshes the parameters come out to about 1e-8). All frames are fitted at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.procrustes import rigid_align
from face_tracking_ros.geometry.rotation import matrix_to_omega
from face_tracking_ros.model.face_model import FaceModel


@dataclass(frozen=True)
class NodeFit:
    """Pose and parameters of F meshes in a model.

    Attributes:
        omega: (F, 3) rotation vectors of the face frame in the camera frame, rad.
        t: (F, 3) translations of the face frame in the camera frame, m.
        sigma: (F, p) shape parameters.
        alpha: (F, q) action parameters.
        rms: (F,) RMS node distance of the fitted model to the meshes, m.
        iterations: number of alternations made.
    """

    omega: np.ndarray
    t: np.ndarray
    sigma: np.ndarray
    alpha: np.ndarray
    rms: np.ndarray
    iterations: int


def fit_model_to_nodes(
    model: FaceModel, nodes: np.ndarray, tolerance: float = 1e-9, max_iterations: int = 300
) -> NodeFit:
    """Fit omega, t, sigma and alpha of eq. 1 and 3 to meshes in the camera frame.

    Args:
        model: the face model (N nodes).
        nodes: (F, N, 3) meshes in the camera frame, in the model's node order, metres.
        tolerance: stop when no frame's RMS node distance changes by more than this, m.
        max_iterations: largest number of alternations.

    Raises:
        InputError: if nodes is not a finite (F, N, 3) array with F >= 1.
    """
    nodes = np.asarray(nodes, dtype=float)
    if nodes.ndim != 3 or nodes.shape[1:] != (model.num_nodes, 3) or not len(nodes):
        msg = f'nodes must be (F >= 1, {model.num_nodes}, 3), got shape {nodes.shape}'
        raise InputError(msg)
    if not np.all(np.isfinite(nodes)):
        msg = 'nodes to fit hold NaN or Inf'
        raise InputError(msg)
    bases = np.hstack([model.shape_basis, model.action_basis])
    solve = np.linalg.pinv(bases)
    coefficients = np.zeros((len(nodes), bases.shape[1]))
    rms = np.full(len(nodes), np.inf)
    iterations, converged = 0, False
    while not converged and iterations < max_iterations:
        iterations += 1
        shapes = (model.mean_shape + coefficients @ bases.T).reshape(len(nodes), -1, 3)
        pose = rigid_align(shapes, nodes)
        in_face = np.einsum('fba,fnb->fna', pose.rotation, nodes - pose.t[:, None, :])
        coefficients = (in_face.reshape(len(nodes), -1) - model.mean_shape) @ solve.T
        residual = in_face.reshape(len(nodes), -1) - model.mean_shape - coefficients @ bases.T
        previous, rms = rms, np.sqrt(3.0 * np.mean(residual**2, axis=1))
        converged = bool(np.max(np.abs(previous - rms)) < tolerance)
    return NodeFit(
        omega=np.array([matrix_to_omega(rotation) for rotation in pose.rotation]),
        t=pose.t,
        sigma=coefficients[:, : model.p],
        alpha=coefficients[:, model.p :],
        rms=rms,
        iterations=iterations,
    )
