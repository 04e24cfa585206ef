"""Tests of the stereo tracking figures (node RMS, reprojection, drift, boundary slip)."""

from __future__ import annotations

import numpy as np
import pytest

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.camera import StereoRig
from face_tracking_ros.model.topology import Group, mesh_topology
from face_tracking_ros.tracking.stereo_evaluation import evaluate_stereo

RIG = StereoRig.ideal()
TOPOLOGY = mesh_topology(34)


def _truth(frames: int = 5) -> np.ndarray:
    """A still face 0.6 m away, (F, 34, 3), m."""
    face = TOPOLOGY.reference_shape + np.array([0.0, 0.0, 0.6])
    return np.repeat(face[None], frames, axis=0)


def test_perfect_tracking_scores_zero() -> None:
    truth = _truth()
    evaluation = evaluate_stereo(truth, truth, RIG, TOPOLOGY, np.ones(5, dtype=int))
    assert evaluation.node_rms == 0.0 and evaluation.max_reprojection == 0.0
    assert evaluation.drift == 0.0 and evaluation.boundary_slip == 0.0
    assert evaluation.tracked_fraction == 1.0 and evaluation.frames == 5
    assert '3-D node RMS 0.00 mm' in evaluation.report()


def test_constant_offset_is_error_but_not_drift() -> None:
    truth = _truth()
    offset = np.array([0.001, 0.0, 0.0])  # 1 mm along x at 0.6 m and f = 600 px: 1 px
    evaluation = evaluate_stereo(truth + offset, truth, RIG, TOPOLOGY)
    assert evaluation.node_rms == pytest.approx(0.001)
    assert evaluation.node_rms_by_group['edge'] == pytest.approx(0.001)
    assert evaluation.drift == pytest.approx(0.0, abs=1e-12)
    # One node off by 3 mm more: its own RMS shows it, the others' do not.
    moved = truth + offset
    moved[:, TOPOLOGY.index('chin'), 2] += 0.003
    by_node = evaluate_stereo(moved, truth, RIG, TOPOLOGY).node_rms_by_node
    assert list(by_node) == list(TOPOLOGY.node_names)
    assert by_node['chin'] == pytest.approx(np.hypot(0.001, 0.003))
    assert by_node['nose_tip'] == pytest.approx(0.001)
    figures = evaluation.in_mm()
    assert figures['node_rms_mm'] == pytest.approx(1.0) and figures['frames'] == 5
    assert figures['node_rms_by_node_mm']['chin'] == pytest.approx(1.0)
    assert figures['max_reprojection_px'] == evaluation.max_reprojection
    assert evaluation.boundary_slip == pytest.approx(0.0, abs=1e-12)
    # Depths vary over the face (reference z -27..+30 mm): 1 mm at z = 0.573..0.630 m.
    assert 600 * 0.001 / 0.63 <= evaluation.max_reprojection <= 600 * 0.001 / 0.57


def test_drift_and_slip_along_the_boundary() -> None:
    truth = _truth()
    tracked = truth.copy()
    chain = np.flatnonzero(TOPOLOGY.group_mask(Group.EDGE))
    cheek = chain[2]  # right_cheek_lower: neighbours right_cheek_upper and right_jaw
    along = truth[0, chain[3]] - truth[0, chain[1]]
    along /= np.linalg.norm(along)
    normal = np.cross(along, [0.0, 0.0, 1.0])
    normal /= np.linalg.norm(normal)
    tracked[-1, cheek] += 0.002 * along + 0.001 * normal
    status = np.array([1, 1, 2, 1, 1])
    evaluation = evaluate_stereo(tracked, truth, RIG, TOPOLOGY, status)
    assert evaluation.boundary_slip == pytest.approx(0.002)
    assert evaluation.max_drift == pytest.approx(np.sqrt(0.002**2 + 0.001**2))
    assert evaluation.drift == pytest.approx(evaluation.max_drift / np.sqrt(34))
    assert evaluation.tracked_fraction == pytest.approx(0.8)


def test_the_reprojection_error_is_the_larger_of_the_two_cameras() -> None:
    """The nose tip (x = 0, y = 38 mm, 573 mm away) tracked 3 mm too deep.

    By hand: in the left camera only v moves, by 600 * 0.038 (1 / 0.573 - 1 / 0.576) = 0.21 px;
    in the right one (P[0, 3] = -66) u moves too, by 66 (1 / 0.573 - 1 / 0.576): 0.63 px in all.
    """
    truth = _truth()
    tracked = truth.copy()
    tracked[-1, TOPOLOGY.index('nose_tip'), 2] += 0.003
    evaluation = evaluate_stereo(tracked, truth, RIG, TOPOLOGY)
    shrink = 1 / 0.573 - 1 / 0.576
    assert evaluation.max_reprojection == pytest.approx(shrink * np.hypot(66, 600 * 0.038))


def test_mesh_without_edge_nodes_has_no_slip() -> None:
    truth = _truth()[:, :19]
    evaluation = evaluate_stereo(truth, truth, RIG, mesh_topology(19))
    assert np.isnan(evaluation.boundary_slip) and 'edge' not in evaluation.node_rms_by_group


@pytest.mark.parametrize(
    ('meshes', 'truth', 'match'),
    [
        (np.zeros((5, 34, 3)), np.zeros((4, 34, 3)), 'must both be'),
        (np.zeros((5, 19, 3)), np.zeros((5, 19, 3)), 'must both be'),
        (np.zeros((0, 34, 3)), np.zeros((0, 34, 3)), 'at least one frame'),
        (np.full((2, 34, 3), np.nan), np.zeros((2, 34, 3)), 'no NaN'),
    ],
)
def test_bad_input_is_rejected(meshes: np.ndarray, truth: np.ndarray, match: str) -> None:
    with pytest.raises(InputError, match=match):
        evaluate_stereo(meshes, truth, RIG, TOPOLOGY)
