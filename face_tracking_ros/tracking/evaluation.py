"""Run a tracker over frames with ground truth and measure it (issue 6 targets).

:func:`evaluate_tracker` feeds images to any tracker with ``reset``/``step`` (the eq. 6
:class:`~face_tracking_ros.tracking.mono.MonoTracker` or the LK + PnP baseline) and scores the
results with :func:`~face_tracking_ros.tracking.accuracy.tracking_accuracy` (rotation and
translation MAE per axis, alpha RMS as a percentage of its range, drift, loss count, jitter),
adding what a still head needs (the standard deviation of the estimated angles) and the compute
time per frame. The benchmark calls it, and so do the slow accuracy checks (``face-tracking
track`` scores its output bag with ``tracking_accuracy`` directly).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
import time
from typing import Protocol

import numpy as np

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.rotation import omega_to_angles
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.tracking.accuracy import TrackingAccuracy, tracking_accuracy
from face_tracking_ros.tracking.initialisation import Initialisation
from face_tracking_ros.tracking.result import TrackResult, TrackStatus
from face_tracking_ros.wording import counted


class Tracker(Protocol):
    """What :func:`evaluate_tracker` needs of a tracker."""

    def reset(self, init: Initialisation | None = None) -> None:
        """Restart from 2-D node positions in the next image."""

    def step(self, image: np.ndarray) -> TrackResult:
        """Track into one image."""


@dataclass(frozen=True)
class TrackedSequence:
    """Per-frame outputs of a tracker over a sequence.

    Attributes:
        status: (F,) TrackStatus values.
        omega: (F, 3) rotation vectors, rad.
        t: (F, 3) translations, m.
        alpha: (F, q) action parameters.
        nodes: (F, N, 3) nodes in the camera frame, m.
        seconds: (F,) CPU time of each ``step`` (``time.process_time``), s.
    """

    status: np.ndarray
    omega: np.ndarray
    t: np.ndarray
    alpha: np.ndarray
    nodes: np.ndarray
    seconds: np.ndarray


@dataclass(frozen=True)
class TrackerEvaluation:
    """A tracker's accuracy and speed on one sequence.

    Attributes:
        accuracy: errors against truth (:class:`TrackingAccuracy`).
        angle_std_deg: (x, y, z) standard deviation of the estimated rotation angles over the
            tracked frames, degrees: the jitter of a still head (meaningful on still sequences).
        ms_median: median CPU time per frame, ms (first frame excluded); all threads of the
            process count, so set ``cv2.setNumThreads(1)`` to measure one core.
        ms_p95: 95th percentile of the CPU time per frame, ms.
    """

    accuracy: TrackingAccuracy
    angle_std_deg: tuple[float, float, float]
    ms_median: float
    ms_p95: float

    def as_dict(self) -> dict[str, object]:
        """JSON-ready dictionary."""
        return {
            **self.accuracy.as_dict(),
            'angle_std_deg': self.angle_std_deg,
            'ms_median': self.ms_median,
            'ms_p95': self.ms_p95,
        }


def run_tracker(
    tracker: Tracker, images: Iterable[np.ndarray], init: Initialisation | None
) -> TrackedSequence:
    """Reset ``tracker`` with ``init`` and step it through ``images`` (grey, uint8)."""
    return tracked_sequence(*track_images(tracker, images, init))


def track_images(
    tracker: Tracker, images: Iterable[np.ndarray], init: Initialisation | None
) -> tuple[list[TrackResult], np.ndarray]:
    """Reset ``tracker`` with ``init``; its result and CPU time (s) of each of ``images``."""
    tracker.reset(init)
    results, seconds = [], []
    for image in images:
        start = time.process_time()
        results.append(tracker.step(image))
        seconds.append(time.process_time() - start)
    return results, np.array(seconds)


def tracked_sequence(results: list[TrackResult], seconds: np.ndarray) -> TrackedSequence:
    """The TrackedSequence of per-frame results and their CPU times (s).

    Raises:
        InputError: if there are no results.
    """
    if not results:
        msg = 'no images to track'
        raise InputError(msg)
    return TrackedSequence(
        status=np.array([int(r.status) for r in results]),
        omega=np.array([r.omega for r in results]),
        t=np.array([r.t for r in results]),
        alpha=np.array([r.alpha for r in results]),
        nodes=np.array([r.nodes_cam for r in results]),
        seconds=np.asarray(seconds, dtype=float),
    )


def evaluate_tracker(
    tracker: Tracker,
    model: FaceModel,
    images: Iterable[np.ndarray],
    true_nodes: np.ndarray,
    init: Initialisation | None,
) -> TrackerEvaluation:
    """Track a sequence and score it against the true nodes of every frame.

    Args:
        tracker: the tracker (its model must be ``model``).
        model: the face model, for the truth reference (the model fitted to the true nodes).
        images: F grey uint8 images.
        true_nodes: (F, N, 3) true nodes in the camera frame, in the model's node order, m.
        init: 2-D node positions in the first image (None: the tracker's own detector).

    Raises:
        InputError: if the frame counts disagree or no frame was tracked.
    """
    return evaluate_sequence(run_tracker(tracker, images, init), model, true_nodes)


def evaluate_sequence(
    tracked: TrackedSequence, model: FaceModel, true_nodes: np.ndarray
) -> TrackerEvaluation:
    """:func:`score` of a tracked sequence, after checking it has a frame per true frame.

    Raises:
        InputError: if the frame counts disagree or no frame was tracked.
    """
    if len(tracked.status) != len(true_nodes):
        images, frames = counted(len(tracked.status), 'image'), counted(len(true_nodes), 'frame')
        msg = f'{images} but {frames} of true nodes'
        raise InputError(msg)
    return score(tracked, model, true_nodes)


def score(tracked: TrackedSequence, model: FaceModel, true_nodes: np.ndarray) -> TrackerEvaluation:
    """Accuracy, still-head jitter and timing of a tracked sequence."""
    accuracy = tracking_accuracy(
        model, tracked.status, tracked.omega, tracked.t, tracked.alpha, tracked.nodes, true_nodes
    )
    ok = tracked.status == TrackStatus.TRACKING
    angles = np.degrees(omega_to_angles(tracked.omega[ok]))
    spread = angles.std(axis=0) if len(angles) > 1 else np.full(3, np.nan)
    milliseconds = 1000.0 * (tracked.seconds[1:] if len(tracked.seconds) > 1 else tracked.seconds)
    return TrackerEvaluation(
        accuracy=accuracy,
        angle_std_deg=(float(spread[0]), float(spread[1]), float(spread[2])),
        ms_median=float(np.median(milliseconds)),
        ms_p95=float(np.percentile(milliseconds, 95)),
    )
