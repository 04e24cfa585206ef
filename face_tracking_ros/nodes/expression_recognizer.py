"""The expression_recognizer node: expression events from a face's action parameters (§4.5).

Subscribes ``face/action``, ``face/state`` (whose status ends an expression when the face is
lost) and the latched ``face/model`` (nothing is recognised while the tracker's model is not the
classifier's); publishes ``face/expression`` (ExpressionEvent at onsets and offsets) and, while
subscribed, ``face/expression_scores``. Parameters:
:class:`~face_tracking_ros.processing.expression.ExpressionNodeConfig` and, as ``events.*``,
:class:`~face_tracking_ros.recognition.events.EventConfig`.
"""

from __future__ import annotations

from face_tracking_ros.nodes.processor_node import ProcessorNode, run


def main(args: list[str] | None = None) -> None:
    """Entry point of ``ros2 run face_tracking_ros expression_recognizer``."""
    run('expression_recognizer', lambda: ProcessorNode('expression_recognizer'), args)


if __name__ == '__main__':
    main()
