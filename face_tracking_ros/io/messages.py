"""Message factories: build ROS messages by type name, for rclpy or for rosbags.

Live nodes publish rclpy messages; offline replay writes rosbags messages into MCAP bags. Both run
the same conversion code (:mod:`face_tracking_ros.io.conversions`), which builds messages through
a :class:`MessageFactory` given by type name (``'sensor_msgs/msg/Image'``) and keyword fields.
Reading needs no factory: rclpy and rosbags messages have the same field names.

- :class:`RosbagsMessages` fills every field that is not given with its ROS default, because
  rosbags' message classes require all fields.
- :class:`RclpyMessages` imports the rclpy message classes lazily (so this module imports without
  ROS) and hands numpy arrays over as ``bytes`` or ``array.array``, which rclpy stores without a
  per-element copy.
"""

from __future__ import annotations

import array
from collections.abc import Callable
from functools import partial
import importlib
from typing import Any, Protocol

import numpy as np
from rosbags.typesys.base import Nodetype
from rosbags.typesys.store import Typestore

_ARRAY_TYPECODES = {
    np.dtype(np.float64): 'd',
    np.dtype(np.float32): 'f',
    np.dtype(np.uint32): 'I',
    np.dtype(np.int32): 'i',
    np.dtype(np.uint16): 'H',
}

_BASE_DEFAULTS: dict[str, Any] = {'string': '', 'bool': False}
_NUMPY_BASES = {
    'bool': np.bool_,
    'byte': np.uint8,
    'char': np.uint8,
    'int8': np.int8,
    'int16': np.int16,
    'int32': np.int32,
    'int64': np.int64,
    'uint8': np.uint8,
    'uint16': np.uint16,
    'uint32': np.uint32,
    'uint64': np.uint64,
    'float32': np.float32,
    'float64': np.float64,
}


class MessageFactory(Protocol):
    """Builds a message of a ROS type from keyword fields; missing fields take ROS defaults."""

    def make(self, msgtype: str, **fields: Any) -> Any:
        """Build a message of type ``msgtype`` (e.g. ``'std_msgs/msg/Header'``)."""
        ...

    def points(self, xyz: np.ndarray) -> list[Any]:
        """geometry_msgs/Point messages of the rows of an (N, 3) array (a mesh's nodes)."""
        ...


class RosbagsMessages:
    """Builds rosbags message objects from a typestore, filling in defaults.

    Each type's class, field names and default builders are looked up once, on its first
    message: the trackers build about a hundred messages per image, so the lookup of the type's
    field descriptors would cost more than the construction.
    """

    def __init__(self, typestore: Typestore) -> None:
        """Use the message classes of ``typestore``."""
        self._typestore = typestore
        self._layouts: dict[str, tuple[type, tuple[tuple[str, Callable[[], Any]], ...]]] = {}

    def make(self, msgtype: str, **fields: Any) -> Any:
        """Build a rosbags message; fields not given take their ROS default values."""
        layout = self._layouts.get(msgtype) or self._layout(msgtype)
        cls, defaults = layout
        for name, default in defaults:
            if name not in fields:
                fields[name] = default()
        return cls(**fields)

    def points(self, xyz: np.ndarray) -> list[Any]:
        """geometry_msgs/Point messages of the rows of an (N, 3) array (a mesh's nodes)."""
        point = self._typestore.types['geometry_msgs/msg/Point']
        return [point(x, y, z) for x, y, z in np.asarray(xyz, dtype=float).tolist()]

    def _layout(self, msgtype: str) -> tuple[type, tuple[tuple[str, Callable[[], Any]], ...]]:
        """The class of ``msgtype`` and a default builder per field, kept for the next message."""
        _, definitions = self._typestore.fielddefs[msgtype]
        layout = (
            self._typestore.types[msgtype],
            tuple((name, self._default(desc)) for name, desc in definitions),
        )
        self._layouts[msgtype] = layout
        return layout

    def _default(self, desc: tuple[Nodetype, Any]) -> Callable[[], Any]:
        """Builder of a field's default value, as rosbags stores it (a new object per call)."""
        kind, detail = desc
        if kind == Nodetype.NAME:
            return partial(self.make, detail)
        if kind == Nodetype.BASE:
            value = _BASE_DEFAULTS.get(detail[0], 0)
            return lambda: value
        element, length = detail
        element_kind, element_detail = element
        if element_kind == Nodetype.BASE and element_detail[0] in _NUMPY_BASES:
            size = length if kind == Nodetype.ARRAY else 0
            return partial(np.zeros, size, dtype=_NUMPY_BASES[element_detail[0]])
        if kind == Nodetype.ARRAY:
            builder = self._default(element)
            return lambda: [builder() for _ in range(length)]
        return list


class RclpyMessages:
    """Builds rclpy message objects, importing their classes on first use."""

    def __init__(self) -> None:
        """Start with no classes imported."""
        self._classes: dict[str, type] = {}

    def make(self, msgtype: str, **fields: Any) -> Any:
        """Build an rclpy message, handing numpy arrays over without per-element copies."""
        return self.message_class(msgtype)(
            **{name: _to_rclpy(value) for name, value in fields.items()}
        )

    def points(self, xyz: np.ndarray) -> list[Any]:
        """geometry_msgs/Point messages of the rows of an (N, 3) array (a mesh's nodes)."""
        point = self.message_class('geometry_msgs/msg/Point')
        return [point(x=x, y=y, z=z) for x, y, z in np.asarray(xyz, dtype=float).tolist()]

    def message_class(self, msgtype: str) -> type:
        """The rclpy class of ``package/msg/Name`` (imported once per factory)."""
        if msgtype not in self._classes:
            package, kind, name = msgtype.split('/')
            self._classes[msgtype] = getattr(importlib.import_module(f'{package}.{kind}'), name)
        return self._classes[msgtype]


def _to_rclpy(value: Any) -> Any:
    """Convert a numpy array into the form rclpy stores without iterating over it."""
    if not isinstance(value, np.ndarray):
        return value
    if value.dtype == np.uint8:
        return value.tobytes()
    typecode = _ARRAY_TYPECODES.get(value.dtype)
    if typecode is None:
        return value.tolist()
    converted = array.array(typecode)
    converted.frombytes(np.ascontiguousarray(value).tobytes())
    return converted
