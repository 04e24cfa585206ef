"""The compiled Gauss-Newton step of the node fit (:mod:`.node_fit`, eq. 1 and 3).

One pass per frame over the residuals and the Jacobian of eq. 1 and 3 and their normal
equations, where numpy made some twenty small arrays an iteration (a tracker's one-frame fit
spent ~110 us an iteration there). Imported by :meth:`.node_fit.NodeFitProblem.fit` when it first
fits, so a process that only reads fits (a recogniser) loads no numba; compiled at that first call
(or loaded from numba's cache). The sums may be reassociated (vectorised): the steps equal
numpy's to rounding.
"""

from __future__ import annotations

import numba
import numpy as np

from face_tracking_ros.compiled import FAST


@numba.njit(**FAST)
def gauss_newton_iteration(
    mean: np.ndarray,
    bases_nodes: np.ndarray,
    nodes: np.ndarray,
    omega: np.ndarray,
    t: np.ndarray,
    coefficients: np.ndarray,
    rotation: np.ndarray,
    d_rotation: np.ndarray,
    row_scale: np.ndarray,
    prior_root: np.ndarray,
    damping: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """One damped Gauss-Newton step of (omega, t, coefficients) of every frame.

    The residuals ``sqrt(w_i) (R (mean_i + B_i c) + t - X_i)``, with the prior's rows ``L' alpha``
    after them, are linearised in (omega, t, c); the step solves the normal equations with
    ``damping`` times their diagonal added.

    Args:
        mean: (N, 3) mean shape.
        bases_nodes: (N, 3, D) the bases [S A] per node.
        nodes: (F, N, 3) target meshes, camera frame.
        omega: (F, 3) rotation vectors.
        t: (F, 3) translations.
        coefficients: (F, D) sigma then alpha.
        rotation: (F, 3, 3) R(omega).
        d_rotation: (F, 3, 3, 3) dR / d omega_k.
        row_scale: (3N,) sqrt(w_i) of every coordinate.
        prior_root: (q, q) ``L'`` of the prior on the last q coefficients ((0, 0): none).
        damping: relative Levenberg damping of the normal matrix's diagonal.

    Returns:
        ``(omega, t, coefficients, largest)``: the moved parameters and the largest step's
        magnitude (NaN if a step is).
    """
    frames, count = nodes.shape[0], nodes.shape[1]
    parameters = bases_nodes.shape[2]
    unknowns = 6 + parameters
    actions = prior_root.shape[0]
    steps = np.empty((frames, unknowns))
    shape = np.empty(3)
    row = np.empty(unknowns)
    for f in range(frames):
        normal = np.zeros((unknowns, unknowns))
        gradient = np.zeros(unknowns)
        for n in range(count):
            _model_node(mean, bases_nodes, coefficients[f], n, shape)
            for a in range(3):
                scale = row_scale[3 * n + a]
                residual = _node_residual(shape, rotation[f], t[f], nodes[f, n], a) * scale
                model_jacobian_row(shape, rotation[f], d_rotation[f], bases_nodes, n, a, row)
                for i in range(unknowns):
                    row[i] *= scale
                for i in range(unknowns):
                    gradient[i] += row[i] * residual
                    for j in range(i, unknowns):
                        normal[i, j] += row[i] * row[j]
        first = unknowns - actions  # the prior's rows: L' alpha, d/d alpha = L'
        for r in range(actions):
            residual = 0.0
            for i in range(actions):
                residual += prior_root[r, i] * coefficients[f, parameters - actions + i]
            for i in range(actions):
                gradient[first + i] += prior_root[r, i] * residual
                for j in range(i, actions):
                    normal[first + i, first + j] += prior_root[r, i] * prior_root[r, j]
        for i in range(unknowns):
            normal[i, i] += damping * normal[i, i]
            for j in range(i):
                normal[i, j] = normal[j, i]
        steps[f] = -np.linalg.solve(normal, gradient)
    largest = 0.0
    for value in steps.ravel():
        magnitude = abs(value)
        if np.isnan(magnitude) or magnitude > largest:
            largest = magnitude
    return omega + steps[:, :3], t + steps[:, 3:6], coefficients + steps[:, 6:], largest


@numba.njit(**FAST)
def rms_distances(
    mean: np.ndarray,
    bases_nodes: np.ndarray,
    nodes: np.ndarray,
    coefficients: np.ndarray,
    rotation: np.ndarray,
    t: np.ndarray,
) -> np.ndarray:
    """(F,) RMS node distance of the posed model ``R (mean + B c) + t`` to each frame's mesh.

    Args as :func:`gauss_newton_iteration`'s.
    """
    frames, count = nodes.shape[0], nodes.shape[1]
    rms = np.empty(frames)
    shape = np.empty(3)
    for f in range(frames):
        total = 0.0
        for n in range(count):
            _model_node(mean, bases_nodes, coefficients[f], n, shape)
            for a in range(3):
                residual = _node_residual(shape, rotation[f], t[f], nodes[f, n], a)
                total += residual * residual
        rms[f] = np.sqrt(total / count)
    return rms


@numba.njit(**FAST)
def model_jacobian_row(
    shape: np.ndarray,
    rotation: np.ndarray,
    d_rotation: np.ndarray,
    bases_nodes: np.ndarray,
    n: int,
    a: int,
    row: np.ndarray,
) -> None:
    """Coordinate ``a`` of node ``n`` of d(R shape + t) / d(omega, t, c), into ``row`` (6 + D,).

    Eq. 1 and 3 with ``shape = mean_n + B_n c`` (3,) the node in the face frame: the omega
    columns ``dR/domega_k shape``, the t columns the unit vector of ``a``, the coefficient
    columns ``R B_n``. Shared with the stereo tracker's face-model term
    (:func:`~face_tracking_ros.tracking.stereo_kernels.model_normal`, B = A there).

    Args:
        shape: (3,) the node in the face frame.
        rotation: (3, 3) R(omega).
        d_rotation: (3, 3, 3) dR / d omega_k.
        bases_nodes: (N, 3, D) the bases per node.
        n: the node.
        a: the coordinate (0, 1, 2).
        row: (6 + D,) written.
    """
    for k in range(3):
        row[k] = (
            d_rotation[k, a, 0] * shape[0]
            + d_rotation[k, a, 1] * shape[1]
            + d_rotation[k, a, 2] * shape[2]
        )
    for k in range(3):
        row[3 + k] = 1.0 if k == a else 0.0
    for d in range(bases_nodes.shape[2]):
        row[6 + d] = (
            rotation[a, 0] * bases_nodes[n, 0, d]
            + rotation[a, 1] * bases_nodes[n, 1, d]
            + rotation[a, 2] * bases_nodes[n, 2, d]
        )


@numba.njit(**FAST)
def _model_node(
    mean: np.ndarray, bases_nodes: np.ndarray, coefficients: np.ndarray, n: int, shape: np.ndarray
) -> None:
    """Node ``n`` of the model's shape, ``mean_n + B_n c`` (eq. 3), written into ``shape`` (3,)."""
    for c in range(3):
        value = mean[n, c]
        for d in range(bases_nodes.shape[2]):
            value += bases_nodes[n, c, d] * coefficients[d]
        shape[c] = value


@numba.njit(**FAST)
def _node_residual(
    shape: np.ndarray, rotation: np.ndarray, t: np.ndarray, node: np.ndarray, a: int
) -> float:
    """Coordinate ``a`` of ``R shape + t - node``: a node's residual of eq. 1."""
    return (
        shape[0] * rotation[a, 0]
        + shape[1] * rotation[a, 1]
        + shape[2] * rotation[a, 2]
        + t[a]
        - node[a]
    )
