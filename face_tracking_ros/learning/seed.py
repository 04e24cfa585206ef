"""Model learning exactly as the seed's §3.4 (Figure 4), with the §4.3 eigenvalue-weighted option.

The loop, on meshes already aligned by :func:`~face_tracking_ros.learning.alignment.
align_training_set` and flattened to vectors X(s, f) (3N,), metres:

1. neutral_s: initially the mean of subject s's neutral-labelled frames;
2. mean_shape = the mean of the neutral_s (equal weight per subject);
3. S = the p leading principal components of the neutral_s - mean_shape (p given, or the
   smallest p explaining ``explained_variance`` of the neutral variance);
4. residual(s, f) = (I - S S^T)(X(s, f) - mean_shape): the frames minus the mean shape and the
   contribution of the shape basis; A = the q leading principal components of the residuals
   (second moment about zero: alpha = 0 is the neutral face in eq. 3);
5. alpha(s, f) = the coding of X(s, f) - mean_shape on A, and neutral_s = the mean over all of
   subject s's frames of X(s, f) - A alpha(s, f) ("subtract off the projection of the action
   vectors from the mesh data ... averaged together for each subject");
6. repeat from 2 until S and A stop changing.

Coding in step 5:

* ``eigenvalue_weighted=False`` (the seed): the orthogonal projection, alpha = A^T (X - mean).
* ``eigenvalue_weighted=True`` (§4.3, after Costen et al.'s simultaneous extraction of
  functional subspaces, which codes each sample jointly on all non-orthogonal subspaces with
  eigenvalue weights before re-forming the ensembles): the maximum a-posteriori coding of
  X - mean on [S A] under the Gaussian model X - mean = S sigma + A alpha + e with
  sigma ~ N(0, diag(lambda_S)), alpha ~ N(0, diag(lambda_A)) and e ~ N(0, nu I)::

      [sigma; alpha] = (C^T C + nu diag(lambda_S, lambda_A)^-1)^-1 C^T (X - mean),  C = [S A]

  lambda_S and lambda_A are the current PCA eigenvalues of the two ensembles and nu is the
  probabilistic-PCA noise variance of the residual ensemble (its discarded variance per
  dimension, Tipping and Bishop 1999). Directions of A that S already explains, and weak action
  components, are then removed only in proportion to their eigenvalues.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.learning.result import LearningResult, assemble_result
from face_tracking_ros.learning.subspace import (
    check_components,
    moment_components,
    principal_components,
    scatter,
    subspace_similarity,
)
from face_tracking_ros.learning.training_set import TrainingSet
from face_tracking_ros.wording import counted


@dataclass(frozen=True)
class SeedConfig:
    """Parameters of the §3.4 learner.

    Attributes:
        p: identity dimension; None chooses it by ``explained_variance``.
        q: expression dimension.
        explained_variance: share of the neutral-shape variance S must explain when p is None.
        eigenvalue_weighted: use the §4.3 eigenvalue-weighted coding (see the module docstring).
        tolerance: convergence when 1 - subspace similarity of S and of A with the previous
            iteration are both below it.
        max_iterations: iteration limit.
    """

    p: int | None = 2
    q: int = 5
    explained_variance: float = 0.95
    eigenvalue_weighted: bool = False
    tolerance: float = 1e-6
    max_iterations: int = 100


def learn_seed(training: TrainingSet, config: SeedConfig | None = None) -> LearningResult:
    """Learn mean shape, S and A by the §3.4 iteration (optionally §4.3-weighted).

    Args:
        training: aligned training meshes (face frame), with neutral flags.
        config: dimensions and convergence; defaults as in :class:`SeedConfig`.

    Returns:
        The model (method 'seed' or 'seed-weighted') and the iteration history.

    Raises:
        ConfigError: if there are fewer than p + 1 subjects, q is out of range or
            max_iterations is below 1.
    """
    config = config or SeedConfig()
    check_dimensions(training, config.p, config.q)
    check_iterations(config.max_iterations)
    frames = training.flat()
    check_components(config.q, *frames.shape)
    moments = _FrameMoments.of(training, frames)
    neutral = training.subject_means(frames, training.neutral)
    estimate = _estimate(moments, neutral, config.p, config)
    history = [1.0]  # no earlier S and A to compare with
    converged = False
    while len(history) < config.max_iterations and not converged:
        previous = estimate
        neutral = _neutral_off_action(training, moments, previous)
        estimate = _estimate(moments, neutral, previous.shape_basis.shape[1], config)
        history.append(_change(estimate, previous))
        converged = history[-1] < config.tolerance
    method = 'seed-weighted' if config.eigenvalue_weighted else 'seed'
    return assemble_result(
        training,
        mean_shape=estimate.mean_shape,
        shape_basis=estimate.shape_basis,
        action_basis=estimate.action_basis,
        subject_neutral=neutral,
        alpha=estimate.alpha,
        method=method,
        history=history,
        converged=converged,
        metadata={'tolerance': config.tolerance},
    )


class _FrameMoments(NamedTuple):
    """The training frames and the statistics every iteration needs, taken once.

    Every frame's deviation from mean_shape, and its residual off S, are linear in the frame:
    their second moments and their subject means follow from the frames' own, so an iteration
    makes no (F, 3N) array.
    """

    frames: np.ndarray  # (F, 3N)
    frame_mean: np.ndarray  # (3N,)
    frame_covariance: np.ndarray  # (3N, 3N), about frame_mean
    subject_frame_means: np.ndarray  # (subjects, 3N)

    @classmethod
    def of(cls, training: TrainingSet, frames: np.ndarray) -> _FrameMoments:
        """The moments of ``training``'s flattened ``frames``."""
        frame_mean = frames.mean(axis=0)
        return cls(
            frames=frames,
            frame_mean=frame_mean,
            frame_covariance=scatter(frames, about=frame_mean) / len(frames),
            subject_frame_means=training.subject_means(frames),
        )


class _Estimate(NamedTuple):
    """One iteration's model: steps 2 to 5 of the module docstring."""

    mean_shape: np.ndarray  # (3N,)
    shape_basis: np.ndarray  # (3N, p)
    action_basis: np.ndarray  # (3N, q)
    alpha: np.ndarray  # (F, q)


def _estimate(
    moments: _FrameMoments, neutral: np.ndarray, p: int | None, config: SeedConfig
) -> _Estimate:
    """Steps 2 to 5 from the subjects' ``neutral`` shapes; p None is chosen here (step 3)."""
    mean_shape = neutral.mean(axis=0)
    identity = principal_components(neutral - mean_shape, len(neutral) - 1)
    if p is None:
        p = choose_dimension(identity.explained, config.explained_variance)
    shape_basis = identity.basis[:, :p]
    off_shape = np.eye(len(mean_shape)) - shape_basis @ shape_basis.T
    offset = moments.frame_mean - mean_shape
    deviation_moment = moments.frame_covariance + np.outer(offset, offset)
    residual_moment = off_shape @ deviation_moment @ off_shape
    action = moment_components(residual_moment, config.q)
    if config.eigenvalue_weighted:
        alpha = _weighted_alpha(
            moments.frames,
            mean_shape,
            shape_basis,
            action.basis,
            identity.variances[:p],
            action.variances,
            _noise_variance(residual_moment, action.variances),
        )
    else:
        alpha = moments.frames @ action.basis - mean_shape @ action.basis
    return _Estimate(mean_shape, shape_basis, action.basis, alpha)


def _neutral_off_action(
    training: TrainingSet, moments: _FrameMoments, estimate: _Estimate
) -> np.ndarray:
    """Step 5: each subject's mean over its frames of X - A alpha (subjects, 3N)."""
    return (
        moments.subject_frame_means
        - training.subject_means(estimate.alpha) @ estimate.action_basis.T
    )


def _change(estimate: _Estimate, previous: _Estimate) -> float:
    """Step 6's test: 1 - the smaller subspace similarity of S and of A to the last iteration's."""
    return max(
        1.0 - subspace_similarity(estimate.shape_basis, previous.shape_basis),
        1.0 - subspace_similarity(estimate.action_basis, previous.action_basis),
    )


def choose_dimension(explained: np.ndarray, share: float) -> int:
    """Smallest number of leading components whose explained shares sum to at least ``share``."""
    return int(min(np.searchsorted(np.cumsum(explained), share - 1e-12) + 1, len(explained)))


def check_dimensions(training: TrainingSet, p: int | None, q: int) -> None:
    """Raise ConfigError unless p + 1 <= subjects, 1 <= q < 3N and q <= the meshes (F).

    The expression basis is q principal components of the F mesh vectors, so F bounds q too.
    """
    if p is not None and p < 1:
        msg = f'p must be at least 1, got {p}'
        raise ConfigError(msg)
    check_subject_count(training.num_subjects, p)
    if not 1 <= q < 3 * training.num_nodes:
        msg = f'q must be between 1 and {3 * training.num_nodes - 1}, got {q}'
        raise ConfigError(msg)
    meshes = len(training.meshes)
    if q > meshes:
        msg = (
            f'q = {q} expression modes cannot come from {meshes} training meshes: at most {meshes}'
        )
        raise ConfigError(msg)


def check_subject_count(num_subjects: int, p: int | None) -> None:
    """Raise ConfigError unless p + 1 <= subjects (2 subjects when p is chosen, None).

    The subjects' mean neutral shapes span at most subjects - 1 directions about their mean.
    """
    needed = 2 if p is None else p + 1
    if num_subjects < needed:
        msg = (
            f'{counted(num_subjects, "subject")} cannot give an identity subspace of p = {p}: '
            f'at least p + 1 = {needed} subjects are needed'
        )
        raise ConfigError(msg)


def check_iterations(max_iterations: int) -> None:
    """Raise ConfigError unless the iteration limit allows one iteration at least."""
    if max_iterations < 1:
        msg = f'max_iterations must be at least 1, got {max_iterations}'
        raise ConfigError(msg)


def _noise_variance(residual_moment: np.ndarray, action_variances: np.ndarray) -> float:
    """Probabilistic-PCA noise variance: residual variance left by A, per remaining dimension.

    Args:
        residual_moment: (3N, 3N) mean second moment of the residuals off S.
        action_variances: (q,) its leading eigenvalues, A's.
    """
    total = np.trace(residual_moment)
    return max(float(total - action_variances.sum()), 0.0) / (
        len(residual_moment) - len(action_variances)
    )


def _weighted_alpha(
    frames: np.ndarray,
    mean_shape: np.ndarray,
    shape_basis: np.ndarray,
    action_basis: np.ndarray,
    shape_variances: np.ndarray,
    action_variances: np.ndarray,
    noise_variance: float,
) -> np.ndarray:
    """§4.3: alpha of the MAP coding of the frames' deviations from mean_shape on [S A] (F, q).

    The coding's priors are the eigenvalues; being linear in the frames, it is computed without
    forming the (F, 3N) deviations.
    """
    coding = np.hstack([shape_basis, action_basis])
    prior_precision = noise_variance / np.concatenate([shape_variances, action_variances])
    normal = coding.T @ coding + np.diag(prior_precision)
    # A (p + q)-square, well-conditioned system: its inverse is exact enough, and avoids LAPACK
    # solver calls that multi-threaded OpenBLAS makes slow on a busy machine.
    decoding = np.linalg.inv(normal)[shape_basis.shape[1] :] @ coding.T
    return frames @ decoding.T - decoding @ mean_shape
