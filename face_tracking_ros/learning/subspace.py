"""Subspace tools shared by the learners and the evaluation: PCA, similarity, eq. 3 fits.

Vectors are flattened meshes (3N,), node-major, metres; a basis is a (3N, k) matrix.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from face_tracking_ros.errors import ConfigError

_BLOCK_ROWS = 65536  # rows per block of :func:`scatter` (53 MB of 102 float64 coordinates)


@dataclass(frozen=True)
class PrincipalComponents:
    """Leading principal directions of a set of vectors.

    Attributes:
        basis: (D, k) orthonormal directions, by decreasing variance.
        variances: (k,) mean squared coordinate along each direction (eigenvalues), m^2.
        explained: (k,) share of the total mean square explained by each direction.
    """

    basis: np.ndarray
    variances: np.ndarray
    explained: np.ndarray


def principal_components(vectors: np.ndarray, k: int) -> PrincipalComponents:
    """The k leading eigenvectors of the mean second-moment matrix sum_f v_f v_f^T / F.

    The vectors are not centred: callers subtract what the model's origin is (the mean shape, a
    subject's neutral). Computed by ``scipy.linalg.eigh`` of the (D, D) second-moment matrix,
    which for thousands of meshes of D <= 102 coordinates is several times faster than an SVD of
    the data.

    Args:
        vectors: (F, D) vectors.
        k: number of directions kept, 1 <= k <= min(F, D).

    Returns:
        Directions, their variances (eigenvalues of the mean second moment) and shares.

    Raises:
        ConfigError: if k is out of range.
    """
    check_components(k, *vectors.shape)
    return moment_components(scatter(vectors) / len(vectors), k)


def scatter(
    vectors: np.ndarray,
    sample_weights: np.ndarray | None = None,
    about: np.ndarray | None = None,
    about_index: np.ndarray | None = None,
    rows: np.ndarray | None = None,
) -> np.ndarray:
    """(D, D) weighted scatter sum_f w_f (v_f - c_f)(v_f - c_f)^T of (F, D) vectors.

    Summed over blocks of rows, so no (F, D) temporary is made: a learner's frames can run to a
    million meshes (800 MB), and passes over arrays of that size cost more than the arithmetic.

    Args:
        vectors: (F, D) vectors.
        sample_weights: (F,) non-negative weights; None for weights 1.
        about: the points c_f the scatter is taken about: (D,) one point, or (K, D) points of
            which vector f takes ``about[about_index[f]]``; None for the origin.
        about_index: (F,) row of ``about`` of each vector, when ``about`` is (K, D).
        rows: (R,) the vectors to sum over (each block gathered in turn, not copied at once);
            ``sample_weights`` and ``about_index`` are then (R,), one per row. None for all.
    """
    dim = vectors.shape[1]
    count = len(vectors) if rows is None else len(rows)
    total = np.zeros((dim, dim))
    for start in range(0, count, _BLOCK_ROWS):
        part = slice(start, start + _BLOCK_ROWS)
        block = vectors[part] if rows is None else vectors[rows[part]]
        if about is not None:
            block = block - (about if about_index is None else about[about_index[part]])
        weighted = block if sample_weights is None else block * sample_weights[part, None]
        total += weighted.T @ block
    return total


def moment_components(moment: np.ndarray, k: int) -> PrincipalComponents:
    """The k leading eigenvectors of a (D, D) second moment (see :func:`principal_components`)."""
    dim = len(moment)
    variances, basis = scipy.linalg.eigh(
        moment, subset_by_index=[dim - k, dim - 1], check_finite=False
    )
    variances = np.maximum(variances[::-1], 0.0)
    total = np.trace(moment)
    return PrincipalComponents(
        basis=_fix_signs(basis[:, ::-1]),
        variances=variances,
        explained=variances / total if total > 0 else np.zeros(k),
    )


def check_components(k: int, count: int, dim: int) -> None:
    """Raise ConfigError unless 1 <= k <= min(count, dim) components can be kept."""
    if not 1 <= k <= min(count, dim):
        msg = f'cannot keep {k} principal components of {count} vectors of dimension {dim}'
        raise ConfigError(msg)


def orthonormal_basis(basis: np.ndarray) -> np.ndarray:
    """Orthonormal (D, k) basis of the column span of a full-rank (D, k) matrix."""
    q, _ = np.linalg.qr(basis)
    return q


def subspace_similarity(basis: np.ndarray, other: np.ndarray) -> float:
    """Share of one subspace that lies inside another; 1 means contained (identical if equal dim).

    With Q1 (D, k1) and Q2 (D, k2) orthonormal bases of the two column spans, the similarity is
    ||Q1^T Q2||_F^2 / k1: the mean squared length of the projection onto span(Q2) of a unit
    vector of span(Q1), averaged over an orthonormal basis, i.e. the mean squared cosine of the
    principal angles. This is the seed's "project one subspace onto the other" measure (§3.4):
    one minus it is the mean squared projection error. For k1 = k2 it is symmetric; for k1 < k2
    it is the share of the first subspace inside the second (at most 1), and for k1 > k2 it is at
    most k2 / k1.

    Args:
        basis: (D, k1) spanning matrix of the first subspace (need not be orthonormal).
        other: (D, k2) spanning matrix of the second subspace.

    Returns:
        Similarity in [0, 1].
    """
    q1 = orthonormal_basis(basis)
    q2 = orthonormal_basis(other)
    return float(np.sum((q1.T @ q2) ** 2) / q1.shape[1])


def fit_coefficients(
    bases: np.ndarray, vectors: np.ndarray, origin: np.ndarray | None = None
) -> np.ndarray:
    """Least-squares coefficients c of vectors - origin ~ bases @ c, for many vectors at once.

    Args:
        bases: (D, k) basis (columns need not be orthogonal, e.g. [S A] of eq. 3).
        vectors: (F, D) vectors (deviations from the model origin when ``origin`` is None).
        origin: (D,) the model origin (e.g. the mean shape), subtracted from the coefficients
            rather than from the vectors, so no (F, D) difference is made.

    Returns:
        (F, k) coefficients.
    """
    solve = scipy.linalg.pinv(bases).T
    coefficients = vectors @ solve
    if origin is not None:
        coefficients -= origin @ solve
    return coefficients


def _fix_signs(basis: np.ndarray) -> np.ndarray:
    """Make each column's largest-magnitude entry positive, so bases are reproducible."""
    signs = np.sign(basis[np.argmax(np.abs(basis), axis=0), np.arange(basis.shape[1])])
    return basis * np.where(signs == 0, 1.0, signs)
