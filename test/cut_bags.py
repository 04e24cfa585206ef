"""Copies of bags cut off part way (a recording or a track killed, a full disk); their parts."""

from __future__ import annotations

from pathlib import Path
import shutil

from face_tracking_ros.errors import BagError
from face_tracking_ros.io.bags import BagWriter, RawMessage, read_raw


def cut_copy(bag: Path, target: Path, fraction: float, keep_metadata: bool = True) -> Path:
    """A copy of ``bag`` whose MCAP file is cut after ``fraction`` of its bytes.

    Without ``keep_metadata``, the copy has no ``metadata.yaml``, as a bag whose writer was
    killed (rosbags writes it at the close).
    """
    shutil.copytree(bag, target)
    if not keep_metadata:
        (target / 'metadata.yaml').unlink()
    mcap_file = next(target.glob('*.mcap'))
    data = mcap_file.read_bytes()
    mcap_file.write_bytes(data[: round(fraction * len(data))])
    return target


def read_until_damage(path: Path) -> tuple[list[RawMessage], str]:
    """Raw messages read before the reader stopped, and its error ('' if it did not)."""
    messages: list[RawMessage] = []
    try:
        messages.extend(read_raw(path))
    except BagError as error:
        return messages, str(error)
    return messages, ''


def readable_copy(bag: Path, target: Path) -> Path:
    """A complete bag (summary, metadata.yaml) of the messages ``bag`` gives before its damage."""
    with BagWriter(target) as writer:
        for message in read_until_damage(bag)[0]:
            writer.write_raw(message.topic, message.msgtype, message.data, message.stamp_ns)
    return target
