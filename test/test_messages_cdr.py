"""rclpy and rosbags serialise the same message to the same CDR bytes.

CDR leaves the value of alignment padding unspecified: rosbags writes zeros, rclpy (Fast CDR)
leaves whatever was in its buffer. The comparison therefore computes the padding positions from
the field definitions and compares every other byte, and the total length.

This pins the .msg text registered in the rosbags typestore (face_tracking_ros.io.typestore) to
the types rclpy was built with (msg_defs/), so bags written offline read back in ROS and back.
"""

from __future__ import annotations

import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys.base import Nodetype
from rosbags.typesys.store import Typestore

from face_tracking_ros.cli import main as cli

from message_samples import (
    custom_msgtypes,
    rclpy_class,
    sample_fields,
    to_plain,
    to_rclpy,
    to_rosbags,
)

STANDARD_TYPES = ['sensor_msgs/msg/Image', 'sensor_msgs/msg/CameraInfo']
CDR_HEADER = 4  # encapsulation kind and options; alignment is relative to its end
PRIMITIVE_SIZES = {
    'bool': 1,
    'byte': 1,
    'char': 1,
    'int8': 1,
    'uint8': 1,
    'int16': 2,
    'uint16': 2,
    'int32': 4,
    'uint32': 4,
    'int64': 8,
    'uint64': 8,
    'float32': 4,
    'float64': 8,
}


class PaddingWalker:
    """Walk a message as CDR lays it out, recording the byte positions of alignment padding."""

    def __init__(self, store: Typestore) -> None:
        """Start at the first byte after the encapsulation header."""
        self.store = store
        self.offset = 0
        self.padding: set[int] = set()

    def align(self, size: int) -> None:
        """Skip to the next multiple of ``size``, recording the skipped bytes."""
        skip = -self.offset % size
        self.padding.update(range(CDR_HEADER + self.offset, CDR_HEADER + self.offset + skip))
        self.offset += skip

    def message(self, msgtype: str, fields: dict) -> None:
        """Walk every field of a message."""
        for name, node in self.store.fielddefs[msgtype][1]:
            self.node(node, fields[name])

    def node(self, node: tuple, value: object) -> None:
        """Walk one field."""
        kind, spec = node
        if kind == Nodetype.BASE:
            self.primitive(spec[0], value)
        elif kind == Nodetype.NAME:
            self.message(spec, value)
        else:
            if kind == Nodetype.SEQUENCE:
                self.primitive('uint32', len(value))
            for item in value:
                self.node(spec[0], item)

    def primitive(self, typename: str, value: object) -> None:
        """Walk a primitive; a string is a uint32 length, the bytes and a NUL."""
        if typename == 'string':
            self.primitive('uint32', 0)
            self.offset += len(str(value).encode()) + 1
        else:
            self.align(PRIMITIVE_SIZES[typename])
            self.offset += PRIMITIVE_SIZES[typename]


def padding_positions(store: Typestore, msgtype: str, fields: dict) -> set[int]:
    """Byte positions (in the serialised message) that are alignment padding."""
    walker = PaddingWalker(store)
    walker.message(msgtype, fields)
    return walker.padding


@pytest.mark.parametrize('msgtype', custom_msgtypes() + STANDARD_TYPES)
def test_rclpy_and_rosbags_give_identical_cdr(store: Typestore, msgtype: str) -> None:
    fields = sample_fields(store, msgtype, seed=11)

    from_rclpy = serialize_message(to_rclpy(store, msgtype, fields))
    from_rosbags = store.serialize_cdr(to_rosbags(store, msgtype, fields), msgtype)

    padding = padding_positions(store, msgtype, fields)
    assert len(from_rosbags) == len(from_rclpy)
    differing = [
        i for i, (a, b) in enumerate(zip(from_rosbags, from_rclpy, strict=True)) if a != b
    ]
    assert [i for i in differing if i not in padding] == []


def test_padding_walker_finds_string_padding(store: Typestore) -> None:
    fields = {'stamp': {'sec': 1, 'nanosec': 2}, 'frame_id': 'ab'}  # 4 + 4 + 4 + 3 bytes

    assert padding_positions(store, 'std_msgs/msg/Header', fields) == set()
    fields = {'header': fields, 'face_id': 'f', 'sigma': [1.0], 'covariance': []}
    # Positions count the 4-byte encapsulation header; alignment is relative to its end. The
    # header ends at 19; face_id's length at 20..23 (pad 19), 'f' and NUL at 24..25; sigma's
    # count at 28..31 (pad 26, 27); its float64 at 36..43, aligned to 8 after 4 (pad 32..35);
    # covariance's count at 44..47.
    expected = {19, 26, 27, 32, 33, 34, 35}
    assert padding_positions(store, 'face_tracking_msgs/msg/ShapeParams', fields) == expected


@pytest.mark.parametrize('msgtype', custom_msgtypes())
def test_rosbags_cdr_deserialises_in_rclpy(store: Typestore, msgtype: str) -> None:
    fields = sample_fields(store, msgtype, seed=13)
    data = store.serialize_cdr(to_rosbags(store, msgtype, fields), msgtype)

    message = deserialize_message(bytes(data), rclpy_class(msgtype))

    assert to_plain(store, msgtype, message) == fields


def test_every_custom_msg_is_in_the_typestore(store: Typestore) -> None:
    names = custom_msgtypes()

    assert 'face_tracking_msgs/msg/FaceState' in names
    assert all(name in store.fielddefs for name in names)


def test_msgs_prints_a_definition_by_full_or_short_name(capsys) -> None:
    """The README's message table names the types short: 'msgs FaceState' was unknown."""
    assert cli.main(['msgs', 'FaceState']) == 0
    short = capsys.readouterr().out
    assert cli.main(['msgs', 'face_tracking_msgs/msg/FaceState']) == 0
    assert capsys.readouterr().out == short and 'float64[] sigma' in short
    assert cli.main(['msgs', 'FaceStat']) == cli.EXIT_ERROR
    assert "unknown message type 'FaceStat' (this package has ActionParams" in (
        capsys.readouterr().err
    )
