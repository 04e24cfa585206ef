"""Offline replay: run a node's processor over a bag, without DDS, as fast as the CPU allows.

The processor is the same object the live node runs (:mod:`face_tracking_ros.processing`), so a
replay exercises the code that runs on the robot. Messages are fed in the bag's log-time order;
every output is written to an MCAP bag with the log time of the input that produced it, so the
output is deterministic. Ctrl-C stops the loop and still closes the output bag, which stays
readable; bad input messages are counted and reported, not fatal.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from face_tracking_ros.errors import BagError, FaceTrackingError
from face_tracking_ros.processing.base import Port, Processor

Record = tuple[str, str, int, Any]  # (bag topic, msgtype, log time ns, message)


@dataclass
class ReplayStats:
    """What a replay did.

    Attributes:
        inputs: input messages fed to the processor, per port topic.
        outputs: output messages written, per topic.
        errors: bad input messages, per error text (first 200 characters).
        interrupted: True if Ctrl-C stopped the replay early.
    """

    inputs: Counter[str] = field(default_factory=Counter)
    outputs: Counter[str] = field(default_factory=Counter)
    errors: Counter[str] = field(default_factory=Counter)
    interrupted: bool = False


def resolve_inputs(
    ports: Iterable[Port], bag_topics: Mapping[str, str], overrides: Mapping[str, str]
) -> dict[str, str]:
    """Map bag topics to a processor's input ports.

    A port is matched by an override (port topic -> bag topic), else by the bag topic that ends
    with the port's name, else by the only bag topic of the port's message type. Ports with no
    match are left out (e.g. an optional ``face/model``).

    Args:
        ports: the processor's input ports.
        bag_topics: bag topic -> message type.
        overrides: port topic -> bag topic, from the command line.

    Returns:
        bag topic -> port topic.

    Raises:
        BagError: if an override names a topic the bag lacks or of the wrong type.
    """
    mapping: dict[str, str] = {}
    for port in ports:
        bag_topic = overrides.get(port.topic) or _match(port, bag_topics)
        if bag_topic is None:
            continue
        if bag_topics.get(bag_topic) != port.msgtype:
            found = bag_topics.get(bag_topic, 'no such topic')
            msg = f'topic {bag_topic!r} for input {port.topic!r} must be {port.msgtype}: {found}'
            raise BagError(msg)
        mapping[bag_topic] = port.topic
    return mapping


def _match(port: Port, bag_topics: Mapping[str, str]) -> str | None:
    """The bag topic that ends with the port name, else the only one of the port's type."""
    of_type = [topic for topic, msgtype in bag_topics.items() if msgtype == port.msgtype]
    by_name = [topic for topic in of_type if topic.strip('/').endswith(port.topic)]
    if len(by_name) == 1:
        return by_name[0]
    return of_type[0] if len(of_type) == 1 else None


def replay(
    processor: Processor,
    records: Iterable[Record],
    write: Callable[[str, str, Any, int], None],
    topic_map: Mapping[str, str],
    record_inputs: bool = False,
    on_step: Callable[[], None] | None = None,
) -> ReplayStats:
    """Feed bag records to a processor and write its outputs.

    Args:
        processor: the node's processor.
        records: (bag topic, msgtype, log time ns, message), in log-time order.
        write: ``write(topic, msgtype, msg, log_time_ns)`` into the output bag (BagWriter.write).
        topic_map: bag topic -> processor input topic (see :func:`resolve_inputs`).
        record_inputs: also write the input messages, under their bag topics.
        on_step: called after each input message (progress bars).

    Returns:
        The counts of what was read, written and rejected.
    """
    output_types = {port.topic: port.msgtype for port in processor.outputs}
    wanted = frozenset(port.topic for port in processor.outputs if port.on_demand)
    stats = ReplayStats()
    try:
        for bag_topic, msgtype, log_time, msg in records:
            port_topic = topic_map.get(bag_topic)
            if port_topic is None:
                continue
            if record_inputs:
                write(bag_topic, msgtype, msg, log_time)
            stats.inputs[port_topic] += 1
            try:
                outputs = processor.handle(port_topic, msg, wanted)
            except FaceTrackingError as error:
                stats.errors[f'{port_topic}: {error}'[:200]] += 1
                outputs = []
            for output in outputs:
                write(output.topic, output_types[output.topic], output.msg, log_time)
                stats.outputs[output.topic] += 1
            if on_step is not None:
                on_step()
    except KeyboardInterrupt:
        stats.interrupted = True
    return stats
