"""The mono_tracker node: monocular model-based face tracking (eq. 6) on a camera stream.

Subscribes ``image`` (or ``image/compressed``), ``camera_info`` and the latched ``face/model``;
publishes ``face/state``, ``face/pose``, ``face/action``, ``face/shape``, ``face/mesh_raw``,
``face/mesh`` and, while subscribed, ``face/overlay``; serves ``reset_tracking``. Every parameter
is declared with its description (``tracker.*`` are the tracker's tunables).
"""

from __future__ import annotations

from typing import Any

from face_tracking_msgs.srv import ResetTracking

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io import conversions
from face_tracking_ros.nodes.processor_node import ProcessorNode, run
from face_tracking_ros.processing.mono import make_mono_processor


class MonoTrackerNode(ProcessorNode):
    """Runs :class:`MonoProcessor` on the image stream and serves ``reset_tracking``."""

    def __init__(self) -> None:
        """Declare parameters, load the model and the optional init file, wire the topics."""
        super().__init__('mono_tracker', make_mono_processor)
        self._reset = self.create_service(ResetTracking, 'reset_tracking', self._on_reset)

    def _on_reset(self, request: Any, response: Any) -> Any:
        """Restart tracking from the request's 2-D node positions, or automatically if empty."""
        try:
            init = conversions.initialisation_from_reset(request)
        except ConfigError as error:
            response.success, response.message = False, str(error)
            return response
        self.processor.reset(init)  # type: ignore[attr-defined]
        response.success = True
        response.message = 'automatic re-initialisation' if init is None else 'initialising'
        return response


def main(args: list[str] | None = None) -> None:
    """Entry point of ``ros2 run face_tracking_ros mono_tracker``."""
    run(MonoTrackerNode, args)


if __name__ == '__main__':
    main()
