"""Offline replay: run a node's processor over a bag, without DDS, as fast as the CPU allows.

The processor is the same object the live node runs (:mod:`face_tracking_ros.processing`), so a
replay exercises the code that runs on the robot. Messages are fed in the bag's log-time order;
every output is written to an MCAP bag with the log time of the input that produced it, so the
output is deterministic. A processor's deferred work
(:class:`~face_tracking_ros.processing.base.Deferring`, e.g. the mono tracker's bundle
adjustment stages) runs once its outputs for the message are written, as the node runs it once
they are published. At the end of the bag, processors that hold outputs back for it
(:class:`~face_tracking_ros.processing.base.Finishing`, e.g. the stereo tracker's
``retroactive_depths``) emit them, written with the last input's log time. Ctrl-C (and SIGTERM
where it acts as one) stops the loop once the input it came in has all its outputs written (a
second one at once); the outputs held back until then are still emitted and the output bag is
closed, so it stays readable and nothing already tracked is lost; bad input messages are
counted and reported, not fatal.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Callable, Collection, Iterable, Iterator, Mapping, Sequence
import contextlib
from dataclasses import dataclass, field, replace
from pathlib import Path
import signal
import threading
from types import FrameType
from typing import Any, TypeVar

from face_tracking_ros.data import default_model_path
from face_tracking_ros.errors import BagError, ConfigError, FaceTrackingError, problem_kind
from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import BagWriter, bag_topics, message_count, read_messages
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.provenance import KEY as PROVENANCE_KEY
from face_tracking_ros.io.provenance import MODEL_PARAMETER, MONO, STEREO, Provenance, tracked_with
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.processing.base import (
    Deferring,
    Finishing,
    Output,
    Port,
    Processor,
    Reporting,
    Warns,
)
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.processing.registry import processor_factory
from face_tracking_ros.wording import counted

_IMAGE_TYPES = (conversions.IMAGE_TYPE, conversions.COMPRESSED_IMAGE_TYPE)
_CAMERA_INFO_TYPES = (conversions.CAMERA_INFO_TYPE,)
SUMMARY_PROBLEMS = 10  # kinds of problem a summary lists, the most frequent first
Record = tuple[str, str, int, Any]  # (bag topic, msgtype, log time ns, message)
ResultT = TypeVar('ResultT')


@dataclass
class ReplayStats:
    """What a replay did.

    Attributes:
        inputs: input messages fed to the processor, per port topic.
        outputs: output messages written, per topic.
        errors: bad input messages, per kind of problem
            (:func:`~face_tracking_ros.errors.problem_kind`: messages alike but for their
            numbers), under the first message of the kind (first 200 characters).
        interrupted: True if Ctrl-C stopped the replay early.
        read_error: why part of the input bag was unreadable ('' if none was).
        status: what each reporting processor reported at the end, per node name
            (:class:`~face_tracking_ros.processing.base.Reporting`; filled by :func:`replay_bag`).
        warnings: what each processor that can warn warned of at the end, per node name, as the
            live node's status would (:class:`~face_tracking_ros.processing.base.Warns`, e.g. a
            tracker that tracked none of the last images; filled by :func:`replay_bag`).
        read_topics: the bag topics read, each to the input it fed (bag topic -> input; filled
            by :func:`replay_bag`).
    """

    inputs: Counter[str] = field(default_factory=Counter)
    outputs: Counter[str] = field(default_factory=Counter)
    errors: Counter[str] = field(default_factory=Counter)
    interrupted: bool = False
    read_error: str = ''
    status: dict[str, dict[str, str]] = field(default_factory=dict)
    warnings: dict[str, str] = field(default_factory=dict)
    read_topics: dict[str, str] = field(default_factory=dict)
    _first_of_kind: dict[str, str] = field(default_factory=dict, init=False, repr=False)

    def count_error(self, text: str) -> None:
        """Count a bad input message under the first message of its kind."""
        first = self._first_of_kind.setdefault(problem_kind(text), text[:200])
        self.errors[first] += 1

    def summary(self, out: Path) -> list[str]:
        """The replay summarised in lines of text, ``out`` being the output bag it wrote.

        Of the input problems, the :data:`SUMMARY_PROBLEMS` most frequent kinds, then how many
        others.
        """
        inputs = ', '.join(f'{n} {t}' for t, n in sorted(self.inputs.items())) or 'none'
        outputs = ', '.join(f'{n} {t}' for t, n in sorted(self.outputs.items())) or 'none'
        lines = [f'read: {inputs}', f'wrote to {out}: {outputs}']
        if self.errors:
            lines.append(
                'input problems, each kind as its first message (the live node reports these on'
                ' /diagnostics):'
            )
        problems = self.errors.most_common()
        lines += [f'  {count}x {text}' for text, count in problems[:SUMMARY_PROBLEMS]]
        if len(problems) > SUMMARY_PROBLEMS:
            rest = problems[SUMMARY_PROBLEMS:]
            messages = sum(count for _, count in rest)
            kinds = counted(len(rest), 'other kind of problem', 'other kinds of problem')
            lines.append(f'  ... {kinds} ({counted(messages, "message")})')
        if self.read_error:
            lines.append(f'input bag damaged, replayed its readable part: {self.read_error}')
        lines += [
            f'{node}: ' + ', '.join(f'{key} {value}' for key, value in status.items())
            for node, status in self.status.items()
        ]
        lines += [f'{node}: warning: {warning}' for node, warning in self.warnings.items()]
        if self.interrupted:
            lines.append('interrupted: the output bag holds what was processed so far')
        return lines


def resolve_inputs(
    ports: Iterable[Port], bag_topics: Mapping[str, str], overrides: Mapping[str, str]
) -> dict[str, str]:
    """Map bag topics to a processor's input ports.

    A port is matched by an override (port topic -> bag topic, with or without the leading
    '/' the bag's name has), else by the bag topic that ends with the port's name, else by the
    only bag topic of the port's message type if no other port took it (by override, name or
    type: a bag with only ``left/camera_info`` feeds the left port, not the right one too).
    Ports with no match are left out (e.g. an optional ``face/model``).

    Args:
        ports: the processor's input ports.
        bag_topics: bag topic -> message type.
        overrides: port topic -> bag topic, from the command line.

    Returns:
        bag topic -> port topic.

    Raises:
        BagError: if an override names a topic the bag lacks or of the wrong type.
        ConfigError: if an override gives a port the topic of another (e.g. the left image's
            to the right one).
    """
    ports = list(ports)
    named = {port.topic: _named(port, bag_topics) for port in ports}
    given = {
        port.topic: bag_spelling(overrides[port.topic], bag_topics)
        for port in ports
        if overrides.get(port.topic)
    }
    taken = {*named.values(), *given.values()}
    mapping: dict[str, str] = {}
    for port in ports:
        bag_topic = (
            given.get(port.topic)
            or named[port.topic]
            or _only_of_type(port, bag_topics, taken | mapping.keys())
        )
        if bag_topic is None:
            continue
        if bag_topics.get(bag_topic) != port.msgtype:
            found = (
                bag_topics.get(bag_topic) or f'no such topic (the bag has {", ".join(bag_topics)})'
            )
            msg = f'topic {bag_topic!r} for input {port.topic!r} must be {port.msgtype}: {found}'
            raise BagError(msg)
        if bag_topic in mapping:
            msg = (
                f'topic {bag_topic!r} would feed both inputs {mapping[bag_topic]!r} and '
                f'{port.topic!r}: give each its own topic'
            )
            raise ConfigError(msg)
        mapping[bag_topic] = port.topic
    return mapping


def _check_remaps(remaps: Mapping[str, str], nodes: Sequence[str], inputs: list[Port]) -> None:
    """Refuse a remap whose input is not one the nodes read from the bag (it would be ignored).

    Raises:
        ConfigError: naming the remap and the nodes' inputs.
    """
    names = sorted({port.topic for port in inputs})
    unknown = next((name for name in remaps if name not in names), None)
    if unknown is not None:
        whose = 'its' if len(nodes) == 1 else 'their'
        msg = (
            f'remap {unknown}={remaps[unknown]}: {unknown!r} is not an input of '
            f'{", ".join(nodes)}; {whose} inputs from the bag are {", ".join(names)}'
        )
        raise ConfigError(msg)


def bag_spelling(topic: str, bag_topics: Mapping[str, str]) -> str:
    """``topic`` as the bag spells it, with or without a leading '/' (else as given)."""
    other = topic[1:] if topic.startswith('/') else f'/{topic}'
    return other if topic not in bag_topics and other in bag_topics else topic


def _named(port: Port, bag_topics: Mapping[str, str]) -> str | None:
    """The one bag topic of the port's type whose name ends with the port's, if any."""
    by_name = [
        topic
        for topic, msgtype in bag_topics.items()
        if msgtype == port.msgtype and topic.strip('/').endswith(port.topic)
    ]
    return by_name[0] if len(by_name) == 1 else None


def _only_of_type(
    port: Port, bag_topics: Mapping[str, str], taken: Collection[str | None]
) -> str | None:
    """The bag's only topic of the port's type, unless another port has it."""
    of_type = [topic for topic, msgtype in bag_topics.items() if msgtype == port.msgtype]
    return of_type[0] if len(of_type) == 1 and of_type[0] not in taken else None


def replay(
    processors: Sequence[Processor],
    records: Iterable[Record],
    write: Callable[[str, str, Any, int], None],
    topic_map: Mapping[str, str],
    record_inputs: bool = False,
    on_step: Callable[[], None] | None = None,
    on_output: Callable[[Output, int], None] | None = None,
    wanted: frozenset[str] = frozenset(),
) -> ReplayStats:
    """Feed bag records to processors, route outputs between them, and write every output.

    Several processors form a graph as the nodes would over DDS: an output on topic T is also
    delivered, at once and in order, to every other processor with an input port T (e.g. a
    tracker's ``face/action`` and ``face/state`` to the expression recogniser). After the last
    record, each :class:`~face_tracking_ros.processing.base.Finishing` processor, in order, gives
    the outputs it held back; they are written with the last record's log time and routed on
    the same way.

    Args:
        processors: the nodes' processors.
        records: (bag topic, msgtype, log time ns, message), in log-time order.
        write: ``write(topic, msgtype, msg, log_time_ns)`` into the output bag (BagWriter.write).
        topic_map: bag topic -> processor input topic (see :func:`resolve_inputs`).
        record_inputs: also write the input messages, under their bag topics.
        on_step: called after each input message (progress bars).
        on_output: called with every output and its log time as it is produced.
        wanted: on-demand outputs to produce (e.g. 'face/overlay'), as if subscribed.

    Returns:
        The counts of what was read, written and rejected.
    """
    stats = ReplayStats()
    graph = _Graph(processors, write, wanted, stats, on_output)
    iterator = iter(records)
    log_time = 0
    stop = _StopRequest()
    try:
        with stop.held():
            while not stop.requested and (record := _next_readable(iterator, stats)) is not None:
                bag_topic, msgtype, log_time, msg = record
                port_topic = topic_map.get(bag_topic)
                if port_topic is None:
                    continue
                if record_inputs:
                    write(bag_topic, msgtype, msg, log_time)
                stats.inputs[port_topic] += 1
                graph.deliver(None, [Output(port_topic, msg)], log_time)
                if on_step is not None:
                    on_step()
    except KeyboardInterrupt:
        stats.interrupted = True
    stats.interrupted = stats.interrupted or stop.requested
    for processor in processors:
        if isinstance(processor, Finishing):
            graph.deliver(processor, processor.finish(), log_time)
    return stats


class _StopRequest:
    """Ctrl-C during a replay, held until the input it came in has all its outputs written.

    Raised where it landed, it cut that input's outputs short (the bag held face/state but not
    face/pose of the last image, and the tracker's counts were one image ahead of the bag). A
    second signal interrupts at once, for an input that does not end.
    """

    def __init__(self) -> None:
        """No stop requested yet."""
        self.requested = False

    @contextlib.contextmanager
    def held(self) -> Iterator[None]:
        """Within the block, a signal that would raise KeyboardInterrupt requests a stop.

        SIGINT under Python's own handler, SIGTERM under the ``face-tracking`` command's; other
        handlers, and threads other than the main one, are left as they are.
        """
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
        held = [sig for sig, handler in previous.items() if handler is signal.default_int_handler]
        for sig in held:
            signal.signal(sig, self._handle)
        try:
            yield
        finally:
            for sig in held:
                signal.signal(sig, previous[sig])

    def _handle(self, _signum: int, _frame: FrameType | None) -> None:
        """Request a stop; the second time, interrupt at once.

        Raises:
            KeyboardInterrupt: at the second signal.
        """
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True


class _Graph:
    """The processors wired as their nodes would be over DDS; every output is written."""

    def __init__(
        self,
        processors: Sequence[Processor],
        write: Callable[[str, str, Any, int], None],
        wanted: frozenset[str],
        stats: ReplayStats,
        on_output: Callable[[Output, int], None] | None,
    ) -> None:
        """Keep the processors and where their outputs go (see :func:`replay`)."""
        self._output_types = {port.topic: port.msgtype for p in processors for port in p.outputs}
        # Per topic, its consumers in order and whether each defers work, found once: a
        # runtime-checkable Protocol's isinstance took 5 us, twice an image.
        self._consumers = {
            port.topic: [
                (p, isinstance(p, Deferring)) for p in processors if _consumes(p, port.topic)
            ]
            for processor in processors
            for port in processor.inputs
        }
        self._write = write
        self._wanted = wanted
        self._stats = stats
        self._on_output = on_output

    def deliver(self, source: Processor | None, messages: Sequence[Output], log_time: int) -> None:
        """Write a processor's outputs, then feed them, and what they cause, to the consumers.

        Args:
            source: the processor that produced ``messages``; None for the bag's inputs, which
                are fed but not written.
            messages: messages to route, in order.
            log_time: log time of the input that caused them, ns.
        """
        pending = deque((source, message) for message in messages)
        if source is not None:
            for message in messages:
                self._write_output(message, log_time)
        while pending:
            origin, message = pending.popleft()
            for processor, deferring in self._consumers.get(message.topic, ()):
                if processor is origin:
                    continue
                for output in _handle(processor, message, self._wanted, self._stats):
                    self._write_output(output, log_time)
                    pending.append((processor, output))
                if deferring:  # as the node, once the outputs are out
                    _guarded(processor.run_deferred, message.topic, self._stats)

    def _write_output(self, output: Output, log_time: int) -> None:
        """Write one output and report it."""
        self._write(output.topic, self._output_types[output.topic], output.msg, log_time)
        self._stats.outputs[output.topic] += 1
        if self._on_output is not None:
            self._on_output(output, log_time)


def _consumes(processor: Processor, topic: str) -> bool:
    """True if one of the processor's input ports is ``topic``."""
    return any(port.topic == topic for port in processor.inputs)


def _handle(
    processor: Processor, message: Output, wanted: frozenset[str], stats: ReplayStats
) -> list[Output]:
    """The processor's outputs for one message; a bad input is counted, not raised."""
    outputs = _guarded(
        lambda: processor.handle(message.topic, message.msg, wanted), message.topic, stats
    )
    return outputs or []


def _guarded(work: Callable[[], ResultT], topic: str, stats: ReplayStats) -> ResultT | None:
    """``work()`` for a message on ``topic``, or None once its bad input has been counted."""
    try:
        return work()
    except FaceTrackingError as error:
        stats.count_error(f'{topic}: {error}')
        return None


def _check_tracking_model(nodes: Sequence[str], bag: Path, params: OverrideParameters) -> None:
    """Refuse recognisers replayed over tracks the bag says were made with another face model.

    The recognisers read the tracks' sigma and alpha with their own ``model_file`` (the packaged
    model when not given); another model's coefficients describe other faces and expressions, so
    identities and expression events came out wrong without a word. A bag that a tracker's
    replay wrote names its model (:func:`~face_tracking_ros.io.provenance.tracked_with`); one
    without that record (a live recording) is not checked. A graph with its tracker in it feeds
    the recognisers that tracker's coefficients, under the same ``model_file``.

    Raises:
        ConfigError: naming the model the bag was tracked with.
    """
    if {MONO, STEREO} & set(nodes):
        return
    tracked_with([bag], Path(params.overrides.get(MODEL_PARAMETER) or default_model_path()))


def wire_replay(
    nodes: Sequence[str],
    bag: Path,
    params: OverrideParameters,
    remaps: Mapping[str, str],
    wanted: frozenset[str],
    topics: Mapping[str, str] | None = None,
) -> tuple[list[Processor], dict[str, str]]:
    """The nodes' processors and the bag topics they read (bag topic -> input), all checked.

    Everything :func:`replay_bag` refuses before it writes anything is refused here (a command
    that writes a file the replay then reads checks its replay so first).

    Args:
        nodes: node names (see :func:`replay_bag`).
        bag: input rosbag2 directory.
        params: the nodes' parameters.
        remaps: processor input topic -> bag topic.
        wanted: on-demand outputs to produce.
        topics: the bag's topics (name -> type); None: read here, once the processors and
            parameters are checked.

    Raises:
        BagError, ConfigError: as :func:`replay_bag`.
    """
    factory = RosbagsMessages(typestore())
    processors = [processor_factory(node)(params, factory) for node in nodes]
    params.check_all_used()
    _check_tracking_model(nodes, bag, params)
    produced = {port.topic for p in processors for port in p.outputs}
    on_demand = sorted({port.topic for p in processors for port in p.outputs if port.on_demand})
    unknown = sorted(wanted - set(on_demand))
    if unknown:
        msg = (
            f'{", ".join(unknown)}: not an on-demand output of {", ".join(nodes)} (they have '
            f'{", ".join(on_demand) or "none"})'
        )
        raise ConfigError(msg)
    # An input two nodes read (both recognisers' face/state) is one input, fed to both.
    inputs = {port.topic: port for p in processors for port in p.inputs}
    external = [port for topic, port in inputs.items() if topic not in produced]
    _check_remaps(remaps, nodes, external)
    topics = bag_topics(bag) if topics is None else topics
    topic_map = resolve_inputs(external, topics, remaps)
    if not topic_map:
        expected = ', '.join(f'{p.topic} ({p.msgtype})' for p in external)
        found = ', '.join(f'{topic} ({msgtype})' for topic, msgtype in topics.items()) or 'none'
        msg = (
            f'{bag}: no topic matches the inputs of {", ".join(nodes)}: {expected}; the bag has '
            f'{found}'
        )
        raise BagError(msg)
    _check_camera_inputs(bag, nodes, processors, topics, topic_map)
    return processors, topic_map


def fed_topic(topic_map: Mapping[str, str], port: str) -> str | None:
    """The bag topic that feeds input ``port`` in a :func:`wire_replay` topic map; None: none."""
    return next((topic for topic, fed in topic_map.items() if fed == port), None)


def _check_camera_inputs(
    bag: Path,
    nodes: Sequence[str],
    processors: Sequence[Processor],
    topics: Mapping[str, str],
    topic_map: Mapping[str, str],
) -> None:
    """Refuse a node whose camera inputs the bag feeds only in part.

    A mono bag's only image topic, matched by type to the stereo_tracker's left image, left it
    no right image to pair: the replay wrote nothing and ended with status 0. Likewise a node
    fed images but not the camera_info of a bag that has some (two of them, neither named for
    the input: a stereo bag's left and right ones): it held every image and said its camera had
    no calibration yet. (A bag without any camera_info is not refused: the tracker holds the
    images and its status says why.)

    Raises:
        BagError: naming the node, its inputs no topic feeds, the image inputs fed and by what,
            and the bag's topics of the missing inputs' kind.
    """
    fed = {port: topic for topic, port in topic_map.items()}
    for node, processor in zip(nodes, processors, strict=True):
        images = [port.topic for port in processor.inputs if port.msgtype in _IMAGE_TYPES]
        reading = ', '.join(f'{port} reads {fed[port]}' for port in images if port in fed)
        if not reading:
            continue
        for kinds, found in ((_IMAGE_TYPES, 'images'), (_CAMERA_INFO_TYPES, 'camera_info topics')):
            missing = [
                p.topic for p in processor.inputs if p.msgtype in kinds and p.topic not in fed
            ]
            present = ', '.join(t for t, kind in topics.items() if kind in kinds)
            if missing and present:
                msg = (
                    f"{bag}: no topic for the {node}'s {', '.join(missing)} ({reading}; "
                    'matched by a name ending in it, else give --remap INPUT=TOPIC); the '
                    f"bag's {found}: {present}"
                )
                raise BagError(msg)


def replay_bag(
    nodes: Sequence[str],
    bag: Path,
    out: Path,
    params: OverrideParameters,
    remaps: Mapping[str, str] | None = None,
    record_inputs: bool = False,
    progress: bool = True,
    on_output: Callable[[Output, int], None] | None = None,
    wanted: frozenset[str] = frozenset(),
    topics: Mapping[str, str] | None = None,
) -> ReplayStats:
    """Replay a bag through one node's processor, or a graph of several, into a new MCAP bag.

    Args:
        nodes: node names, e.g. ('mono_tracker', 'expression_recognizer') (see
            :data:`processing.registry.PROCESSORS`); parameters are shared by name, so
            node-specific ones can be given as ``model_file`` once for all.
        bag: input rosbag2 directory.
        out: output rosbag2 directory (must not exist); its metadata records what it was made
            from (:class:`~face_tracking_ros.io.provenance.Provenance`).
        params: the nodes' parameters (``--param name=value``).
        remaps: processor input topic -> bag topic, where the automatic match is not wanted.
        record_inputs: also copy the consumed input messages into ``out``.
        progress: show a progress bar on stderr.
        on_output: called with every output as it is produced (e.g. to print events).
        wanted: on-demand outputs to produce (e.g. 'face/overlay'); none by default.
        topics: the bag's topics (name -> type), when the caller has read them; None: read
            here.

    Returns:
        What was read, written and rejected. A bag that becomes unreadable part way (e.g.
        truncated) ends the replay early with ``stats.read_error`` set; so does one whose
        messages were not all readable (:func:`~face_tracking_ros.io.bags.read_raw`), once the
        readable ones are replayed; ``out`` stays valid.

    Raises:
        BagError: if the bag cannot be opened or no topic matches the nodes' inputs.
        ConfigError: for unknown parameters, a node without a processor, or a wanted topic
            that is not an on-demand output of the nodes.
    """
    processors, topic_map = wire_replay(nodes, bag, params, remaps or {}, wanted, topics)
    total = message_count(bag, topic_map) if progress else None  # the bar's; opens the bag
    provenance = Provenance.of(bag, nodes, params.overrides, remaps)
    out.parent.mkdir(parents=True, exist_ok=True)
    with BagWriter(out) as writer, _progress_bar(total) as step:
        stats = replay(
            processors,
            read_messages(bag, topics=list(topic_map)),
            writer.write,
            topic_map,
            record_inputs,
            on_step=step,
            on_output=on_output,
            wanted=wanted,
        )
        complete = not (stats.interrupted or stats.read_error)
        writer.set_custom_data(PROVENANCE_KEY, replace(provenance, complete=complete).text())
    for node, processor in zip(nodes, processors, strict=True):
        if isinstance(processor, Reporting):
            stats.status[node] = processor.status()
        if isinstance(processor, Warns) and (warning := processor.warning()):
            stats.warnings[node] = warning
    stats.read_topics = topic_map
    return stats


@contextlib.contextmanager
def _progress_bar(total: int | None) -> Iterator[Callable[[], None] | None]:
    """A progress bar on stderr of ``total`` messages, as its step (None: no bar).

    tqdm is imported for a bar only: its import took 27 ms of every replay.
    """
    if total is None:
        yield None
        return
    from tqdm import tqdm

    with tqdm(total=total, unit='msg') as bar:
        yield bar.update


def _next_readable(iterator: Iterator[Record], stats: ReplayStats) -> Record | None:
    """The next record, or None at the end or where the bag says it is damaged."""
    try:
        return next(iterator)
    except StopIteration:
        return None
    except BagError as error:
        stats.read_error = str(error)
        return None
