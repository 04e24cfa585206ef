"""The regions of interest of eq. 6: where each pyramid level's ROIs lie on the face.

Regions of interest are small 3-D surface patches in the face frame around each node, on the
thin-plate surface through the nodes (:mod:`.surface_patches`), projected through eq. 1-2 at
frames n, n-1 and 1: they foreshorten with out-of-plane rotation, so the templates of frames n-1
and 1 stay comparable as the head turns (the seed's §4.4 weak point). The samples deform with
eq. 3 like the skin between the nodes (the node bases carried to them by thin-plate
interpolation, :func:`~.surface_patches.patch_basis`), so an expression stretches the patches
instead of being read as a head rotation (§4.4's x-axis error): measured on a 1000-frame
synthetic sequence with an exact model and initialisation, pitch error 0.96 -> 0.37 degrees and
alpha error 7.3 -> 2.6 % (flat lighting); under moving light 1.18 -> 0.81 degrees.

:class:`RoiLayout` places each pyramid level's ROIs on the face at a track's sigma (and, after a
bundle adjustment of the first views, on the skin it measured, :mod:`.bundle`); the model posed
and projected samples an image on them (:mod:`.mono_projection`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.topology import Group
from face_tracking_ros.tracking.bundle import ray_directions, skin_offsets, surface_basis
from face_tracking_ros.tracking.mono_config import MonoTrackerConfig
from face_tracking_ros.tracking.projection import POSE_DIM
from face_tracking_ros.tracking.surface_patches import (
    ThinPlate,
    node_frames,
    patch_basis,
    patch_interpolation,
    surface_patch_interpolation,
)


class Params(NamedTuple):
    """The estimated quantities of eq. 1 and 3."""

    omega: np.ndarray
    t: np.ndarray
    alpha: np.ndarray
    sigma: np.ndarray

    def updated(self, step: np.ndarray, q: int) -> Params:
        """Parameters after a solver step over (omega, t, alpha[, sigma])."""
        sigma_step = step[POSE_DIM + q :]
        return Params(
            omega=self.omega + step[:3],
            t=self.t + step[3:6],
            alpha=self.alpha + step[POSE_DIM : POSE_DIM + q],
            sigma=self.sigma + sigma_step if sigma_step.size else self.sigma,
        )


class Roi(NamedTuple):
    """One pyramid level's ROI samples relative to their nodes, deforming with eq. 3.

    Attributes:
        offsets: (3, N, M) offsets from each node to its samples at alpha = 0 and the track's
            initial sigma, face frame, component-major, m.
        action: (q, 3, N, M) their derivative with respect to alpha (:func:`patch_basis`).
        identity: (p, 3, N, M) their derivative with respect to sigma.
        sigma: (p,) the sigma of ``offsets``.
    """

    offsets: np.ndarray
    action: np.ndarray
    identity: np.ndarray
    sigma: np.ndarray

    def basis(self, free_sigma: bool) -> np.ndarray:
        """(c, 3, N, M) derivative of the offsets with respect to alpha (then sigma)."""
        if not free_sigma:
            return self.action
        return np.concatenate([self.action, self.identity])


class RoiSurface(NamedTuple):
    """The face at an estimate where every pyramid level's ROIs are laid (:meth:`RoiLayout.at`).

    Attributes:
        params: the estimate: its sigma shapes the nodes, its depth sets the grid's spacing and
            its pose the rays a skin depth moves the samples along.
        shape: (N, 3) eq. 3's nodes at its sigma (alpha = 0), face frame, m.
        grid: (N, M, 2) the ROI sample offsets in grid steps (:meth:`RoiLayout.grid`).
        plate: the thin plate through the nodes, solved once for every level's samples.
    """

    params: Params
    shape: np.ndarray
    grid: np.ndarray
    plate: ThinPlate


class RoiLayout:
    """Where each pyramid level's ROIs lie on the face of a track.

    Args:
        model: the face model (eq. 3).
        focal: the camera's focal length, px.
        grid: (M, 2) the ROI's square of sample offsets, in grid steps
            (:func:`~face_tracking_ros.imaging.square_offsets` of ``patch_half_size``).
        config: the tracker's tunables (``patch_half_size``, ``patch_spacing_px``,
            ``edge_patch_shift``).
    """

    def __init__(
        self, model: FaceModel, focal: float, grid: np.ndarray, config: MonoTrackerConfig
    ) -> None:
        """Keep what the ROIs are built from."""
        self._model = model
        self._focal = focal
        self._grid = grid
        self._config = config
        self._triangles = model.topology.triangles
        self._edge_nodes = model.topology.group_mask(Group.EDGE)
        self._node_bases = (
            np.ascontiguousarray(model.action_basis_nodes()),
            model.shape_basis_nodes(),
        )

    def rois(self, params: Params, num_levels: int) -> tuple[tuple[Roi, ...], np.ndarray]:
        """Every level's ROI samples (:meth:`roi`) and the (N, 3) node normals at ``params``."""
        surface = self.at(params)
        rois = tuple(self.roi(surface, level) for level in range(num_levels))
        return rois, self.normals(params.sigma)

    def normals(self, sigma: np.ndarray) -> np.ndarray:
        """(N, 3) node normals of the mesh at ``sigma`` (alpha = 0), face frame."""
        return node_frames(self._model.identity_shape(sigma), self._triangles)[:, 2]

    def at(self, params: Params) -> RoiSurface:
        """The face at ``params`` where its ROIs are laid: nodes, grid and thin plate."""
        shape = self._model.identity_shape(params.sigma)
        return RoiSurface(params, shape, self.grid(shape), ThinPlate.through(shape))

    def roi(self, surface: RoiSurface, level: int, depth: np.ndarray | None = None) -> Roi:
        """One pyramid level's ROI samples on the face at an estimate (:meth:`at`).

        Each ROI is a square grid in the face frame's x-y directions lifted onto the thin-plate
        surface through the nodes, with the spacing that gives ``patch_spacing_px`` at the
        initial depth, doubled on every coarser level; face-edge nodes' grids are shifted towards
        the face centre so they cover skin rather than the background beyond the face edge. With
        a skin ``depth`` (a bundle adjustment's) the samples are moved onto that skin
        (:meth:`on_skin`), and only the moved samples' bases are made. The samples move with
        eq. 3's bases carried to them by :func:`patch_basis`.
        """
        params = surface.params
        spacing = self._config.patch_spacing_px * params.t[2] / self._focal
        steps = surface.grid * (spacing * (1 << level))
        offsets, weights = surface_patch_interpolation(surface.plate, steps)
        offsets = np.ascontiguousarray(offsets.transpose(2, 0, 1))
        if depth is not None:
            return self.on_skin(offsets, surface, level, depth)
        action, identity = self._bases(weights)
        return Roi(offsets, action, identity, params.sigma)

    def on_skin(
        self, offsets: np.ndarray, surface: RoiSurface, level: int, depth: np.ndarray
    ) -> Roi:
        """A level's ROI on skin ``depth``, from its (3, N, M) sample ``offsets`` on the surface.

        The offsets are :meth:`roi`'s on the thin-plate surface at ``surface``. Each sample
        moves along its ray from frame 1's camera (``surface.params``) by the skin depth
        (:func:`~.bundle.skin_offsets`), and eq. 3's bases are carried to where it moved.
        (Keeping the surface samples' bases would save a thin-plate evaluation per level, a
        fifth of an adjustment's time; it moved the mono protocol's rotation errors by 0.05
        degrees at most, but with it a 20-image gap at 30 fps (test_dropped_images) left the
        track 15 images on a wrong pose.)
        """
        params, shape = surface.params, surface.shape
        basis = surface_basis(self.patch_coordinates(surface.grid, level))
        points = shape[:, None, :] + offsets.transpose(1, 2, 0)
        direction = ray_directions(points, params.omega, params.t).transpose(2, 0, 1)
        moved = skin_offsets(offsets, basis, direction, depth)
        weights = patch_interpolation(surface.plate, moved.transpose(1, 2, 0))
        action, identity = self._bases(weights)
        return Roi(np.ascontiguousarray(moved), action, identity, params.sigma)

    def _bases(self, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Eq. 3's action and identity bases at ROI samples of thin-plate ``weights``.

        (q, 3, N, M) and (p, 3, N, M), as :class:`Roi` holds them (:func:`patch_basis`).
        """
        action, identity = (
            np.ascontiguousarray(patch_basis(weights, node_basis).transpose(3, 2, 0, 1))
            for node_basis in self._node_bases
        )
        return action, identity

    def grid(self, shape: np.ndarray) -> np.ndarray:
        """(N, M, 2) ROI sample offsets in grid steps along the face frame's x and y.

        A square of ``(2 h + 1)^2`` steps per node; the face-edge nodes' grids shifted towards the
        face centre by ``edge_patch_shift`` h, so they cover skin rather than the background.
        """
        config = self._config
        inward = shape[:, :2].mean(axis=0) - shape[self._edge_nodes, :2]
        inward /= np.linalg.norm(inward, axis=1, keepdims=True)
        grid = np.repeat(self._grid[None], len(shape), axis=0)
        grid[self._edge_nodes] += inward[:, None, :] * (
            config.edge_patch_shift * config.patch_half_size
        )
        return grid

    def patch_coordinates(self, grid: np.ndarray, level: int) -> np.ndarray:
        """(N, M, 2) patch coordinates of a level's samples for the skin depth basis.

        In units of the level-0 ROI's half-width h; a coarser level's samples reach further out
        and are held at the edge of the level-0 ROI, where the skin depth was measured.
        """
        level_zero = grid / self._config.patch_half_size
        across = np.ascontiguousarray(level_zero.transpose(0, 2, 1))  # 12x faster to reduce
        low, high = across.min(axis=2)[:, None], across.max(axis=2)[:, None]
        return np.clip(level_zero * (1 << level), low, high)
