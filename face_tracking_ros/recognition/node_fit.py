"""Projection of 3-D meshes onto a face model: omega, t, sigma and alpha of known nodes (eq. 1, 3).

Training the expression classifier on the alpha a *learned* model would report needs the truth
meshes of labelled sequences expressed in that model: per frame, the pose and parameters that
minimise the node distance

    sum_i || R(omega) (mean_i + S_i sigma + A_i alpha) + t - X_c^i ||^2

(eq. 1 with eq. 3). Start: the pose of the mean shape by Procrustes
(:func:`face_tracking_ros.geometry.procrustes.rigid_align`), then sigma and alpha by linear least
squares on the nodes brought into the face frame (or a given fit, such as the previous frame's
when the meshes are tracked). Then Gauss-Newton on all of (omega, t, sigma,
alpha) with the analytic Jacobian of eq. 1 and 3 (the ``cv2.Rodrigues`` derivatives of
:func:`face_tracking_ros.geometry.rotation.rodrigues`) and a tiny Levenberg damping for
bases that nearly contain a rigid motion; an iteration forms and solves every frame's small
normal equations in one compiled pass (:mod:`.node_fit_kernels`). It converges quadratically: on
exact model meshes the parameters come out to about 1e-12 in 3 to 5 iterations. (Alternating the
two block minimisations instead converges only linearly, in hundreds of iterations, because pose
and bases are coupled.)

Meshes that are measured, not true, can add the §4.1 Gaussian prior on alpha: with nodes in error
by s per coordinate, the maximum a posteriori fit minimises the node distance plus
``s^2 alpha' Sigma_alpha^-1 alpha`` (the ``alpha_precision`` ``s^2 Sigma_alpha^-1``), appended to
the least squares as the rows ``L' alpha`` (``L L'`` its Cholesky factorisation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.procrustes import rigid_align
from face_tracking_ros.geometry.rotation import matrix_to_omega, rodrigues
from face_tracking_ros.model.face_model import FaceModel

LEVENBERG_DAMPING = 1e-9  # relative to the diagonal of the normal matrix


@dataclass(frozen=True)
class NodeFit:
    """Pose and parameters of F meshes in a model.

    Attributes:
        omega: (F, 3) rotation vectors of the face frame in the camera frame, rad.
        t: (F, 3) translations of the face frame in the camera frame, m.
        sigma: (F, p) shape parameters.
        alpha: (F, q) action parameters.
        rms: (F,) RMS node distance of the fitted model to the meshes, m.
        iterations: number of Gauss-Newton iterations made.
    """

    omega: np.ndarray
    t: np.ndarray
    sigma: np.ndarray
    alpha: np.ndarray
    rms: np.ndarray
    iterations: int


def fit_model_to_nodes(
    model: FaceModel,
    nodes: np.ndarray,
    tolerance: float = 1e-12,
    max_iterations: int = 20,
    weights: np.ndarray | None = None,
    start: NodeFit | None = None,
    alpha_precision: np.ndarray | None = None,
) -> NodeFit:
    """Fit omega, t, sigma and alpha of eq. 1 and 3 to meshes in the camera frame.

    Args:
        model: the face model (N nodes).
        nodes: (F, N, 3) meshes in the camera frame, in the model's node order, metres.
        tolerance: stop when no parameter of any frame changes by more than this (rad or m).
        max_iterations: largest number of Gauss-Newton iterations.
        weights: optional (N,) non-negative node weights w_i of the squared node distances
            (0: the node is ignored); None for equal weights. ``rms`` stays unweighted.
        start: a fit of as many frames to start Gauss-Newton from, such as the previous
            frame's when the meshes are tracked (it skips the Procrustes and linear start);
            None starts from those.
        alpha_precision: optional (q, q) precision of the Gaussian prior on alpha, in the
            units of the node distances: ``alpha' P alpha`` is added to the weighted squared
            node distances (``s^2 Sigma_alpha^-1`` for nodes in error by s per coordinate, see
            the module notes); None: no prior.

    Raises:
        InputError: if nodes is not a finite (F, N, 3) array with F >= 1, weights is not a
            finite non-negative (N,) array, start is a fit of another number of frames or
            parameters, or alpha_precision is not a symmetric positive definite (q, q) matrix.
    """
    problem = NodeFitProblem.of(model, weights, alpha_precision)
    return problem.fit(nodes, tolerance, max_iterations, start)


@dataclass(frozen=True)
class NodeFitProblem:
    """A model with node weights and a prior, checked and prepared for many fits (a tracker's).

    :func:`fit_model_to_nodes` with the same model, weights and prior, without checking and
    preparing them again on every call.

    Attributes:
        model: the face model (N nodes).
        weights: (N,) node weights w_i.
        row_scale: (3N,) sqrt(w_i) of every coordinate.
        bases: (3N, p + q) [S A].
        bases_nodes: (N, 3, p + q) the bases per node.
        mean: (N, 3) the mean shape.
        prior_root: (q, q) ``L'`` of the prior's precision (None: no prior).
    """

    model: FaceModel
    weights: np.ndarray
    row_scale: np.ndarray
    bases: np.ndarray
    bases_nodes: np.ndarray
    mean: np.ndarray
    prior_root: np.ndarray | None

    @classmethod
    def of(
        cls,
        model: FaceModel,
        weights: np.ndarray | None = None,
        alpha_precision: np.ndarray | None = None,
    ) -> NodeFitProblem:
        """The prepared fit (arguments as :func:`fit_model_to_nodes`'s).

        Raises:
            InputError: if weights or alpha_precision are not usable (as
                :func:`fit_model_to_nodes`).
        """
        w = _checked_weights(model, weights)
        bases = np.hstack([model.shape_basis, model.action_basis])
        return cls(
            model=model,
            weights=w,
            row_scale=np.repeat(np.sqrt(w), 3),
            bases=bases,
            bases_nodes=bases.reshape(model.num_nodes, 3, -1),
            mean=model.mean_shape.reshape(-1, 3),
            prior_root=None if alpha_precision is None else _prior_root(model, alpha_precision),
        )

    def fit(
        self,
        nodes: np.ndarray,
        tolerance: float = 1e-12,
        max_iterations: int = 20,
        start: NodeFit | None = None,
    ) -> NodeFit:
        """:func:`fit_model_to_nodes` of (F, N, 3) meshes (arguments as its).

        Raises:
            InputError: if nodes is not a finite (F, N, 3) array with F >= 1, or start is a
                fit of another number of frames or parameters.
        """
        model = self.model
        nodes = _checked_nodes(model, nodes)
        if start is None:
            omega, t, coefficients = _initial_estimate(model, nodes, self.weights, self.bases)
        else:
            omega, t, coefficients = _start_of(start, len(nodes), self.bases.shape[1])
        from face_tracking_ros.recognition.node_fit_kernels import (  # noqa: PLC0415
            gauss_newton_iteration,  # numba at the first fit alone (module notes)
            rms_distances,
        )

        prior_root = np.zeros((0, 0)) if self.prior_root is None else self.prior_root
        iterations, converged = 0, False
        while not converged and iterations < max_iterations:
            iterations += 1
            rotation, d_rotation = _rotations(omega)
            omega, t, coefficients, largest = gauss_newton_iteration(
                self.mean,
                self.bases_nodes,
                nodes,
                omega,
                t,
                coefficients,
                rotation,
                d_rotation,
                self.row_scale,
                prior_root,
                LEVENBERG_DAMPING,
            )
            converged = bool(largest < tolerance)
        rotation, _ = _rotations(omega)
        rms = rms_distances(self.mean, self.bases_nodes, nodes, coefficients, rotation, t)
        return NodeFit(
            omega=omega,
            t=t,
            sigma=coefficients[:, : model.p],
            alpha=coefficients[:, model.p :],
            rms=rms,
            iterations=iterations,
        )


def _checked_nodes(model: FaceModel, nodes: np.ndarray) -> np.ndarray:
    """The meshes as a float array, checked.

    Raises:
        InputError: as :func:`fit_model_to_nodes`.
    """
    nodes = np.asarray(nodes, dtype=float)
    if nodes.ndim != 3 or nodes.shape[1:] != (model.num_nodes, 3) or not len(nodes):
        msg = f'nodes must be (F >= 1, {model.num_nodes}, 3), got shape {nodes.shape}'
        raise InputError(msg)
    if not np.all(np.isfinite(nodes)):
        msg = 'nodes to fit hold NaN or Inf'
        raise InputError(msg)
    return nodes


def _checked_weights(model: FaceModel, weights: np.ndarray | None) -> np.ndarray:
    """The node weights (ones if None) as a float array, checked.

    Raises:
        InputError: as :func:`fit_model_to_nodes`.
    """
    w = np.ones(model.num_nodes) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (model.num_nodes,) or not np.all(np.isfinite(w)) or np.any(w < 0):
        msg = f'weights must be finite and >= 0 with shape ({model.num_nodes},)'
        raise InputError(msg)
    return w


def _prior_root(model: FaceModel, precision: np.ndarray) -> np.ndarray:
    """(q, q) ``L'`` of the prior's precision ``P = L L'``, whose rows ``L' alpha`` it adds.

    Raises:
        InputError: if the precision is not a finite, symmetric, positive definite (q, q) matrix.
    """
    precision = np.asarray(precision, dtype=float)
    shape = (model.q, model.q)
    if (
        precision.shape != shape
        or not np.all(np.isfinite(precision))
        or not np.allclose(precision, precision.T)
    ):
        msg = f'alpha_precision must be a finite symmetric {shape} matrix, got {precision.shape}'
        raise InputError(msg)
    try:
        return np.linalg.cholesky(precision).T
    except np.linalg.LinAlgError:
        msg = 'alpha_precision must be positive definite'
        raise InputError(msg) from None


def _initial_estimate(
    model: FaceModel, nodes: np.ndarray, weights: np.ndarray, bases: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Newton's start: the weighted Procrustes pose of the mean shape, then sigma, alpha.

    Sigma and alpha come by linear least squares on the nodes brought into the face frame.

    Returns:
        ``(omega, t, coefficients)``: (F, 3), (F, 3) and (F, p + q), sigma then alpha.
    """
    row_scale = np.repeat(np.sqrt(weights), 3)
    pose = rigid_align(model.mean_shape.reshape(-1, 3), nodes, weights)
    in_face = np.einsum('fba,fnb->fna', pose.rotation, nodes - pose.t[:, None, :])
    centred = (in_face.reshape(len(nodes), -1) - model.mean_shape) * row_scale
    coefficients = centred @ np.linalg.pinv(row_scale[:, None] * bases).T
    omega = np.array([matrix_to_omega(rotation) for rotation in pose.rotation])
    return omega, pose.t, coefficients


def _start_of(
    start: NodeFit, frames: int, parameters: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(omega, t, coefficients)`` of a given fit, checked against the frames and parameters.

    Raises:
        InputError: if the fit has another number of frames or parameters.
    """
    coefficients = np.hstack([start.sigma, start.alpha])
    if start.omega.shape != (frames, 3) or coefficients.shape != (frames, parameters):
        msg = (
            f'the start fit has {len(start.omega)} frames and {coefficients.shape[-1]} '
            f'parameters, the fit {frames} and {parameters}'
        )
        raise InputError(msg)
    return start.omega, start.t, coefficients


def _rotations(omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3, 3) R(omega) and (F, 3, 3, 3) dR / d omega_k of (F, 3) rotation vectors."""
    rotation, d_rotation = (np.array(a) for a in zip(*map(rodrigues, omega), strict=True))
    return rotation, d_rotation
