"""Projection of face-model points through eq. 1-3 with the analytic Jacobian.

For points ``P`` of the face frame that depend linearly on model coefficients ``c`` (eq. 3:
``P = mean + S sigma + A alpha`` plus a constant patch offset), eq. 1 gives the camera-frame
points ``X_c = R(omega) P + t`` and eq. 2 the pixels ``x = pi(X_c)``. The Jacobian of ``x`` with
respect to ``(omega, t, c)`` is the chain rule ``dpi/dX_c [dR/domega P, I, R dP/dc]``, built from
the analytic derivatives of :func:`~face_tracking_ros.geometry.rotation.rotate_with_jacobian` and
:meth:`~face_tracking_ros.geometry.camera.PinholeCamera.project_with_jacobian`.
"""

from __future__ import annotations

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
