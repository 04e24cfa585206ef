"""What the recognisers take from their tracker's ``face/state``: whether the face is tracked.

The trackers publish ``face/action`` and ``face/shape`` for tracked images only, and
``face/state`` for every image. A recogniser reads the state's status to know when a track ends
(the face lost, or the tracker not yet initialised): the expression recogniser ends the active
expression, the identity recogniser starts its decision over for the next track. An estimate of
an image whose state said the face was not tracked (from a tracker that publishes its last
estimate while lost, as this package's did before) is to be ignored.

The expression recogniser also reads the state's ``occluded`` flags (:class:`CoveredExpressions`):
while an occluder covers mouth or brow nodes, the nodes that carry the expressions, the tracker
has not measured them and its alpha does not show what they do.

Order: each tracker publishes an image's ``face/state`` before its ``face/action`` and
``face/shape`` (:func:`~.face_outputs.face_outputs`), and a replay writes and routes them in
that order. Live, on separate topics, they may arrive in either order; :class:`TrackEnds` needs
the state first (it matches stamps, and a tracker publishes no estimate of an untracked image
anyway), :class:`CoveredExpressions` does not: it judges an estimate by the last state seen, its
own image's or, when that comes later, the image's before, which is off only at a cover's first
and last image.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import NS_PER_S, stamp_to_ns
from face_tracking_ros.model.topology import Group, MeshTopology
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


# The nodes whose cover hides the expression: the mouth and the brows carry 81 % of the packaged
# 34-node model's action basis (its columns' squared norm: mouth 2.28, brows 1.76, face edge
# 0.81, eyes, eye corners and nose 0.15, of 5).
EXPRESSIVE_GROUPS = (Group.MOUTH, Group.BROW)
# Fewest of them flagged at once for a cover: an occluder covers neighbouring nodes together (the
# mono tracker takes a node as covered only next to a covered one or with two more), while the
# stereo tracker flags brow or mouth nodes of an unoccluded face turning (on a rendered 640x480
# free-motion sequence, yaw up to 30 degrees: one or more on 94 of 300 pairs, two or more on 32;
# 251 and 87 when it flagged a patch disagreeing alone).
MIN_COVERED_EXPRESSIVE = 2


class CoveredExpressions:
    """Reads a tracker's FaceState messages for the images whose expressive nodes are covered.

    A cover starts at a state that flags at least :data:`MIN_COVERED_EXPRESSIVE` mouth or brow
    nodes (:data:`EXPRESSIVE_GROUPS`) as covered by an occluder and goes on until a state flags
    fewer: a LOST state carries the last tracked image's flags (the face was lost while covered),
    INITIALIZING none. For ``hold`` seconds from its first image, the estimates of a cover do
    not show what the expression does.
    """

    def __init__(self, topology: MeshTopology, hold: float) -> None:
        """Judge the nodes of ``topology``; hold a cover for at most ``hold`` seconds (0: none)."""
        self._expressive = topology.group_mask(*EXPRESSIVE_GROUPS)
        self._hold_ns = round(hold * NS_PER_S)
        self._since: int | None = None  # stamp of the current cover's first state

    def update(self, state: Any) -> None:
        """Take a FaceState's flags: a cover starts, goes on or ends.

        Flags of another node count (a tracker with another model) cover nothing.
        """
        occluded = conversions.occluded_nodes(state)
        stamp = stamp_to_ns(state.header.stamp)
        if (
            occluded.shape != self._expressive.shape
            or np.count_nonzero(occluded & self._expressive) < MIN_COVERED_EXPRESSIVE
        ):
            self._since = None
        elif self._since is None or stamp < self._since:  # a cover starts (or a new track's)
            self._since = stamp

    def held(self, stamp_ns: int) -> bool:
        """Whether an image stamped ``stamp_ns`` lies in a cover, less than ``hold`` s into it."""
        return self._since is not None and 0 <= stamp_ns - self._since < self._hold_ns
