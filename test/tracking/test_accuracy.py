"""The tracking accuracy figures (tracking.accuracy) on estimates with errors made by hand.

The other tests bound these figures (< 1.5 degrees, ...): a figure computed too small passed
them. Here each error is put in on purpose, so each figure has a value worked out by hand.
"""

from __future__ import annotations

import numpy as np
import pytest
from recognition_streams import truth_model

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.rotation import angles_to_omega, omega_to_angles, rodrigues
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.tracking.accuracy import drift_window, tracking_accuracy
from face_tracking_ros.tracking.result import TrackStatus

MODEL = truth_model(FacePopulation('default', 0))
STATUS = np.array([TrackStatus.INITIALIZING, *[TrackStatus.TRACKING] * 2, TrackStatus.LOST,
                   *[TrackStatus.TRACKING] * 2])  # fmt: skip
TRACKED = STATUS == TrackStatus.TRACKING
# Rotation errors of the four tracked frames about x, y, z, degrees: mean |error| (2, 2, 0); the
# mean over axes is 1 on the first two frames and 5/3 on the last two, so the drift (last two
# minus first two) is 2/3; the x error steps 0, 2, 0 from frame to frame, so the jitter is
# std(0, 2, 0) / sqrt(2) averaged over the axes, (sqrt(8) / 3) / sqrt(2) / 3 = 2/9.
ANGLE_ERROR_DEG = np.array(
    [[1.0, -2.0, 0.0], [1.0, -2.0, 0.0], [3.0, -2.0, 0.0], [3.0, -2.0, 0.0]]
)
# Translation errors, mm: mean |error| (1, 0, 2).
T_ERROR_MM = np.array([[1.0, 0.0, -2.0], [-1.0, 0.0, -2.0], [1.0, 0.0, -2.0], [-1.0, 0.0, -2.0]])


def _truth(
    expression: float = 0.01, roll_deg: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """True omega (F, 3), t (F, 3), alpha (F, q) and the (F, 34, 3) nodes of eq. 1 and 3.

    Args:
        expression: standard deviation of alpha's components (0: a face without expression).
        roll_deg: the head's roll (angle about the camera z axis) in every frame, or random.
    """
    rng = np.random.default_rng(8)
    frames = len(STATUS)
    sigma = rng.normal(size=MODEL.p) * 0.03
    alpha = rng.normal(size=(frames, MODEL.q)) * expression
    omega = rng.uniform(-0.3, 0.3, size=(frames, 3))
    if roll_deg is not None:
        angles = omega_to_angles(omega)
        angles[:, 2] = np.radians(roll_deg)
        omega = angles_to_omega(angles)
    t = rng.normal(size=(frames, 3)) * 0.02 + [0.0, 0.0, 0.6]
    shapes = MODEL.mean_shape + MODEL.shape_basis @ sigma + alpha @ MODEL.action_basis.T
    nodes = [
        shape.reshape(-1, 3) @ rodrigues(w)[0].T + d
        for shape, w, d in zip(shapes, omega, t, strict=True)
    ]
    return omega, t, alpha, np.array(nodes)


def test_each_figure_is_the_error_put_in_and_untracked_frames_are_left_out():
    omega, t, alpha, nodes = _truth()
    # The estimates of the frames not TRACKING are far off everywhere: they must not count.
    estimated_omega, estimated_t = omega + 1.0, t + 1.0
    estimated_alpha, estimated_nodes = alpha + 1.0, nodes + 1.0
    angles = omega_to_angles(omega[TRACKED]) + np.radians(ANGLE_ERROR_DEG)
    estimated_omega[TRACKED] = angles_to_omega(angles)
    estimated_t[TRACKED] = t[TRACKED] + T_ERROR_MM / 1000
    # 3 mm along z on half the nodes: RMS 3 / sqrt(2) mm (a mean would give 1.5).
    estimated_nodes[TRACKED] = nodes[TRACKED]
    estimated_nodes[TRACKED, :17, 2] += 0.003
    # An alpha error of norm 0.002 on every tracked frame, against alpha's largest range.
    step = np.zeros(MODEL.q)
    step[:2] = [0.0012, -0.0016]
    estimated_alpha[TRACKED] = alpha[TRACKED] + step
    spread = np.ptp(alpha[TRACKED], axis=0).max()

    accuracy = tracking_accuracy(
        MODEL, STATUS, estimated_omega, estimated_t, estimated_alpha, estimated_nodes, nodes
    )

    assert (accuracy.frames, accuracy.tracked, accuracy.lost) == (6, 4, 1)
    # The reference pose is the model fitted to the true nodes: their own pose, to rounding.
    assert accuracy.rotation_mae_deg == pytest.approx((2.0, 2.0, 0.0), abs=1e-6)
    assert accuracy.translation_mae_mm == pytest.approx((1.0, 0.0, 2.0), abs=1e-6)
    assert accuracy.node_rms_mm == pytest.approx(3.0 / np.sqrt(2.0), abs=1e-12)
    assert accuracy.alpha_rms_percent == pytest.approx(100 * 0.002 / spread, rel=1e-6)
    assert accuracy.drift_deg == pytest.approx(2.0 / 3.0, abs=1e-6)
    assert accuracy.jitter_deg == pytest.approx(2.0 / 9.0, abs=1e-6)
    assert 'drift (last 2 - first 2):        +0.667 deg' in accuracy.report()


def test_a_sequence_without_expression_has_no_alpha_figure_and_bad_input_is_refused():
    omega, t, alpha, nodes = _truth(expression=0.0)
    flat = tracking_accuracy(MODEL, STATUS, omega, t, alpha + 0.01, nodes, nodes)
    assert np.isnan(flat.alpha_rms_percent) and flat.node_rms_mm == 0.0
    lost = np.full(len(STATUS), TrackStatus.LOST)
    with pytest.raises(InputError, match='no frame was tracked: nothing to compare'):
        tracking_accuracy(MODEL, lost, omega, t, alpha, nodes, nodes)
    with pytest.raises(InputError, match=r'estimated nodes \(6, 19, 3\) and true nodes \(6, 34'):
        tracking_accuracy(MODEL, STATUS, omega, t, alpha, nodes[:, :19], nodes)


def test_the_drift_compares_the_first_and_last_100_tracked_frames_or_whole_halves():
    assert [drift_window(n) for n in (1, 3, 150, 200, 201, 380)] == [0, 1, 75, 100, 100, 100]


def test_the_drift_is_the_last_windows_mean_error_minus_the_first_windows():
    omega, t, alpha, nodes = _truth()
    tracking = np.full(len(STATUS), TrackStatus.TRACKING)
    ramp = np.zeros((len(STATUS), 3))
    ramp[:, 0] = np.arange(len(STATUS))  # about x: 0, 1, ..., 5 degrees
    estimated = angles_to_omega(omega_to_angles(omega) + np.radians(ramp))
    accuracy = tracking_accuracy(MODEL, tracking, estimated, t, alpha, nodes, nodes)
    # Windows of 3 frames; the mean error over the axes is x / 3: (3 + 4 + 5 - 0 - 1 - 2) / 9.
    assert accuracy.drift_deg == pytest.approx(1.0, abs=1e-6)
    assert accuracy.jitter_deg == pytest.approx(0.0, abs=1e-6)  # steady steps of 1 degree
    # Three tracked frames: windows of one frame, (2 - 0) / 3; two steps give a jitter.
    tracking[3:] = TrackStatus.LOST
    first_three = tracking_accuracy(MODEL, tracking, estimated, t, alpha, nodes, nodes)
    assert first_three.drift_deg == pytest.approx(2.0 / 3.0, abs=1e-6)
    assert first_three.jitter_deg == pytest.approx(0.0, abs=1e-6)
    tracking[1:] = TrackStatus.LOST  # one frame: nothing to compare it with
    only_one = tracking_accuracy(MODEL, tracking, estimated, t, alpha, nodes, nodes)
    assert np.isnan(only_one.drift_deg) and np.isnan(only_one.jitter_deg)


def test_angle_errors_are_wrapped_across_180_degrees():
    """A head upside down: roll 181 (-179) degrees estimated as 179 is 2 degrees off, not 358."""
    omega, t, alpha, nodes = _truth(roll_deg=181.0)
    estimated = angles_to_omega(omega_to_angles(omega) - np.radians([0.0, 0.0, 2.0]))
    accuracy = tracking_accuracy(MODEL, STATUS, estimated, t, alpha, nodes, nodes)
    assert accuracy.rotation_mae_deg == pytest.approx((0.0, 0.0, 2.0), abs=1e-6)
