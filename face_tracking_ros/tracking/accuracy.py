"""Tracking accuracy against ground truth: pose, nodes, alpha, drift and jitter.

The truth pose of a synthetic face is that of the generator's face frame, while a tracker
estimates the pose of its model's face frame; the two frames differ by whatever rigid offset the
learned mean shape has. So the reference for pose and alpha is the model fitted to the TRUE 3-D
nodes of each frame (:func:`~face_tracking_ros.recognition.node_fit.fit_model_to_nodes`): the
pose and expression the tracker would report if it recovered the true mesh exactly. Node errors
need no such care: nodes are compared in the camera frame.

Rotation errors are per axis of the camera (x: pitch, the seed's weak axis in §4.4; y: yaw;
z: roll), from :func:`~face_tracking_ros.geometry.rotation.omega_to_angles`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.distances import rms_length
from face_tracking_ros.geometry.rotation import omega_to_angles
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.recognition.node_fit import fit_model_to_nodes
from face_tracking_ros.tracking.result import TrackStatus

DRIFT_WINDOW = 100  # frames compared at the start and the end of a sequence (issue 6)


@dataclass(frozen=True)
class TrackingAccuracy:
    """Errors of a tracked sequence against truth.

    Attributes:
        frames: frames compared.
        tracked: frames with status TRACKING (errors are over these).
        lost: frames with status LOST.
        rotation_mae_deg: (x, y, z) mean absolute rotation error, degrees.
        translation_mae_mm: (x, y, z) mean absolute translation error, mm.
        node_rms_mm: RMS 3-D node error in the camera frame, mm.
        alpha_rms_percent: RMS over frames of the alpha error's norm, as a percentage of alpha's
            range in the sequence (the largest peak-to-peak range of a component of the
            reference alpha); nan for a sequence without expression.
        drift_deg: mean rotation error (all axes) over the last 100 tracked frames minus that
            over the first 100 (half the tracked frames each when fewer than 200:
            :func:`drift_window`), degrees (> 0: the error grows).
        jitter_deg: frame-to-frame noise of the rotation error, ``std(diff(error)) / sqrt(2)``
            averaged over axes, degrees: the jitter a still head would show.
    """

    frames: int
    tracked: int
    lost: int
    rotation_mae_deg: tuple[float, float, float]
    translation_mae_mm: tuple[float, float, float]
    node_rms_mm: float
    alpha_rms_percent: float
    drift_deg: float
    jitter_deg: float

    def as_dict(self) -> dict[str, object]:
        """JSON-ready dictionary."""
        return asdict(self)

    def report(self) -> str:
        """A short table of the figures, one a line."""
        rotation = ' / '.join(f'{v:.2f}' for v in self.rotation_mae_deg)
        translation = ' / '.join(f'{v:.2f}' for v in self.translation_mae_mm)
        window = drift_window(self.tracked)
        drift = f'drift (last {window} - first {window}):'
        return '\n'.join(
            [
                f'frames {self.frames}: tracked {self.tracked}, lost {self.lost}',
                f'rotation MAE about x / y / z:    {rotation} deg',
                f'translation MAE in x / y / z:    {translation} mm',
                f'3-D node RMS:                    {self.node_rms_mm:.2f} mm',
                f'alpha RMS (% of range):          {self.alpha_rms_percent:.1f} %',
                f'{drift:<33}{self.drift_deg:+.3f} deg',
                f'jitter (frame-to-frame):         {self.jitter_deg:.3f} deg',
            ]
        )


def tracking_accuracy(
    model: FaceModel,
    status: np.ndarray,
    omega: np.ndarray,
    t: np.ndarray,
    alpha: np.ndarray,
    nodes: np.ndarray,
    true_nodes: np.ndarray,
) -> TrackingAccuracy:
    """Compare a tracked sequence with the truth of the same frames.

    Args:
        model: the model the tracker used.
        status: (F,) TrackStatus values.
        omega: (F, 3) estimated rotation vectors, rad.
        t: (F, 3) estimated translations, m.
        alpha: (F, q) estimated action parameters.
        nodes: (F, N, 3) estimated nodes, camera frame, m.
        true_nodes: (F, N, 3) true nodes, camera frame, m.

    Raises:
        InputError: if shapes disagree or no frame is TRACKING.
    """
    frames = len(status)
    if true_nodes.shape != nodes.shape or len(nodes) != frames:
        msg = f'estimated nodes {nodes.shape} and true nodes {true_nodes.shape} differ'
        raise InputError(msg)
    ok = np.asarray(status) == TrackStatus.TRACKING
    if not ok.any():
        msg = 'no frame was tracked: nothing to compare'
        raise InputError(msg)
    reference = fit_model_to_nodes(model, true_nodes[ok])
    angle_error = np.degrees(_wrap(omega_to_angles(omega[ok]) - omega_to_angles(reference.omega)))
    translation_error = 1000 * np.abs(t[ok] - reference.t)
    node_error = 1000 * np.linalg.norm(nodes[ok] - true_nodes[ok], axis=2)
    return TrackingAccuracy(
        frames=frames,
        tracked=int(ok.sum()),
        lost=int(np.sum(np.asarray(status) == TrackStatus.LOST)),
        rotation_mae_deg=_triple(np.abs(angle_error).mean(axis=0)),
        translation_mae_mm=_triple(translation_error.mean(axis=0)),
        node_rms_mm=float(np.sqrt(np.mean(node_error**2))),
        alpha_rms_percent=_alpha_rms_percent(alpha[ok], reference.alpha),
        drift_deg=_drift(np.abs(angle_error).mean(axis=1)),
        jitter_deg=float(np.mean(np.std(np.diff(angle_error, axis=0), axis=0)) / np.sqrt(2))
        if len(angle_error) > 2
        else float('nan'),
    )


def _wrap(angles: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return (angles + np.pi) % (2 * np.pi) - np.pi


def _triple(values: np.ndarray) -> tuple[float, float, float]:
    return float(values[0]), float(values[1]), float(values[2])


def _alpha_rms_percent(estimated: np.ndarray, reference: np.ndarray) -> float:
    """RMS of the alpha error norm as a percentage of the reference alpha's largest range."""
    spread = float(np.ptp(reference, axis=0).max(initial=0.0))
    if spread < 1e-9:
        return float('nan')
    return 100 * rms_length(estimated - reference) / spread


def drift_window(tracked: int) -> int:
    """Frames the drift compares at each end of ``tracked`` frames (whole halves if shorter)."""
    return min(DRIFT_WINDOW, tracked // 2)


def _drift(error: np.ndarray) -> float:
    """Mean error over the last window minus that over the first (:func:`drift_window`)."""
    window = drift_window(len(error))
    if window < 1:
        return float('nan')
    return float(error[-window:].mean() - error[:window].mean())
