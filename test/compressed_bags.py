"""Copies of bags with their images as image_transport's compressed plugin records them."""

from __future__ import annotations

from collections.abc import Collection, Mapping
from pathlib import Path

import cv2

from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import BagWriter, read_messages
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.typestore import typestore

IMAGE_TYPE = 'sensor_msgs/msg/Image'
COMPRESSED_TYPE = 'sensor_msgs/msg/CompressedImage'


def compressed_copy(
    bag: Path,
    out: Path,
    names: Mapping[str, str] | None = None,
    only: Collection[str] | None = None,
) -> Path:
    """``bag`` with its images as lossless PNG CompressedImage messages.

    Args:
        bag: a bag of grey or colour Image topics and others.
        out: the new bag's directory.
        names: bag topic -> topic in the copy; an image topic not named goes to
            ``<topic>/compressed``, any other keeps its name.
        only: the image topics to compress (the others stay Image); None: every one.
    """
    names = names or {}
    factory = RosbagsMessages(typestore())
    with BagWriter(out) as writer:
        for message in read_messages(bag):
            topic, msgtype, msg = message.topic, message.msgtype, message.msg
            if msgtype == IMAGE_TYPE and (only is None or topic in only):
                png = cv2.imencode('.png', conversions.image_to_gray(msg))[1].reshape(-1)
                topic, msgtype = f'{topic}/compressed', COMPRESSED_TYPE
                msg = factory.make(msgtype, header=msg.header, format='mono8; png', data=png)
            writer.write(names.get(message.topic, topic), msgtype, msg, message.stamp_ns)
    return out
