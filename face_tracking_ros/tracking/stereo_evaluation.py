"""Accuracy of stereo-tracked meshes against ground truth (the targets of issue 5).

Figures, all from (F, N, 3) tracked and true node positions in the left camera frame:

- ``node_rms``: RMS 3-D node error over all frames and nodes;
- ``max_reprojection``: largest distance between the projections of a tracked and a true node,
  over frames, nodes and both cameras (the seed's §3.3 quality figure, < 2 px there);
- ``drift``: RMS over nodes of the change of the error from the first to the last frame,
  ``(X(F) - X_true(F)) - (X(1) - X_true(1))``, so an initialisation offset is not drift;
- ``boundary_slip``: largest component, along the face boundary, of that change of error for
  the face-edge nodes over all frames (the §4.2 failure: edge nodes travelling along the edge).
  The boundary direction at an edge node is that of the chord between its two neighbours on the
  true temple-chin-temple chain (the chain's own direction at its two ends).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.camera import StereoRig
from face_tracking_ros.model.topology import Group, MeshTopology
from face_tracking_ros.wording import counted


@dataclass(frozen=True)
class StereoEvaluation:
    """Accuracy figures of a tracked stereo sequence (metres and pixels).

    Attributes:
        frames: number of frames F evaluated.
        node_rms: RMS 3-D node error, m.
        node_rms_by_group: RMS 3-D node error per anatomical group name, m.
        node_rms_by_node: RMS 3-D error of each node, by node name, m.
        max_reprojection: largest reprojection error in either camera, px.
        drift: RMS over nodes of the change of error from frame 1 to frame F, m.
        max_drift: largest node change of error from frame 1 to frame F, m.
        boundary_slip: largest change of error along the boundary of an edge node, m (NaN for
            a mesh without edge nodes).
        boundary_slip_rms: RMS of that quantity over edge nodes and frames, m.
        tracked_fraction: fraction of frames with status TRACKING (1 when no status is given).
    """

    frames: int
    node_rms: float
    node_rms_by_group: dict[str, float]
    node_rms_by_node: dict[str, float]
    max_reprojection: float
    drift: float
    max_drift: float
    boundary_slip: float
    boundary_slip_rms: float
    tracked_fraction: float

    def in_mm(self) -> dict[str, Any]:
        """The figures as a plain dict, lengths in mm (keys with an ``_mm`` suffix)."""
        figures = asdict(self)
        converted: dict[str, Any] = {}
        for key, value in figures.items():
            if key == 'max_reprojection':
                converted['max_reprojection_px'] = value
            elif isinstance(value, dict):
                converted[f'{key}_mm'] = {name: 1000.0 * rms for name, rms in value.items()}
            elif key in ('frames', 'tracked_fraction'):
                converted[key] = value
            else:
                converted[f'{key}_mm'] = 1000.0 * value
        return converted

    def report(self) -> str:
        """A one-paragraph summary in millimetres and pixels."""
        groups = ', '.join(
            f'{name} {1000 * rms:.2f}' for name, rms in self.node_rms_by_group.items()
        )
        return (
            f'{counted(self.frames, "frame")}, {100 * self.tracked_fraction:.0f}% tracked: 3-D '
            f'node RMS '
            f'{1000 * self.node_rms:.2f} mm ({groups}); max reprojection '
            f'{self.max_reprojection:.2f} px; drift frame 1 -> {self.frames} RMS '
            f'{1000 * self.drift:.2f} mm (max {1000 * self.max_drift:.2f}); boundary slip max '
            f'{1000 * self.boundary_slip:.2f} mm (RMS {1000 * self.boundary_slip_rms:.2f})'
        )


def evaluate_stereo(
    meshes: np.ndarray,
    truth: np.ndarray,
    rig: StereoRig,
    topology: MeshTopology,
    status: np.ndarray | None = None,
) -> StereoEvaluation:
    """Score tracked meshes against the true nodes.

    Args:
        meshes: (F, N, 3) tracked nodes, left camera frame, m.
        truth: (F, N, 3) true nodes, m.
        rig: the stereo rig (for the reprojection errors).
        topology: the mesh (its groups and edge chain).
        status: optional (F,) TrackStatus values.

    Raises:
        InputError: if the arrays do not have the same (F, N, 3) shape with F >= 1 and the
            topology's N, or hold NaN.
    """
    meshes, truth = _checked(meshes, truth, topology)
    error = meshes - truth
    distance = np.linalg.norm(error, axis=2)
    by_group = {
        group.value: float(np.sqrt(np.mean(distance[:, topology.group_mask(group)] ** 2)))
        for group in Group
        if topology.group_mask(group).any()
    }
    reprojection = _max_reprojection(meshes, truth, rig)
    change = error - error[:1]
    final_change = np.linalg.norm(change[-1], axis=1)
    slip = _boundary_slip(change, truth, topology)
    tracked = 1.0 if status is None else float(np.mean(np.asarray(status) == 1))
    return StereoEvaluation(
        frames=len(meshes),
        node_rms=float(np.sqrt(np.mean(distance**2))),
        node_rms_by_group=by_group,
        node_rms_by_node={
            name: float(np.sqrt(np.mean(distance[:, index] ** 2)))
            for index, name in enumerate(topology.node_names)
        },
        max_reprojection=reprojection,
        drift=float(np.sqrt(np.mean(final_change**2))),
        max_drift=float(final_change.max()),
        boundary_slip=float(np.max(slip)) if slip.size else float('nan'),
        boundary_slip_rms=float(np.sqrt(np.mean(slip**2))) if slip.size else float('nan'),
        tracked_fraction=tracked,
    )


def _checked(
    meshes: np.ndarray, truth: np.ndarray, topology: MeshTopology
) -> tuple[np.ndarray, np.ndarray]:
    """The meshes and truth as float arrays, refused unless both are finite (F >= 1, N, 3).

    Raises:
        InputError: as :func:`evaluate_stereo`.
    """
    meshes = np.asarray(meshes, dtype=float)
    truth = np.asarray(truth, dtype=float)
    expected = (topology.num_nodes, 3)
    if meshes.ndim != 3 or meshes.shape != truth.shape or meshes.shape[1:] != expected:
        msg = f'meshes {meshes.shape} and truth {truth.shape} must both be (F, {expected[0]}, 3)'
        raise InputError(msg)
    if len(meshes) == 0 or not (np.all(np.isfinite(meshes)) and np.all(np.isfinite(truth))):
        msg = 'meshes and truth must hold at least one frame and no NaN'
        raise InputError(msg)
    return meshes, truth


def _max_reprojection(meshes: np.ndarray, truth: np.ndarray, rig: StereoRig) -> float:
    """The largest distance between a tracked and a true node's projections, either camera, px."""
    return max(
        float(
            np.max(
                np.linalg.norm(
                    camera.project(meshes.reshape(-1, 3)) - camera.project(truth.reshape(-1, 3)),
                    axis=1,
                )
            )
        )
        for camera in (rig.left, rig.right)
    )


def _boundary_slip(change: np.ndarray, truth: np.ndarray, topology: MeshTopology) -> np.ndarray:
    """(F, E) |component along the boundary| of the change of error of the E edge nodes."""
    chain = np.flatnonzero(topology.group_mask(Group.EDGE))
    if chain.size < 2:
        return np.zeros((change.shape[0], 0))
    previous = np.concatenate([chain[:1], chain[:-1]])
    following = np.concatenate([chain[1:], chain[-1:]])
    tangent = truth[:, following] - truth[:, previous]
    tangent /= np.linalg.norm(tangent, axis=2, keepdims=True)
    return np.abs(np.einsum('fed,fed->fe', change[:, chain], tangent))
