"""The Gaussian priors of §4.1 on alpha and sigma, as the monocular tracker's solves use them.

Eq. 6's solve (:mod:`.mono_solve`) adds ``lambda alpha' Sigma_alpha^-1 alpha`` (and, while it
estimates sigma, ``lambda sigma' Sigma_sigma^-1 sigma``) to its cost; the bundle adjustment of the
first views (:mod:`.mono_adjustment`) takes the same precisions.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.linalg import inv

from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.tracking.projection import POSE_DIM


class Priors(NamedTuple):
    """The Gaussian priors of §4.1 on alpha and sigma: their precisions ``lambda Sigma^-1``.

    Their Hessians are in the solve's units (squared residuals over the robust scale s squared),
    padded to the pose and halved like the data term's; the costs and halved gradients are
    :func:`~.mono_kernels.prior_terms` of them.

    Attributes:
        alpha_precision: (q, q) ``lambda Sigma_alpha^-1``.
        sigma_precision: (p, p) ``lambda Sigma_sigma^-1``.
    """

    alpha_precision: np.ndarray
    sigma_precision: np.ndarray

    @classmethod
    def of(cls, model: FaceModel, weight: float) -> Priors:
        """The model's priors weighed by ``weight`` (lambda, ``prior_weight``)."""
        return cls(
            weight * inv(model.alpha_prior_covariance), weight * inv(model.sigma_prior_covariance)
        )

    def hessian(self, free_sigma: bool) -> np.ndarray:
        """Hessian (halved) of the alpha (and sigma) priors, padded to the pose."""
        q = len(self.alpha_precision)
        size = POSE_DIM + q + (len(self.sigma_precision) if free_sigma else 0)
        hessian = np.zeros((size, size))
        hessian[POSE_DIM : POSE_DIM + q, POSE_DIM : POSE_DIM + q] = self.alpha_precision
        if free_sigma:
            hessian[POSE_DIM + q :, POSE_DIM + q :] = self.sigma_precision
        return hessian
