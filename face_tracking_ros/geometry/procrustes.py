"""Weighted rigid Procrustes alignment of face meshes (seed §3.3).

Rigid means rotation and translation, no scale: the meshes are metric 3-D reconstructions, so a
scale change would be a real change of face size. Nodes are weighted per anatomical group
(:meth:`~face_tracking_ros.model.topology.MeshTopology.alignment_weights`: eyes and nose 0.9,
lips and brows 0.1) so that expressions move the alignment as little as possible.

The rotation is the weighted Kabsch/Umeyama solution: with weights w_i, centroids c_x, c_y and the
weighted cross-covariance H = sum_i w_i (x_i - c_x)(y_i - c_y)^T = U S V^T, the rotation taking x
onto y is R = V diag(1, 1, d) U^T with d = sign(det(V U^T)), which excludes reflections, and
t = c_y - R c_x. ``scipy.spatial.transform.Rotation.align_vectors`` solves the same problem for one
pair; here thousands of meshes are aligned at once, so the 3x3 SVDs are batched through
``numpy.linalg.svd`` (the tests check the result against scipy).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from face_tracking_ros.errors import InputError

MIN_WEIGHTED_NODES = 3


@dataclass(frozen=True)
class RigidAlignment:
    """Rigid transforms taking source meshes onto targets: ``aligned = source @ R^T + t``.

    Attributes:
        rotation: (..., 3, 3) rotation matrices R (det +1).
        t: (..., 3) translations, metres.
        aligned: (..., N, 3) the transformed source meshes, metres.
        rms: (...,) weighted RMS node distance between aligned source and target, metres.
    """

    rotation: np.ndarray
    t: np.ndarray
    aligned: np.ndarray
    rms: np.ndarray


@dataclass(frozen=True)
class GeneralizedProcrustesResult:
    """Result of :func:`generalized_procrustes`.

    Attributes:
        aligned: (F, N, 3) meshes aligned to the common mean, metres.
        mean: (N, 3) mean of the aligned meshes, metres.
        rotation: (F, 3, 3) rotation applied to each input mesh.
        t: (F, 3) translation applied to each input mesh, metres.
        iterations: number of align-to-mean passes made.
        converged: whether the mean moved less than the tolerance in the last pass.
    """

    aligned: np.ndarray
    mean: np.ndarray
    rotation: np.ndarray
    t: np.ndarray
    iterations: int
    converged: bool


def rigid_align(
    source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None
) -> RigidAlignment:
    """Weighted rigid Procrustes: the rotation and translation best mapping source onto target.

    Minimises sum_i w_i ||R x_i + t - y_i||^2 over rotations R (no reflection) and translations t
    (§3.3). Batched: source and target broadcast against each other.

    Args:
        source: (N, 3) or (F, N, 3) meshes to move, metres.
        target: (N, 3) or (F, N, 3) meshes to move onto, metres.
        weights: (N,) non-negative node weights; None for equal weights.

    Returns:
        The transforms, the aligned source and the weighted RMS residual.

    Raises:
        InputError: on shape mismatch, non-finite values or fewer than 3 positively weighted nodes.
    """
    source = _as_meshes(source, 'source')
    target = _as_meshes(target, 'target')
    w, rotation, t = _transform(source, target, weights)
    aligned = source @ np.swapaxes(rotation, -1, -2) + t[..., None, :]
    rms = np.sqrt(np.sum((aligned - target) ** 2, axis=-1) @ w)
    return RigidAlignment(rotation=rotation, t=t, aligned=aligned, rms=rms)


def rigid_rotation(
    source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray:
    """The rotation of :func:`rigid_align` alone, (3, 3) or (F, 3, 3) (nothing aligned).

    Raises:
        InputError: as :func:`rigid_align`.
    """
    return _transform(_as_meshes(source, 'source'), _as_meshes(target, 'target'), weights)[1]


def _transform(
    source: np.ndarray, target: np.ndarray, weights: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(w, rotation, t)``: the normalised weights and the transform of :func:`rigid_align`.

    Args:
        source: (..., N, 3) checked meshes to move, metres.
        target: (..., N, 3) checked meshes to move onto, metres.
        weights: (N,) non-negative node weights; None for equal weights.

    Raises:
        InputError: if the node counts differ or the weights are not usable.
    """
    num_nodes = source.shape[-2]
    if target.shape[-2] != num_nodes:
        msg = f'source has {num_nodes} nodes but target has {target.shape[-2]}'
        raise InputError(msg)
    w = _normalised_weights(weights, num_nodes)
    source_centroid = w @ source
    target_centroid = w @ target
    covariance = np.swapaxes(source - source_centroid[..., None, :], -1, -2) @ (
        w[:, None] * (target - target_centroid[..., None, :])
    )
    u, _, vt = np.linalg.svd(covariance)
    d = np.sign(np.linalg.det(u @ vt))
    vt = vt.copy()
    vt[..., 2, :] *= d[..., None]
    rotation = np.swapaxes(u @ vt, -1, -2)
    t = target_centroid - (rotation @ source_centroid[..., None])[..., 0]
    return w, rotation, t


def generalized_procrustes(
    meshes: np.ndarray,
    weights: np.ndarray | None = None,
    reference: np.ndarray | None = None,
    tolerance: float = 1e-9,
    max_iterations: int = 100,
) -> GeneralizedProcrustesResult:
    """Generalised Procrustes analysis: align many meshes to their common mean (§3.3).

    Starting from ``reference`` (or the first mesh), every mesh is aligned to the current target,
    the mean of the aligned meshes becomes the next target after being aligned back onto the
    reference (which fixes the otherwise free rotation and translation of the mean), and the loop
    stops when the mean moves less than ``tolerance`` at every node.

    Args:
        meshes: (F, N, 3) meshes, metres.
        weights: (N,) node weights (see :func:`rigid_align`).
        reference: (N, 3) mesh fixing the pose of the mean; default the first mesh.
        tolerance: largest node displacement of the mean between passes at convergence, metres.
        max_iterations: largest number of passes.

    Returns:
        Aligned meshes, their mean, the per-mesh transforms and the iteration count.

    Raises:
        InputError: on malformed meshes, weights or reference.
    """
    meshes = _as_meshes(meshes, 'meshes')
    if meshes.ndim != 3 or meshes.shape[0] == 0:
        msg = f'meshes must be a non-empty (F, N, 3) stack, got shape {meshes.shape}'
        raise InputError(msg)
    gauge = meshes[0] if reference is None else _as_meshes(reference, 'reference')
    target = gauge
    converged = False
    iterations = 0
    while iterations < max_iterations and not converged:
        iterations += 1
        alignment = rigid_align(meshes, target, weights)
        mean = rigid_align(alignment.aligned.mean(axis=0), gauge, weights).aligned
        converged = bool(np.abs(mean - target).max() < tolerance)
        target = mean
    final = rigid_align(meshes, target, weights)
    return GeneralizedProcrustesResult(
        aligned=final.aligned,
        mean=final.aligned.mean(axis=0),
        rotation=final.rotation,
        t=final.t,
        iterations=iterations,
        converged=converged,
    )


def _as_meshes(array: np.ndarray, name: str) -> np.ndarray:
    """Check a (..., N, 3) finite float array."""
    array = np.asarray(array, dtype=float)
    if array.ndim < 2 or array.shape[-1] != 3:
        msg = f'{name} must have shape (N, 3) or (F, N, 3), got {array.shape}'
        raise InputError(msg)
    if not np.all(np.isfinite(array)):
        msg = f'{name} holds NaN or Inf'
        raise InputError(msg)
    return array


def _normalised_weights(weights: np.ndarray | None, num_nodes: int) -> np.ndarray:
    """(N,) weights summing to 1; equal weights for None."""
    if weights is None:
        return np.full(num_nodes, 1.0 / num_nodes)
    w = np.asarray(weights, dtype=float)
    if w.shape != (num_nodes,) or not np.all(np.isfinite(w)) or np.any(w < 0.0):
        msg = f'weights must be {num_nodes} finite non-negative values, got {weights!r}'
        raise InputError(msg)
    if np.count_nonzero(w) < MIN_WEIGHTED_NODES:
        msg = f'weights must give at least {MIN_WEIGHTED_NODES} nodes a positive weight'
        raise InputError(msg)
    return w / w.sum()
