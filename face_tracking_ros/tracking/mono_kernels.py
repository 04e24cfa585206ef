"""Compiled (numba) inner loops of the monocular tracker's eq. 6 solve.

The monocular tracker's per-frame budget (2 ms at 640x480 with 34 nodes, issue 6) is below what
numpy's per-call overhead allows: a frame made ~2000 array operations on arrays of a few
thousand elements, so the call overhead cost more than the arithmetic. The loops over the ROI
samples that run at every Levenberg-Marquardt iteration are therefore compiled, each one pass
over the samples of a pyramid level:

- :func:`roi_points`: the ROI samples of every node moved by eq. 3 and mapped through eq. 1-2;
  :func:`roi_maps` adds what sampling them takes (``cv2.remap``'s maps, with the central
  differences' points for a linearisation, the inside mask and the box the pixels span);
- :func:`roi_jacobian`: their Jacobian with respect to (omega, t, c), the chain rule of
  :mod:`.projection` contracted with the image gradient; :func:`linearised` makes the whole
  linearisation of a level in one call: the gradient from the stencil's samples, the Jacobian,
  its rows' photometric projection and ``J' V J``;
- :func:`huber_irls`, :func:`normal_equations`, :func:`weighted_gram`: eq. 6's robust cost and
  its IRLS normal equations;
- :func:`damped_step`: the Levenberg-Marquardt step; :func:`iteration` makes a whole iteration
  from a level's samples in one call: the projected residuals, the robust scale, the normal
  equations with the priors (:func:`prior_terms`) and the step;
- :func:`condition_number`: the loss check's condition number of the solution's normal matrix;
  :func:`node_visibility`: the nodes' visibility weights.

A level's linearisation is thus two compiled calls around one ``cv2.remap``, an iteration two
around another (the points, then :func:`iteration`): the Python glue between kernels cost as
much as the kernels.

Arrays are component-major (one contiguous row per coordinate or parameter), and the loops run
along a node's M samples, so the compiler vectorises them. Kernels are typed (compiled when this
module is imported, from numba's on-disk cache when it holds them), but for those a replay may
not need: the ones only other kernels call (:func:`weighted_gram`, :func:`damped_step`,
:func:`normal_equations`: compiled into their callers) and those of a float32 or float64
template (:func:`iteration`'s, :func:`point_cost`, :func:`blended_template`) are compiled, or
loaded, at their first call for the types they are called with (loading each from the cache
took 3-16 ms of a replay's start; :func:`prior_terms` and ``_rms`` so changed the tracker's
results in the last bits, and stay typed). Their floating point may be reassociated and
contracted (fused multiply-add) but keeps IEEE infinities and NaNs, so they agree with the numpy
expressions of the same equations to rounding and a diverged solve still shows.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np
from numpy.linalg import LinAlgError

from face_tracking_ros.compiled import EXACT, FAST
from face_tracking_ros.imaging.photometric import (
    project_out,
    project_out_row,
    projected_difference,
)
from face_tracking_ros.tracking.pixel_box import span

MAD_TO_STD = 1.4826  # robust standard deviation from the median absolute deviation


@numba.njit(**FAST)
def _left_jacobian(rotation: np.ndarray, d_rotation: np.ndarray) -> np.ndarray:
    """(3, 3) matrix of columns j_k with ``dR/domega_k = [j_k]x R`` (eq. 1).

    ``dR/domega_k R'`` is the skew-symmetric ``[j_k]x``; its (2, 1), (0, 2) and (1, 0) entries
    are j_k.
    """
    left = np.empty((3, 3))
    for k in range(3):
        for a, (row, column) in enumerate(((2, 1), (0, 2), (1, 0))):
            left[a, k] = (
                d_rotation[k, row, 0] * rotation[column, 0]
                + d_rotation[k, row, 1] * rotation[column, 1]
                + d_rotation[k, row, 2] * rotation[column, 2]
            )
    return left


@numba.njit(**FAST)
def _node_jacobian(
    camera: np.ndarray,
    rotation: np.ndarray,
    left_jacobian: np.ndarray,
    t: np.ndarray,
    rotated_nodes: np.ndarray,
    node_basis: np.ndarray,
    out: np.ndarray,
) -> None:
    """(2 N, 6 + c) Jacobian of the node pixels (eq. 1-3) into ``out``, level px.

    Rows 2 n and 2 n + 1 are the chain of :func:`roi_jacobian` at node n with the image
    gradient g = (1, 0) and (0, 1), the node moving with its basis B_n alone:
    ``h = (P_axis - x_axis P_3) / h_3``.
    """
    homogeneous = np.empty(3)
    for n in range(rotated_nodes.shape[1]):
        x, y, z = rotated_nodes[0, n], rotated_nodes[1, n], rotated_nodes[2, n]
        point = (x + t[0], y + t[1], z + t[2])
        for a in range(3):
            homogeneous[a] = camera[a, 3]
            for b in range(3):
                homogeneous[a] += camera[a, b] * point[b]
        for axis in range(2):
            pixel = homogeneous[axis] / homogeneous[2]
            h_0 = (camera[axis, 0] - pixel * camera[2, 0]) / homogeneous[2]
            h_1 = (camera[axis, 1] - pixel * camera[2, 1]) / homogeneous[2]
            h_2 = (camera[axis, 2] - pixel * camera[2, 2]) / homogeneous[2]
            moment = (y * h_2 - z * h_1, z * h_0 - x * h_2, x * h_1 - y * h_0)
            row = out[2 * n + axis]
            for k in range(3):
                row[k] = (
                    left_jacobian[0, k] * moment[0]
                    + left_jacobian[1, k] * moment[1]
                    + left_jacobian[2, k] * moment[2]
                )
            row[3], row[4], row[5] = h_0, h_1, h_2
            chain = (
                rotation[0, 0] * h_0 + rotation[1, 0] * h_1 + rotation[2, 0] * h_2,
                rotation[0, 1] * h_0 + rotation[1, 1] * h_1 + rotation[2, 1] * h_2,
                rotation[0, 2] * h_0 + rotation[1, 2] * h_1 + rotation[2, 2] * h_2,
            )
            for j in range(node_basis.shape[2]):
                row[6 + j] = (
                    node_basis[n, 0, j] * chain[0]
                    + node_basis[n, 1, j] * chain[1]
                    + node_basis[n, 2, j] * chain[2]
                )


@numba.njit(
    'Tuple((f8[:, :, ::1], f4[:, :, ::1]))(f8[:, ::1], f8[:, ::1], f8[::1], f8[:, ::1], '
    'f8[:, :, ::1], f8[:, :, :, ::1], f8[::1], f8[:, :, :, ::1], f8[::1])',
    **FAST,
)
def roi_points(
    rotation: np.ndarray,
    shape: np.ndarray,
    t: np.ndarray,
    camera: np.ndarray,
    offsets: np.ndarray,
    action: np.ndarray,
    alpha: np.ndarray,
    identity: np.ndarray,
    sigma_change: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """ROI sample points in the camera frame (eq. 1, 3) and their pixels (eq. 2).

    Sample m of node n sits at ``P = shape_n + offset_nm + A_nm alpha + S_nm (sigma - sigma_0)``
    in the face frame (the ROI deforming with eq. 3); eq. 1 rotates it, ``R P``, and eq. 2 maps
    ``R P + t`` to ``(h_1 / h_3, h_2 / h_3)`` with ``h = (P_3 R) P + P_3 t + p_4`` for the camera
    matrix ``[P_3 | p_4]``.

    Args:
        rotation: (3, 3) R(omega).
        shape: (N, 3) nodes of eq. 3 at (sigma, alpha), m.
        t: (3,) translation of eq. 1, m.
        camera: (3, 4) projection matrix of the pixels wanted (a pyramid level's).
        offsets: (3, N, M) offsets from the nodes to their samples at alpha = 0, sigma_0, m.
        action: (q, 3, N, M) derivative of the offsets with respect to alpha.
        alpha: (q,) expression coefficients.
        identity: (p, 3, N, M) derivative of the offsets with respect to sigma.
        sigma_change: (p,) ``sigma - sigma_0`` (all zero while sigma is held fixed).

    Returns:
        ``(rotated, pixels)``: (3, N, M) ``R P``, m, and (2, N, M) float32 pixels (x, then y).
    """
    count, size = offsets.shape[1], offsets.shape[2]
    rotated = np.empty((3, count, size))
    pixels = np.empty((2, count, size), dtype=np.float32)
    moves_sigma = np.any(sigma_change != 0.0)
    # [P_3 R | P_3 t + p_4] maps the face-frame points to homogeneous pixels.
    mapping = np.zeros((3, 4))
    for a in range(3):
        mapping[a, 3] = camera[a, 3]
        for b in range(3):
            mapping[a, 3] += camera[a, b] * t[b]
            for c in range(3):
                mapping[a, c] += camera[a, b] * rotation[b, c]
    face = np.empty((3, size))  # P of one node's samples
    r_00, r_01, r_02 = rotation[0, 0], rotation[0, 1], rotation[0, 2]
    r_10, r_11, r_12 = rotation[1, 0], rotation[1, 1], rotation[1, 2]
    r_20, r_21, r_22 = rotation[2, 0], rotation[2, 1], rotation[2, 2]
    for n in range(count):
        for a in range(3):
            point, offset, node = face[a], offsets[a, n], shape[n, a]
            for m in range(size):
                point[m] = offset[m] + node
            for k in range(alpha.size):
                weight, basis = alpha[k], action[k, a, n]
                for m in range(size):
                    point[m] += weight * basis[m]
            if moves_sigma:
                for k in range(sigma_change.size):
                    weight, basis = sigma_change[k], identity[k, a, n]
                    for m in range(size):
                        point[m] += weight * basis[m]
        x_row, y_row = pixels[0, n], pixels[1, n]
        rotated_x, rotated_y, rotated_z = rotated[0, n], rotated[1, n], rotated[2, n]
        face_x, face_y, face_z = face[0], face[1], face[2]
        m_00, m_01, m_02, m_03 = mapping[0, 0], mapping[0, 1], mapping[0, 2], mapping[0, 3]
        m_10, m_11, m_12, m_13 = mapping[1, 0], mapping[1, 1], mapping[1, 2], mapping[1, 3]
        m_20, m_21, m_22, m_23 = mapping[2, 0], mapping[2, 1], mapping[2, 2], mapping[2, 3]
        # R P and the pixels in one pass over contiguous rows (rotated[:, n] is not one).
        for m in range(size):
            x, y, z = face_x[m], face_y[m], face_z[m]
            rotated_x[m] = r_00 * x + r_01 * y + r_02 * z
            rotated_y[m] = r_10 * x + r_11 * y + r_12 * z
            rotated_z[m] = r_20 * x + r_21 * y + r_22 * z
            inverse_depth = 1.0 / (m_20 * x + m_21 * y + m_22 * z + m_23)
            x_row[m] = (m_00 * x + m_01 * y + m_02 * z + m_03) * inverse_depth
            y_row[m] = (m_10 * x + m_11 * y + m_12 * z + m_13) * inverse_depth
    return rotated, pixels


@numba.njit('f8[::1](f8[:, :], f8[:, ::1], f8[:, ::1], f8)', **FAST)
def node_visibility(
    normals: np.ndarray, rotation: np.ndarray, nodes: np.ndarray, low: float
) -> np.ndarray:
    """(N,) weights in [0, 1]: ``clip((c - low) / max(low, 1e-6), 0, 1)`` per node.

    c is the cosine between node n's outward normal turned by R (eq. 1) and the ray from the node
    to the camera, ``-(R n_n) . X_n / |X_n|``.

    Args:
        normals: (N, 3) outward node normals, face frame.
        rotation: (3, 3) R(omega).
        nodes: (N, 3) camera-frame nodes X_n, m.
        low: the cosine where the weight starts to rise from 0 (it reaches 1 at twice it).
    """
    weights = np.empty(len(nodes))
    ramp = max(low, 1e-6)
    for n in range(len(nodes)):
        x, y, z = nodes[n, 0], nodes[n, 1], nodes[n, 2]
        facing = 0.0
        for a in range(3):
            turned = (
                rotation[a, 0] * normals[n, 0]
                + rotation[a, 1] * normals[n, 1]
                + rotation[a, 2] * normals[n, 2]
            )
            facing -= turned * nodes[n, a]
        weight = (facing / np.sqrt(x * x + y * y + z * z) - low) / ramp
        weights[n] = 0.0 if weight < 0.0 else (1.0 if weight > 1.0 else weight)  # NaN stays
    return weights


@numba.njit(
    'Tuple((f8[:, :, ::1], f4[:, ::1], f4[:, ::1], b1[:, ::1], f4[::1]))(f8[:, ::1], f8[:, ::1], '
    'f8[::1], f8[:, ::1], f8[:, :, ::1], f8[:, :, :, ::1], f8[::1], f8[:, :, :, ::1], f8[::1], '
    'b1, f8, f8, f8)',
    **FAST,
)
def roi_maps(
    rotation: np.ndarray,
    shape: np.ndarray,
    t: np.ndarray,
    camera: np.ndarray,
    offsets: np.ndarray,
    action: np.ndarray,
    alpha: np.ndarray,
    identity: np.ndarray,
    sigma_change: np.ndarray,
    stencil: bool,
    width: float,
    height: float,
    margin: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The ROI points of :func:`roi_points` with what sampling them takes, in one pass.

    The ``cv2.remap`` maps of the pixels (eq. 2) and, for ``stencil``, of the central
    differences' points one pixel either side (+x, -x, +y, -y, as
    :func:`~face_tracking_ros.imaging.sample_with_gradient_xy` takes them); which samples lie
    ``margin`` px inside a (height, width) image (:func:`~face_tracking_ros.imaging.inside_xy`);
    and the box the pixels span, which the pyramid makes level 0 over
    (:meth:`~face_tracking_ros.imaging.ImagePyramid.level_reaching`).

    Args:
        rotation: (3, 3) R(omega).
        shape: (N, 3) nodes of eq. 3 at (sigma, alpha), m.
        t: (3,) translation of eq. 1, m.
        camera: (3, 4) projection matrix of the level's pixels.
        offsets: (3, N, M) offsets from the nodes to their samples at alpha = 0, sigma_0, m.
        action: (q, 3, N, M) derivative of the offsets with respect to alpha.
        alpha: (q,) expression coefficients.
        identity: (p, 3, N, M) derivative of the offsets with respect to sigma.
        sigma_change: (p,) ``sigma - sigma_0``.
        stencil: whether the maps hold the central differences' points too.
        width: the level's width, px.
        height: the level's height, px.
        margin: px a sample must lie inside the image.

    Returns:
        ``(rotated, map_x, map_y, inside, box)``: (3, N, M) ``R P``, m; (S, N M) float32 x and
        y maps, row 0 the pixels and for ``stencil`` (S = 5) rows 1-4 the stencil's points;
        (N, M) inside mask; (4,) float32 least and greatest x, then y, of the pixels (NaN if
        any is not finite).
    """
    rotated, pixels = roi_points(
        rotation, shape, t, camera, offsets, action, alpha, identity, sigma_change
    )
    count, size = pixels.shape[1], pixels.shape[2]
    inside = np.empty((count, size), dtype=np.bool_)
    finite = 0.0  # NaN once a pixel is not finite
    right, bottom = width - 1 - margin, height - 1 - margin
    for n in range(count):
        x_row, y_row, inside_row = pixels[0, n], pixels[1, n], inside[n]
        for m in range(size):
            x, y = x_row[m], y_row[m]
            finite += x * 0.0 + y * 0.0
            inside_row[m] = (x >= margin) & (y >= margin) & (x <= right) & (y <= bottom)
    points_x, points_y = pixels[0].reshape(count * size), pixels[1].reshape(count * size)
    box = np.array([*span(points_x), *span(points_y)], dtype=np.float32)
    if not np.isfinite(finite):
        box[:] = np.nan
    if not stencil:
        return rotated, points_x.reshape(1, -1), points_y.reshape(1, -1), inside, box
    # The stencil's points as float32 sums, x + 0 too (-0 becomes +0), as numpy makes them.
    map_x = np.empty((5, count * size), dtype=np.float32)
    map_y = np.empty((5, count * size), dtype=np.float32)
    for row, (shift_x, shift_y) in enumerate(((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1))):
        step_x, step_y = np.float32(shift_x), np.float32(shift_y)
        out_x, out_y = map_x[row], map_y[row]
        for i in range(count * size):
            out_x[i] = points_x[i] + step_x
            out_y[i] = points_y[i] + step_y
    return rotated, map_x, map_y, inside, box


@numba.njit(
    'Tuple((f8[:, :, ::1], f8[:, ::1]))(f8[:, :, ::1], f8[:, ::1], f8[::1], f8[:, ::1], '
    'f4[:, :, ::1], f8[:, ::1], f8[:, :, ::1], f8[:, :, ::1], f8[:, :, :, ::1])',
    **FAST,
)
def roi_jacobian(
    rotated: np.ndarray,
    rotated_nodes: np.ndarray,
    t: np.ndarray,
    camera: np.ndarray,
    gradient: np.ndarray,
    rotation: np.ndarray,
    d_rotation: np.ndarray,
    node_basis: np.ndarray,
    sample_basis: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Jacobian of the ROI samples ``I(pi(R P + t))`` with respect to (omega, t, c).

    The chain rule of eq. 1-3 contracted with the image gradient g first: per sample,
    ``h = (P_(1,2)' g - (g . x) P_3) / h_3`` carries g to the camera-frame point (eq. 2,
    :func:`~.stereo_kernels.space_rows`); the omega rows are ``j_k . (R P x h)`` (eq. 1,
    ``dR/domega_k = [j_k]x R``), the t rows ``h`` and the coefficient rows
    ``(R' h)' (B_n + D_nm)`` (eq. 3), B_n the node's basis and D_nm the sample's own deformation
    (:func:`~.surface_patches.patch_basis`). The node pixels' Jacobian comes with it, to
    measure how far a step moves the nodes.

    Args:
        rotated: (3, N, M) ``R P`` of the ROI samples, m.
        rotated_nodes: (3, N) ``R X_n`` of the nodes, m.
        t: (3,) translation, m.
        camera: (3, 4) projection matrix of the level's pixels.
        gradient: (2, N, M) float32 image gradient at the samples, grey levels per level px.
        rotation: (3, 3) R(omega).
        d_rotation: (3, 3, 3) dR/domega_k (:func:`~face_tracking_ros.geometry.rotation.rodrigues`).
        node_basis: (N, 3, c) derivative of eq. 3's nodes with respect to the coefficients.
        sample_basis: (c, 3, N, M) derivative of the samples' offsets from their nodes.

    Returns:
        ``(jacobian, node_jacobian)``: (6 + c, N, M) Jacobian of the samples (grey levels per
        rad, per m, per unit coefficient) and (2 N, 6 + c) Jacobian of the node pixels (row 2 n
        for x, 2 n + 1 for y), level px.
    """
    count, size = rotated.shape[1], rotated.shape[2]
    coefficients = node_basis.shape[2]
    jacobian = np.empty((6 + coefficients, count, size))
    node_jacobian = np.empty((2 * count, 6 + coefficients))
    left_jacobian = _left_jacobian(rotation, d_rotation)
    _node_jacobian(camera, rotation, left_jacobian, t, rotated_nodes, node_basis, node_jacobian)
    # The small matrices as scalars: the loops below then hold them in registers.
    p_00, p_01, p_02, p_03 = camera[0, 0], camera[0, 1], camera[0, 2], camera[0, 3]
    p_10, p_11, p_12, p_13 = camera[1, 0], camera[1, 1], camera[1, 2], camera[1, 3]
    p_20, p_21, p_22, p_23 = camera[2, 0], camera[2, 1], camera[2, 2], camera[2, 3]
    l_00, l_01, l_02 = left_jacobian[0, 0], left_jacobian[0, 1], left_jacobian[0, 2]
    l_10, l_11, l_12 = left_jacobian[1, 0], left_jacobian[1, 1], left_jacobian[1, 2]
    l_20, l_21, l_22 = left_jacobian[2, 0], left_jacobian[2, 1], left_jacobian[2, 2]
    r_00, r_01, r_02 = rotation[0, 0], rotation[0, 1], rotation[0, 2]
    r_10, r_11, r_12 = rotation[1, 0], rotation[1, 1], rotation[1, 2]
    r_20, r_21, r_22 = rotation[2, 0], rotation[2, 1], rotation[2, 2]
    t_0, t_1, t_2 = t[0], t[1], t[2]
    chain = np.empty((3, size))  # R' h of one node's samples
    chain_0, chain_1, chain_2 = chain[0], chain[1], chain[2]
    for n in range(count):
        x_row, y_row, z_row = rotated[0, n], rotated[1, n], rotated[2, n]
        g_x, g_y = gradient[0, n], gradient[1, n]
        omega_0, omega_1, omega_2 = jacobian[0, n], jacobian[1, n], jacobian[2, n]
        h_x, h_y, h_z = jacobian[3, n], jacobian[4, n], jacobian[5, n]
        for m in range(size):
            x, y, z = x_row[m], y_row[m], z_row[m]
            x_c, y_c, z_c = x + t_0, y + t_1, z + t_2
            u = p_00 * x_c + p_01 * y_c + p_02 * z_c + p_03
            v = p_10 * x_c + p_11 * y_c + p_12 * z_c + p_13
            inverse_depth = 1.0 / (p_20 * x_c + p_21 * y_c + p_22 * z_c + p_23)
            along = (g_x[m] * u + g_y[m] * v) * inverse_depth
            h_0 = (p_00 * g_x[m] + p_10 * g_y[m] - p_20 * along) * inverse_depth
            h_1 = (p_01 * g_x[m] + p_11 * g_y[m] - p_21 * along) * inverse_depth
            h_2 = (p_02 * g_x[m] + p_12 * g_y[m] - p_22 * along) * inverse_depth
            moment_0, moment_1, moment_2 = y * h_2 - z * h_1, z * h_0 - x * h_2, x * h_1 - y * h_0
            omega_0[m] = l_00 * moment_0 + l_10 * moment_1 + l_20 * moment_2
            omega_1[m] = l_01 * moment_0 + l_11 * moment_1 + l_21 * moment_2
            omega_2[m] = l_02 * moment_0 + l_12 * moment_1 + l_22 * moment_2
            h_x[m], h_y[m], h_z[m] = h_0, h_1, h_2
            chain_0[m] = r_00 * h_0 + r_10 * h_1 + r_20 * h_2
            chain_1[m] = r_01 * h_0 + r_11 * h_1 + r_21 * h_2
            chain_2[m] = r_02 * h_0 + r_12 * h_1 + r_22 * h_2
        for j in range(coefficients):
            row = jacobian[6 + j, n]
            b_0, b_1, b_2 = node_basis[n, 0, j], node_basis[n, 1, j], node_basis[n, 2, j]
            d_0, d_1, d_2 = sample_basis[j, 0, n], sample_basis[j, 1, n], sample_basis[j, 2, n]
            for m in range(size):
                row[m] = (
                    (b_0 + d_0[m]) * chain_0[m]
                    + (b_1 + d_1[m]) * chain_1[m]
                    + (b_2 + d_2[m]) * chain_2[m]
                )
    return jacobian, node_jacobian


@numba.njit(**FAST)
def weighted_gram(jacobian_t: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``J' W J`` of eq. 6's normal equations: (P, K) rows J' of K samples, (K,) weights W.

    Returns:
        (P, P) symmetric matrix.
    """
    size, count = jacobian_t.shape
    gram = np.empty((size, size))
    weighted = np.empty(count)
    for a in range(size):
        row = jacobian_t[a]
        for i in range(count):
            weighted[i] = row[i] * weights[i]
        for b in range(a, size):
            other = jacobian_t[b]
            total = 0.0
            for i in range(count):
                total += weighted[i] * other[i]
            gram[a, b] = total
            gram[b, a] = total
    return gram


@numba.njit('Tuple((f8[::1], f8))(f8[:, ::1], f8[:, ::1], f8, f8)', **FAST)
def huber_irls(
    residuals: np.ndarray, weights: np.ndarray, scale: float, k: float
) -> tuple[np.ndarray, float]:
    """IRLS weights and cost of the Huber loss on eq. 6's residuals r with sample weights w.

    With ``u = |r| / s``, the loss is ``rho(u) = u^2`` inside k and ``2 k u - k^2`` outside, its
    IRLS weight ``min(1, k / u)``.

    Args:
        residuals: (N, M) residuals r, grey levels.
        weights: (N, M) sample weights w (visibility, inside the image).
        scale: the robust residual scale s, grey levels.
        k: the Huber threshold, in units of s.

    Returns:
        ``(irls, cost)``: (N M,) weights ``w min(1, k / u)`` and ``sum w rho(u)``.
    """
    flat_residuals, flat_weights = residuals.ravel(), weights.ravel()
    irls = np.empty(flat_residuals.size)
    cost = 0.0
    for i in range(flat_residuals.size):
        magnitude = abs(flat_residuals[i]) / scale
        if magnitude <= k:
            irls[i] = flat_weights[i]
            cost += flat_weights[i] * magnitude * magnitude
        else:
            irls[i] = flat_weights[i] * (k / magnitude)
            cost += flat_weights[i] * (2.0 * k * magnitude - k * k)
    return irls, cost


@numba.njit(**FAST)
def damped_step(hessian: np.ndarray, gradient: np.ndarray, damping: float) -> np.ndarray:
    """Levenberg-Marquardt step ``-(H + lambda diag H)^-1 g``, solved Jacobi-scaled.

    With ``S = diag(H)^-1/2``, the step is ``-S (S H S + lambda I)^-1 S g``.

    Args:
        hessian: (P, P) normal matrix H (halved Hessian of the cost).
        gradient: (P,) g (halved gradient).
        damping: lambda, relative to diag(H).

    Raises:
        LinAlgError: if H or g is not finite, or the damped matrix is not positive definite.
    """
    size = gradient.size
    if not (np.all(np.isfinite(hessian)) and np.all(np.isfinite(gradient))):
        raise LinAlgError('non-finite normal equations')
    scaling = np.empty(size)
    for a in range(size):
        scaling[a] = 1.0 / np.sqrt(max(hessian[a, a], 1e-12))
    # S H S + lambda I is symmetric positive definite (H = J' W J + the prior's precision, W >= 0):
    # its Cholesky factor L (lower triangle), then two triangular solves.
    factor = np.zeros((size, size))
    for a in range(size):
        for b in range(a + 1):
            total = hessian[a, b] * scaling[a] * scaling[b] + (damping if a == b else 0.0)
            for c in range(b):
                total -= factor[a, c] * factor[b, c]
            if a > b:
                factor[a, b] = total / factor[b, b]
            elif total > 0.0:
                factor[a, a] = np.sqrt(total)
            else:
                raise LinAlgError('damped normal matrix not positive definite')
    step = gradient * scaling
    for a in range(size):
        for c in range(a):
            step[a] -= factor[a, c] * step[c]
        step[a] /= factor[a, a]
    for a in range(size - 1, -1, -1):
        for c in range(a + 1, size):
            step[a] -= factor[c, a] * step[c]
        step[a] /= factor[a, a]
    return -scaling * step


@numba.njit(**FAST)
def normal_equations(
    jacobian_t: np.ndarray,
    residuals: np.ndarray,
    weights: np.ndarray,
    visibility: np.ndarray,
    scale: float,
    k: float,
    visible_hessian: np.ndarray,
) -> tuple[float, np.ndarray, np.ndarray]:
    """Huber cost and IRLS normal equations of eq. 6's data term on one pyramid level.

    With W the IRLS weights of :func:`huber_irls`, ``H = J' W J / s^2`` and ``g = J' W r / s^2``;
    ``J' W J`` is ``visible_hessian`` (``J' V J`` with the visibility weights V alone) plus the
    samples whose weight W differs from V.

    Args:
        jacobian_t: (P, N M) transposed Jacobian J' of the residuals.
        residuals: (N, M) residuals r.
        weights: (N, M) sample weights (visibility times inside the image).
        visibility: (N, M) visibility weights V.
        scale: the robust residual scale s.
        k: the Huber threshold, in units of s.
        visible_hessian: (P, P) ``J' V J``.

    Returns:
        ``(cost, H, g)``: the data cost ``sum w rho(|r| / s)``, (P, P) H and (P,) g.
    """
    irls, cost = huber_irls(residuals, weights, scale, k)
    flat_residuals, flat_visibility = residuals.ravel(), visibility.ravel()
    size, count = jacobian_t.shape
    changed = np.flatnonzero(irls != flat_visibility)
    columns = np.empty((size, changed.size))
    for a in range(size):
        row = jacobian_t[a]
        for i in range(changed.size):
            columns[a, i] = row[changed[i]]
    hessian = weighted_gram(columns, irls[changed] - flat_visibility[changed])
    inverse_variance = 1.0 / (scale * scale)
    gradient = np.empty(size)
    for a in range(size):
        row = jacobian_t[a]
        total = 0.0
        for i in range(count):
            total += row[i] * irls[i] * flat_residuals[i]
        gradient[a] = total * inverse_variance
        for b in range(size):
            hessian[a, b] = (visible_hessian[a, b] + hessian[a, b]) * inverse_variance
    return cost, hessian, gradient


@numba.njit('Tuple((f8, f8[::1]))(f8[:, ::1], f8[::1])', **EXACT)
def prior_terms(prior_hessian: np.ndarray, coefficients: np.ndarray) -> tuple[float, np.ndarray]:
    """The priors' cost ``x' L x`` and halved gradient ``L x`` (:class:`~.mono_priors.Priors`).

    Args:
        prior_hessian: (P, P) the priors' precision L padded to the pose (zero over it).
        coefficients: (P - 6,) x: alpha (then sigma).

    Returns:
        ``(cost, L x)``, the latter (P - 6,).
    """
    first = prior_hessian.shape[0] - coefficients.size
    gradient = np.empty(coefficients.size)
    cost = 0.0
    for a in range(coefficients.size):
        total = 0.0
        for b in range(coefficients.size):
            total += prior_hessian[first + a, first + b] * coefficients[b]
        gradient[a] = total
        cost += coefficients[a] * total
    return cost, gradient


@numba.njit(**FAST)
def point_cost(
    samples: np.ndarray,
    template: np.ndarray,
    basis_rows: np.ndarray,
    node_weights: np.ndarray,
    inside: np.ndarray,
    scale: float,
    k: float,
    prior_hessian: np.ndarray,
    coefficients: np.ndarray,
) -> tuple[np.ndarray, float]:
    """The cost of eq. 6 and the priors at a point, and its residuals, in one compiled call.

    What an iteration (:func:`iteration`) costs a point without its normal equations: for the
    point a level's last step reached, which no iteration evaluated.

    Args:
        samples: (N, M) float32 samples of the level at the point.
        template: (N, M) float32 or float64 template T.
        basis_rows: (N, K, M) orthonormal rows U' of each patch's brightness changes.
        node_weights: (N,) weight of each node's ROI.
        inside: (N, M) the samples inside the image (the others weigh 0).
        scale: the robust residual scale s.
        k: the Huber threshold, in units of s.
        prior_hessian: (P, P) the priors' precision L, zero over the pose.
        coefficients: (P - 6,) alpha (then sigma) at the point.

    Returns:
        ``(residuals, cost)``: the (N, M) residuals ``(1 - P) (I - T)`` and the Huber cost
        (:func:`huber_irls`) with sample weights ``node_weights`` times ``inside``, plus the
        priors' ``x' L x`` (:func:`prior_terms`).
    """
    residuals = projected_difference(samples, template, basis_rows)
    count, size = samples.shape
    weights = np.empty((count, size))
    for n in range(count):
        for m in range(size):
            weights[n, m] = node_weights[n] * inside[n, m]
    cost = huber_irls(residuals, weights, scale, k)[1]
    return residuals, cost + prior_terms(prior_hessian, coefficients)[0]


class Iteration(NamedTuple):
    """What :func:`iteration` makes of one Levenberg-Marquardt iteration (see there)."""

    residuals: np.ndarray
    cost: float
    hessian: np.ndarray
    scale: float
    step: np.ndarray
    motion: float


@numba.njit(**FAST)
def _iteration(
    samples: np.ndarray,
    template: np.ndarray,
    basis_rows: np.ndarray,
    visibility: np.ndarray,
    inside: np.ndarray,
    scale: float,
    scale_floor: float,
    k: float,
    jacobian_t: np.ndarray,
    visible_hessian: np.ndarray,
    prior_hessian: np.ndarray,
    coefficients: np.ndarray,
    damping: float,
    accepted_cost: float,
    node_jacobian: np.ndarray,
) -> tuple[np.ndarray, float, np.ndarray, float, np.ndarray, float]:
    """:func:`iteration`'s work on its arguments as arrays (NaN ``scale``: estimate it)."""
    count, size = samples.shape
    residuals = np.empty((count, size))
    weights = np.empty((count, size))
    projection_weights = np.empty(basis_rows.shape[1])
    active = np.empty(count * size)
    found = 0
    for n in range(count):
        row = residuals[n]
        for m in range(size):
            row[m] = samples[n, m] - template[n, m]
        project_out_row(row, basis_rows[n], projection_weights)
        for m in range(size):
            weights[n, m] = visibility[n, m] * inside[n, m]
            if weights[n, m] > 0.0:
                active[found] = abs(row[m])
                found += 1
    if np.isnan(scale):
        spread = MAD_TO_STD * np.median(active[:found]) if found else 0.0
        scale = max(scale_floor, spread)
    cost, hessian, gradient = normal_equations(
        jacobian_t, residuals, weights, visibility, scale, k, visible_hessian
    )
    prior_cost, prior_gradient = prior_terms(prior_hessian, coefficients)
    cost += prior_cost
    first = gradient.size - coefficients.size
    for a in range(first, gradient.size):
        gradient[a] += prior_gradient[a - first]
    for a in range(gradient.size):
        for b in range(gradient.size):
            hessian[a, b] += prior_hessian[a, b]
    if cost > accepted_cost:  # the level ends before this point: no step from it
        return residuals, cost, hessian, scale, np.empty(0), 0.0
    step = damped_step(hessian, gradient, damping)
    motion = 0.0
    for i in range(node_jacobian.shape[0]):
        total = 0.0
        for a in range(step.size):
            total += node_jacobian[i, a] * step[a]
        motion = max(motion, abs(total))
    return residuals, cost, hessian, scale, step, motion


def iteration(
    samples: np.ndarray,
    template: np.ndarray,
    basis_rows: np.ndarray,
    visibility: np.ndarray,
    inside: np.ndarray,
    scale: float | None,
    scale_floor: float,
    k: float,
    linear: tuple[np.ndarray, np.ndarray, np.ndarray],
    prior_hessian: np.ndarray,
    coefficients: np.ndarray,
    damping: float,
    accepted_cost: float,
) -> Iteration:
    """One Levenberg-Marquardt iteration of eq. 6 on a pyramid level, in one compiled pass.

    From the level's samples at the iteration's point: the residuals ``(1 - P) (I - T)``
    (photometrically projected, :func:`~face_tracking_ros.imaging.photometric.project_out`); the
    robust scale s if not given (``max(scale_floor, 1.4826 median |r|)`` over the samples of
    nonzero weight); the Huber cost and IRLS normal equations (:func:`normal_equations`) with the
    priors' ``x' L x``, ``L x`` and L added; and, unless the cost exceeds ``accepted_cost``, the
    damped step (:func:`damped_step`) and the most it moves a node, level px.

    Args:
        samples: (N, M) float32 samples of the level at the point.
        template: (N, M) float32 or float64 template T.
        basis_rows: (N, K, M) orthonormal rows U' of each patch's brightness changes.
        visibility: (N, M) the samples' visibility weights V.
        inside: (N, M) the samples inside the image (the others weigh 0).
        scale: the robust residual scale s, or None to estimate it from these residuals.
        scale_floor: the least estimated s.
        k: the Huber threshold, in units of s.
        linear: the linearisation's (P, N M) projected J', (P, P) ``J' V J`` and (2 N, P) node
            Jacobian.
        prior_hessian: (P, P) the priors' precision L, zero over the pose.
        coefficients: (P - 6,) alpha (then sigma) at the point.
        damping: lambda of the step, relative to diag(H).
        accepted_cost: the cost of the level's last accepted point (inf for none).

    Returns:
        The :class:`Iteration`: (N, M) residuals, the cost (data plus priors), (P, P) H, the
        scale, the (P,) step (empty when the cost rose) and its largest node motion.

    Raises:
        LinAlgError: as :func:`damped_step`.
    """
    jacobian_t, visible_hessian, node_jacobian = linear
    return Iteration(
        *_iteration(
            samples,
            template,
            basis_rows,
            visibility,
            inside,
            np.nan if scale is None else scale,
            scale_floor,
            k,
            jacobian_t,
            visible_hessian,
            prior_hessian,
            coefficients,
            damping,
            accepted_cost,
            node_jacobian,
        )
    )


@numba.njit(
    'Tuple((f8[:, ::1], f8[:, ::1], f8[:, ::1]))(f4[:, ::1], f8[:, :, ::1], f8[:, ::1], '
    'f8[::1], f8[:, ::1], f8[:, ::1], f8[:, :, ::1], f8[:, :, ::1], f8[:, :, :, ::1], '
    'f8[:, :, ::1], f8[::1])',
    **FAST,
)
def linearised(
    stencil: np.ndarray,
    rotated: np.ndarray,
    rotated_nodes: np.ndarray,
    t: np.ndarray,
    camera: np.ndarray,
    rotation: np.ndarray,
    d_rotation: np.ndarray,
    node_basis: np.ndarray,
    sample_basis: np.ndarray,
    basis_rows: np.ndarray,
    visibility: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 6's linearisation on one level: projected Jacobian J, ``J' V J`` and node Jacobian.

    The image gradient is the central difference of the stencil's samples (as
    :func:`~face_tracking_ros.imaging.sample_with_gradient_xy` takes it); :func:`roi_jacobian`
    carries it through eq. 1-3; each patch's rows are projected by ``1 - P`` of the photometric
    model (:func:`~face_tracking_ros.imaging.photometric.project_out`); and ``J' V J`` is
    :func:`weighted_gram` with the samples' visibility weights V.

    Args:
        stencil: (5, N M) float32 samples at the ROI pixels, then one pixel +x, -x, +y, -y.
        rotated: (3, N, M) ``R P`` of the ROI samples, m.
        rotated_nodes: (3, N) ``R X_n`` of the nodes, m.
        t: (3,) translation, m.
        camera: (3, 4) projection matrix of the level's pixels.
        rotation: (3, 3) R(omega).
        d_rotation: (3, 3, 3) dR/domega_k.
        node_basis: (N, 3, c) derivative of eq. 3's nodes with respect to the coefficients.
        sample_basis: (c, 3, N, M) derivative of the samples' offsets from their nodes.
        basis_rows: (N, K, M) orthonormal rows U' of each patch's brightness changes.
        visibility: (N M,) the samples' visibility weights V.

    Returns:
        ``(jacobian_t, hessian, node_jacobian)``: (6 + c, N M) projected J' (grey levels per
        parameter), (6 + c, 6 + c) ``J' V J`` and (2 N, 6 + c) node Jacobian, level px.
    """
    count, size = rotated.shape[1], rotated.shape[2]
    gradient = np.empty((2, count, size), dtype=np.float32)
    half = np.float32(0.5)
    for n in range(count):
        for m in range(size):
            i = n * size + m
            gradient[0, n, m] = (stencil[1, i] - stencil[2, i]) * half
            gradient[1, n, m] = (stencil[3, i] - stencil[4, i]) * half
    jacobian, node_jacobian = roi_jacobian(
        rotated, rotated_nodes, t, camera, gradient, rotation, d_rotation, node_basis, sample_basis
    )
    project_out(jacobian, basis_rows)
    jacobian_t = jacobian.reshape(jacobian.shape[0], count * size)
    return jacobian_t, weighted_gram(jacobian_t, visibility), node_jacobian


@numba.njit('f8(f8[:, ::1])', **FAST)
def condition_number(hessian: np.ndarray) -> float:
    """Condition number of the Jacobi-scaled normal matrix ``S H S``, ``S = diag(H)^-1/2``.

    Its largest eigenvalue over its smallest; inf when that is not positive (singular, or left
    slightly indefinite by rounding: a negative condition would pass ``condition >
    max_condition``).
    """
    size = hessian.shape[0]
    scaling = np.empty(size)
    for a in range(size):
        scaling[a] = 1.0 / np.sqrt(max(hessian[a, a], 1e-12))
    scaled = np.empty((size, size))
    for a in range(size):
        for b in range(size):
            scaled[a, b] = hessian[a, b] * scaling[a] * scaling[b]
    eigenvalues = np.linalg.eigvalsh(scaled)
    return eigenvalues[-1] / eigenvalues[0] if eigenvalues[0] > 0 else np.inf


@numba.njit(**EXACT)
def blended_template(
    previous: np.ndarray, keyframe: np.ndarray, epsilon: np.ndarray
) -> np.ndarray:
    """Eq. 6's blended template ``T = I_(n-1) + epsilon (I_1 - I_(n-1))`` of (N, M) templates.

    ``epsilon`` is (N,), one weight per node's ROI. numpy's bits: the difference is taken in
    the wider type of the two templates, the rest in float64.
    """
    count, size = previous.shape
    blended = np.empty((count, size))
    for n in range(count):
        weight = epsilon[n]
        for m in range(size):
            blended[n, m] = previous[n, m] + weight * (keyframe[n, m] - previous[n, m])
    return blended


class Votes(NamedTuple):
    """What :func:`loss_votes` makes of a solution's nodes for the loss checks (see there)."""

    visible: np.ndarray
    textured: np.ndarray
    visible_count: int
    voting: int
    failing: int


@numba.njit(
    'Tuple((b1[::1], b1[::1], i8, i8, i8))(f8[::1], f8[:, ::1], f8, f8, f8[::1], f8[::1], '
    'f8[::1], f8, f8)',
    **EXACT,
)
def _loss_votes(
    visibility: np.ndarray,
    pixels: np.ndarray,
    width: float,
    height: float,
    image_texture: np.ndarray,
    template_texture: np.ndarray,
    node_rms: np.ndarray,
    floor: float,
    ratio: float,
) -> tuple[np.ndarray, np.ndarray, int, int, int]:
    """:func:`loss_votes`'s work on its arguments as arrays."""
    count = visibility.size
    visible = np.empty(count, dtype=np.bool_)
    textured = np.empty(count, dtype=np.bool_)
    visible_count = voting = failing = 0
    right, bottom = width - 1.0, height - 1.0
    for n in range(count):
        x, y = pixels[n, 0], pixels[n, 1]
        seen = visibility[n] > 0.0 and x >= 0.0 and y >= 0.0 and x <= right and y <= bottom
        image, template = image_texture[n], template_texture[n]
        # np.maximum's: NaN if either is.
        larger = np.nan if np.isnan(image) or np.isnan(template) else max(image, template)
        votes = seen and larger > floor
        matched = image > floor and node_rms[n] < ratio * image
        visible[n] = seen
        textured[n] = seen and image > floor
        visible_count += seen
        voting += votes
        failing += votes and not matched
    return visible, textured, visible_count, voting, failing


def loss_votes(
    visibility: np.ndarray,
    pixels: np.ndarray,
    size: tuple[int, int],
    texture: tuple[np.ndarray, np.ndarray],
    node_rms: np.ndarray,
    floor: float,
    ratio: float,
) -> Votes:
    """Which nodes are visible and which match their templates, for the loss checks.

    A node is visible when its visibility weight is positive and its pixel lies in the (width,
    height) image; it votes when visible and its ROI shows texture above ``floor`` in the image
    or its template; it fails when it votes and its residual is not below ``ratio`` times the
    image ROI's texture (or that texture is not above ``floor``).
    (:meth:`~.mono_loss.LossChecks.reason`, in one compiled pass.)

    Args:
        visibility: (N,) node visibility weights.
        pixels: (N, 2) node pixels, level 0.
        size: the image's (width, height).
        texture: (N,) the ROIs' texture in the image and in the template.
        node_rms: (N,) RMS of each node's residual.
        floor: the least texture that counts, grey levels.
        ratio: the residual-to-texture ratio a node must stay below.

    Returns:
        The :class:`Votes`: (N,) visible mask, (N,) mask of those textured in the image, and
        how many nodes are visible, vote and fail.
    """
    width, height = size
    return Votes(
        *_loss_votes(
            visibility,
            pixels,
            float(width),
            float(height),
            texture[0],
            texture[1],
            node_rms,
            floor,
            ratio,
        )
    )


@numba.njit('f8(f8[::1], i8, i8)', **EXACT)
def _pairwise_sum(values: np.ndarray, start: int, count: int) -> float:
    """The sum of ``values[start:start + count]`` in numpy's order (its ``pairwise_sum``).

    Below 8 values one running sum; up to 128, eight running sums over the values taken eight
    at a time, added as ``((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7))``, then the rest
    one by one; beyond, the two halves (the first a multiple of 8) summed so and added.
    """
    if count < 8:
        total = 0.0
        for i in range(start, start + count):
            total += values[i]
        return total
    if count > 128:
        half = count // 2
        half -= half % 8
        return _pairwise_sum(values, start, half) + _pairwise_sum(
            values, start + half, count - half
        )
    s0, s1, s2, s3 = values[start], values[start + 1], values[start + 2], values[start + 3]
    s4, s5, s6, s7 = values[start + 4], values[start + 5], values[start + 6], values[start + 7]
    whole = start + count - count % 8
    for i in range(start + 8, whole, 8):
        s0, s1, s2, s3 = s0 + values[i], s1 + values[i + 1], s2 + values[i + 2], s3 + values[i + 3]
        s4, s5 = s4 + values[i + 4], s5 + values[i + 5]
        s6, s7 = s6 + values[i + 6], s7 + values[i + 7]
    total = ((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7))
    for i in range(whole, start + count):
        total += values[i]
    return total


@numba.njit('f8(f8[::1], f8[::1])', **EXACT)
def _rms(row: np.ndarray, squares: np.ndarray) -> float:
    """RMS of an (M,) row, ``np.sqrt(np.mean(row**2))``'s bits; ``squares`` an (M,) buffer.

    numpy's mean sums the squares pairwise (:func:`_pairwise_sum`), then divides by M.
    """
    size = row.size
    for m in range(size):
        squares[m] = row[m] * row[m]
    return np.sqrt(_pairwise_sum(squares, 0, size) / size)


@numba.njit('f8[::1](f8[:, ::1])', **EXACT)
def row_rms(values: np.ndarray) -> np.ndarray:
    """(N,) RMS of each row of (N, M) values: ``np.sqrt(np.mean(values**2, axis=1))``'s bits.

    A node's RMS residual and its ROI's texture (:mod:`.mono_loss`).
    """
    count, size = values.shape
    rms = np.empty(count)
    squares = np.empty(size)
    for n in range(count):
        rms[n] = _rms(values[n], squares)
    return rms


@numba.njit('f8(f8[:, ::1], f8[::1], b1[::1])', **EXACT)
def median_rms_ratio(residuals: np.ndarray, texture: np.ndarray, nodes: np.ndarray) -> float:
    """Median over ``nodes`` of each row's RMS over its texture; 0 for no node.

    The drift check's ratio (:func:`~.mono_loss._drift_ratio`): ``np.median(row_rms(
    residuals[nodes]) / texture[nodes])``'s value.

    Args:
        residuals: (N, M) residuals, a row per node.
        texture: (N,) the nodes' ROI texture.
        nodes: (N,) the nodes counted.
    """
    count, size = residuals.shape
    ratios = np.empty(count)
    squares = np.empty(size)
    found = 0
    for n in range(count):
        if nodes[n]:
            ratios[found] = _rms(residuals[n], squares) / texture[n]
            found += 1
    return np.median(ratios[:found]) if found else 0.0
