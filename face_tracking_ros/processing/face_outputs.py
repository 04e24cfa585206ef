"""The per-frame outputs both trackers publish for a face: ports and messages, in one place."""

from __future__ import annotations

from typing import Any

import numpy as np

from face_tracking_ros.io import conversions
from face_tracking_ros.io.messages import MessageFactory
from face_tracking_ros.model.topology import MeshTopology
from face_tracking_ros.processing.base import Output, Port
from face_tracking_ros.tracking.result import TrackResult

MESH_PORTS = (
    Port('face/state', 'face_tracking_msgs/msg/FaceState'),
    Port('face/mesh_raw', 'face_tracking_msgs/msg/FaceMesh'),
    Port('face/mesh', 'visualization_msgs/msg/MarkerArray'),
)
"""Outputs of any tracker: the state and the 3-D mesh."""

MODEL_PORTS = (
    Port('face/pose', 'geometry_msgs/msg/PoseStamped'),
    Port('face/action', 'face_tracking_msgs/msg/ActionParams'),
    Port('face/shape', 'face_tracking_msgs/msg/ShapeParams'),
)
"""Outputs of a tracker with a face model: pose, expression and identity parameters, of tracked
images only (a LOST or not yet initialised face has no estimate of them: ``face/state`` says so,
with the last valid one)."""


def face_outputs(
    factory: MessageFactory,
    header: Any,
    face_id: str,
    result: TrackResult,
    topology: MeshTopology,
    with_model: bool = True,
) -> list[Output]:
    """The outputs of :data:`MESH_PORTS` (and :data:`MODEL_PORTS` with a model) for a result.

    The pose, action and shape are left out unless the result is TRACKING: published while the
    face is lost, their last valid values read as the face's current ones (an expression
    recogniser would hold a smile for as long as the face is gone). The mesh is left out while
    there is no estimate at all (INITIALIZING): a FaceMesh has no status, and its nodes would be
    the zeros the state carries then, a face at the camera's centre; its markers are deleted
    then (:func:`~face_tracking_ros.io.conversions.deleted_mesh_markers`).

    Args:
        factory: message factory.
        header: header of the source image, carried to every output.
        face_id: tracker-assigned face identifier.
        result: the tracker's estimate.
        topology: mesh topology (names and edges).
        with_model: include pose, action and shape (trackers without a model have none).
    """
    messages = conversions.face_messages(factory, header, face_id, result, topology)
    outputs = [Output('face/state', messages.state)]
    if np.isfinite(result.nodes_cam).all():
        outputs += [Output('face/mesh_raw', messages.mesh), Output('face/mesh', messages.markers)]
    else:
        deleted = conversions.deleted_mesh_markers(factory, header, face_id)
        outputs.append(Output('face/mesh', deleted))
    if with_model and result.ok:
        outputs += [
            Output('face/pose', messages.pose),
            Output('face/action', messages.action),
            Output('face/shape', messages.shape),
        ]
    return outputs
