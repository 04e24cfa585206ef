"""The stereo_tracker node: 3-D mesh tracking in rectified stereo (eq. 4 and 5).

Subscribes ``left/image_raw``, ``left/camera_info``, ``right/image_raw``, ``right/camera_info``
(raw images, rectified with their calibration: ``rectify``; or the images'
``/compressed`` topics with ``compressed:=true``) and the latched ``face/model``;
publishes ``face/mesh_raw``, ``face/mesh``, ``face/state`` and, with a model, for tracked pairs
``face/pose``, ``face/action``, ``face/shape``; serves ``reset_tracking``. Parameters:
:class:`~face_tracking_ros.processing.stereo.StereoNodeConfig`, as ``tracker.*``
:class:`~face_tracking_ros.tracking.stereo_config.StereoTrackerConfig` and, as ``detector.*``,
:class:`~face_tracking_ros.tracking.detector.DetectorConfig`.
"""

from __future__ import annotations

from face_tracking_ros.nodes.processor_node import run
from face_tracking_ros.nodes.tracker_node import TrackerNode


def main(args: list[str] | None = None) -> None:
    """Entry point of ``ros2 run face_tracking_ros stereo_tracker``."""
    run('stereo_tracker', lambda: TrackerNode('stereo_tracker'), args)


if __name__ == '__main__':
    main()
