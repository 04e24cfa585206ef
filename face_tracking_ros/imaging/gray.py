"""Encoding-independent grey conversion of sensor_msgs/Image-like arrays."""

from __future__ import annotations

import cv2
import numpy as np

from face_tracking_ros.errors import InputError

# sensor_msgs/image_encodings names -> (channels, cvtColor code or None for grey already).
_CONVERSIONS: dict[str, tuple[int, int | None]] = {
    'mono8': (1, None),
    'rgb8': (3, cv2.COLOR_RGB2GRAY),
    'bgr8': (3, cv2.COLOR_BGR2GRAY),
}
SUPPORTED_ENCODINGS: tuple[str, ...] = tuple(_CONVERSIONS)


def to_gray(array: np.ndarray, encoding: str) -> np.ndarray:
    """Grey image of a mono8, rgb8 or bgr8 array.

    Args:
        array: (H, W) or (H, W, 1) uint8 for mono8; (H, W, 3) uint8 for rgb8 and bgr8.
        encoding: the sensor_msgs/Image encoding of ``array``.

    Returns:
        (H, W) uint8 grey image (a view for mono8, a new array otherwise).

    Raises:
        InputError: for another encoding, a dtype other than uint8, or a shape that does not match
            the encoding.
    """
    if encoding not in _CONVERSIONS:
        msg = (
            f'unsupported image encoding {encoding!r}; supported: {", ".join(SUPPORTED_ENCODINGS)}'
        )
        raise InputError(msg)
    array = np.asarray(array)
    channels, code = _CONVERSIONS[encoding]
    if array.dtype != np.uint8:
        msg = f'{encoding} image must be uint8, got {array.dtype}'
        raise InputError(msg)
    shape_ok = array.ndim == 3 and array.shape[2] == channels
    if channels == 1:
        shape_ok = shape_ok or array.ndim == 2
    if not shape_ok or min(array.shape[:2], default=0) < 1:
        msg = f'{encoding} image must be (H, W{", 3" if channels == 3 else ""}), got {array.shape}'
        raise InputError(msg)
    if code is None:
        return array.reshape(array.shape[:2])
    return cv2.cvtColor(array, code)
