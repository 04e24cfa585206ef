"""The image terms of the stereo tracker: eq. 4 over node patches, plus a face-texture term (§4.2).

Every image sample is a 3-D point tied to up to three nodes: ``P = sum_k b_k X^(n_k) + o`` with
barycentric weights b and an offset o, projected into a camera by eq. 2. A
:class:`SampleLayout` holds G groups of M such samples:

- node patches (the ROI of eq. 4): group i is node i alone (b = (1, 0, 0)) with offsets on a
  small grid lying on the face surface around the node (the thin-plate surface through the
  nodes), so the patch is seen with the right perspective in both cameras (a fronto-parallel
  square would be compressed differently in the two views on the sloping cheeks and temples,
  which biases the cross-camera terms);
- face texture (the seed's §4.2 remedy): group t is triangle t of the mesh, its samples on a
  barycentric grid inside it (o = 0); a boundary node sliding along the face edge distorts the
  texture of every triangle it belongs to, which this term sees.

For a current image I_c of camera c, the cost of one group is a robust sum over its samples of

    sum_k a_k rho_huber(I_c(P) - T_k - mean(I_c(P) - T_k))

over templates T_k (the same samples in earlier images) with coefficients a_k: for node patches
the four terms of eq. 4 ((1 - gamma) for the same camera, gamma for the other camera, at frame
n - 1), each split (1 - epsilon) : epsilon with the same terms against frame 1 (the drift term
of eq. 6 carried over to stereo). Removing each group's mean difference (ZSSD) makes the terms
insensitive to a brightness offset between the cameras or over time. The Gauss-Newton
normal equations are accumulated from per-node blocks (:mod:`.block_assembly`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.imaging import (
    inside_image,
    sample_points,
    sample_with_gradient,
    square_offsets,
)
from face_tracking_ros.tracking.block_assembly import scatter_blocks, scatter_vectors
from face_tracking_ros.tracking.surface_patches import surface_patch_offsets


@dataclass(frozen=True)
class SampleLayout:
    """G groups of M 3-D sample points tied to mesh nodes.

    Attributes:
        nodes: (G, 3) int node indices n_k of each group (repeated for a single-node group).
        bary: (M, 3) barycentric weights b_k of each sample, rows sum to 1.
        offsets: (G, M, 3) offsets o at pyramid level 0 in the frame-1 orientation, m.
        mask: (G, M) bool, the samples in use.
    """

    nodes: np.ndarray
    bary: np.ndarray
    offsets: np.ndarray
    mask: np.ndarray

    @classmethod
    def node_patches(
        cls,
        nodes: np.ndarray,
        spacing: np.ndarray,
        half_size: int,
        one_sided: np.ndarray,
    ) -> SampleLayout:
        """Patches of (2 h + 1)^2 samples on the face surface around each node (ROI of eq. 4).

        The samples lie on a square grid in camera x and y about the node, lifted onto the
        thin-plate surface through the nodes (:func:`.surface_patches.surface_patch_offsets`).

        A node on the face boundary sees the face on one side only; beyond it lie the neck,
        the ears or the background at other depths, which move differently in the two cameras
        and over time. Its patch keeps only the samples on the face side: those whose offset
        points towards the centroid of the mesh (§4.2). The node's own sample lies on the rim
        and is left out (its offset is zero but for rounding, whose sign must not decide).

        Args:
            nodes: (N, 3) nodes in the left camera frame, m.
            spacing: (N,) sample spacing at level 0, m (about one pixel: depth / focal).
            half_size: h, samples each side of the node.
            one_sided: (N,) bool, the boundary nodes whose patch keeps the face side only.
        """
        grid = spacing[:, None, None] * square_offsets(half_size).astype(float)[None]
        offsets = surface_patch_offsets(nodes, grid)
        inward = nodes.mean(axis=0) - nodes
        facing = (np.einsum('nmd,nd->nm', offsets, inward) >= 0.0) & np.any(grid, axis=2)
        bary = np.zeros((grid.shape[1], 3))
        bary[:, 0] = 1.0
        return cls(
            nodes=np.repeat(np.arange(nodes.shape[0])[:, None], 3, axis=1),
            bary=bary,
            offsets=offsets,
            mask=facing | ~np.asarray(one_sided, dtype=bool)[:, None],
        )

    @classmethod
    def triangle_texture(cls, triangles: np.ndarray, subdivisions: int) -> SampleLayout:
        """Samples on the barycentric grid of order ``subdivisions`` strictly inside each triangle.

        Args:
            triangles: (T, 3) node indices.
            subdivisions: grid order s >= 3; each triangle gets (s - 1)(s - 2) / 2 samples.
        """
        i, j = np.meshgrid(np.arange(1, subdivisions), np.arange(1, subdivisions), indexing='ij')
        keep = i + j < subdivisions
        first, second = i[keep].astype(float), j[keep].astype(float)
        bary = np.stack([first, second, subdivisions - first - second], axis=1) / subdivisions
        triangles = np.asarray(triangles, dtype=np.int64)
        shape = (triangles.shape[0], bary.shape[0])
        return cls(
            nodes=triangles,
            bary=bary,
            offsets=np.zeros((*shape, 3)),
            mask=np.ones(shape, dtype=bool),
        )

    @property
    def slot_count(self) -> int:
        """Nodes each group depends on: 1 for node patches, 3 for triangles."""
        return 1 if not np.any(self.bary[:, 1:]) else 3

    def points(self, nodes: np.ndarray, rotation: np.ndarray, level: int) -> np.ndarray:
        """3-D sample points (G, M, 3), m, for nodes (N, 3) and the patch orientation (3, 3).

        Offsets are rotated by ``rotation`` (the head's rotation since frame 1) and scaled by
        2**level so a patch keeps its size in pixels on every pyramid level.
        """
        offsets = float(1 << level) * (self.offsets @ rotation.T)
        if self.slot_count == 1:
            return nodes[self.nodes[:, 0]][:, None, :] + offsets
        return np.einsum('mk,gkd->gmd', self.bary, nodes[self.nodes]) + offsets


@dataclass(frozen=True)
class NormalEquations:
    """Gauss-Newton terms of an image term, by node blocks.

    Attributes:
        cost: robust cost, grey^2.
        hessian: (3N, 3N) J^T W J, node-major, grey^2 / m^2.
        gradient: (3N,) J^T W r, grey^2 / m.
        group_rms: (G,) RMS of the leading (k = 0) ZSSD residual of each group, grey levels
            (NaN if no sample of the group is inside the image).
        group_contrast: (G,) standard deviation of the leading template in each group, grey
            levels; ``group_rms / group_contrast`` is about 1 for an unrelated image.
    """

    cost: float
    hessian: np.ndarray
    gradient: np.ndarray
    group_rms: np.ndarray
    group_contrast: np.ndarray


def sample_templates(
    image: np.ndarray, camera: PinholeCamera, points: np.ndarray, level: int
) -> np.ndarray:
    """Grey levels (G, M) of an image (a pyramid level) at 3-D sample points (G, M, 3)."""
    pixels = camera.project(points.reshape(-1, 3)) / float(1 << level)
    values, _ = sample_with_gradient(image, pixels)
    return values.reshape(points.shape[:2])


def huber_scale(residuals: np.ndarray, floor: float) -> float:
    """Robust scale of residuals: 1.4826 median |r| (the normal MAD), at least ``floor``."""
    finite = residuals[np.isfinite(residuals)]
    if finite.size == 0:
        return floor
    return max(floor, 1.4826 * float(np.median(np.abs(finite))))


def image_cost(
    image: np.ndarray,
    camera: PinholeCamera,
    layout: SampleLayout,
    points: np.ndarray,
    level: int,
    templates: np.ndarray,
    coefficients: np.ndarray,
    huber: float,
) -> float:
    """The robust cost of :func:`image_normal_equations` alone (no derivatives), grey^2."""
    pixels = camera.project(points.reshape(-1, 3)) / float(1 << level)
    values = sample_points(image, pixels)
    valid = _valid(pixels, image.shape, points, layout)
    return _robust_residuals(values, valid, templates, coefficients, huber)[3]


def image_normal_equations(
    image: np.ndarray,
    camera: PinholeCamera,
    layout: SampleLayout,
    points: np.ndarray,
    level: int,
    templates: np.ndarray,
    coefficients: np.ndarray,
    huber: float,
    num_nodes: int,
) -> NormalEquations:
    """Robust ZSSD cost of one camera's image against templates, and its normal equations.

    Args:
        image: (H, W) float32 pyramid level ``level`` of the current image I_c.
        camera: the camera of that image (its P maps left-frame points to level-0 pixels).
        layout: the sample layout.
        points: (G, M, 3) current sample points (:meth:`SampleLayout.points`), m.
        level: pyramid level.
        templates: (K, G, M) template grey levels T_k.
        coefficients: (K,) a_k >= 0, or (K, G) for a coefficient per group.
        huber: Huber threshold, grey levels.
        num_nodes: N.

    Returns:
        The cost, the normal equations by node blocks and the RMS of the k = 0 residual.
    """
    groups, samples = points.shape[:2]
    scale = 1.0 / float(1 << level)
    pixels, projection_jacobian = camera.project_with_jacobian(points.reshape(-1, 3))
    pixels = pixels * scale
    values, gradient = sample_with_gradient(image, pixels)
    valid = _valid(pixels, image.shape, points, layout)
    counts = valid.sum(axis=1)
    safe_counts = np.maximum(counts, 1)[:, None]
    differences, weight, weighted_residual, cost = _robust_residuals(
        values, valid, templates, coefficients, huber
    )
    # d I / d P per sample (G, M, 3), then per node slot (G, M, S slots * 3); a single-node
    # layout has one slot, a triangle layout three.
    slot_count = layout.slot_count
    row = gradient[:, :1] * projection_jacobian[:, 0] + gradient[:, 1:] * projection_jacobian[:, 1]
    row = row.reshape(groups, samples, 3) * scale
    slots = layout.bary[None, :, :slot_count, None] * row[:, :, None, :]
    slots = slots.reshape(groups, samples, 3 * slot_count) * valid[..., None]
    slots -= valid[..., None] * (slots.sum(axis=1) / safe_counts)[:, None, :]
    hessian_slots = np.swapaxes(slots * weight[..., None], 1, 2) @ slots
    gradient_slots = np.matmul(weighted_residual[:, None, :], slots)[:, 0]
    shape = (groups, slot_count, 3, slot_count, 3)
    blocks = hessian_slots.reshape(shape).transpose(0, 1, 3, 2, 4)
    nodes = layout.nodes[:, :slot_count]
    rows = np.broadcast_to(nodes[:, :, None], shape[:2] + (slot_count,))
    cols = np.broadcast_to(nodes[:, None, :], shape[:2] + (slot_count,))
    hessian = scatter_blocks(rows, cols, blocks, num_nodes)
    node_gradient = scatter_vectors(
        nodes, gradient_slots.reshape(groups, slot_count, 3), num_nodes
    )
    leading = templates[0] - (templates[0] * valid).sum(axis=1, keepdims=True) / safe_counts
    with np.errstate(invalid='ignore', divide='ignore'):
        group_rms = np.sqrt((differences[0] ** 2).sum(axis=1) / counts)
        group_contrast = np.sqrt((valid * leading**2).sum(axis=1) / counts)
    return NormalEquations(
        cost=cost,
        hessian=hessian,
        gradient=node_gradient,
        group_rms=group_rms,
        group_contrast=group_contrast,
    )


def _valid(
    pixels: np.ndarray, shape: tuple[int, int], points: np.ndarray, layout: SampleLayout
) -> np.ndarray:
    """(G, M) samples in use: in the layout's mask, in front of the camera, inside the image."""
    valid = inside_image(pixels, shape, margin=1.0) & (points[..., 2].ravel() > 0)
    return valid.reshape(points.shape[:2]) & layout.mask


def _robust_residuals(
    values: np.ndarray,
    valid: np.ndarray,
    templates: np.ndarray,
    coefficients: np.ndarray,
    huber: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """ZSSD residuals against each template and their Huber-weighted combination.

    Returns:
        ``(differences, weight, weighted_residual, cost)``: (K, G, M) residuals with each
        group's mean removed (0 where not valid); (G, M) total weight sum_k a_k w_k; (G, M)
        sum_k a_k w_k r_k; the robust cost sum_k a_k rho_huber(r_k).
    """
    counts = np.maximum(valid.sum(axis=1), 1)[:, None]
    differences = values.reshape(valid.shape)[None] - templates
    differences -= (differences * valid).sum(axis=2, keepdims=True) / counts[None]
    differences *= valid
    magnitude = np.abs(differences)
    robust = np.minimum(1.0, huber / np.maximum(magnitude, 1e-12))
    coefficients = np.asarray(coefficients, dtype=float).reshape(templates.shape[0], -1, 1)
    weighted = coefficients * robust
    loss = np.where(magnitude <= huber, magnitude**2, 2.0 * huber * magnitude - huber**2)
    return (
        differences,
        weighted.sum(axis=0),
        (weighted * differences).sum(axis=0),
        float((coefficients * loss).sum()),
    )
