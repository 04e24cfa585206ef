"""The processors of the package's nodes, by node name, for offline replay.

Each entry names a function that builds a node's processor from a :class:`ParameterSource` and a
message factory; the live node module calls the same function with its ROS parameters. Entries
are imported on use, so replaying one node does not import every tracker.
"""

from __future__ import annotations

from collections.abc import Callable
import importlib

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io.messages import MessageFactory
from face_tracking_ros.processing.base import Processor
from face_tracking_ros.processing.parameters import ParameterSource

ProcessorFactory = Callable[[ParameterSource, MessageFactory], Processor]

PROCESSORS: dict[str, str] = {
    'mono_tracker': 'face_tracking_ros.processing.mono:make_mono_processor',
    'stereo_tracker': 'face_tracking_ros.processing.stereo:make_stereo_processor',
    'expression_recognizer': 'face_tracking_ros.processing.expression:make_expression_processor',
    'identity_recognizer': 'face_tracking_ros.processing.identity:make_identity_processor',
}


def processor_factory(node: str) -> ProcessorFactory:
    """The processor factory of a node name.

    Raises:
        ConfigError: for a node without a processor.
    """
    if node not in PROCESSORS:
        msg = f'no replayable node {node!r}; choose one of {", ".join(sorted(PROCESSORS))}'
        raise ConfigError(msg)
    module, function = PROCESSORS[node].split(':')
    return getattr(importlib.import_module(module), function)
