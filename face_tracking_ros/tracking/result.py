"""What a tracker returns for one image: status, pose, model parameters, nodes and residuals.

Shared by the monocular (eq. 6) and stereo (eq. 4) trackers. Menpo-style: the model is what is
estimated, the tracker is how, and this result is what came out, with its iteration history.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np


class TrackStatus(IntEnum):
    """Tracking state; values equal FaceState.msg's STATUS_* constants."""

    INITIALIZING = 0
    TRACKING = 1
    LOST = 2


@dataclass(frozen=True)
class TrackResult:
    """The estimate for one image.

    Attributes:
        status: TRACKING when the estimate is valid; LOST carries the last valid estimate;
            INITIALIZING before any fit.
        omega: (3,) rotation vector of the face frame in the camera frame (eq. 1), rad.
        t: (3,) translation of the face frame in the camera frame (eq. 1), m.
        alpha: (q,) action (expression) parameters of eq. 3.
        sigma: (p,) shape (identity) parameters of eq. 3.
        nodes_cam: (N, 3) node positions X_c in the camera frame (eq. 1), m.
        nodes_px: (N, 2) node projections x (eq. 2), px (x = column, y = row).
        node_residuals: (N,) RMS photometric residual of each node's patch, grey levels (a
            stereo tracker's: in the left image).
        mean_residual: mean of ``node_residuals`` (a stereo tracker's: of both images), grey
            levels.
        iterations: solver iterations spent on this image, summed over pyramid levels.
        cost_history: cost after each iteration, in the order they were run.
        reason: why the status is LOST or INITIALIZING ('' when tracking).
        right_node_residuals: (N,) a stereo tracker's residuals in the right image; None for a
            monocular tracker.
        occluded: (N,) bool, the nodes judged covered by an occluder on this image, not measured:
            the stereo tracker moves them with the head's rigid motion
            (:mod:`.stereo_occlusion`), the mono tracker leaves them out of eq. 6 and the face
            model places them (:func:`.mono_loss.covered_nodes`); LOST carries the last valid
            estimate's; None before any estimate (or from a tracker without the check).
    """

    status: TrackStatus
    omega: np.ndarray
    t: np.ndarray
    alpha: np.ndarray
    sigma: np.ndarray
    nodes_cam: np.ndarray
    nodes_px: np.ndarray
    node_residuals: np.ndarray
    mean_residual: float
    iterations: int = 0
    cost_history: tuple[float, ...] = field(default_factory=tuple)
    reason: str = ''
    right_node_residuals: np.ndarray | None = None
    occluded: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        """True when the status is TRACKING."""
        return self.status == TrackStatus.TRACKING

    @classmethod
    def empty(cls, num_nodes: int, p: int, q: int, reason: str) -> TrackResult:
        """An INITIALIZING result with NaN pose and nodes, before any fit (e.g. no face yet)."""
        nan3 = np.full(3, np.nan)
        return cls(
            status=TrackStatus.INITIALIZING,
            omega=nan3,
            t=nan3.copy(),
            alpha=np.zeros(q),
            sigma=np.zeros(p),
            nodes_cam=np.full((num_nodes, 3), np.nan),
            nodes_px=np.full((num_nodes, 2), np.nan),
            node_residuals=np.full(num_nodes, np.nan),
            mean_residual=float('nan'),
            reason=reason,
        )
