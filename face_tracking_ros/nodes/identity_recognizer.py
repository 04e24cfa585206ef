"""The identity_recognizer node: who the tracked face is, from its shape parameters (§3.6).

Subscribes ``face/shape``, ``face/state`` (whose status starts the decision over when the face
is lost) and the latched ``face/model`` (nothing is decided or enrolled while the tracker's model
is not the gallery's); publishes ``face/identity`` (IdentityEvent when the decision changes, and
for each new track); serves
``enroll_identity`` (EnrollIdentity.srv). Parameters:
:class:`~face_tracking_ros.processing.identity.IdentityNodeConfig` and, as ``identity.*``,
:class:`~face_tracking_ros.recognition.identity.IdentityConfig`.
"""

from __future__ import annotations

from typing import Any

from face_tracking_msgs.srv import EnrollIdentity

from face_tracking_ros.errors import FaceTrackingError
from face_tracking_ros.nodes.processor_node import ProcessorNode, run


class IdentityRecognizerNode(ProcessorNode):
    """Runs the identity processor and serves ``enroll_identity``."""

    def __init__(self) -> None:
        """Build the node, its topics and the enrolment service."""
        super().__init__('identity_recognizer')
        self._enroll_service = self.create_service(
            EnrollIdentity, 'enroll_identity', self._on_enroll
        )

    def _on_enroll(self, request: Any, response: Any) -> Any:
        """Enrol the tracked face from its sigma of the last ``request.duration`` seconds."""
        try:
            samples = self.processor.enroll(request.name, request.duration)  # type: ignore[attr-defined]
        except FaceTrackingError as error:
            response.success, response.message, response.samples = False, str(error), 0
            return response
        response.success, response.samples = True, samples
        response.message = f'enrolled {request.name!r} from {samples} shape estimates'
        self.get_logger().info(response.message)
        return response


def main(args: list[str] | None = None) -> None:
    """Entry point of ``ros2 run face_tracking_ros identity_recognizer``."""
    run('identity_recognizer', IdentityRecognizerNode, args)


if __name__ == '__main__':
    main()
