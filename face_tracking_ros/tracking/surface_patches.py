"""Small 3-D surface patches around the mesh nodes, so eq. 6's regions of interest follow the face.

Instead of a fronto-parallel square of pixels, each node's region of interest is a grid of points
on a smooth surface through the mesh nodes, fixed in the face frame. Projected through the
current pose (eq. 1-2) it foreshortens and turns as the skin around the node does, so templates
sampled at frame 1 (or a keyframe) and frame n-1 stay comparable under out-of-plane rotation
(seed §4.4). The surface is the thin-plate spline ``z(x, y)`` through the nodes: exact at the
nodes, smooth between them, the least-bending surface the sparse mesh allows. Tangent planes
(first order at each node) err by millimetres around the nose and eye corners, which biases the
rotation by degrees when templates are compared across a 30-degree turn.

The skin between the nodes deforms with them: :func:`patch_basis` carries eq. 3 from the nodes to
every patch sample by the same thin-plate interpolation (in the face frame's x-y), so a sample
moves with ``sum_j w_j(x, y) (S_j sigma + A_j alpha)`` rather than rigidly with its own node. A
smiling mouth stretches the patches around it as the skin stretches; without this, the rigid
patches disagree with the stretched skin and the solver explains part of every expression by a
head rotation (measured on synthetic sequences: pitch error during expressions 1.28 -> 0.4
degrees with everything else exact). The stereo tracker, which has no eq. 3 to carry, carries
the nodes' own deformation with the same weights (:class:`PatchDeformation`).

Node normals (for visibility) come from the mesh triangulation: a node's normal is the
area-weighted mean of the normals of its triangles, oriented towards the camera of a frontal view
(-z of the face frame).
"""

from __future__ import annotations

from dataclasses import dataclass

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


def patch_basis(weights: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """Eq. 3's bases carried to the patch samples, relative to each sample's own node.

    Each sample ``shape_i + offset`` moves with the thin-plate interpolation (over the face
    frame's x-y at ``shape``) of the node bases, ``sum_j w_j(x, y) B_j``; this returns that motion
    minus its node's own ``B_i``, so a sample at coefficient c sits at
    ``X_i(c) + offset + D c`` with ``X_i(c)`` the node of eq. 3. Thin-plate interpolation
    reproduces affine fields exactly, so a basis that moves the nodes affinely (a rigid motion,
    a uniform stretch) moves every sample the same way.

    Args:
        weights: (N, M, N) the samples' thin-plate weights, :func:`patch_interpolation` of the
            nodes ``shape`` and the offsets to their samples (computed once for every basis).
        basis: (N, 3, c) per-node derivative of eq. 3 with respect to c coefficients.

    Returns:
        (N, M, 3, c) derivative of each sample's offset with respect to the coefficients.
    """
    count, samples = weights.shape[:2]
    dense = weights.reshape(-1, count) @ basis.reshape(count, -1)  # a BLAS product, 6x einsum's
    return dense.reshape(count, samples, *basis.shape[1:]) - basis[:, None]


@dataclass(frozen=True)
class ThinPlate:
    """The thin-plate interpolation over the face frame's x-y through a set of nodes.

    Solved once (the spline's (N + 3)-square system for each node's unit value, scipy's
    ``RBFInterpolator``) and evaluated at any number of point sets: every pyramid level's ROIs
    at one sigma, on the thin-plate surface and on the skin, take their weights from one.

    Attributes:
        nodes: (N, 3) the nodes, m.
        interpolation: the spline through their x-y, one value column per node.
    """

    nodes: np.ndarray
    interpolation: RBFInterpolator

    @classmethod
    def through(cls, nodes: np.ndarray) -> ThinPlate:
        """The thin plate through (N, 3) ``nodes`` (m)."""
        count = nodes.shape[0]
        return cls(nodes, RBFInterpolator(nodes[:, :2], np.eye(count), kernel='thin_plate_spline'))

    def weights(self, xy: np.ndarray) -> np.ndarray:
        """(..., N) the nodes' thin-plate weights at (..., 2) points ``xy``."""
        count = self.nodes.shape[0]
        return self.interpolation(xy.reshape(-1, 2)).reshape(*xy.shape[:-1], count)


def patch_interpolation(plate: ThinPlate, offsets: np.ndarray) -> np.ndarray:
    """Thin-plate weights that carry a motion of the nodes to every patch sample.

    A sample at ``shape_i + offset`` moves by ``sum_j w_j (x, y) d_j`` when the nodes move by
    d (interpolated over the face frame's x-y at ``shape``, the plate's nodes). The weights of
    each sample sum to 1 and reproduce any affine motion of the nodes exactly.

    Args:
        plate: the thin plate through the nodes ``shape`` (N, 3), m, where the interpolation
            is set up.
        offsets: (N, M, 3) offsets from each node to its samples, m.

    Returns:
        (N, M, N) weight w_j of node j at each sample.
    """
    return plate.weights(plate.nodes[:, None, :2] + offsets[..., :2])


def surface_patch_interpolation(
    plate: ThinPlate, grid: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`surface_patch_offsets` and the :func:`patch_interpolation` weights at them.

    Both from one thin-plate evaluation: the surface's depth at a sample is its weights applied
    to the nodes' depths (the thin-plate interpolant is linear in the values it interpolates).

    Args:
        plate: the thin plate through the nodes (N, 3), face frame, m.
        grid: (N, M, 2) sample offsets along the face frame's x and y, m.

    Returns:
        ``(offsets, weights)``: (N, M, 3) offsets from each node to its samples on the surface,
        m, and (N, M, N) the weight w_j of node j at each sample.
    """
    shape = plate.nodes
    xy = shape[:, None, :2] + grid
    weights = plate.weights(xy)
    samples = np.concatenate([xy, (weights @ shape[:, 2])[..., None]], axis=-1)
    return samples - shape[:, None, :], weights


def surface_patch_offsets(
    shape: np.ndarray, grid: np.ndarray, through: np.ndarray | None = None
) -> np.ndarray:
    """3-D offsets of each node's patch samples on the thin-plate surface through the nodes.

    Args:
        shape: (N, 3) nodes in the face frame, m.
        grid: (M, 2) or (N, M, 2) sample offsets along the face frame's x and y, m.
        through: optional (K, 3) further points the surface passes through (not nodes), m.

    Returns:
        (N, M, 3) offsets from each node to its samples ``(x, y, z(x, y))``, m.
    """
    grid = np.broadcast_to(grid, (shape.shape[0], *np.shape(grid)[-2:]))
    points = shape if through is None else np.concatenate([shape, through])
    surface = RBFInterpolator(points[:, :2], points[:, 2], kernel='thin_plate_spline')
    xy = shape[:, None, :2] + grid
    depth = surface(xy.reshape(-1, 2)).reshape(xy.shape[:2])
    return np.concatenate([xy, depth[..., None]], axis=-1) - shape[:, None, :]


@dataclass(frozen=True)
class PatchDeformation:
    """Node patches that deform with the mesh, for a tracker whose nodes move freely.

    A tracker without a face model (the stereo tracker) still knows how the skin between its
    nodes moves: as the nodes do. The deformation of the nodes, their motion less the rigid
    motion of the head (``d_j = X_j - R X_j(1)``; the translation cancels), is carried to every
    sample of node i's patch by the thin-plate weights of :func:`patch_interpolation`:

        P = X_i + R o + sum_j w_j d_j - d_i

    so a raised brow stretches the skin between brow and eye as the skin does; a rigid patch
    (``X_i + R o``) cannot follow that, and the tracker stops short of the brow's motion.

    The weights are set up once per track, at its frame-1 nodes; moving those nodes along their
    rays later (the stereo tracker's depth refinement) shifts them in x-y by about a millimetre
    at most, which is left out. The stereo tracker evaluates the field at every trial point, so
    its costs are exact, but its Gauss-Newton blocks keep each sample's derivative with respect
    to its own node only (the field's dependence on the other nodes is left out of the steps).

    Attributes:
        weights: (N, S_p) w_j of every node-patch sample (node after node, M samples each).
    """

    weights: np.ndarray

    @classmethod
    def of(cls, first_nodes: np.ndarray, offsets: np.ndarray) -> PatchDeformation:
        """The weights at frame 1.

        Args:
            first_nodes: (N, 3) frame-1 nodes, m.
            offsets: (N, M, 3) frame-1 offsets from each node to its patch samples, m.
        """
        plate = ThinPlate.through(first_nodes)
        weights = patch_interpolation(plate, offsets).reshape(-1, first_nodes.shape[0])
        return cls(weights=np.ascontiguousarray(weights.T))

    def field(
        self, nodes: np.ndarray, first_nodes: np.ndarray, rotation: np.ndarray
    ) -> np.ndarray:
        """(3, S_p) ``sum_j w_j d_j - d_i`` at every node-patch sample, m.

        Args:
            nodes: (N, 3) current nodes, m.
            first_nodes: (N, 3) frame-1 nodes, m.
            rotation: (3, 3) R, the head's rotation since frame 1.
        """
        deformation = (nodes - first_nodes @ rotation.T).T
        field = deformation @ self.weights
        count = deformation.shape[1]
        field.reshape(3, count, -1)[...] -= deformation[:, :, None]
        return field


def patch_field(
    deformation: PatchDeformation | None,
    nodes: np.ndarray,
    first_nodes: np.ndarray,
    rotation: np.ndarray,
) -> np.ndarray | None:
    """(3, S_p) :meth:`PatchDeformation.field` at ``nodes``; None for rigid patches.

    The sample points take it with their level's offsets
    (:meth:`~.stereo_data.SampleSet.points`).
    """
    return None if deformation is None else deformation.field(nodes, first_nodes, rotation)
