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
    'rgba8': (4, cv2.COLOR_RGBA2GRAY),
    'bgra8': (4, cv2.COLOR_BGRA2GRAY),
}
SUPPORTED_ENCODINGS: tuple[str, ...] = tuple(_CONVERSIONS)


def encoding_channels(encoding: str) -> int:
    """Number of uint8 channels of a supported encoding.

    Raises:
        InputError: for an unsupported encoding.
    """
    if encoding not in _CONVERSIONS:
        msg = (
            f'unsupported image encoding {encoding!r}; supported: {", ".join(SUPPORTED_ENCODINGS)}'
        )
        raise InputError(msg)
    return _CONVERSIONS[encoding][0]


def to_gray(array: np.ndarray, encoding: str) -> np.ndarray:
    """Grey image of a mono8, rgb8, bgr8, rgba8 or bgra8 array.

    Args:
        array: (H, W) or (H, W, 1) uint8 for mono8; (H, W, 3) uint8 for rgb8 and bgr8.
        encoding: the sensor_msgs/Image encoding of ``array``.

    Returns:
        (H, W) uint8 grey image (a view for mono8, a new array otherwise).

    Raises:
        InputError: for another encoding, a dtype other than uint8, or a shape that does not match
            the encoding.
    """
    channels = encoding_channels(encoding)
    code = _CONVERSIONS[encoding][1]
    array = np.asarray(array)
    if array.dtype != np.uint8:
        msg = f'{encoding} image must be uint8, got {array.dtype}'
        raise InputError(msg)
    shape_ok = array.ndim == 3 and array.shape[2] == channels
    if channels == 1:
        shape_ok = shape_ok or array.ndim == 2
    if not shape_ok or min(array.shape[:2], default=0) < 1:
        expected = '(H, W)' if channels == 1 else f'(H, W, {channels})'
        msg = f'{encoding} image must be {expected}, got {array.shape}'
        raise InputError(msg)
    if code is None:
        return array.reshape(array.shape[:2])
    return cv2.cvtColor(array, code)
