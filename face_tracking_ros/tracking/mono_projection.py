"""The face model posed at an estimate and seen by the camera, where the tracker samples its ROIs.

:class:`FaceProjection` poses the model at a parameter vector (eq. 1, 3), projects it (eq. 2),
weighs each node by how squarely it faces the camera, and samples an image on the ROIs of
:mod:`.mono_rois` there (:class:`Sampled`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.imaging import ImagePyramid, inside_xy, sample_xy
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.tracking.mono_kernels import roi_points
from face_tracking_ros.tracking.mono_rois import Params, Roi


class Sampled(NamedTuple):
    """One level's samples of the ROIs at a pose, and which lie inside the image."""

    samples: np.ndarray  # (N, M) float32
    inside: np.ndarray  # (N, M) bool, at least 1 px inside


class FaceProjection:
    """The face model posed at a parameter vector (eq. 1, 3) and seen by the camera (eq. 2).

    The last parameter vector's rotation and shape are kept: one is projected several times
    (its evaluation, linearisation, templates, visibility, result).

    Args:
        model: the face model (eq. 3).
        camera: the camera.
        num_levels: the number of pyramid levels the ROIs are sampled on.
        visibility_cos: a node's weight ramps from 0 to 1 as the cosine between its outward
            normal and the ray to the camera goes from this value to twice it.
    """

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
        self._posed: tuple[Params, tuple[np.ndarray, ...]] | None = None  # _posed_at's

    def pose(self, params: Params) -> tuple[np.ndarray, np.ndarray]:
        """R(omega) (eq. 1) and the (N, 3) shape (eq. 3) of ``params``."""
        return self._posed_at(params)[:2]

    def d_rotation(self, params: Params) -> np.ndarray:
        """(3, 3, 3) dR/domega_k at ``params`` (eq. 1), kept with :meth:`pose`'s."""
        return self._posed_at(params)[2]

    def _posed_at(self, params: Params) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """R(omega), the shape and dR/domega of ``params``, computed once per parameter vector."""
        if self._posed is None or params is not self._posed[0]:
            rotation, d_rotation = rodrigues(params.omega)
            shape = self._model.shape(params.sigma, params.alpha)
            self._posed = (params, (rotation, shape, d_rotation))
        return self._posed[1]

    def nodes(self, params: Params) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) camera-frame nodes (eq. 1, 3) and their (N, 2) pixels (eq. 2)."""
        rotation, shape = self.pose(params)
        points_cam = shape @ rotation.T + params.t
        return points_cam, self._camera.project(points_cam)

    def visibility(self, params: Params, normals: np.ndarray) -> np.ndarray:
        """(N,) weights in [0, 1] from the angle between node normals and rays to the camera."""
        rotation, shape = self.pose(params)
        nodes = shape @ rotation.T + params.t
        rays = nodes / np.linalg.norm(nodes, axis=1, keepdims=True)
        facing = -np.einsum('na,na->n', normals @ rotation.T, rays)
        low = self._visibility_cos
        return np.clip((facing - low) / max(low, 1e-6), 0.0, 1.0)

    def roi_points(
        self, params: Params, camera: np.ndarray, roi: Roi
    ) -> tuple[np.ndarray, np.ndarray]:
        """(3, N, M) ``R P`` of the ROI points (eq. 1, 3) and their (2, N, M) level pixels (eq. 2).

        ``camera`` is the level's projection matrix P.
        """
        rotation, shape = self.pose(params)
        return roi_points(
            rotation,
            shape,
            params.t,
            camera,
            roi.offsets,
            roi.action,
            params.alpha,
            roi.identity,
            params.sigma - roi.sigma,
        )

    def sample(self, pyramid: ImagePyramid, params: Params, level: int, roi: Roi) -> Sampled:
        """Level ``level``'s samples of its ROIs ``roi`` at ``params``."""
        _, (x, y) = self.roi_points(params, self.level_cameras[level], roi)
        image = pyramid.level(level, x, y)
        return Sampled(sample_xy(image, x, y), inside_xy(x, y, image.shape, margin=1.0))
