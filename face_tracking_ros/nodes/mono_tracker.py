"""The mono_tracker node: monocular model-based face tracking (eq. 6) on a camera stream.

Subscribes ``image`` (or ``image/compressed`` with ``compressed:=true``), ``camera_info`` and the
latched ``face/model``; publishes ``face/state``, ``face/mesh_raw``, ``face/mesh``, for tracked
images ``face/pose``, ``face/action``, ``face/shape`` and, while subscribed, ``face/overlay``;
serves ``reset_tracking``. Parameters:
:class:`~face_tracking_ros.processing.mono.MonoNodeConfig`, as ``tracker.*``
:class:`~face_tracking_ros.tracking.mono_config.MonoTrackerConfig`, as ``smoothing.*``
:class:`~face_tracking_ros.tracking.pose_filter.PoseFilterConfig` and, as ``detector.*``,
:class:`~face_tracking_ros.tracking.detector.DetectorConfig`.
"""

from __future__ import annotations

from face_tracking_ros.nodes.processor_node import run
from face_tracking_ros.nodes.tracker_node import TrackerNode


def main(args: list[str] | None = None) -> None:
    """Entry point of ``ros2 run face_tracking_ros mono_tracker``."""
    run('mono_tracker', lambda: TrackerNode('mono_tracker'), args)


if __name__ == '__main__':
    main()
