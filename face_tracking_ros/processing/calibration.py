"""One camera's calibration as a tracking processor keeps it: from camera_info, with its rectifier.

A camera driver repeats its camera_info with every image. The mono and stereo processors keep
the calibration of each camera with the :class:`~face_tracking_ros.imaging.rectification.Rectifier`
it gives, and rebuild their tracker only when a calibration is new or has changed
(:meth:`PinholeCamera.same_calibration
<face_tracking_ros.geometry.camera.PinholeCamera.same_calibration>`): a repeat changes nothing.
A calibration that cannot be used (it cannot be rectified; for a stereo rig, the processor's own
check of the two cameras) is refused before it is kept, so the one before stays.
"""

from __future__ import annotations

from typing import Any

from face_tracking_ros.geometry.camera import PinholeCamera
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
        self.rectifier = Rectifier(camera, self._rectify)

    def rectified(self, initialisation: Initialisation | None) -> Initialisation | None:
        """Node positions in the raw image (init file, reset) moved to the rectified image."""
        if initialisation is None:
            return None
        return initialisation.moved(self.rectifier.points)
