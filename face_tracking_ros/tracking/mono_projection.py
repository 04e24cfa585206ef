"""The face model posed at an estimate and seen by the camera, where the tracker samples its ROIs.

:class:`FaceProjection` poses the model at a parameter vector (eq. 1, 3), projects it (eq. 2),
weighs each node by how squarely it faces the camera, and samples an image on the ROIs of
:mod:`.mono_rois` there (:class:`Sampled`).
"""

from __future__ import annotations

from functools import cached_property
import math
from typing import NamedTuple

import numpy as np

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.imaging import GRADIENT_MARGIN, ImagePyramid, sample_maps
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.tracking.mono_kernels import node_visibility, roi_maps
from face_tracking_ros.tracking.mono_rois import Params, Roi


class Sampled(NamedTuple):
    """One level's samples of the ROIs at a pose, and which lie inside the image."""

    samples: np.ndarray  # (N, M) float32
    inside: np.ndarray  # (N, M) bool, at least 1 px inside


class RoiMaps(NamedTuple):
    """One level's ROI points at a pose and the ``cv2.remap`` maps of them.

    Attributes:
        rotated: (3, N, M) ``R P`` of the points (eq. 1, 3), m.
        map_x: (S, N M) float32 x of the pixels (eq. 2), then of the stencil's points if any.
        map_y: (S, N M) float32 y likewise.
        inside: (N, M) the samples at least 1 px inside the image.
        box: (4,) least and greatest x, then y, of the pixels.
    """

    rotated: np.ndarray
    map_x: np.ndarray
    map_y: np.ndarray
    inside: np.ndarray
    box: np.ndarray


class _Pose:
    """The model posed at one parameter vector (eq. 1, 3), and its nodes seen (eq. 2) once asked.

    Attributes:
        params: the parameter vector.
        rotation: (3, 3) R(omega).
        d_rotation: (3, 3, 3) dR/domega_k.
        shape: (N, 3) the shape of eq. 3.
    """

    def __init__(self, params: Params, shape: np.ndarray, camera: PinholeCamera) -> None:
        """Pose the model of (N, 3) ``shape`` (eq. 3 at ``params``) at ``params``."""
        self.params = params
        self.rotation, self.d_rotation = rodrigues(params.omega)
        self.shape = shape
        self._camera = camera

    @cached_property
    def nodes(self) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) camera-frame nodes (eq. 1, 3) and their (N, 2) pixels (eq. 2)."""
        points_cam = self.shape @ self.rotation.T + self.params.t
        return points_cam, self._camera.project(points_cam)


class FaceProjection:
    """The face model posed at a parameter vector (eq. 1, 3) and seen by the camera (eq. 2).

    The poses of the last ``_KEPT`` parameter vectors are kept, each made once: a frame poses
    the last estimate, the one before it and the solve's points several times over (the motion
    prediction, its evaluations and linearisations, templates, visibility, loss checks and
    result). A parameter vector is known by its identity: :class:`~.mono_rois.Params` is
    immutable, and no code changes its arrays in place.

    Args:
        model: the face model (eq. 3).
        camera: the camera.
        num_levels: the number of pyramid levels the ROIs are sampled on.
        visibility_cos: a node's weight ramps from 0 to 1 as the cosine between its outward
            normal and the ray to the camera goes from this value to twice it.
    """

    _KEPT = 8

    def __init__(
        self, model: FaceModel, camera: PinholeCamera, num_levels: int, visibility_cos: float
    ) -> None:
        """Keep the model and camera; make each pyramid level's projection matrix."""
        self._model = model
        self._camera = camera
        self._visibility_cos = visibility_cos
        # P of each pyramid level: level l's pixels are level 0's times 2^-l.
        self.level_cameras = tuple(
            camera.p * np.array([[1.0 / (1 << level)], [1.0 / (1 << level)], [1.0]])
            for level in range(num_levels)
        )
        # (width, height) of each level: level l's is level 0's halved l times, rounded up.
        self._level_sizes = tuple(
            (float(-(-camera.width // (1 << level))), float(-(-camera.height // (1 << level))))
            for level in range(num_levels)
        )
        self._poses: dict[int, _Pose] = {}  # by id(params), the least recently used first
        # The last sigma's neutral mesh, flat (eq. 3 at alpha = 0): sigma stays while a track
        # runs (but during its first sigma_frames), alpha changes with every step.
        self._neutral: tuple[bytes, np.ndarray] | None = None

    def pose(self, params: Params) -> tuple[np.ndarray, np.ndarray]:
        """R(omega) (eq. 1) and the (N, 3) shape (eq. 3) of ``params``."""
        posed = self._posed_at(params)
        return posed.rotation, posed.shape

    def rotation(self, params: Params) -> np.ndarray:
        """(3, 3) R(omega) of ``params`` (eq. 1), kept with :meth:`pose`'s."""
        return self._posed_at(params).rotation

    def d_rotation(self, params: Params) -> np.ndarray:
        """(3, 3, 3) dR/domega_k at ``params`` (eq. 1), kept with :meth:`pose`'s."""
        return self._posed_at(params).d_rotation

    def _posed_at(self, params: Params) -> _Pose:
        """The pose of ``params``, made once while it is among the last ``_KEPT`` used."""
        # A kept pose holds its params, so no other live object can have their id.
        posed = self._poses.pop(id(params), None) or _Pose(
            params, self._shape(params), self._camera
        )
        self._poses[id(params)] = posed  # now the most recently used
        if len(self._poses) > self._KEPT:
            del self._poses[next(iter(self._poses))]
        return posed

    def _shape(self, params: Params) -> np.ndarray:
        """(N, 3) eq. 3 at ``params``: :meth:`FaceModel.shape`'s bits, its sigma part kept.

        ``(mean + S sigma) + A alpha``, as that sums them, with ``mean + S sigma`` made once per
        sigma.
        """
        model, key = self._model, params.sigma.tobytes()
        if self._neutral is None or self._neutral[0] != key:
            self._neutral = (key, model.mean_shape + model.shape_basis @ params.sigma)
        return (self._neutral[1] + model.action_basis @ params.alpha).reshape(-1, 3)

    def nodes(self, params: Params) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) camera-frame nodes (eq. 1, 3) and (N, 2) pixels (eq. 2); kept: read only."""
        return self._posed_at(params).nodes

    def project(self, points: np.ndarray) -> np.ndarray:
        """(N, 2) level-0 pixels of (N, 3) camera-frame points, m (eq. 2)."""
        return self._camera.project(points)

    def visibility(self, params: Params, normals: np.ndarray) -> np.ndarray:
        """(N,) weights in [0, 1] from the angle between node normals and rays to the camera."""
        posed = self._posed_at(params)
        return node_visibility(normals, posed.rotation, posed.nodes[0], self._visibility_cos)

    def points(self, params: Params, level: int, roi: Roi, stencil: bool = False) -> RoiMaps:
        """Level ``level``'s ROI points ``roi`` at ``params`` (eq. 1-3), ready to sample.

        ``stencil`` adds the central differences' points (:func:`~.mono_kernels.roi_maps`).

        Raises:
            InputError: if a point's pixel is not finite.
        """
        rotation, shape = self.pose(params)
        width, height = self._level_sizes[level]
        maps = RoiMaps(
            *roi_maps(
                rotation,
                shape,
                params.t,
                self.level_cameras[level],
                roi.offsets,
                roi.action,
                params.alpha,
                roi.identity,
                params.sigma - roi.sigma,
                stencil,
                width,
                height,
                GRADIENT_MARGIN,
            )
        )
        if math.isnan(maps.box[0]):
            msg = 'points hold NaN or Inf'
            raise InputError(msg)
        return maps

    def sample(self, pyramid: ImagePyramid, params: Params, level: int, roi: Roi) -> Sampled:
        """Level ``level``'s samples of its ROIs ``roi`` at ``params``."""
        maps = self.points(params, level, roi)
        shape = maps.inside.shape
        image = pyramid.level_reaching(level, maps.box)
        samples = sample_maps(image, maps.map_x.reshape(shape), maps.map_y.reshape(shape))
        return Sampled(samples, maps.inside)

    def sample_stencil(
        self, pyramid: ImagePyramid, params: Params, level: int, roi: Roi
    ) -> tuple[RoiMaps, Sampled, np.ndarray]:
        """:meth:`sample` with its points and the central differences' samples.

        Returns:
            The points, the samples and the (5, N M) float32 stencil samples (at the points,
            then one pixel +x, -x, +y, -y), all from one ``cv2.remap`` call.
        """
        maps = self.points(params, level, roi, stencil=True)
        image = pyramid.level_reaching(level, maps.box)
        stencil = sample_maps(image, maps.map_x, maps.map_y)
        return maps, Sampled(stencil[0].reshape(maps.inside.shape), maps.inside), stencil
