"""``face-tracking msgs``: list the face_tracking_msgs types, or print one's definition."""

from __future__ import annotations

import argparse

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io.typestore import custom_type_names, msg_dir, typestore


def register(parser: argparse.ArgumentParser) -> None:
    """Register the ``msgs`` subcommand's options."""
    parser.description = (
        'List the face_tracking_msgs message types registered in the rosbags '
        'typestore (and where their .msg text was found), or print the full definition of one.'
    )
    parser.add_argument(
        'msgtype',
        nargs='?',
        help="type to print, e.g. 'face_tracking_msgs/msg/FaceState' or, for this package's "
        "own, 'FaceState'",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    """List the custom types, or print the definition of ``args.msgtype``.

    Raises:
        ConfigError: If ``args.msgtype`` is not a known type (the custom ones are listed).
    """
    store = typestore()
    if args.msgtype is None:
        print(f'# from {msg_dir()}')
        for name in custom_type_names():
            print(name)
        return
    short = {name.rpartition('/')[2]: name for name in custom_type_names()}
    msgtype = short.get(args.msgtype, args.msgtype)
    if msgtype not in store.fielddefs:
        known = ', '.join(sorted(short))
        raise ConfigError(f'unknown message type {args.msgtype!r} (this package has {known})')
    print(store.generate_msgdef(msgtype)[0])
