"""Rotation vectors (Rodrigues) with analytic Jacobians, for eq. 1 of the seed.

``R(omega)`` is the rotation matrix of the rotation vector ``omega`` (axis times angle, radians).
OpenCV's ``cv2.Rodrigues`` provides both the matrix and its analytic derivative; this module only
reshapes that derivative into the forms the Gauss-Newton solvers need.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from face_tracking_ros.errors import InputError


def rodrigues(omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation matrix of a rotation vector and its derivative.

    Args:
        omega: (3,) rotation vector, radians.

    Returns:
        ``(R, dR)``: R is (3, 3); dR is (3, 3, 3) with ``dR[k] = dR/d omega_k``.

    Raises:
        InputError: if omega is not a finite 3-vector.
    """
    omega = np.asarray(omega, dtype=float)
    if omega.shape != (3,) or not np.isfinite(omega).all():
        msg = f'omega must be a finite (3,) rotation vector, got shape {omega.shape}: {omega}'
        raise InputError(msg)
    rotation, jacobian = cv2.Rodrigues(omega)
    # OpenCV's jacobian is (3, 9): row k holds dR/d omega_k flattened row-major.
    return rotation, jacobian.reshape(3, 3, 3)


def rotate_with_jacobian(omega: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotate points by R(omega) and differentiate with respect to omega.

    Args:
        omega: (3,) rotation vector, radians.
        points: (N, 3) points.

    Returns:
        ``(RX, J)``: RX is (N, 3) rotated points; J is (N, 3, 3) with ``J[i, :, k] = dR/d omega_k
        @ X_i``.
    """
    rotation, d_rotation = rodrigues(omega)
    rotated = points @ rotation.T
    jacobian = np.einsum('kab,nb->nak', d_rotation, points)
    return rotated, jacobian


def matrix_to_omega(rotation: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) of a (3, 3) rotation matrix."""
    omega, _ = cv2.Rodrigues(np.asarray(rotation, dtype=float))
    return omega.ravel()


def rotation_angle(omega_a: np.ndarray, omega_b: np.ndarray) -> float:
    """Angle of the rotation between R(omega_a) and R(omega_b), rad."""
    return angle_between(rodrigues(omega_a)[0], rodrigues(omega_b)[0])


def angle_between(rotation_a: np.ndarray, rotation_b: np.ndarray) -> float:
    """Angle of the rotation between two (3, 3) rotation matrices R_a and R_b, rad.

    ``trace(R_a' R_b) = 1 + 2 cos(angle)``, summed and clipped as Python floats: the same value
    as with np.trace and np.clip, without their overhead (the tracker checks one every frame).
    """
    relative = rotation_a.T @ rotation_b
    cosine = 0.5 * (relative[0, 0] + relative[1, 1] + relative[2, 2] - 1.0)
    return float(np.arccos(min(max(cosine, -1.0), 1.0)))


def omega_to_quaternion(omega: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w) of a rotation vector, as geometry_msgs/Quaternion orders it."""
    return Rotation.from_rotvec(np.asarray(omega, dtype=float)).as_quat()


def quaternion_to_omega(quaternion: np.ndarray) -> np.ndarray:
    """Rotation vector of a quaternion (x, y, z, w)."""
    return Rotation.from_quat(np.asarray(quaternion, dtype=float)).as_rotvec()


def omega_to_angles(omega: np.ndarray) -> np.ndarray:
    """Rotation angles about the camera x, y and z axes (pitch, yaw, roll), radians.

    Uses the extrinsic x-y-z convention, so for small rotations the angles are the components of
    omega. The seed's §4.4 reports errors about these axes; so do the benchmarks.

    Args:
        omega: (..., 3) rotation vectors.

    Returns:
        (..., 3) angles.
    """
    return Rotation.from_rotvec(np.asarray(omega, dtype=float)).as_euler('xyz')


def angles_to_omega(angles: np.ndarray) -> np.ndarray:
    """Inverse of :func:`omega_to_angles`."""
    return Rotation.from_euler('xyz', np.asarray(angles, dtype=float)).as_rotvec()
