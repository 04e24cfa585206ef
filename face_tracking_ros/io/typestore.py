"""A rosbags typestore that knows the standard ROS 2 Kilted types and face_tracking_msgs.

The custom types are parsed from the same ``.msg`` text that ``msg_defs/`` builds for rclpy, so a
bag written here deserialises in ROS 2 and vice versa. The text is found, in this order:

1. in the installed interface package, ``<prefix>/share/face_tracking_msgs/msg`` (through the
   ament index, i.e. ``AMENT_PREFIX_PATH``): the definitions rclpy runs with;
2. in the source tree next to this package, ``msg_defs/msg`` (editable installs without a built
   face_tracking_msgs).

Example:
    >>> from face_tracking_ros.io.typestore import typestore
    >>> FaceState = typestore().types['face_tracking_msgs/msg/FaceState']
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from face_tracking_ros.errors import ConfigError

MSG_PACKAGE = 'face_tracking_msgs'
SOURCE_MSG_DIR = Path(__file__).resolve().parents[2] / 'msg_defs' / 'msg'


def _installed_msg_dir() -> Path | None:
    """Return ``share/face_tracking_msgs/msg`` of the installed package, or None if not found."""
    try:
        from ament_index_python.packages import get_package_share_directory
    except ImportError:
        return None
    try:
        share = Path(get_package_share_directory(MSG_PACKAGE))
    except (LookupError, OSError):  # package not installed, or AMENT_PREFIX_PATH unset
        return None
    msg_dir = share / 'msg'
    return msg_dir if msg_dir.is_dir() else None


def msg_dir() -> Path:
    """Locate the directory holding the face_tracking_msgs ``.msg`` files.

    Returns:
        The installed ``share/face_tracking_msgs/msg`` if the ament index knows it, else the source
        tree's ``msg_defs/msg``.

    Raises:
        ConfigError: If neither exists.
    """
    found = _installed_msg_dir()
    if found is not None:
        return found
    if SOURCE_MSG_DIR.is_dir():
        return SOURCE_MSG_DIR
    raise ConfigError(
        f'cannot find the {MSG_PACKAGE} .msg files: neither installed (ament index, '
        f'AMENT_PREFIX_PATH) nor in the source tree at {SOURCE_MSG_DIR}'
    )


def custom_type_names(directory: Path | None = None) -> list[str]:
    """List the face_tracking_msgs message types, e.g. ``'face_tracking_msgs/msg/FaceState'``.

    Args:
        directory: Directory of ``.msg`` files; default :func:`msg_dir`.

    Returns:
        Sorted type names.
    """
    directory = msg_dir() if directory is None else directory
    return sorted(f'{MSG_PACKAGE}/msg/{path.stem}' for path in directory.glob('*.msg'))


@cache
def typestore() -> Typestore:
    """Build (once per process) the typestore: ROS 2 Kilted standard types plus face_tracking_msgs.

    Returns:
        A rosbags :class:`~rosbags.typesys.store.Typestore`; treat it as read-only.

    Raises:
        ConfigError: If the ``.msg`` files cannot be found.
    """
    store = get_typestore(Stores.ROS2_KILTED)
    directory = msg_dir()
    types = {}
    for name in custom_type_names(directory):
        text = (directory / f'{name.rsplit("/", 1)[1]}.msg').read_text()
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store
