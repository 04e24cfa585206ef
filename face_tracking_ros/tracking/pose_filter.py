"""Adaptive smoothing of the published head pose: the One Euro filter on the pose (omega, t).

A monocular pose estimate (eq. 6) carries frame-to-frame estimation noise that is white in
time: on a still head mostly pitch, the axis one view determines worst (§4.4). The One Euro
filter (Casiez, Roussel and Vogel, CHI 2012) is a first-order low-pass whose cutoff rises with
the speed, so a still head is smoothed hard and a moving one barely lags:

    f_c = min_cutoff + beta_rotation |w| + beta_translation |v|
    a = 1 / (1 + 1 / (2 pi f_c dt))

with ``w`` (rad/s) and ``v`` (m/s) the angular and linear velocities of the pose, each low-passed
at ``derivative_cutoff`` as vectors (a vector's noise averages out, the noise of its norm would
not). Each step moves the filtered pose by the share ``a`` of the way to the new estimate: on the
rotation group for omega, ``R_f <- R_f exp(a log(R_f^T R(omega)))``, linearly for t. The nodes
move rigidly with the pose, ``X_c' = R_f R(omega)^T (X_c - t) + t_f`` (eq. 1), and are projected
again (eq. 2).

Only the output is filtered: the tracker's own state, from which it starts the next frame, stays
its raw estimate. alpha and sigma pass unchanged (alpha's noise on a still face is below 1 % of
its range). A result that is not TRACKING passes unchanged and restarts the filter, so a track
that resumes after a loss is not pulled towards the pose before it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
import math
import time

import numpy as np

from face_tracking_ros.errors import ConfigError, InputError, check_fields
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.geometry.rotation import matrix_to_omega, rodrigues
from face_tracking_ros.tracking.evaluation import Tracker
from face_tracking_ros.tracking.initialisation import Initialisation
from face_tracking_ros.tracking.result import TrackResult, TrackStatus


@dataclass(frozen=True)
class PoseFilterConfig:
    """Tunables of the One Euro pose filter.

    Attributes:
        enabled: smooth the published pose; False publishes the tracker's raw estimate.
        min_cutoff: cutoff frequency on a still head, Hz (> 0): lower smooths more.
        beta_rotation: cutoff increase per rad/s of head rotation speed, Hz s/rad (>= 0).
        beta_translation: cutoff increase per m/s of head translation speed, Hz s/m (>= 0).
        derivative_cutoff: cutoff of the velocity estimates that drive the cutoff, Hz (> 0).
    """

    enabled: bool = True
    min_cutoff: float = 0.3
    beta_rotation: float = 16.0
    beta_translation: float = 300.0
    derivative_cutoff: float = 1.0

    def __post_init__(self) -> None:
        """Validate every field; the error names the field and its value."""
        checks = {
            'min_cutoff': self.min_cutoff > 0.0,
            'beta_rotation': self.beta_rotation >= 0.0,
            'beta_translation': self.beta_translation >= 0.0,
            'derivative_cutoff': self.derivative_cutoff > 0.0,
        }
        check_fields(self, checks)


def smoothing_factor(cutoff: float, dt: float) -> float:
    """Share ``a`` of the way a first-order low-pass at ``cutoff`` Hz moves in ``dt`` s."""
    return 1.0 / (1.0 + 1.0 / (2.0 * math.pi * cutoff * dt))


@dataclass
class _Filtered:
    """The filter's state: the filtered pose R_f, t_f and velocities; the last result's time."""

    rotation: np.ndarray
    t: np.ndarray
    angular_velocity: np.ndarray
    velocity: np.ndarray
    time_s: float


def _norm(vector: np.ndarray) -> float:
    """The Euclidean norm of a 1-D vector: np.linalg.norm's value (``sqrt(v . v)``), cheaply."""
    return math.sqrt(vector.dot(vector))


class PoseFilter:
    """One Euro filter of a tracker's pose results (see the module docstring)."""

    def __init__(self, camera: PinholeCamera, config: PoseFilterConfig | None = None) -> None:
        """Smooth results of a tracker that sees through ``camera`` (for the node pixels)."""
        self._camera = camera
        self._config = config or PoseFilterConfig()
        self._state: _Filtered | None = None

    def reset(self) -> None:
        """Forget the past: the next result passes unchanged and starts the filter."""
        self._state = None

    def filter(self, result: TrackResult, time_s: float) -> TrackResult:
        """The smoothed result of the image taken at ``time_s`` (seconds, any origin).

        Raises:
            InputError: if ``time_s`` is not later than the previous result's.
        """
        if not self._config.enabled:
            return result
        if result.status != TrackStatus.TRACKING:
            self._state = None
            return result
        rotation = rodrigues(result.omega)[0]
        state = self._state
        if state is None:
            self._state = _Filtered(rotation, result.t.copy(), np.zeros(3), np.zeros(3), time_s)
            return result
        dt = time_s - state.time_s
        if not dt > 0:
            msg = f'pose filter: time {time_s} s is not later than the previous {state.time_s} s'
            raise InputError(msg)
        self._step(state, rotation, result.t, dt)
        state.time_s = time_s
        return self._moved(result, rotation, state)

    def _step(self, state: _Filtered, rotation: np.ndarray, t: np.ndarray, dt: float) -> None:
        """Move the filtered pose towards the estimate (R(omega), t) by the One Euro share."""
        config = self._config
        turn = matrix_to_omega(state.rotation.T @ rotation)
        shift = t - state.t
        derivative = smoothing_factor(config.derivative_cutoff, dt)
        state.angular_velocity += derivative * (turn / dt - state.angular_velocity)
        state.velocity += derivative * (shift / dt - state.velocity)
        cutoff = (
            config.min_cutoff
            + config.beta_rotation * _norm(state.angular_velocity)
            + config.beta_translation * _norm(state.velocity)
        )
        share = smoothing_factor(cutoff, dt)
        state.rotation = state.rotation @ rodrigues(share * turn)[0]
        state.t = state.t + share * shift

    def _moved(self, result: TrackResult, rotation: np.ndarray, state: _Filtered) -> TrackResult:
        """``result`` with the filtered pose and its nodes moved rigidly with it (eq. 1, 2).

        Args:
            result: the tracker's result.
            rotation: (3, 3) R(omega) of the result.
            state: the filter's state after this result.
        """
        nodes_cam = (result.nodes_cam - result.t) @ rotation @ state.rotation.T + state.t
        return replace(
            result,
            omega=matrix_to_omega(state.rotation),
            t=state.t.copy(),
            nodes_cam=nodes_cam,
            nodes_px=self._camera.project(nodes_cam),
        )


class FilteredTracker:
    """A tracker whose results pass through a :class:`PoseFilter`, frames at a fixed rate.

    What a node publishes for images taken ``1 / frame_rate`` s apart; for evaluation
    (:func:`~face_tracking_ros.tracking.evaluation.evaluate_tracker`) and the benchmark.
    """

    def __init__(self, tracker: Tracker, pose_filter: PoseFilter, frame_rate: float) -> None:
        """Wrap ``tracker``; its images are ``1 / frame_rate`` s apart.

        Raises:
            ConfigError: if ``frame_rate`` is not positive.
        """
        _check_frame_rate(frame_rate)
        self._tracker = tracker
        self._filter = pose_filter
        self._frame_rate = frame_rate
        self._frame = 0

    def reset(self, init: Initialisation | None = None) -> None:
        """Restart the tracker from ``init`` and the filter from its next result."""
        self._tracker.reset(init)
        self._filter.reset()
        self._frame = 0

    def step(self, image: np.ndarray) -> TrackResult:
        """Track into one image and smooth the result."""
        result = self._tracker.step(image)
        time_s = self._frame / self._frame_rate
        self._frame += 1
        return self._filter.filter(result, time_s)


def filter_results(
    pose_filter: PoseFilter, results: Sequence[TrackResult], frame_rate: float
) -> tuple[list[TrackResult], np.ndarray]:
    """What a :class:`FilteredTracker` gives for a tracker's ``results`` of consecutive frames.

    The filter only smooths the output (the tracker continues from its raw estimate), so a
    tracker run once gives both its raw and its published results. ``pose_filter`` is reset
    first; frames are ``1 / frame_rate`` s apart.

    Returns:
        The smoothed results and the CPU time (s) the filter took on each.

    Raises:
        ConfigError: if ``frame_rate`` is not positive.
    """
    _check_frame_rate(frame_rate)
    pose_filter.reset()
    filtered, seconds = [], []
    for frame, result in enumerate(results):
        start = time.process_time()
        filtered.append(pose_filter.filter(result, frame / frame_rate))
        seconds.append(time.process_time() - start)
    return filtered, np.array(seconds)


def _check_frame_rate(frame_rate: float) -> None:
    """Raise a ConfigError unless ``frame_rate`` (images per second) is positive."""
    if not frame_rate > 0:
        msg = f'frame_rate must be > 0, got {frame_rate}'
        raise ConfigError(msg)
