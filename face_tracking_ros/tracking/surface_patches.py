"""Small 3-D surface patches around the mesh nodes, so eq. 6's regions of interest follow the face.

Instead of a fronto-parallel square of pixels, each node's region of interest is a grid of points
on a smooth surface through the mesh nodes, fixed in the face frame. Projected through the
current pose (eq. 1-2) it foreshortens and turns as the skin around the node does, so templates
sampled at frame 1 (or a keyframe) and frame n-1 stay comparable under out-of-plane rotation
(seed §4.4). The surface is the thin-plate spline ``z(x, y)`` through the nodes: exact at the
nodes, smooth between them, the least-bending surface the sparse mesh allows. Tangent planes
(first order at each node) err by millimetres around the nose and eye corners, which biases the
rotation by degrees when templates are compared across a 30-degree turn.

Node normals (for visibility) come from the mesh triangulation: a node's normal is the
area-weighted mean of the normals of its triangles, oriented towards the camera of a frontal view
(-z of the face frame).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import RBFInterpolator

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


def surface_patch_offsets(shape: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """3-D offsets of each node's patch samples on the thin-plate surface through the nodes.

    Args:
        shape: (N, 3) nodes in the face frame, m.
        grid: (M, 2) or (N, M, 2) sample offsets along the face frame's x and y, m.

    Returns:
        (N, M, 3) offsets from each node to its samples ``(x, y, z(x, y))``, m.
    """
    grid = np.broadcast_to(grid, (shape.shape[0], *np.shape(grid)[-2:]))
    surface = RBFInterpolator(shape[:, :2], shape[:, 2], kernel='thin_plate_spline')
    xy = shape[:, None, :2] + grid
    depth = surface(xy.reshape(-1, 2)).reshape(xy.shape[:2])
    return np.concatenate([xy, depth[..., None]], axis=-1) - shape[:, None, :]
