"""Error types of face_tracking_ros.

Every error the package raises on bad input derives from :class:`FaceTrackingError`, so callers
(nodes, the command line) can catch one type and report its message, which always names the
offending file, topic, field or parameter.
"""

from __future__ import annotations


class FaceTrackingError(Exception):
    """Base class of every error raised by face_tracking_ros."""


class InputError(FaceTrackingError):
    """An input array, image or message is malformed (shape, dtype, encoding, NaN, size)."""


class ConfigError(FaceTrackingError):
    """A parameter or command-line argument is out of range or inconsistent."""


class FieldError(ConfigError):
    """A configuration dataclass's field is out of range.

    Attributes:
        field: the field's name (a parameter source names it as its parameter).
    """

    def __init__(self, message: str, field: str) -> None:
        """An error ``message`` about ``field``."""
        super().__init__(message)
        self.field = field


def check_fields(config: object, checks: dict[str, bool]) -> None:
    """Raise a ConfigError naming the first field of ``config`` whose check is False.

    Args:
        config: a configuration dataclass (its class name and the field's value go in the
            message).
        checks: field name -> whether its value is valid.
    """
    for name, ok in checks.items():
        if not ok:
            msg = f'invalid {type(config).__name__}.{name} = {getattr(config, name)!r}'
            raise FieldError(msg, name)


class ModelFileError(FaceTrackingError):
    """A model, gallery or classifier file is missing, malformed or of another format version."""


class BagError(FaceTrackingError):
    """A bag is missing, truncated, corrupt or lacks the topics asked for."""
