"""What a learner returns, and the assembly of a FaceModel with its §4.1 prior."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from face_tracking_ros.learning.subspace import fit_coefficients
from face_tracking_ros.learning.training_set import TrainingSet
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.topology import mesh_topology


@dataclass(frozen=True)
class LearningResult:
    """A learned model with the learner's history and per-subject / per-frame estimates.

    Attributes:
        model: the learned :class:`FaceModel` (eq. 3 with the §4.1 prior).
        iterations: iterations made.
        converged: whether the change fell below the tolerance.
        history: (iterations,) subspace change per iteration: 1 - similarity with the previous
            iteration's basis (the larger of S's and A's for the seed learner, A's for the joint
            learner; 1 for the first iteration).
        subject_neutral: (S, 3N) final neutral-face estimate of each subject, metres.
        subject_sigma: (S, p) identity parameters of each subject's neutral, metres.
        frame_sigma: (F, p) sigma of each training frame from a least-squares fit of eq. 3 with
            both sigma and alpha free (the seed's Figure 5 data).
        frame_alpha: (F, q) alpha of each training frame with sigma held at the subject's
            sigma, as the §3.5 tracker holds it constant over a sequence:
            alpha = A^T (X - mean_shape - S sigma_s).
    """

    model: FaceModel
    iterations: int
    converged: bool
    history: np.ndarray
    subject_neutral: np.ndarray
    subject_sigma: np.ndarray
    frame_sigma: np.ndarray
    frame_alpha: np.ndarray


def assemble_result(
    training: TrainingSet,
    mean_shape: np.ndarray,
    shape_basis: np.ndarray,
    action_basis: np.ndarray,
    subject_neutral: np.ndarray,
    alpha: np.ndarray,
    method: str,
    history: list[float],
    converged: bool,
    metadata: dict[str, Any],
) -> LearningResult:
    """Build the model, its §4.1 Gaussian prior and the per-frame eq. 3 fits.

    The prior is zero-mean, as the tracker assumes: sigma's covariance is the second moment of
    the subjects' sigma = S^T (neutral_s - mean_shape) (equal weight per subject), alpha's is the
    second moment about zero (alpha = 0 is the neutral face) of the learner's per-frame alpha.
    The eigenvalues are the diagonals of these matrices (:meth:`FaceModel.from_prior_covariances`).

    Args:
        training: the aligned training set.
        mean_shape: (3N,) mean shape, metres.
        shape_basis: (3N, p) orthonormal S.
        action_basis: (3N, q) orthonormal A.
        subject_neutral: (S, 3N) each subject's neutral estimate, metres.
        alpha: (F, q) the learner's alpha per training frame, metres.
        method: learner name stored in the model.
        history: change per iteration.
        converged: whether the learner converged.
        metadata: facts to store in the model file.
    """
    subject_sigma = (subject_neutral - mean_shape) @ shape_basis
    sigma_covariance = subject_sigma.T @ subject_sigma / len(subject_sigma)
    alpha_covariance = alpha.T @ alpha / len(alpha)
    p = shape_basis.shape[1]
    model = FaceModel.from_prior_covariances(
        node_names=mesh_topology(training.num_nodes).node_names,
        mean_shape=mean_shape,
        shape_basis=shape_basis,
        action_basis=action_basis,
        sigma_prior_covariance=sigma_covariance,
        alpha_prior_covariance=alpha_covariance,
        method=method,
        metadata={
            **metadata,
            'subjects': list(training.subject_ids),
            'frames': len(training.meshes),
            'iterations': len(history),
            'converged': converged,
        },
    )
    # The fits are linear in the frames, so the frames' deviations (F, 3N) are never formed.
    frames = training.flat()
    coding = np.hstack([shape_basis, action_basis])
    frame_sigma = fit_coefficients(coding, frames, origin=mean_shape)[:, :p]
    frame_alpha = (
        frames @ action_basis
        - mean_shape @ action_basis
        - (subject_sigma @ (shape_basis.T @ action_basis))[training.subject_index]
    )
    return LearningResult(
        model=model,
        iterations=len(history),
        converged=converged,
        history=np.asarray(history),
        subject_neutral=subject_neutral,
        subject_sigma=subject_sigma,
        frame_sigma=frame_sigma,
        frame_alpha=frame_alpha,
    )
