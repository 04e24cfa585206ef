"""Message definitions a bag carries: each type is read as the bag defines it.

A rosbag2 bag stores each topic's message definition (the MCAP schema: the ros2msg text with the
definitions it depends on). A bag written by an earlier version of this package, or by another
system, may define a type otherwise than this version: a field added to a
face_tracking_msgs message, or a type this package does not know at all. CDR is positional, so
reading such messages with this version's definitions would misread them or fail; they are read
with the bag's own definition instead, and outputs written before a message changed stay
readable. A type defined as this version defines it (the usual case) is read with the package's
typestore.
"""

from __future__ import annotations

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import TypesysError
from rosbags.typesys.store import Typestore


class BagDefinitions:
    """Chooses, per message type and bag definition, the typestore to deserialise with."""

    def __init__(self, store: Typestore) -> None:
        """Read with ``store`` (the package's typestore) wherever the bag agrees with it."""
        self._store = store
        self._chosen: dict[tuple[str, str], Typestore] = {}

    def store_for(self, msgtype: str, msgdef: str) -> Typestore:
        """The typestore for ``msgtype`` as the bag defines it (``msgdef``, '' if it does not).

        The package's store when the definitions agree, the bag gives none, or the bag's cannot
        be parsed (its messages then fail to deserialise, and the caller says so); else a store
        of the bag's definition alone.
        """
        key = (msgtype, msgdef)
        if key not in self._chosen:
            self._chosen[key] = self._choose(msgtype, msgdef)
        return self._chosen[key]

    def _choose(self, msgtype: str, msgdef: str) -> Typestore:
        """The package's store, or one of the bag's definition (see :meth:`store_for`).

        The package's definition is compared as a rosbag2 writer gives it (ROS 2's text:
        ``builtin_interfaces/Time stamp``, not ROS 1's ``time stamp``); compared as ROS 1's, no
        bag agreed, and each read parsed and compiled a store of every type it read (10 ms of a
        replay's start).
        """
        known = msgtype in self._store.types
        ours = self._store.generate_msgdef(msgtype, ros_version=2)[0] if known else ''
        if not msgdef or ours == msgdef:
            return self._store
        own = get_typestore(Stores.EMPTY)
        try:
            own.register(get_types_from_msg(msgdef, msgtype))
        except (TypesysError, ValueError):
            return self._store
        return own
