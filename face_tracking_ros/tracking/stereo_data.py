"""The image terms of the stereo tracker: eq. 4 over node patches, plus a face-texture term (§4.2).

Every image sample is a 3-D point tied to up to three nodes: ``P = sum_k b_k X^(n_k) + o`` with
barycentric weights b and an offset o, projected into a camera by eq. 2. A
:class:`SampleLayout` holds G groups of M such samples:

- node patches (the ROI of eq. 4): group i is node i alone (b = (1, 0, 0)) with offsets on a
  small grid lying on the face surface around the node (the thin-plate surface through the
  nodes), so the patch is seen with the right perspective in both cameras (a fronto-parallel
  square would be compressed differently in the two views on the sloping cheeks and temples,
  which biases the cross-camera terms); the tracker moves the offsets with the mesh's
  deformation (:class:`~.surface_patches.PatchDeformation`);
- face texture (the seed's §4.2 remedy): group t is triangle t of the mesh (the tracker's
  face-edge triangles), its samples on a barycentric grid inside it (o = 0); a boundary node
  sliding along the face edge distorts the texture of every triangle it belongs to, which this
  term sees.

For a current image I_c of camera c, the cost of one group is a robust sum over its samples of

    sum_k a_k rho_huber(I_c(P) - T_k - mean(I_c(P) - T_k))

over templates T_k (the same samples in earlier images) with coefficients a_k: for node patches
the four terms of eq. 4 ((1 - gamma) for the same camera, gamma for the other camera, at frame
n - 1), each split (1 - epsilon) : epsilon with the same terms against frame 1 (the drift term
of eq. 6 carried over to stereo). Removing each group's mean difference (ZSSD) makes the terms
insensitive to a brightness offset between the cameras or over time. A node patch removes more:
the least-squares brightness ramp ``a + b u + c v`` over its grid (u, v). Skin is not a
Lambertian surface; its highlight moves with the viewpoint (between the two cameras) and with
the expression, and changes a patch's brightness smoothly across it, which the cross-camera
terms would otherwise read as disparity. On the synthetic skin (a Blinn-Phong highlight) the
centre of the upper lip, a horizontal lip border with little texture of its own, was put 0.5 to
6 mm too far by the ZSSD alone; with the ramp removed, the node RMS of the 19-node mesh over
issue 5's six 380-frame training sequences went 1.25 -> 0.86 mm (34 nodes: 2.19 -> 2.07 mm). It
costs some low-frequency texture: on a textured plane, with no highlight, a stereo match errs by
0.27 instead of 0.19 mm RMS. A face-boundary node's one-sided patch keeps its mean only: its half
patch has little texture to spare, and its left-right residual is what tells a rim seen
differently by the two cameras (:mod:`.depth_refinement`).

The layouts of a tracker are laid end to end along one sample axis (:class:`SampleSet`), and
every camera's image is one row of the arrays, so one evaluation of all the image terms is a
few calls whatever the number of layouts and cameras: sample the images (:func:`sample_images`),
form the robust residuals (:func:`robust_residuals`), and only where the solver needs them the
Gauss-Newton normal equations by node blocks (:func:`node_blocks`, assembled by
:meth:`SampleSet.assemble`); the last two are compiled passes over the samples
(:mod:`.stereo_kernels`). Grey levels and their ZSSD residuals stay float32 as
sampled; weights, derivatives and sums are float64.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.camera import PinholeCamera, StereoRig
from face_tracking_ros.imaging import (
    GRADIENT_MARGIN,
    STENCIL_X,
    STENCIL_Y,
    PyramidLevel,
    sample_maps,
    sample_stencils,
    sample_xy,
    square_offsets,
)
from face_tracking_ros.tracking.stereo_kernels import (
    group_summaries,
    layout_points,
    node_normal_blocks,
    pixel_maps,
    scatter_sums,
    space_rows,
    stencil_maps,
    zssd_residuals,
)
from face_tracking_ros.tracking.surface_patches import surface_patch_offsets

BRIGHTNESS_TERMS = 3  # 1, u, v: a brightness ramp over a node patch (see SampleLayout)
# Where the node patches' surface passes beyond each face-boundary node: this far out in camera
# x-y (away from the nodes' centroid) and this far behind it in camera z, m (see SampleLayout).
RIM_OUTWARD = 0.010
RIM_BEHIND = 0.020
_NO_FIELD = np.zeros((3, 0))  # SampleSet.points without a deformation


@dataclass(frozen=True)
class SampleLayout:
    """G groups of M 3-D sample points tied to mesh nodes.

    Attributes:
        nodes: (G, 3) int node indices n_k of each group (repeated for a single-node group).
        bary: (M, 3) barycentric weights b_k of each sample, rows sum to 1.
        offsets: (G, M, 3) offsets o at pyramid level 0 in the frame-1 orientation, m.
        mask: (G, M) bool, the samples in use.
        brightness: (M, BRIGHTNESS_TERMS) the brightness model of each sample, ``1, u, v``
            over a node patch's grid (u, v in [-1, 1]); see :func:`robust_residuals`.
        terms: (G,) int, how many leading brightness terms each group's residuals are fitted
            with and freed of: 1 (the mean, ZSSD) or BRIGHTNESS_TERMS (a brightness ramp).
        cross: (G, M) weight of each sample in the cross-camera terms (mean 1 over a group's
            grid; see :meth:`node_patches`).
    """

    nodes: np.ndarray
    bary: np.ndarray
    offsets: np.ndarray
    mask: np.ndarray
    brightness: np.ndarray
    terms: np.ndarray
    cross: np.ndarray

    @classmethod
    def node_patches(
        cls,
        nodes: np.ndarray,
        spacing: np.ndarray,
        half_size: int,
        one_sided: np.ndarray,
        taper: float = 0.0,
    ) -> SampleLayout:
        """Patches of (2 h + 1)^2 samples on the face surface around each node (ROI of eq. 4).

        The samples lie on a square grid in camera x and y about the node, lifted onto the
        thin-plate surface through the nodes (:func:`.surface_patches.surface_patch_offsets`).

        A node on the face boundary sees the face on one side only; beyond it lie the neck,
        the ears or the background at other depths, which move differently in the two cameras
        and over time. Its patch keeps only the samples on the face side: those whose offset
        points towards the centroid of the mesh (§4.2). The node's own sample lies on the rim
        and is left out (its offset is zero but for rounding, whose sign must not decide).

        Beyond the face boundary the skin turns away from the cameras, towards the ears and
        under the jaw, which the nodes alone do not tell: the thin plate through them runs on
        flat there and lies behind the convex skin on the face side of a boundary node, 0.6
        (temples) to 3.4 mm (jaw) on average over the one-sided 7x7 patches of issue 5's
        subjects, so the left-right cost of those patches has its minimum 1.4 mm too near on
        average (noise-free renders; 2.8 mm RMS, the jaws left out). The surface therefore also
        passes through one point beyond each boundary node (:func:`rim_points`), which halves
        that: 0.8 mm RMS off the skin, the cost's minimum 1.6 mm RMS off.

        Inside the face the thin plate is flatter than the skin where the skin curves between
        the nodes: it runs in front of the skin around a convex node (on three of issue 5's
        subjects the nose tip by 0.5-1.1 mm on average over a 7x7 patch, up to 3.7 mm at its
        corners; the upper lip and the chin by 0.4-0.7 mm), and the left-right cost of the
        patch has its minimum too far (the nose tip 0.6-1.2 mm). The error of the patch grows
        with the square of the distance from the node, so the cross-camera terms of a
        two-sided patch can weigh its samples by a Gaussian of their grid distance from the
        node (``taper`` samples standard deviation, the tracker's ``cross_taper``; 0: all
        alike), scaled to a mean of 1 over the grid (``cross``). One-sided patches keep equal
        weights: their node lies on the rim and their surface is the rim points'.

        Args:
            nodes: (N, 3) nodes in the left camera frame, m.
            spacing: (N,) sample spacing at level 0, m (about one pixel: depth / focal).
            half_size: h, samples each side of the node.
            one_sided: (N,) bool, the boundary nodes whose patch keeps the face side only.
            taper: standard deviation of the cross-camera weights of a two-sided patch, in
                samples; 0 for equal weights.
        """
        one_sided = np.asarray(one_sided, dtype=bool)
        square = square_offsets(half_size).astype(float)
        grid = spacing[:, None, None] * square[None]
        offsets = surface_patch_offsets(nodes, grid, rim_points(nodes, one_sided))
        inward = nodes.mean(axis=0) - nodes
        facing = (np.einsum('nmd,nd->nm', offsets, inward) >= 0.0) & np.any(grid, axis=2)
        bary = np.zeros((grid.shape[1], 3))
        bary[:, 0] = 1.0
        return cls(
            nodes=np.repeat(np.arange(nodes.shape[0])[:, None], 3, axis=1),
            bary=bary,
            offsets=offsets,
            mask=facing | ~one_sided[:, None],
            brightness=np.column_stack([np.ones(len(square)), square / max(half_size, 1)]),
            terms=np.where(one_sided, 1, BRIGHTNESS_TERMS),
            cross=np.where(one_sided[:, None], 1.0, gaussian_taper(square, taper)),
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
        brightness = np.zeros((shape[1], BRIGHTNESS_TERMS))
        brightness[:, 0] = 1.0
        return cls(
            nodes=triangles,
            bary=bary,
            offsets=np.zeros((*shape, 3)),
            mask=np.ones(shape, dtype=bool),
            brightness=brightness,
            terms=np.ones(shape[0], dtype=np.int64),
            cross=np.ones(shape),
        )

    @property
    def slot_count(self) -> int:
        """Nodes each group depends on: 1 for node patches, 3 for triangles."""
        return 1 if not np.any(self.bary[:, 1:]) else 3


def gaussian_taper(square: np.ndarray, sigma: float) -> np.ndarray:
    """(M,) weights of a patch's grid samples, Gaussian in their distance from the node, mean 1.

    Args:
        square: (M, 2) grid offsets in samples (:func:`~face_tracking_ros.imaging.square_offsets`).
        sigma: standard deviation, samples; 0 for equal weights.
    """
    if sigma == 0:
        return np.ones(len(square))
    weights = np.exp(-0.5 * np.sum(square**2, axis=1) / sigma**2)
    return weights / weights.mean()


def rim_points(nodes: np.ndarray, boundary: np.ndarray) -> np.ndarray:
    """(K, 3) points where the skin runs beyond the K face-boundary nodes, m.

    Each lies :data:`RIM_OUTWARD` beyond its node in camera x-y, away from the centroid of the
    nodes, and :data:`RIM_BEHIND` farther from the camera (see :meth:`SampleLayout.node_patches`).

    Args:
        nodes: (N, 3) nodes in the left camera frame, m.
        boundary: (N,) bool, the face-boundary nodes.
    """
    edge = nodes[boundary]
    outward = edge[:, :2] - nodes[:, :2].mean(axis=0)
    outward /= np.linalg.norm(outward, axis=1, keepdims=True)
    return np.column_stack([edge[:, :2] + RIM_OUTWARD * outward, edge[:, 2] + RIM_BEHIND])


@dataclass(frozen=True)
class SampleSet:
    """The samples of one or more layouts along one axis, layout after layout, group after group.

    Sample arrays are component-major: (3, S) points, (C, S) grey levels of C images.

    Attributes:
        layouts: the layouts; layout l holds samples ``bounds[l]:bounds[l + 1]``.
        bounds: (L + 1,) int.
        mask: (S,) bool, the samples in use.
        gather: per layout, (k, S_l) node index of each of the k slots of every sample.
        weights: per layout, (k, S_l) barycentric weight b of each slot (k = 1: weight 1).
        offsets: (S, 3) offsets at level 0 in the frame-1 orientation, m.
        block_index: (B,) flat index in the (3N, 3N) matrix of every entry of the layouts' node
            blocks (:func:`node_blocks`), layout after layout.
        vector_index: (V,) index in the (3N,) vector of every entry of their node vectors.
        num_nodes: N.
        brightness: (S, BRIGHTNESS_TERMS) the brightness model of every sample.
        terms: per layout, (G_l,) int brightness terms of each group (:class:`SampleLayout`).
        group_terms: (G,) int, ``terms`` of every group, layout after layout.
        group_sizes: (L,) int, M_l, the samples of a group of each layout.
        group_bounds: (L + 1,) the first group of every layout, then G.
        cross: (S,) every sample's weight in the cross-camera terms (:class:`SampleLayout`).
    """

    layouts: tuple[SampleLayout, ...]
    bounds: np.ndarray
    mask: np.ndarray
    gather: tuple[np.ndarray, ...]
    weights: tuple[np.ndarray, ...]
    offsets: np.ndarray
    block_index: np.ndarray
    vector_index: np.ndarray
    num_nodes: int
    brightness: np.ndarray
    terms: tuple[np.ndarray, ...]
    group_terms: np.ndarray
    group_sizes: np.ndarray
    group_bounds: tuple[int, ...]
    cross: np.ndarray

    @classmethod
    def of(cls, layouts: Sequence[SampleLayout], num_nodes: int) -> SampleSet:
        """Lay out ``layouts`` (of a mesh of ``num_nodes`` nodes) along one sample axis."""
        layouts = tuple(layouts)
        sizes = [layout.mask.size for layout in layouts]
        group_counts = [layout.mask.shape[0] for layout in layouts]
        terms = [layout.terms.astype(np.int64) for layout in layouts]
        gather, weights, blocks, vectors = [], [], [], []
        for layout in layouts:
            groups, samples = layout.mask.shape
            slots = layout.slot_count
            gather.append(np.repeat(layout.nodes[:, :slots].T, samples, axis=1))
            weights.append(np.tile(layout.bary[:, :slots].T, groups))
            # Row (slot, coordinate) of each group's block in the node-major unknowns.
            rows = (3 * layout.nodes[:, :slots, None] + np.arange(3)).reshape(groups, -1)
            blocks.append((rows[:, :, None] * (3 * num_nodes) + rows[:, None, :]).ravel())
            vectors.append(rows.ravel())
        return cls(
            layouts=layouts,
            bounds=np.cumsum([0, *sizes]),
            mask=np.concatenate([layout.mask.ravel() for layout in layouts]),
            gather=tuple(gather),
            weights=tuple(weights),
            offsets=np.concatenate([layout.offsets.reshape(-1, 3) for layout in layouts]),
            block_index=np.concatenate(blocks),
            vector_index=np.concatenate(vectors),
            num_nodes=num_nodes,
            brightness=np.concatenate(
                [np.tile(layout.brightness, (layout.mask.shape[0], 1)) for layout in layouts]
            ),
            terms=tuple(terms),
            group_terms=np.concatenate(terms),
            group_sizes=np.array([layout.mask.shape[1] for layout in layouts]),
            group_bounds=tuple(int(b) for b in np.cumsum([0, *group_counts])),
            cross=np.concatenate([layout.cross.ravel() for layout in layouts]),
        )

    @property
    def size(self) -> int:
        """S, the number of samples."""
        return int(self.bounds[-1])

    def level_offsets(self, rotation: np.ndarray, level: int) -> np.ndarray:
        """(3, S) offsets turned by ``rotation`` (the head's rotation since frame 1), m.

        They are scaled by 2**level, so a patch keeps its size in pixels on every pyramid level.
        """
        return (float(1 << level) * (self.offsets @ rotation.T)).T

    def points(
        self,
        nodes: np.ndarray,
        offsets: np.ndarray,
        field: np.ndarray | None = None,
        scale: float = 1.0,
    ) -> np.ndarray:
        """(3, S) points ``sum_k b_k X^(n_k) + o`` for nodes (N, 3) and (3, S) offsets, m.

        Args:
            nodes: (N, 3) nodes, m.
            offsets: (3, S) offsets o of the samples, m.
            field: optional (3, S_p) deformation of the first S_p samples (the node patches,
                :meth:`~.surface_patches.PatchDeformation.field`), m; their offsets are then
                ``o + scale * field``.
            scale: the field's factor: 2^l for offsets of pyramid level l.
        """
        field = _NO_FIELD if field is None else field
        points = np.empty((3, self.size))
        layouts = zip(self.bounds[:-1], self.gather, self.weights, strict=True)
        for start, gather, weights in layouts:
            layout_points(nodes, offsets, field, scale, gather, weights, start, points)
        return points

    def assemble(
        self, blocks: Sequence[np.ndarray], vectors: Sequence[np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Sum the layouts' node blocks and vectors into the (3N, 3N) matrix and (3N,) vector.

        Args:
            blocks: per layout, (G_l, 3k, 3k) blocks (:func:`node_blocks`).
            vectors: per layout, (G_l, 3k) vectors.
        """
        return scatter_sums(
            tuple(blocks), tuple(vectors), self.block_index, self.vector_index, 3 * self.num_nodes
        )


class Sampled(NamedTuple):
    """C images sampled at the points of a :class:`SampleSet`, one row per image.

    Attributes:
        homogeneous: (C, 3, S) homogeneous pixel coordinates of the points in each image's
            pyramid level.
        values: (C, S) float32 grey levels.
        gradient: (C, 2, S) float32 image gradient (d/dx, d/dy), grey levels per level pixel.
        valid: (C, S) bool, the samples in use: in the set's mask, in front of the camera and
            at least a pixel inside the image.
    """

    homogeneous: np.ndarray
    values: np.ndarray
    gradient: np.ndarray
    valid: np.ndarray


class Residuals(NamedTuple):
    """ZSSD residuals of sampled images against their templates, Huber-weighted.

    Attributes:
        differences: (C, K, S) float32 residuals against each template with each group's mean
            removed (0 where not valid).
        counts: per layout, (C, G_l) valid samples of each group.
        weight: (C, S) total weight sum_k a_k w_k.
        weighted_residual: (C, S) sum_k a_k w_k r_k.
        cost: the robust cost sum_k a_k rho_huber(r_k), grey^2.
    """

    differences: np.ndarray
    counts: tuple[np.ndarray, ...]
    weight: np.ndarray
    weighted_residual: np.ndarray
    cost: float


class Huber(NamedTuple):
    """Huber thresholds of every sample.

    Attributes:
        threshold: (S,) k, grey levels.
        twice: (S,) 2 k.
        square: (S,) k^2.
        inlier_bound: (S,) float32, the largest float32 <= k: a float32 |r| is within k exactly
            when it is within this (a float32 comparison).
    """

    threshold: np.ndarray
    twice: np.ndarray
    square: np.ndarray
    inlier_bound: np.ndarray

    @classmethod
    def of(cls, samples: SampleSet, thresholds: Sequence[float]) -> Huber:
        """One threshold per layout of ``samples``, grey levels."""
        sizes = np.diff(samples.bounds)
        thresholds = np.asarray(thresholds, dtype=float)
        bound = thresholds.astype(np.float32)
        bound = np.where(bound > thresholds, np.nextafter(bound, np.float32(-np.inf)), bound)
        return cls(
            threshold=np.repeat(thresholds, sizes),
            twice=np.repeat(2.0 * thresholds, sizes),
            square=np.repeat(thresholds**2, sizes),
            inlier_bound=np.repeat(bound.astype(np.float32), sizes),
        )


def level_projections(cameras: Sequence[PinholeCamera], level: int) -> np.ndarray:
    """(C, 3, 4) projection matrices P of eq. 2 onto pyramid level ``level`` of each camera."""
    projections = np.array([camera.p for camera in cameras])
    projections[:, :2] /= float(1 << level)
    return projections


def homogeneous_pixels(projections: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(C, 3, S) homogeneous pixels ``P X`` of (3, S) points in C cameras (eq. 2).

    Args:
        projections: (C, 3, 4) projection matrices (:func:`level_projections`).
        points: (3, S) points in the left camera frame, m.
    """
    count = len(projections)
    linear = projections[:, :, :3].reshape(3 * count, 3)
    return (linear @ points + projections[:, :, 3].reshape(-1, 1)).reshape(count, 3, -1)


# An image to sample: an array, or a pyramid level that the sampler makes where it reads it.
ImageSource = np.ndarray | PyramidLevel


def sample_images(
    images: Sequence[ImageSource],
    projections: np.ndarray,
    points: np.ndarray,
    mask: np.ndarray,
) -> Sampled:
    """Sample C images at 3-D points (eq. 2), with their gradients.

    The pixels, their stencil maps and the valid samples come from one compiled pass
    (:func:`~.stereo_kernels.stencil_maps`), the samples from ``cv2.remap``
    (:func:`~face_tracking_ros.imaging.sampling.sample_stencils`); a pyramid level is made over
    the box its maps span.

    Args:
        images: C (H, W) float32 images, or pyramid levels (one level of each camera, all of one
            size).
        projections: (C, 3, 4) their projection matrices (:func:`level_projections`).
        points: (3, S) points in the left camera frame, m.
        mask: (S,) bool, the samples in use.

    Raises:
        InputError: if a point's pixel is not finite.
    """
    homogeneous = homogeneous_pixels(projections, points)
    height, width = images[0].shape
    high_x, high_y = width - 1 - GRADIENT_MARGIN, height - 1 - GRADIENT_MARGIN
    depth, mask = np.ascontiguousarray(points[2]), np.ascontiguousarray(mask)  # the kernel's
    maps_x, maps_y, valid, boxes, finite = stencil_maps(
        homogeneous, depth, mask, STENCIL_X, STENCIL_Y, GRADIENT_MARGIN, high_x, high_y
    )
    if not finite:
        msg = 'points hold NaN or Inf'
        raise InputError(msg)
    made = [_made(image, box) for image, box in zip(images, boxes, strict=True)]
    values, gradient = sample_stencils(made, maps_x, maps_y)
    return Sampled(homogeneous=homogeneous, values=values, gradient=gradient, valid=valid)


def sample_values(
    images: Sequence[ImageSource], projections: np.ndarray, points: np.ndarray
) -> np.ndarray:
    """(C, S) float32 grey levels of C images at (3, S) points (:func:`sample_images` values).

    The float32 pixels and the boxes they span come from one compiled pass
    (:func:`~.stereo_kernels.pixel_maps`); a pyramid level is made over its box.

    Raises:
        InputError: if a point's pixel is not finite.
    """
    x, y, boxes, finite = pixel_maps(homogeneous_pixels(projections, points))
    if not finite:
        msg = 'points hold NaN or Inf'
        raise InputError(msg)
    values = np.empty(x.shape, dtype=np.float32)
    for row, (image, box) in enumerate(zip(images, boxes, strict=True)):
        if isinstance(image, np.ndarray):
            values[row] = sample_xy(image, x[row], y[row])  # its type checked
        else:
            values[row] = sample_maps(image.reaching(box), x[row], y[row])
    return values


def _made(image: ImageSource, box: Sequence[float]) -> np.ndarray:
    """``image``, made at least over ``box`` (its pixels' least and greatest x, then y)."""
    return image if isinstance(image, np.ndarray) else image.reaching(box)


def robust_residuals(
    samples: SampleSet,
    sampled: Sampled,
    templates: np.ndarray,
    coefficients: np.ndarray,
    huber: Huber,
) -> Residuals:
    """The robust cost of sampled images against templates (the image terms' E).

    One compiled pass (:func:`~.stereo_kernels.zssd_residuals`).

    Args:
        samples: the sample set.
        sampled: its C images.
        templates: (C, K, S) float32 template grey levels T_k of each image.
        coefficients: (K, S) a_k >= 0 of every sample.
        huber: the Huber thresholds.
    """
    differences, counts, weight, weighted_residual, cost = zssd_residuals(
        sampled.values,
        templates,
        sampled.valid,
        coefficients,
        huber.threshold,
        huber.twice,
        huber.square,
        huber.inlier_bound,
        samples.bounds,
        samples.group_sizes,
        samples.brightness,
        samples.group_terms,
    )
    bounds = samples.group_bounds
    return Residuals(
        differences=differences,
        counts=tuple(counts[:, bounds[i] : bounds[i + 1]] for i in range(len(bounds) - 1)),
        weight=weight,
        weighted_residual=weighted_residual,
        cost=cost,
    )


def node_blocks(
    samples: SampleSet, sampled: Sampled, residuals: Residuals, projections: np.ndarray
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Gauss-Newton terms J^T W J and J^T W r of the image terms, by group, summed over images.

    The Jacobian of a sample with respect to its k slot nodes is ``b_k (d pi / d P)^T grad I``
    (eq. 2; :func:`~.stereo_kernels.space_rows`), minus its group's mean (ZSSD) or brightness
    ramp, as the residuals; the blocks are summed by
    :func:`~.stereo_kernels.node_normal_blocks`.

    Args:
        samples: the sample set.
        sampled: its C images, sampled.
        residuals: their robust residuals.
        projections: (C, 3, 4) the images' projection matrices.

    Returns:
        ``(blocks, vectors)``: per layout, (G_l, 3k, 3k) J^T W J and (G_l, 3k) J^T W r of each
        group (grey^2 / m^2, grey^2 / m), for :meth:`SampleSet.assemble`.
    """
    valid = sampled.valid
    rows = space_rows(projections, sampled.homogeneous, sampled.gradient, valid)
    blocks, vectors = [], []
    for index, (counts, slot_weights) in enumerate(
        zip(residuals.counts, samples.weights, strict=True)
    ):
        block, vector = node_normal_blocks(
            rows,
            valid,
            residuals.weight,
            residuals.weighted_residual,
            counts,
            slot_weights,
            samples.bounds[index],
            samples.layouts[index].mask.shape[1],
            samples.brightness,
            samples.terms[index],
        )
        blocks.append(block)
        vectors.append(vector)
    return blocks, vectors


class GroupStatistics(NamedTuple):
    """Per-group residual summaries of an evaluation: RMS per layout, contrasts of the first.

    Attributes:
        rms: per layout, (C, G_l) RMS of the leading (k = 0) ZSSD residual of each group, grey
            levels (NaN if no sample of the group is valid).
        contrast: (C, G_0) standard deviation of the leading template in each group of the
            first layout (a tracker's node patches), grey levels; ``rms / contrast`` is about 1
            for an unrelated image.
        image_contrast: (C, G_0) the same of the image; ``image_contrast / contrast`` is about
            1 while the face is seen, 0 for a blank image.
    """

    rms: tuple[np.ndarray, ...]
    contrast: np.ndarray
    image_contrast: np.ndarray


def group_statistics(
    samples: SampleSet, sampled: Sampled, residuals: Residuals, leading: np.ndarray
) -> GroupStatistics:
    """RMS residual of every group; template and image contrast of the first layout's groups.

    One compiled pass (:func:`~.stereo_kernels.group_summaries`, numpy's bits). The loss
    checks read the node patches' contrasts alone, so the face texture's are not made.

    Args:
        samples: the sample set.
        sampled: its C images.
        residuals: their robust residuals.
        leading: (C, S) the leading template T_0 of each image.
    """
    rms, contrast, image_contrast = group_summaries(
        residuals.differences[:, 0],
        leading,
        sampled.values,
        sampled.valid,
        np.concatenate(residuals.counts, axis=1),
        samples.bounds,
        samples.group_sizes,
    )
    bounds = samples.group_bounds
    return GroupStatistics(
        tuple(rms[:, bounds[i] : bounds[i + 1]] for i in range(len(bounds) - 1)),
        contrast,
        image_contrast,
    )


def group_contrast(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(..., G) RMS of each group's valid values about their mean (NaN for a group without any).

    Args:
        values: (..., G, M) values of G groups of M samples (invalid ones may be NaN).
        valid: (..., G, M) bool, the samples in use.
    """
    count = valid.sum(axis=-1)
    samples = np.where(valid, values, 0.0)
    mean = samples.sum(axis=-1, keepdims=True) / np.maximum(count, 1)[..., None]
    centred = np.where(valid, samples - mean, 0.0)
    with np.errstate(invalid='ignore', divide='ignore'):
        return np.sqrt((centred**2).sum(axis=-1) / count)


class DepthTerms(NamedTuple):
    """The left-right term of every node patch, linearised in a depth change along a direction.

    Attributes:
        slope: (N,) J^T W r along the direction, grey^2 / m.
        curvature: (N,) J^T W J along it, grey^2 / m^2.
        rms: (N,) RMS left-right residual of each patch, grey levels.
    """

    slope: np.ndarray
    curvature: np.ndarray
    rms: np.ndarray


def depth_terms(
    rig: StereoRig,
    left: ImageSource,
    right: ImageSource,
    patches: SampleSet,
    nodes: np.ndarray,
    directions: np.ndarray,
    rotation: np.ndarray,
    huber: float,
) -> DepthTerms:
    """The cross-camera term of eq. 4 within one pair, per node patch, along ``directions``.

    The patches are sampled in the left image (the template) and compared with the right image
    at the same points, with the patches' brightness terms removed and each sample weighed as
    in the cross-camera terms of eq. 4 (:class:`SampleLayout`, ``cross``); each node's 3x3
    block of the normal equations is projected on its direction.

    Args:
        rig: the rectified rig.
        left: (H, W) float32 full-resolution left image, or its pyramid's level 0.
        right: the right image so.
        patches: a sample set of node patches alone (one group per node).
        nodes: (N, 3) nodes, m.
        directions: (N, 3) unit directions of the depth changes.
        rotation: (3, 3) patch orientation (the head's rotation since frame 1).
        huber: Huber threshold, grey levels.
    """
    points = patches.points(nodes, patches.level_offsets(rotation, 0))
    left_projection, right_projection = level_projections((rig.left, rig.right), 0)
    template = sample_values((left,), left_projection[None], points)
    sampled = sample_images((right,), right_projection[None], points, patches.mask)
    coefficients = patches.cross[None]
    residuals = robust_residuals(
        patches, sampled, template[:, None], coefficients, Huber.of(patches, [huber])
    )
    (blocks,), (vectors,) = node_blocks(patches, sampled, residuals, right_projection[None])
    statistics = group_statistics(patches, sampled, residuals, template)
    return DepthTerms(
        slope=np.einsum('na,na->n', directions, vectors),
        curvature=np.einsum('na,nab,nb->n', directions, blocks, directions),
        rms=statistics.rms[0][0],
    )
