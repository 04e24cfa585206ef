"""``face-tracking replay NODE BAG --out OUT``: run a node's own code over a bag, without DDS."""

from __future__ import annotations

import argparse
from pathlib import Path

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.processing.registry import PROCESSORS
from face_tracking_ros.replay import ReplayStats, replay_bag


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``replay`` subcommand."""
    parser = subparsers.add_parser(
        'replay',
        help="run a node's message processing over a bag into an output bag",
        description="Feed a bag's messages to a node's processor (the code the live node runs), "
        'deterministically and as fast as the CPU allows, and write its outputs to a '
        'rosbag2/MCAP bag. Ctrl-C stops early and leaves a valid output bag.',
    )
    parser.add_argument('node', choices=sorted(PROCESSORS), help='node to replay')
    parser.add_argument('bag', type=Path, help='input rosbag2 directory')
    add_replay_options(parser)
    parser.set_defaults(func=run)


def add_replay_options(parser: argparse.ArgumentParser) -> None:
    """Options shared by ``replay`` and ``track``: output, parameters, remapping, inputs."""
    parser.add_argument('--out', type=Path, required=True, help='output bag directory (new)')
    parser.add_argument(
        '--param',
        action='append',
        metavar='NAME=VALUE',
        help="a node parameter, as the node declares it (e.g. 'tracker.epsilon=0.2'); repeatable",
    )
    parser.add_argument(
        '--remap',
        action='append',
        metavar='INPUT=TOPIC',
        help="read the node's input INPUT from bag topic TOPIC (default: matched by name/type)",
    )
    parser.add_argument(
        '--record-inputs', action='store_true', help='also copy the input messages to the output'
    )
    parser.add_argument('--quiet', action='store_true', help='no progress bar')


def parse_remaps(items: list[str] | None) -> dict[str, str]:
    """``['image=/cam/image_raw']`` -> ``{'image': '/cam/image_raw'}``.

    Raises:
        ConfigError: for an item without ``=``.
    """
    remaps = {}
    for item in items or []:
        port, sep, topic = item.partition('=')
        if not sep or not port or not topic:
            msg = f'remap {item!r} must be written INPUT=TOPIC'
            raise ConfigError(msg)
        remaps[port] = topic
    return remaps


def print_stats(stats: ReplayStats, out: Path) -> None:
    """Summarise a replay on stdout."""
    inputs = ', '.join(f'{n} {t}' for t, n in sorted(stats.inputs.items())) or 'none'
    outputs = ', '.join(f'{n} {t}' for t, n in sorted(stats.outputs.items())) or 'none'
    print(f'read: {inputs}')
    print(f'wrote to {out}: {outputs}')
    for text, count in stats.errors.most_common():
        print(f'rejected {count}x: {text}')
    if stats.read_error:
        print(
            f'input bag unreadable past this point, replayed the readable part: {stats.read_error}'
        )
    if stats.interrupted:
        print('interrupted: the output bag holds what was processed so far')


def run(args: argparse.Namespace) -> int:
    """Replay the bag; exit status 1 if it was interrupted or partly unreadable."""
    stats = replay_bag(
        args.node,
        args.bag,
        args.out,
        OverrideParameters.parse(args.param),
        parse_remaps(args.remap),
        args.record_inputs,
        progress=not args.quiet,
    )
    print_stats(stats, args.out)
    return 1 if stats.interrupted or stats.read_error else 0
