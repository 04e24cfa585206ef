"""Helpers of the bag_player and bag_recorder tests: node processes, spinning, bag contents."""

from __future__ import annotations

from collections.abc import Callable, Iterable
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rosbags.typesys.store import Typestore

from face_tracking_ros.io.bags import BagWriter, read_messages
from face_tracking_ros.io.typestore import typestore

from message_samples import sample_fields, to_plain, to_rosbags
from repo_root import REPO

TIMEOUT_S = 20.0
T0 = 1_700_000_000_000_000_000


def start_node(
    module: str, remaps: tuple[str, ...] = (), **parameters: object
) -> subprocess.Popen:
    """Start ``python -m face_tracking_ros.nodes.<module> --ros-args -r R ... -p name:=value``."""
    command = [sys.executable, '-m', f'face_tracking_ros.nodes.{module}', '--ros-args']
    for remap in remaps:
        command += ['-r', remap]
    for name, value in parameters.items():
        command += ['-p', f'{name}:={_ros_arg(value)}']
    return subprocess.Popen(
        command,
        cwd=REPO,
        env=os.environ.copy(),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def _ros_arg(value: object) -> str:
    """A parameter value as ``--ros-args -p`` parses it (YAML)."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list | tuple):
        return '[' + ', '.join(f"'{item}'" for item in value) + ']'
    return str(value)


def finish(process: subprocess.Popen, stop: signal.Signals | None = None) -> tuple[int, str]:
    """Send ``stop`` (if given), wait for the process and return (exit code, output)."""
    if stop is not None:
        process.send_signal(stop)
    try:
        output, _ = process.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        process.kill()
        output, _ = process.communicate()
        raise AssertionError(
            f'{process.args} did not end within {TIMEOUT_S} s:\n{output}'
        ) from None
    return process.returncode, output


def spin_until(node: Node, done: Callable[[], bool], timeout_s: float = TIMEOUT_S) -> None:
    """Spin ``node`` until ``done()``; fail after ``timeout_s``."""
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    deadline = time.monotonic() + timeout_s
    try:
        while not done():
            assert time.monotonic() < deadline, f'not done within {timeout_s} s'
            executor.spin_once(timeout_sec=0.02)
    finally:
        executor.shutdown()


def write_bag(path: Path, records: Iterable[tuple[str, str, int, int]]) -> None:
    """Write a bag of sample messages: (topic, msgtype, seed of the fields, ms from T0)."""
    store = typestore()
    with BagWriter(path) as bag:
        for topic, msgtype, seed, offset_ms in records:
            message = to_rosbags(store, msgtype, sample_fields(store, msgtype, seed))
            bag.write(topic, msgtype, message, T0 + offset_ms * 1_000_000)


def plain_by_topic(store: Typestore, path: Path) -> dict[str, list[dict]]:
    """The fields of every message of a bag, per topic name without a leading '/'."""
    messages: dict[str, list[dict]] = {}
    for message in read_messages(path):
        fields = to_plain(store, message.msgtype, message.msg)
        messages.setdefault(message.topic.lstrip('/'), []).append(fields)
    return messages
