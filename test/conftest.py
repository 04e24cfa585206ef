"""Shared fixtures: a DDS environment that stays on this host, and a private rclpy context.

The environment is set with setdefault (so `make test` and `.ci/run` choose the domain) when
conftest is imported, before any rclpy context exists: rclpy reads it in `rclpy.init`. BLAS is
limited to one thread, as in the nodes and the ``face-tracking`` command, so the tests compute
what they run.
"""

from __future__ import annotations

from collections.abc import Iterator
import importlib
import os
from pathlib import Path
import sys

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rosbags.typesys.base import Nodetype
from rosbags.typesys.store import Typestore

from face_tracking_ros.io.typestore import custom_type_names, typestore
from face_tracking_ros.threads import limit_blas_threads

REPO = Path(__file__).resolve().parents[1]

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('ROS_DOMAIN_ID', '42')
os.environ.setdefault(
    'FASTDDS_DEFAULT_PROFILES_FILE', str(REPO / 'config' / 'fastdds_profile.xml')
)
os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
limit_blas_threads()


@pytest.fixture
def ros_context() -> Iterator[Context]:
    """An initialised rclpy context of its own, shut down after the test."""
    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


# --- Message samples: every field filled with a distinct value, built from the typestore's
# --- field definitions so new messages are covered without new test code.

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


@pytest.fixture(scope='session')
def store() -> Typestore:
    """The project typestore."""
    return typestore()
