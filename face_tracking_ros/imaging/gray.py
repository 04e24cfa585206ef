"""Encoding-independent grey conversion of sensor_msgs/Image-like arrays."""

from __future__ import annotations

import cv2
import numpy as np

from face_tracking_ros.errors import InputError

# sensor_msgs/image_encodings names -> (channels, cvtColor code or None for grey already).
# OpenCV names a Bayer pattern by its second row's second and third pixels, so ROS's RGGB is
# OpenCV's BG (as in cv_bridge); yuv422 is UYVY and yuv422_yuy2 YUYV, two bytes a pixel.
_CONVERSIONS: dict[str, tuple[int, int | None]] = {
    'mono8': (1, None),
    'rgb8': (3, cv2.COLOR_RGB2GRAY),
    'bgr8': (3, cv2.COLOR_BGR2GRAY),
    'rgba8': (4, cv2.COLOR_RGBA2GRAY),
    'bgra8': (4, cv2.COLOR_BGRA2GRAY),
    'bayer_rggb8': (1, cv2.COLOR_BayerBG2GRAY),
    'bayer_bggr8': (1, cv2.COLOR_BayerRG2GRAY),
    'bayer_gbrg8': (1, cv2.COLOR_BayerGR2GRAY),
    'bayer_grbg8': (1, cv2.COLOR_BayerGB2GRAY),
    'yuv422': (2, cv2.COLOR_YUV2GRAY_UYVY),
    'yuv422_yuy2': (2, cv2.COLOR_YUV2GRAY_YUY2),
    # OpenCV's own type names, which cv_bridge's cv2_to_imgmsg gives by default ('passthrough'):
    # its colour images are BGR(A), as cv_bridge and image_view read 8UC3 and 8UC4.
    '8UC1': (1, None),
    '8UC3': (3, cv2.COLOR_BGR2GRAY),
    '8UC4': (4, cv2.COLOR_BGRA2GRAY),
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
    """Grey image of an array in one of the :data:`SUPPORTED_ENCODINGS`.

    Args:
        array: (H, W) or (H, W, 1) uint8 for mono8, 8UC1 and the Bayer patterns (demosaiced to
            grey); (H, W, C) uint8 for the others: 3 for rgb8, bgr8 and 8UC3, 4 for rgba8, bgra8
            and 8UC4, 2 for the YUV 4:2:2 ones.
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
    if not shape_ok or min(array.shape[:2]) < 1:
        expected = '(H, W)' if channels == 1 else f'(H, W, {channels})'
        msg = f'{encoding} image must be {expected}, got {array.shape}'
        raise InputError(msg)
    if channels == 1:
        array = array.reshape(array.shape[:2])
    return array if code is None else cv2.cvtColor(array, code)
