"""Projection of face-model points through eq. 1-3 with the analytic Jacobian.

For points ``P`` of the face frame that depend linearly on model coefficients ``c`` (eq. 3:
``P = mean + S sigma + A alpha`` plus a constant patch offset), eq. 1 gives the camera-frame
points ``X_c = R(omega) P + t`` and eq. 2 the pixels ``x = pi(X_c)``. The Jacobian of ``x`` with
respect to ``(omega, t, c)`` is the chain rule ``dpi/dX_c [dR/domega P, I, R dP/dc]``, built from
the analytic derivatives of :func:`~face_tracking_ros.geometry.rotation.rotate_with_jacobian` and
:meth:`~face_tracking_ros.geometry.camera.PinholeCamera.project_with_jacobian`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.geometry.rotation import rodrigues, rotate_with_jacobian

POSE_DIM = 6  # omega (3) then t (3)


class Projection(NamedTuple):
    """Points projected through eq. 1-2 and their derivatives.

    Attributes:
        pixels: (..., 2) image points x, px.
        points_cam: (..., 3) camera-frame points X_c, m.
        jacobian: (..., 2, 6 + c) dx/d(omega, t, c), px/rad, px/m and px per unit coefficient.
    """

    pixels: np.ndarray
    points_cam: np.ndarray
    jacobian: np.ndarray


def project_with_jacobian(
    camera: PinholeCamera,
    omega: np.ndarray,
    t: np.ndarray,
    points: np.ndarray,
    basis: np.ndarray | None = None,
) -> Projection:
    """Project face-frame points and differentiate with respect to pose and coefficients.

    Args:
        camera: the (rectified) camera of eq. 2.
        omega: (3,) rotation vector of eq. 1, rad.
        t: (3,) translation of eq. 1, m.
        points: (..., 3) face-frame points P, m.
        basis: (..., 3, c) derivative dP/dc, broadcastable against ``points[..., None]`` (e.g. the
            model's ``action_basis_nodes()`` (N, 3, q) reshaped to (N, 1, 3, q) for (N, M, 3)
            patch points); None for c = 0.

    Returns:
        The :class:`Projection`; the Jacobian columns are omega (3), t (3), then c.
    """
    points = np.asarray(points, dtype=float)
    lead = points.shape[:-1]
    rotated, d_rotated = rotate_with_jacobian(omega, points.reshape(-1, 3))
    points_cam = rotated + np.asarray(t, dtype=float)
    pixels, d_pixels = camera.project_with_jacobian(points_cam)
    d_pixels = d_pixels.reshape(*lead, 2, 3)
    blocks = [d_pixels @ d_rotated.reshape(*lead, 3, 3), d_pixels]
    if basis is not None:
        rotation, _ = rodrigues(omega)
        d_coefficients = d_pixels @ (rotation @ basis)
        blocks.append(np.broadcast_to(d_coefficients, (*lead, 2, d_coefficients.shape[-1])))
    return Projection(
        pixels=pixels.reshape(*lead, 2),
        points_cam=points_cam.reshape(*lead, 3),
        jacobian=np.concatenate(blocks, axis=-1),
    )


def photometric_jacobian(
    camera: PinholeCamera,
    omega: np.ndarray,
    rotated: np.ndarray,
    t: np.ndarray,
    gradient: np.ndarray,
    basis: np.ndarray | None = None,
    project: Callable[[np.ndarray], np.ndarray] | None = None,
    sample_basis: np.ndarray | None = None,
) -> np.ndarray:
    """Derivative of image samples ``I(pi(R(omega) P + t))`` with respect to (omega, t, c).

    The chain rule of :func:`project_with_jacobian` contracted with the image gradient first,
    ``h = (dpi/dX_c)' grad I``, so no per-sample 2x3 or 3x3 matrices are formed: the omega rows
    are ``h' dR/domega_k P = j_k . (R P x h)`` (with ``dR/domega_k = [j_k]x R``), the t rows
    ``h`` and the coefficient rows ``(R' h)' dP/dc``. Arrays are component-major (one contiguous
    row per coordinate or parameter), so every step is a 3x3 product or an operation on whole
    rows.

    Args:
        camera: the camera of eq. 2.
        omega: (3,) rotation vector of eq. 1, rad.
        rotated: (3, N, M) face-frame points P rotated into the camera frame, R(omega) P, m (the
            camera-frame points of eq. 1 are ``rotated + t``).
        t: (3,) translation of eq. 1, m.
        gradient: (2, N, M) image gradient (d/dx, d/dy) at their pixels, grey levels / px.
        basis: (N, 3, c) derivative dP/dc shared by the M points of each node, or None.
        project: a linear map of (J, N, M) stacks acting on each node's M samples alone (a
            photometric projection); the result is then the Jacobian of the mapped samples.
            Every row is a combination of the six rows ``R P x h`` and ``h`` with coefficients
            constant over a node's samples, so only those six are mapped.
        sample_basis: (c, 3, N, S) derivative dP/dc of the first S points of each node beyond
            ``basis`` (component-major; points past S have none), for points that move with the
            coefficients other than rigidly with their node. Its rows are mapped by ``project``
            too.

    Returns:
        (6 + c, N, M) Jacobian, one row per parameter: grey levels per rad, per m and per unit
        coefficient.
    """
    rotation, d_rotation = rodrigues(omega)
    count = rotated.shape[1]
    flat = rotated.reshape(3, -1)
    flat_gradient = gradient.reshape(2, -1).astype(float)
    projection = camera.p[:, :3]
    homogeneous = projection @ flat
    homogeneous += (projection @ np.asarray(t, dtype=float) + camera.p[:, 3])[:, None]
    h = space_gradient(projection, homogeneous, flat_gradient)
    x, y, z = flat
    rows = np.stack([y * h[2] - z * h[1], z * h[0] - x * h[2], x * h[1] - y * h[0], *h])
    extra = None if sample_basis is None else _sample_rows(rotation.T @ h, sample_basis, rotated)
    if project is not None:
        rows = project(rows.reshape(6, *rotated.shape[1:])).reshape(6, -1)
        extra = None if extra is None else project(extra).reshape(len(extra), -1)
    blocks = [_left_jacobian(rotation, d_rotation).T @ rows[:3], rows[3:]]
    if basis is not None:
        rotated_h = (rotation.T @ rows[3:]).reshape(3, count, -1).transpose(1, 0, 2)  # (N, 3, M)
        coefficients = np.matmul(basis.transpose(0, 2, 1), rotated_h)  # (N, c, M)
        coefficients = coefficients.transpose(1, 0, 2).reshape(basis.shape[-1], -1)
        blocks.append(
            coefficients if extra is None else coefficients + extra.reshape(len(extra), -1)
        )
    return np.concatenate(blocks, axis=0).reshape(-1, *rotated.shape[1:])


def space_gradient(
    projection: np.ndarray, homogeneous: np.ndarray, gradient: np.ndarray
) -> np.ndarray:
    """The image gradient carried to the camera-frame point: ``h = (d pi / d X_c)^T grad I``.

    With ``x = (P X)_(1, 2) / (P X)_3`` (eq. 2), ``d x / d X = (P_(1, 2) - x P_3) / (P X)_3``, so
    ``h = (P_(1, 2)^T g - (g . x) P_3) / (P X)_3``: the change of a sample's grey level per metre
    of its point's motion. Leading axes of all three arrays broadcast (one per camera, say).

    Args:
        projection: (..., 3, 3) the left 3x3 part of a camera's P, px (per m).
        homogeneous: (..., 3, K) ``P X`` of K points, homogeneous pixels.
        gradient: (..., 2, K) float64 image gradient at their pixels, grey levels / px.

    Returns:
        (..., 3, K) h, grey levels / m.
    """
    inverse_depth = 1.0 / homogeneous[..., 2, :]
    along = (
        gradient[..., 0, :] * homogeneous[..., 0, :] + gradient[..., 1, :] * homogeneous[..., 1, :]
    ) * inverse_depth
    h = np.swapaxes(projection[..., :2, :], -1, -2) @ gradient
    h -= projection[..., 2, :, None] * along[..., None, :]
    h *= inverse_depth[..., None, :]
    return h


def _sample_rows(
    rotated_h: np.ndarray, sample_basis: np.ndarray, rotated: np.ndarray
) -> np.ndarray:
    """(c, N, M) rows ``(R' h)' dP/dc`` of the per-point ``sample_basis`` (zero past its S points).

    Args:
        rotated_h: (3, N M) the chain ``R' h`` of every point.
        sample_basis: (c, 3, N, S) per-point derivatives of the first S points of each node.
        rotated: (3, N, M) the points (for their layout).
    """
    count, size = rotated.shape[1:]
    used = sample_basis.shape[-1]
    chain = rotated_h.reshape(3, count, size)[:, :, :used]
    rows = np.zeros((len(sample_basis), count, size))
    products = rows[:, :, :used]
    for axis in range(3):
        products += sample_basis[:, axis] * chain[axis]
    return rows


def _left_jacobian(rotation: np.ndarray, d_rotation: np.ndarray) -> np.ndarray:
    """(3, 3) matrix J with columns j_k such that dR/domega_k = [j_k]x R (from cv2's dR)."""
    generators = d_rotation @ rotation.T  # (3, 3, 3), each skew-symmetric
    return np.stack([generators[:, 2, 1], generators[:, 0, 2], generators[:, 1, 0]], axis=0)
