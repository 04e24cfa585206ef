"""Small 3-D surface patches around the mesh nodes, so eq. 6's regions of interest follow the face.

Instead of a fronto-parallel square of pixels, each node's region of interest is a square grid in
the plane tangent to the face surface at the node, fixed in the face frame. Projected through the
current pose (eq. 1-2) it foreshortens and rotates exactly as the skin around the node does, so
the templates of frames 1 and n-1 stay comparable under out-of-plane rotation (seed §4.4).

Tangent frames come from the mesh triangulation: a node's normal is the area-weighted mean of the
normals of its triangles, oriented towards the camera of a frontal view (-z of the face frame).
"""

from __future__ import annotations

import numpy as np

from face_tracking_ros.errors import InputError


def node_frames(shape: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Orthonormal tangent frames of the mesh at its nodes.

    Args:
        shape: (N, 3) nodes in the face frame, m.
        triangles: (T, 3) node index triples covering every node.

    Returns:
        (N, 3, 3) frames; row 0 is the tangent closest to the face x axis, row 1 the tangent
        closest to y (towards the chin), row 2 the outward normal (towards a frontal camera).

    Raises:
        InputError: if a node belongs to no triangle.
    """
    corners = shape[triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals *= -np.sign(normals[:, 2:3])  # outward: towards -z of the face frame
    accumulated = np.zeros_like(shape)
    for column in range(3):
        np.add.at(accumulated, triangles[:, column], normals)
    length = np.linalg.norm(accumulated, axis=1, keepdims=True)
    if np.any(length == 0):
        msg = f'nodes {np.flatnonzero(length[:, 0] == 0).tolist()} belong to no triangle'
        raise InputError(msg)
    normal = accumulated / length
    x_axis = np.array([1.0, 0.0, 0.0])
    tangent_x = x_axis - normal * (normal @ x_axis)[:, None]
    tangent_x /= np.linalg.norm(tangent_x, axis=1, keepdims=True)
    tangent_y = np.cross(tangent_x, normal)
    return np.stack([tangent_x, tangent_y, normal], axis=1)


def surface_patch_offsets(frames: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """3-D offsets of each node's patch samples in the face frame.

    Args:
        frames: (N, 3, 3) tangent frames from :func:`node_frames`.
        grid: (M, 2) or (N, M, 2) sample coordinates along the two tangents, m.

    Returns:
        (N, M, 3) offsets, m: ``grid[..., 0] * frames[:, 0] + grid[..., 1] * frames[:, 1]``.
    """
    grid = np.broadcast_to(grid, (frames.shape[0], *np.shape(grid)[-2:]))
    return grid @ frames[:, :2, :]
