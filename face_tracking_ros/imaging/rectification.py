"""Rectification of raw camera images, as image_proc's rectify does it.

The trackers work on the rectified image of a camera's projection matrix P (eq. 2; for a stereo
rig the pair whose epipolar lines are image rows). A camera driver publishes the raw image on
``image_raw`` and its calibration in CameraInfo: intrinsics K, distortion D, rectification
rotation R and P. :class:`Rectifier` turns such raw images into rectified ones with
``cv2.remap`` (maps made once per calibration) and maps raw pixel positions, such as the clicks
of an init file, to the rectified image. For a camera whose raw image already is its rectified
one (no distortion, R the identity, P's 3x3 equal to K) it passes images and points through.
"""

from __future__ import annotations

import cv2
import numpy as np

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.camera import PinholeCamera


class Rectifier:
    """Raw image (and raw pixels) of one camera to the rectified image of its P."""

    def __init__(self, camera: PinholeCamera, enabled: bool = True) -> None:
        """Make the remap maps of ``camera``, if it needs any and ``enabled``.

        Disabled (images that arrive rectified already, e.g. image_rect with the raw camera's
        CameraInfo), it passes images and points through.

        Float maps and bilinear interpolation: a 640x480 grey image takes 0.6-1.0 ms on one core
        here (OpenCV's fixed-point maps took 0.9 ms where float ones took 0.6 ms).

        Raises:
            InputError: for a distortion model OpenCV does not implement.
        """
        self.camera = camera
        self._maps = camera.rectify_maps() if enabled and camera.needs_rectification else None

    @property
    def identity(self) -> bool:
        """True if the camera's raw images are already rectified (nothing to do)."""
        return self._maps is None

    def check_size(self, raw: np.ndarray, name: str = 'image') -> None:
        """Refuse a raw image of another size than the camera's (its camera_info's).

        Raises:
            InputError: naming the image ``name`` and both sizes.
        """
        camera = self.camera
        if raw.shape[:2] != (camera.height, camera.width):
            msg = (
                f'{name} is {raw.shape[1]}x{raw.shape[0]} but camera_info says '
                f'{camera.width}x{camera.height}'
            )
            raise InputError(msg)

    def image(self, raw: np.ndarray) -> np.ndarray:
        """The rectified image of a raw (H, W) image of this camera (the same array if identity).

        Pixels that see nothing of the raw image are 0.
        """
        if self._maps is None:
            return raw
        return cv2.remap(raw, self._maps[0], self._maps[1], cv2.INTER_LINEAR)

    def points(self, raw: np.ndarray) -> np.ndarray:
        """(N, 2) rectified pixels of (N, 2) raw-image pixels (a copy if identity)."""
        if self._maps is None:
            return np.array(raw, dtype=float).reshape(-1, 2)
        return self.camera.rectified_pixels(raw)
