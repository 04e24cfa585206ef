"""``face-tracking replay NODE[,NODE...] BAG --out OUT``: run nodes' own code over a bag.

Several nodes form a graph as they would over DDS: ``mono_tracker,expression_recognizer`` feeds
the tracker's ``face/action`` and ``face/state`` to the recogniser. ``--echo TOPIC`` prints the
messages produced on a topic as they fire (events in one line each).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
import contextlib
from pathlib import Path
from typing import Any

from face_tracking_ros.errors import BagError, ConfigError
from face_tracking_ros.io.atomic import check_output_path
from face_tracking_ros.io.bags import read_raw
from face_tracking_ros.processing.base import Output
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.processing.registry import PROCESSORS
from face_tracking_ros.replay import ReplayStats, replay_bag
from face_tracking_ros.wording import listed


def register(parser: argparse.ArgumentParser) -> None:
    """Register the ``replay`` subcommand's options."""
    parser.description = (
        "Feed a bag's messages to a node's processor (the code the live node runs), "
        'deterministically and as fast as the CPU allows, and write its outputs to a '
        'rosbag2/MCAP bag. Ctrl-C stops early and leaves a valid output bag.'
    )
    parser.add_argument(
        'nodes',
        type=_node_list,
        metavar='NODE[,NODE...]',
        help=f'node(s) to replay, connected by topic name: {", ".join(sorted(PROCESSORS))}',
    )
    parser.add_argument('bag', type=Path, help='input bag: a rosbag2 directory or one .mcap file')
    add_replay_options(parser)
    parser.add_argument(
        '--echo',
        action='append',
        default=[],
        metavar='TOPIC',
        help='print the messages produced on TOPIC as they fire (e.g. face/expression)',
    )
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
    parser.add_argument(
        '--want',
        action='append',
        default=[],
        metavar='TOPIC',
        help='also produce this on-demand output (e.g. face/overlay), as if subscribed',
    )


def parse_remaps(items: list[str] | None) -> dict[str, str]:
    """``['image=/cam/image_raw']`` -> ``{'image': '/cam/image_raw'}``.

    Raises:
        ConfigError: for an item not of the form INPUT=TOPIC (no ``=``, or an empty side).
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
    """Print a replay's summary (:meth:`~face_tracking_ros.replay.ReplayStats.summary`)."""
    for line in stats.summary(out):
        print(line)


def run(args: argparse.Namespace) -> int:
    """Replay the bag; exit status 1 if it was interrupted or partly unreadable."""
    check_output_path(args.out, '--out', directory=True)
    stats = replay_bag(
        args.nodes,
        args.bag,
        args.out,
        OverrideParameters.parse(args.param),
        parse_remaps(args.remap),
        args.record_inputs,
        progress=not args.quiet,
        on_output=echo(args.echo, first_stamp(args.bag)) if args.echo else None,
        wanted=frozenset(args.want),
    )
    print_stats(stats, args.out)
    produced = ', '.join(topic for topic, count in stats.outputs.items() if count)
    for topic in args.echo:
        if not stats.outputs[topic]:
            print(f'--echo {topic}: nothing was produced on it (outputs: {produced or "none"})')
    return 1 if stats.interrupted or stats.read_error else 0


def _node_list(text: str) -> list[str]:
    """``'a,b'`` -> ``['a', 'b']``, each a node with a processor, named once."""
    nodes = [name.strip() for name in text.split(',') if name.strip()]
    unknown = [name for name in nodes if name not in PROCESSORS]
    if not nodes or unknown:
        given = listed('node', unknown) if unknown else f'node {text!r}'
        msg = f'unknown {given}; choose from {", ".join(sorted(PROCESSORS))}'
        raise argparse.ArgumentTypeError(msg)
    repeated = sorted({name for name in nodes if nodes.count(name) > 1})
    if repeated:
        msg = (
            f'{listed("node", repeated)} named more than once in {text!r}: a node runs once '
            '(its outputs would be written twice to one bag)'
        )
        raise argparse.ArgumentTypeError(msg)
    return nodes


def echo(topics: list[str], start_ns: int) -> Callable[[Output, int], None]:
    """A replay callback printing the outputs on ``topics`` as they fire.

    Each line starts with the time since ``start_ns`` (the bag's first message), in seconds.
    """
    wanted = set(topics)

    def show(output: Output, log_time: int) -> None:
        if output.topic in wanted:
            seconds = (log_time - start_ns) / 1e9
            print(f't={seconds:8.3f} s  {output.topic:18s} {describe(output.msg)}')

    return show


def first_stamp(bag: Path) -> int:
    """Log time of a bag's first message, ns (0 for an empty bag or one damaged before it).

    A damaged bag is not an error here: the replay itself reports the damage.
    """
    with contextlib.suppress(BagError):
        return next((message.stamp_ns for message in read_raw(bag)), 0)
    return 0


def describe(msg: Any) -> str:
    """One line for an event message; the message's repr for anything else."""
    if hasattr(msg, 'label') and hasattr(msg, 'event'):
        kind = 'ONSET ' if msg.event == 0 else 'OFFSET'
        return (
            f'{kind} {msg.label:<10s} confidence {msg.confidence:.2f} '
            f'duration {msg.duration:.2f} s'
        )
    if hasattr(msg, 'identity'):
        return f'{msg.identity:<12s} distance {msg.distance:.2f} confidence {msg.confidence:.2f}'
    return repr(msg)
