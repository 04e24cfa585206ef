"""What the recognisers take from their tracker's ``face/state``: whether the face is tracked.

The trackers publish ``face/action`` and ``face/shape`` for tracked images only, and
``face/state`` for every image. A recogniser reads the state's status to know when a track ends
(the face lost, or the tracker not yet initialised): the expression recogniser ends the active
expression, the identity recogniser starts its decision over for the next track. An estimate of
an image whose state said the face was not tracked (from a tracker that publishes its last
estimate while lost, as this package's did before) is to be ignored.
"""

from __future__ import annotations

from typing import Any

from face_tracking_ros.io.bags import stamp_to_ns
from face_tracking_ros.processing.base import Port
from face_tracking_ros.tracking.result import TrackStatus

STATE_PORT = Port('face/state', 'face_tracking_msgs/msg/FaceState')


class TrackEnds:
    """Reads a tracker's FaceState messages for the images whose face was not tracked."""

    def __init__(self) -> None:
        """No state seen yet."""
        self._untracked_stamp: int | None = None  # of the last state that was not TRACKING

    def ended(self, state: Any) -> bool:
        """Whether this FaceState says the face is not tracked (a track ends or has ended)."""
        if state.status == TrackStatus.TRACKING:
            return False
        self._untracked_stamp = stamp_to_ns(state.header.stamp)
        return True

    def untracked(self, stamp_ns: int) -> bool:
        """Whether an estimate stamped ``stamp_ns`` is of an image whose face was not tracked."""
        return stamp_ns == self._untracked_stamp
