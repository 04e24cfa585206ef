"""A soft face-model term for the stereo tracker: the mesh deforms as the learned actions do.

The stereo tracker's image terms (eq. 4) are weak where the face turns away from the cameras
(the face-edge nodes, §4.2) and along the lips' horizontal contours; the eq. 5 terms only keep
the mesh smooth. The learned action basis A (eq. 3) knows how such nodes move with the others:
when the mouth opens, the chin drops. This term asks the tracked nodes X (N, 3), camera frame,
m, to stay near the subject's frame-1 mesh animated by the model:

    M(omega, t, alpha) = R(omega) (B + A alpha) + t          (eq. 1 and 3)

where the base shape B is the frame-1 mesh in the face frame minus its own fitted action, so
the subject's identity is its own (a learned S sigma would err by millimetres on an unseen
face) and only the deformation comes from the model. The term is

    E_model(X) = min over (omega, t, alpha) of  sum_i lambda_i ||X_i - M_i||^2

(variable projection: the pose and alpha follow X). It is evaluated as
``(X - X(1)) - (M - M(1))`` with M(1) the model at the frame-1 fit, which is the same up to
rounding but exactly zero for an unmoved mesh (no motion gives exactly no motion). Its
Gauss-Newton terms with respect to X are the gradient W (X - M) at the optimum and the
Hessian W - W J (J^T W J)^-1 J^T W, with W the per-node weights lambda_i and
J = dM / d(omega, t, alpha): motion along the model's own degrees of freedom (a head turn, an
expression) costs nothing, motion off them costs lambda_i per m^2. Units: lambda_i in
grey^2 / m^2, like eq. 5's rho.

The solver evaluates the term at every trial point (:meth:`ActionPrior.evaluate` refits the
parameters from the last fit, a :class:`ModelPoint` that keeps M and its Jacobian) and forms
its normal equations only where it linearises, from that evaluation. The arithmetic of both is
compiled (:mod:`.stereo_kernels`: some thirty small numpy calls a trial point otherwise).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from typing import NamedTuple

import numpy as np

from face_tracking_ros.geometry.rotation import rodrigues, rotate_with_jacobian
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.recognition.node_fit import fit_model_to_nodes
from face_tracking_ros.tracking.stereo_kernels import (
    model_difference,
    model_hessian,
    model_normal,
    model_shape,
    model_step,
)

FIT_ITERATIONS = 1  # Gauss-Newton steps of (omega, t, alpha), warm-started from the last fit
ALPHA_DAMPING = 1e-9  # relative Levenberg damping on the normal matrix of the fit


@dataclass(frozen=True)
class ModelPoint:
    """The animated mesh at one parameter vector, with the normal matrix of a fit from there.

    The weighted Jacobian and the normal matrices are made when first asked for, in one compiled
    pass: the solver needs them only at the points it linearises at.

    Attributes:
        theta: (6 + q,) parameters (omega, t, alpha).
        nodes: (N, 3) M(theta) = R(omega) shape + t, m.
        shape: (N, 3) B + A alpha in the face frame, m.
        rotation: (3, 3) R(omega).
        d_rotation: (3, 3, 3) dR / d omega_k.
        action_basis: (N, 3, q) A.
        row_weights: (3N,) lambda_i of every coordinate.
    """

    theta: np.ndarray
    nodes: np.ndarray
    shape: np.ndarray
    rotation: np.ndarray
    d_rotation: np.ndarray
    action_basis: np.ndarray
    row_weights: np.ndarray

    @cached_property
    def _linear(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """W J, J^T W J and that damped (one compiled pass, :func:`.model_normal`)."""
        return model_normal(
            self.shape,
            self.rotation,
            self.d_rotation,
            self.action_basis,
            self.row_weights,
            ALPHA_DAMPING,
        )

    @property
    def weighted(self) -> np.ndarray:
        """(3N, 6 + q) W J, J = dM / d(omega, t, alpha)."""
        return self._linear[0]

    @property
    def normal(self) -> np.ndarray:
        """(6 + q, 6 + q) J^T W J."""
        return self._linear[1]

    @property
    def damped_normal(self) -> np.ndarray:
        """J^T W J with the fit's relative Levenberg damping on its diagonal."""
        return self._linear[2]


class PriorEvaluation(NamedTuple):
    """E_model at some nodes.

    Attributes:
        cost: E_model, grey^2.
        point: the model at the parameters fitted to the nodes.
        difference: (3N,) X - M there, as (X - X(1)) - (M - M(1)), m.
    """

    cost: float
    point: ModelPoint
    difference: np.ndarray


@dataclass(frozen=True)
class ActionPrior:
    """The model term of one tracking run (fixed at frame 1).

    Attributes:
        base: (N, 3) base shape B in the face frame, m.
        action_basis: (N, 3, q) the model's A per node.
        weights: (N,) lambda_i, grey^2 / m^2.
        first_nodes: (N, 3) X(1), m.
        first_model: (N, 3) M at the frame-1 parameters, m (X(1) up to rounding).
        first_rotation: (3, 3) R(omega) of the frame-1 parameters.
        row_weights: (3N,) lambda_i of every coordinate.
    """

    base: np.ndarray
    action_basis: np.ndarray
    weights: np.ndarray
    first_nodes: np.ndarray
    first_model: np.ndarray
    first_rotation: np.ndarray
    row_weights: np.ndarray

    @classmethod
    def build(
        cls, model: FaceModel, first_nodes: np.ndarray, weights: np.ndarray
    ) -> tuple[ActionPrior, np.ndarray]:
        """The term for a run whose frame-1 nodes are given, and its frame-1 parameters.

        Args:
            model: a face model of the tracked mesh (its A; its mean and S give the start).
            first_nodes: (N, 3) frame-1 nodes X(1), camera frame, m.
            weights: (N,) lambda_i, grey^2 / m^2.

        Returns:
            ``(prior, theta)``: the term and (6 + q,) parameters (omega, t, alpha) at frame 1,
            at which it is exactly zero.
        """
        fit = fit_model_to_nodes(model, first_nodes[None], tolerance=1e-9)
        omega, t, alpha = fit.omega[0], fit.t[0], fit.alpha[0]
        action = np.ascontiguousarray(model.action_basis_nodes())  # the kernels'
        rotated, _ = rotate_with_jacobian(-omega, first_nodes - t)
        base = rotated - action @ alpha
        theta = np.concatenate([omega, t, alpha])
        rotation, _ = rodrigues(omega)
        weights = np.asarray(weights, dtype=float)
        row_weights = np.repeat(weights, 3)
        partial = cls(base, action, weights, first_nodes, first_nodes, rotation, row_weights)
        first_model = partial.point(theta).nodes
        return cls(base, action, weights, first_nodes, first_model, rotation, row_weights), theta

    def moved(self, shift: np.ndarray) -> ActionPrior:
        """The term for frame-1 nodes X(1) + ``shift`` (N, 3), m, at the same parameters.

        The base shape moves by the shift brought into the face frame, so M at the frame-1
        parameters moves with X(1) and the term stays exactly zero for an unmoved mesh.
        """
        return replace(
            self,
            base=self.base + shift @ self.first_rotation,
            first_nodes=self.first_nodes + shift,
            first_model=self.first_model + shift,
        )

    def point(self, theta: np.ndarray) -> ModelPoint:
        """M(theta) (N, 3), with its Jacobian (3N, 6 + q) with respect to (omega, t, alpha)."""
        rotation, d_rotation = rodrigues(theta[:3])
        shape, nodes = model_shape(self.base, self.action_basis, theta, rotation)
        return ModelPoint(
            theta, nodes, shape, rotation, d_rotation, self.action_basis, self.row_weights
        )

    def fit(self, nodes: np.ndarray, start: ModelPoint) -> ModelPoint:
        """The model at (omega, t, alpha) minimising the weighted node distance to ``nodes``.

        Warm-started from ``start`` (the last fit), FIT_ITERATIONS Gauss-Newton steps.
        """
        return self._fit(nodes - self.first_nodes, start)

    def evaluate(self, nodes: np.ndarray, start: ModelPoint) -> PriorEvaluation:
        """E_model at ``nodes`` (N, 3), m, refitting the parameters from ``start``."""
        motion = nodes - self.first_nodes
        point = self._fit(motion, start)
        difference, cost = model_difference(
            motion, point.nodes, self.first_model, self.row_weights
        )
        return PriorEvaluation(cost, point, difference)

    def normal_equations(self, evaluation: PriorEvaluation) -> tuple[np.ndarray, np.ndarray]:
        """Gauss-Newton terms of E_model at the evaluated nodes (node-major, as eq. 5's).

        Returns:
            ``(hessian, gradient)``: (3N, 3N) W - W J (J^T W J)^-1 J^T W; (3N,) W (X - M).
        """
        point = evaluation.point
        hessian = model_hessian(point.weighted, point.normal, self.row_weights)
        return hessian, self.row_weights * evaluation.difference

    def _fit(self, motion: np.ndarray, start: ModelPoint) -> ModelPoint:
        """:meth:`fit` to the nodes' motion since frame 1, X - X(1) (N, 3), m."""
        point = start
        for _ in range(FIT_ITERATIONS):
            difference, _ = model_difference(
                motion, point.nodes, self.first_model, self.row_weights
            )
            point = self.point(
                model_step(point.weighted, point.damped_normal, difference, point.theta)
            )
        return point
