"""A processing node that also serves ``reset_tracking`` (ResetTracking.srv): the trackers."""

from __future__ import annotations

from typing import Any

from face_tracking_msgs.srv import ResetTracking

from face_tracking_ros.errors import FaceTrackingError
from face_tracking_ros.io import conversions
from face_tracking_ros.nodes.processor_node import ProcessorNode


class TrackerNode(ProcessorNode):
    """Runs a tracker's processor and restarts it on ``reset_tracking`` requests."""

    def __init__(self, name: str) -> None:
        """Build the node ``name`` with the processor registered under that name."""
        super().__init__(name)
        self._reset_service = self.create_service(ResetTracking, 'reset_tracking', self._on_reset)

    def _on_reset(self, request: Any, response: Any) -> Any:
        """Restart from the request's 2-D node positions, or automatically if it has none."""
        try:
            init = conversions.initialisation_from_reset(request)
            source = self.processor.reset(init)  # type: ignore[attr-defined]
        except FaceTrackingError as error:
            response.success, response.message = False, str(error)
            return response
        response.success, response.message = True, source
        return response
