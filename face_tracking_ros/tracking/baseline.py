"""The comparison baseline: per-node pyramidal Lucas-Kanade plus PnP on the mean shape (issue 6).

Each mesh node is followed independently by ``cv2.calcOpticalFlowPyrLK`` (with a forward-backward
check), and the pose is ``cv2.solvePnP`` of the model's mean shape on the followed points: what a
landmark tracker with a generic 3-D face does. It has the same interface as
:class:`~face_tracking_ros.tracking.mono.MonoTracker` (``reset``, ``step``) and the same result
type, so the benchmark runs both on the same frames.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from face_tracking_ros.errors import ConfigError, InputError, check_fields
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.imaging import inside_image
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.tracking.initialisation import (
    MIN_INIT_NODES,
    FitConfig,
    Initialisation,
    fit_model_to_points,
)
from face_tracking_ros.tracking.result import TrackResult, TrackStatus
from face_tracking_ros.wording import counted


@dataclass(frozen=True)
class BaselineConfig:
    """Tunables of the LK + PnP baseline.

    Attributes:
        window: LK window side, px (odd, >= 5).
        pyramid_levels: LK pyramid levels (>= 1).
        forward_backward_px: a node is dropped when tracking it back lands farther than this
            from where it started, px (> 0).
        reprojection_px: RANSAC inlier threshold of the PnP, px (> 0).
    """

    window: int = 21
    pyramid_levels: int = 3
    forward_backward_px: float = 1.0
    reprojection_px: float = 4.0

    def __post_init__(self) -> None:
        """Validate every field."""
        checks = {
            'window': self.window >= 5 and self.window % 2 == 1,
            'pyramid_levels': self.pyramid_levels >= 1,
            'forward_backward_px': self.forward_backward_px > 0,
            'reprojection_px': self.reprojection_px > 0,
        }
        check_fields(self, checks)


class LKPnPTracker:
    """Per-node LK + PnP on the mean shape; the benchmark's baseline.

    Args:
        model: the face model; only its mean shape (and node names) are used for the pose.
        camera: the camera (rectified, distortion-free images).
        config: tunables; defaults to :class:`BaselineConfig()`.
    """

    def __init__(
        self, model: FaceModel, camera: PinholeCamera, config: BaselineConfig | None = None
    ) -> None:
        """Store the collaborators."""
        self._model = model
        self._camera = camera
        self._config = config or BaselineConfig()
        self._mean = model.shape()
        self._init: Initialisation | None = None
        self._previous: np.ndarray | None = None
        self._points: np.ndarray | None = None
        self._active: np.ndarray | None = None
        self._last: TrackResult | None = None

    def reset(self, init: Initialisation | None = None) -> None:
        """Start again on the next image from ``init`` (or the last initialisation)."""
        if init is not None:
            self._init = init
        self._previous = None

    def step(self, image: np.ndarray) -> TrackResult:
        """Follow the nodes into ``image`` and solve the pose; never raises on a bad frame."""
        image = np.asarray(image)
        if image.shape != (self._camera.height, self._camera.width) or image.dtype != np.uint8:
            return self._lost(f'image must be uint8 {self._camera.height}x{self._camera.width}')
        if self._previous is None:
            return self._start(image)
        points, active = self._follow(image)
        self._previous = image
        if active.sum() < MIN_INIT_NODES:
            return self._lost(f'only {counted(int(active.sum()), "node")} followed')
        found, rvec, tvec, inliers = cv2.solvePnPRansac(
            self._mean[active],
            points[active],
            self._camera.p[:, :3],
            None,
            self._last.omega.reshape(3, 1).copy(),
            self._last.t.reshape(3, 1).copy(),
            useExtrinsicGuess=True,
            reprojectionError=self._config.reprojection_px,
            flags=cv2.SOLVEPNP_ITERATIVE,
        )
        if not found or inliers is None or len(inliers) < MIN_INIT_NODES or tvec[2, 0] <= 0:
            return self._lost('PnP found no pose')
        self._points, self._active = points, active
        return self._result(rvec.ravel(), tvec.ravel(), points, '')

    def _start(self, image: np.ndarray) -> TrackResult:
        """Fit the mean shape's pose to the init points and place every node."""
        if self._init is None:
            return TrackResult.empty(
                self._model.num_nodes, self._model.p, self._model.q, 'waiting for init points'
            )
        init = replace(self._init, sigma=np.zeros(self._model.p))
        try:
            fit = fit_model_to_points(self._model, self._camera, init, FitConfig(fit_alpha=False))
        except (InputError, ConfigError) as error:
            return self._lost(f'initialisation failed: {error}')
        points = self._project(fit.omega, fit.t)
        points[init.node_indices(self._model)] = init.points
        self._previous, self._points = image, points
        self._active = inside_image(points, image.shape)
        return self._result(fit.omega, fit.t, points, '')

    def _follow(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """LK forward and backward; (N, 2) new points and the (N,) nodes still followed."""
        config = self._config
        window = (config.window, config.window)
        start = self._points.astype(np.float32).reshape(-1, 1, 2)
        forward, status, _ = cv2.calcOpticalFlowPyrLK(
            self._previous, image, start, None, winSize=window, maxLevel=config.pyramid_levels - 1
        )
        backward, back_status, _ = cv2.calcOpticalFlowPyrLK(
            image,
            self._previous,
            forward,
            None,
            winSize=window,
            maxLevel=config.pyramid_levels - 1,
        )
        error = np.linalg.norm((backward - start).reshape(-1, 2), axis=1)
        points = forward.reshape(-1, 2).astype(float)
        active = (
            self._active
            & (status.ravel() == 1)
            & (back_status.ravel() == 1)
            & (error < config.forward_backward_px)
            & inside_image(points, image.shape)
        )
        return points, active

    def _project(self, omega: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(N, 2) pixels of the mean shape at a pose."""
        rotation, _ = rodrigues(omega)
        return self._camera.project(self._mean @ rotation.T + t)

    def _result(
        self, omega: np.ndarray, t: np.ndarray, points: np.ndarray, reason: str
    ) -> TrackResult:
        """A TRACKING result of the mean shape at (omega, t).

        Its ``node_residuals`` are the PnP reprojection errors of the followed points, px.
        """
        rotation, _ = rodrigues(omega)
        reprojection = np.linalg.norm(self._project(omega, t) - points, axis=1)
        self._last = TrackResult(
            status=TrackStatus.TRACKING,
            omega=np.asarray(omega, dtype=float),
            t=np.asarray(t, dtype=float),
            alpha=np.zeros(self._model.q),
            sigma=np.zeros(self._model.p),
            nodes_cam=self._mean @ rotation.T + t,
            nodes_px=points.copy(),
            node_residuals=reprojection,
            mean_residual=float(np.mean(reprojection)),
            reason=reason,
        )
        return self._last

    def _lost(self, reason: str) -> TrackResult:
        """LOST with the last estimate; the baseline only restarts on :meth:`reset`."""
        if self._last is None:
            model = self._model
            return TrackResult.empty(model.num_nodes, model.p, model.q, reason)
        return replace(self._last, status=TrackStatus.LOST, reason=reason)
