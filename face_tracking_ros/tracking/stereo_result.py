"""What the stereo tracker (:class:`~.stereo.StereoTracker`, §3.3, eq. 4 and 5) gives back.

One stereo pair's estimate with its status (:class:`StereoResult`), a sequence's meshes
(:class:`TrackedSequence`) and the split of a run's results into its tracks (:func:`split_tracks`,
each track starting at its frame 1), along which the offline depth refinement is applied.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from face_tracking_ros.recognition.node_fit import NodeFit
from face_tracking_ros.tracking.result import TrackResult, TrackStatus


@dataclass(frozen=True)
class StereoResult:
    """The stereo tracker's estimate for one stereo pair.

    Attributes:
        status: TRACKING when valid; LOST carries the last valid nodes; INITIALIZING before the
            first pair after a reset.
        nodes_cam: (N, 3) nodes X_c in the left camera frame, m.
        left_px: (N, 2) node projections in the left image, px.
        right_px: (N, 2) node projections in the right image, px.
        left_residuals: (N,) RMS photometric residual of each node patch in the left image
            against frame n - 1 (brightness ramp or, face-edge nodes, mean removed), grey
            levels.
        right_residuals: (N,) the same in the right image, grey levels.
        mean_residual: mean of both residual arrays, grey levels.
        iterations: Levenberg-Marquardt iterations spent, summed over levels.
        cost_history: total cost E(n) after each accepted iteration (a coarse level's last,
            converged step is not evaluated).
        fit: with a model loaded, its pose, sigma and alpha fitted to the nodes (eq. 1-3), as a
            one-frame :class:`~face_tracking_ros.recognition.node_fit.NodeFit`; else None.
        reason: why the status is not TRACKING ('' when tracking).
        first_nodes: (N, 3) the frame-1 nodes as refined up to this pair
            (:mod:`.depth_refinement`), m; None before the first pair.
        rotation: (3, 3) the head's rotation since frame 1; None before the first pair.
        new_track: this pair is frame 1 of a track (after a reset, or a detection after a loss).
        occluded: (N,) bool, the nodes judged covered by an occluder on this pair, held to the
            head's rigid motion (:func:`~.stereo_occlusion.occluder_nodes`; a patch that
            disagrees alone is held but not flagged); LOST carries the last valid pair's; None
            before any estimate.
    """

    status: TrackStatus
    nodes_cam: np.ndarray
    left_px: np.ndarray
    right_px: np.ndarray
    left_residuals: np.ndarray
    right_residuals: np.ndarray
    mean_residual: float
    iterations: int = 0
    cost_history: tuple[float, ...] = ()
    fit: NodeFit | None = None
    reason: str = ''
    first_nodes: np.ndarray | None = None
    rotation: np.ndarray | None = None
    new_track: bool = False
    occluded: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        """True when the status is TRACKING."""
        return self.status == TrackStatus.TRACKING

    def as_track_result(self) -> TrackResult:
        """The shared :class:`~.result.TrackResult` (left camera; NaN pose without a model)."""
        fit = self.fit
        return TrackResult(
            status=self.status,
            omega=np.full(3, np.nan) if fit is None else fit.omega[0],
            t=np.full(3, np.nan) if fit is None else fit.t[0],
            alpha=np.zeros(0) if fit is None else fit.alpha[0],
            sigma=np.zeros(0) if fit is None else fit.sigma[0],
            nodes_cam=self.nodes_cam,
            nodes_px=self.left_px,
            node_residuals=self.left_residuals,
            mean_residual=self.mean_residual,
            iterations=self.iterations,
            cost_history=self.cost_history,
            reason=self.reason,
            right_node_residuals=self.right_residuals,
            occluded=self.occluded,
        )


@dataclass(frozen=True)
class TrackedSequence:
    """Output of :func:`~.stereo.track_sequence`.

    Attributes:
        meshes: (F, N, 3) nodes per frame in the left camera frame, m (the last valid nodes on
            frames that were not TRACKING; NaN before the first), with the frame-1 depths as
            refined over the whole sequence (:mod:`.depth_refinement`) applied to every frame.
        status: (F,) TrackStatus values.
        results: the per-frame results.
    """

    meshes: np.ndarray
    status: np.ndarray
    results: tuple[StereoResult, ...]


def split_tracks(results: Sequence[StereoResult]) -> list[list[StereoResult]]:
    """``results`` split before each result that starts a new track."""
    tracks: list[list[StereoResult]] = [[]]
    for result in results:
        if result.new_track and tracks[-1]:
            tracks.append([])
        tracks[-1].append(result)
    return tracks
