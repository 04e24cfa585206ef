"""Gaussian class-conditional densities: the Mahalanobis rule of identity recognition.

Class k has density N(x; mu_k, C_k). The identity gallery scores a feature vector x by the
squared Mahalanobis distance d_k^2 = (x - mu_k)^T C_k^-1 (x - mu_k) and by the log-likelihood
-0.5 (d_k^2 + log det C_k + d log 2 pi), and turns log-likelihoods into posteriors with a softmax
(Bayes' rule with equal priors). (Expressions use a linear softmax instead, see
:mod:`~face_tracking_ros.recognition.expression`.)
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.special import softmax

from face_tracking_ros.errors import InputError


@dataclass(frozen=True)
class GaussianClasses:
    """K Gaussian classes in a d-dimensional feature space.

    Attributes:
        means: (K, d) class means mu_k.
        covariances: (K, d, d) symmetric positive-definite class covariances C_k.
    """

    means: np.ndarray
    covariances: np.ndarray

    def __post_init__(self) -> None:
        """Check shapes and positive definiteness.

        Raises:
            InputError: if the arrays do not form K means and K SPD d x d covariances.
        """
        k, d = np.shape(self.means) if np.ndim(self.means) == 2 else (-1, -1)
        if k < 0 or np.shape(self.covariances) != (k, d, d):
            msg = (
                f'Gaussian classes need (K, d) means and (K, d, d) covariances, got '
                f'{np.shape(self.means)} and {np.shape(self.covariances)}'
            )
            raise InputError(msg)
        if not (np.all(np.isfinite(self.means)) and np.all(np.isfinite(self.covariances))):
            msg = 'Gaussian class means or covariances hold NaN or Inf'
            raise InputError(msg)
        if not np.allclose(self.covariances, np.swapaxes(self.covariances, 1, 2)):
            msg = 'Gaussian class covariances are not symmetric'
            raise InputError(msg)
        if k and np.min(np.linalg.eigvalsh(self.covariances)) <= 0.0:
            msg = 'Gaussian class covariances are not positive definite'
            raise InputError(msg)

    @property
    def dim(self) -> int:
        """Feature dimension d."""
        return int(self.means.shape[1])

    @cached_property
    def _precisions(self) -> np.ndarray:
        """(K, d, d) inverse covariances."""
        return np.linalg.inv(self.covariances)

    @cached_property
    def _log_normalisers(self) -> np.ndarray:
        """(K,) log det C_k + d log 2 pi."""
        return np.linalg.slogdet(self.covariances)[1] + self.dim * np.log(2.0 * np.pi)

    def mahalanobis_squared(self, x: np.ndarray) -> np.ndarray:
        """Squared Mahalanobis distances d_k^2 of feature vectors to every class.

        Args:
            x: (M, d) feature vectors.

        Returns:
            (M, K) squared distances.

        Raises:
            InputError: if x is not (M, d) and finite.
        """
        x = np.asarray(x, dtype=float)
        if x.ndim != 2 or x.shape[1] != self.dim or not np.all(np.isfinite(x)):
            msg = f'features must be a finite (M, {self.dim}) array, got shape {x.shape}'
            raise InputError(msg)
        diff = x[:, None, :] - self.means[None, :, :]
        return np.einsum('mki,kij,mkj->mk', diff, self._precisions, diff)

    def log_likelihoods(self, x: np.ndarray) -> np.ndarray:
        """(M, K) log N(x_m; mu_k, C_k) of (M, d) feature vectors."""
        return -0.5 * (self.mahalanobis_squared(x) + self._log_normalisers[None, :])

    def posteriors(self, x: np.ndarray) -> np.ndarray:
        """(M, K) class posteriors of (M, d) feature vectors, with equal priors."""
        return softmax(self.log_likelihoods(x), axis=1)
