"""One camera's calibration as a tracking processor keeps it: from camera_info, with its rectifier.

A camera driver repeats its camera_info with every image. The mono and stereo processors keep
the calibration of each camera with the :class:`~face_tracking_ros.imaging.rectification.Rectifier`
it gives, and rebuild their tracker only when a calibration is new or has changed
(:meth:`PinholeCamera.same_calibration
<face_tracking_ros.geometry.camera.PinholeCamera.same_calibration>`): a repeat changes nothing.
A calibration that cannot be used (it cannot be rectified; for a stereo rig, the processor's own
check of the two cameras) is refused before it is kept, so the one before stays; the stereo
processor sets one that does not fit the other camera's aside (:meth:`CameraCalibration.set_aside`)
until that camera's new one comes.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.imaging import inside_image
from face_tracking_ros.imaging.rectification import Rectifier
from face_tracking_ros.io import conversions
from face_tracking_ros.tracking.initialisation import Initialisation


class CameraCalibration:
    """The calibration of one camera kept from its camera_info stream, and its rectifier."""

    def __init__(self, rectify: bool) -> None:
        """No calibration yet; ``rectify``: rectify the camera's raw images (``Rectifier``)."""
        self._rectify = rectify
        self._reader = conversions.CameraInfoReader()
        self.rectifier: Rectifier | None = None  # of the calibration kept
        self.pending: Rectifier | None = None  # a new one set aside (:meth:`set_aside`)

    @property
    def camera(self) -> PinholeCamera | None:
        """The calibration kept, or None before the first one."""
        return None if self.rectifier is None else self.rectifier.camera

    def read(self, msg: Any) -> PinholeCamera | None:
        """The camera of a camera_info message if its calibration is new, else None (a repeat).

        Raises:
            InputError: as :func:`~face_tracking_ros.io.conversions.camera_from_info`.
        """
        camera = self._reader.read(msg)
        kept = self.camera
        return camera if kept is None or not kept.same_calibration(camera) else None

    def keep(self, camera: PinholeCamera) -> None:
        """Keep a new calibration (:meth:`read`) and its rectifier; the tracker needs rebuilding.

        Raises:
            InputError: for a distortion model that cannot be rectified (the old one is kept).
        """
        self.rectifier, self.pending = Rectifier(camera, self._rectify), None

    def set_aside(self, camera: PinholeCamera) -> None:
        """Hold a new calibration (:meth:`read`) that cannot be kept yet as :attr:`pending`.

        A stereo rig's camera switched to another resolution or focal length does not fit the
        other camera's calibration until that one's new calibration comes too.

        Raises:
            InputError: as :meth:`keep`.
        """
        if self.pending is None or not self.pending.camera.same_calibration(camera):
            self.pending = Rectifier(camera, self._rectify)

    def keep_pending(self) -> None:
        """Keep the calibration set aside (:attr:`pending`, not None): as :meth:`keep` does."""
        self.rectifier, self.pending = self.pending, None

    def rectified(self, initialisation: Initialisation | None) -> Initialisation | None:
        """Node positions in the raw image (init file, reset) moved to the rectified image."""
        if initialisation is None:
            return None
        return initialisation.moved(self.rectifier.points)

    def seen(self, nodes_cam: np.ndarray) -> np.ndarray:
        """Where the calibration kept sees (N, 3) camera-frame nodes (m): (N, 2) rectified px.

        NaN for a node behind the camera or outside its image. A calibration that changes while
        a track runs restarts the track from the last tracked nodes seen so: the pixel positions
        the old calibration gave them are another image's once the camera was switched to
        another resolution or focal length.
        """
        pixels = np.full((len(nodes_cam), 2), np.nan)
        front = nodes_cam[:, 2] > 0.0
        pixels[front] = self.camera.project(nodes_cam[front])
        pixels[~inside_image(pixels, (self.camera.height, self.camera.width))] = np.nan
        return pixels
