"""3-D face tracking with a learned deformable face model, for ROS 2.

Layers (imports go one way, top to bottom):

- algorithms: ``model``, ``geometry``, ``imaging``, ``learning``, ``tracking``, ``recognition``,
  ``synthetic`` (numpy/scipy/OpenCV only, no ROS);
- conversions and I/O: ``io`` (rosbags typestore, bag reading and writing);
- front ends: ``cli`` (the ``face-tracking`` command) and the ROS nodes.
"""

from __future__ import annotations

__version__ = '0.1.0'
