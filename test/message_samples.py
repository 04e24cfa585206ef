"""Message samples for the message tests: every field filled with a distinct value.

Built from the typestore's field definitions, so that new messages are covered without new test
code, and read back into plain values from any message object (rclpy, rosbags, mcap_ros2). A
module of its own, not conftest.py: test files import it by a name no other directory's
conftest.py shares, so any order of test files works.
"""

from __future__ import annotations

import importlib

import numpy as np
from rosbags.typesys.base import Nodetype
from rosbags.typesys.store import Typestore

from face_tracking_ros.io.typestore import custom_type_names

FLOAT_TYPES = {'float32', 'float64'}
NUMPY_DTYPES = {
    'bool': 'bool',
    'byte': 'uint8',
    'char': 'uint8',
    'int8': 'int8',
    'uint8': 'uint8',
    'int16': 'int16',
    'uint16': 'uint16',
    'int32': 'int32',
    'uint32': 'uint32',
    'int64': 'int64',
    'uint64': 'uint64',
    'float32': 'float32',
    'float64': 'float64',
}
SEQUENCE_LENGTH = 3


def custom_msgtypes() -> list[str]:
    """The face_tracking_msgs message types (from the .msg files the typestore reads)."""
    return custom_type_names()


def sample_base(typename: str, seed: int) -> object:
    """A value of a primitive ROS type, distinct per seed and exact in float32."""
    if typename == 'string':
        return f'value_{seed}'
    if typename == 'bool':
        return seed % 2 == 1
    if typename in FLOAT_TYPES:
        return seed + 0.25
    return seed % 100 + 1


def sample_fields(store: Typestore, msgtype: str, seed: int = 1) -> dict[str, object]:
    """Plain nested values for every field of ``msgtype`` (dicts, lists, str, int, float)."""
    _, fields = store.fielddefs[msgtype]
    return {
        name: sample_node(store, node, seed + 10 * index)
        for index, (name, node) in enumerate(fields)
    }


def sample_node(store: Typestore, node: tuple, seed: int) -> object:
    """A plain value for one field definition node of the typestore."""
    kind, spec = node
    if kind == Nodetype.BASE:
        return sample_base(spec[0], seed)
    if kind == Nodetype.NAME:
        return sample_fields(store, spec, seed)
    element, length = spec
    count = length if kind == Nodetype.ARRAY else SEQUENCE_LENGTH
    return [sample_node(store, element, seed + i) for i in range(count)]


def is_primitive_array(node: tuple) -> bool:
    """Whether a field is an array or sequence of a non-string primitive (numpy in rosbags)."""
    kind, spec = node
    if kind not in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        return False
    element_kind, element_spec = spec[0]
    return element_kind == Nodetype.BASE and element_spec[0] != 'string'


def to_rosbags(store: Typestore, msgtype: str, fields: dict[str, object]) -> object:
    """Build a rosbags message from plain values."""
    values = {}
    for name, node in store.fielddefs[msgtype][1]:
        kind, spec = node
        value = fields[name]
        if kind == Nodetype.NAME:
            value = to_rosbags(store, spec, value)
        elif is_primitive_array(node):
            value = np.array(value, dtype=NUMPY_DTYPES[spec[0][1][0]])
        elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE) and spec[0][0] == Nodetype.NAME:
            value = [to_rosbags(store, spec[0][1], item) for item in value]
        values[name] = value
    return store.types[msgtype](**values)


def rclpy_class(typename: str) -> type:
    """The rclpy class of a type name such as ``'sensor_msgs/msg/Image'`` or ``'.../srv/...'``."""
    package, kind, name = typename.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


def to_rclpy(store: Typestore, msgtype: str, fields: dict[str, object]) -> object:
    """Build an rclpy message from plain values."""
    message = rclpy_class(msgtype)()
    for name, (kind, spec) in store.fielddefs[msgtype][1]:
        value = fields[name]
        if kind == Nodetype.NAME:
            value = to_rclpy(store, spec, value)
        elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE) and spec[0][0] == Nodetype.NAME:
            value = [to_rclpy(store, spec[0][1], item) for item in value]
        setattr(message, name, value)
    return message


def to_plain(store: Typestore, msgtype: str, message: object) -> dict[str, object]:
    """Read any message object (rclpy, rosbags, mcap_ros2) back into plain values."""
    plain = {}
    for name, (kind, spec) in store.fielddefs[msgtype][1]:
        value = getattr(message, name)
        if kind == Nodetype.NAME:
            value = to_plain(store, spec, value)
        elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            element_kind, element_spec = spec[0]
            if element_kind == Nodetype.NAME:
                value = [to_plain(store, element_spec, item) for item in value]
            else:
                value = [plain_base(item) for item in value]
        else:
            value = plain_base(value)
        plain[name] = value
    return plain


def plain_base(value: object) -> object:
    """A primitive as a Python bool, int, float or str (numpy scalars included)."""
    return value.item() if hasattr(value, 'item') else value
